"""Sensor models: wheel and steering encoders, gyro (bias, bias random walk and noise), IMU tilt,
motor torque, and a pose source (visual odometry or a tracker) at its own rate, with delay,
drift and dropouts.

All measurement noise comes from one seeded :class:`numpy.random.Generator`, drawn in a fixed
order each tick, so a run is reproducible bit for bit. The gyro bias random walk draws from its
own generator (seeded from the run's seed), advanced once per plant step, so switching it off
leaves every other noise sequence unchanged. The pose carries the time it was *taken*; it is
delivered ``delay`` seconds later (the controller must use it for the time it was taken).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SensorConfig", "SensorError", "PoseSource", "GyroBias", "GYRO_BIAS_WALK_ADIS16448"]

GYRO_BIAS_WALK_ADIS16448 = 1.9393e-5
"""Gyro bias random-walk density of a MEMS IMU, rad/s/sqrt(s) (= rad/s^2/sqrt(Hz)): the value
published for the ADIS16448 of the EuRoC MAV dataset (``imu0/sensor.yaml``,
``gyroscope_random_walk``; Burri et al., IJRR 2016), the usual reference value of the Kalibr IMU
noise model. The dissertation does not name the mini rover's IMU; this is a typical
industrial-grade MEMS gyro (consumer parts drift more, up to about 10x)."""


class SensorError(ValueError):
    """A sensor configuration out of range; the message names the field."""


@dataclass(frozen=True)
class SensorConfig:
    """Noise and timing of the rover's sensors (SI; standard deviations unless noted).

    Parameters
    ----------
    wheel_speed_noise : float
        Encoder wheel speed, rad/s.
    steer_noise : float
        Steering encoder, rad (AX-18A resolution 0.29 deg ~ 0.005 rad).
    gyro_bias : float
        Gyro yaw-rate bias at the start of the run, rad/s.
    gyro_noise : float
        White gyro noise per sample, rad/s.
    tilt_noise : float
        IMU roll and pitch noise, rad.
    tilt_offset : tuple of 2 float
        IMU mounting error (roll, pitch), rad.
    torque_noise : float
        Motor torque (from current), N m; ``NaN`` means no torque sensing.
    pose_period : float
        Time between pose fixes, s (``inf``: no pose source).
    pose_delay : float
        Latency from taking a pose to delivering it, s.
    pose_noise_xy, pose_noise_heading : float
        Per-fix noise, m and rad.
    pose_drift : float
        Position drift of the pose source per metre travelled (visual-odometry drift), m/m,
        along a direction drawn once per run.
    pose_heading_drift : float
        Heading drift per metre travelled, rad/m.
    pose_dropout : float
        Probability that a fix is lost.
    pose_outage : tuple of 2 float
        ``(start, end)`` of a window with no fixes, s (``(inf, inf)``: none).
    gyro_bias_walk : float
        Density of the gyro bias random walk, rad/s/sqrt(s): over ``dt`` the bias moves by
        ``gyro_bias_walk * sqrt(dt)`` times a standard normal draw (Kalibr's discrete model,
        sigma_bgd = sigma_bg sqrt(dt)). Default :data:`GYRO_BIAS_WALK_ADIS16448`; 0 keeps
        the bias constant.
    """

    wheel_speed_noise: float = 0.005
    steer_noise: float = 0.002
    gyro_bias: float = 0.002
    gyro_noise: float = 0.001
    tilt_noise: float = 0.002
    tilt_offset: tuple[float, float] = (0.0, 0.0)
    torque_noise: float = 0.01
    pose_period: float = 0.2
    pose_delay: float = 0.0
    pose_noise_xy: float = 0.002
    pose_noise_heading: float = 0.002
    pose_drift: float = 0.0
    pose_heading_drift: float = 0.0
    pose_dropout: float = 0.0
    pose_outage: tuple[float, float] = (math.inf, math.inf)
    gyro_bias_walk: float = GYRO_BIAS_WALK_ADIS16448

    def __post_init__(self) -> None:
        for name in ("wheel_speed_noise", "steer_noise", "gyro_noise", "tilt_noise", "pose_delay", "pose_noise_xy",
                     "pose_noise_heading", "pose_drift", "pose_heading_drift", "gyro_bias_walk"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise SensorError(f"SensorConfig.{name} must be finite and >= 0, got {v!r}")
        if not (self.pose_period > 0):
            raise SensorError(f"SensorConfig.pose_period must be > 0 s (inf for no pose), got {self.pose_period!r}")
        if not 0.0 <= self.pose_dropout <= 1.0:
            raise SensorError(f"SensorConfig.pose_dropout must be a probability in [0, 1], got {self.pose_dropout!r}")


class PoseSource:
    """Schedules pose fixes: taken every ``pose_period`` s, delivered ``pose_delay`` s later,
    with drift, noise, random dropouts and an outage window.

    Parameters
    ----------
    config : SensorConfig
    rng : numpy.random.Generator
        Shared with the other sensors (draws happen in a fixed order).
    """

    def __init__(self, config: SensorConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        ang = rng.uniform(-math.pi, math.pi)
        self._drift_dir = (math.cos(ang), math.sin(ang))
        self._next_take = 0.0
        self._pending: list[tuple[float, float, float, float]] = []  # (t_taken, x, y, heading)

    def take(self, t: float, x: float, y: float, heading: float, travelled: float) -> None:
        """Offer the true pose at sim time ``t`` (call every sim step); a fix is taken when due."""
        c = self.config
        if not math.isfinite(c.pose_period) or t + 1e-9 < self._next_take:
            return
        self._next_take += c.pose_period
        noise = self.rng.standard_normal(3)
        lost = self.rng.uniform() < c.pose_dropout
        if lost or c.pose_outage[0] <= t < c.pose_outage[1]:
            return
        ex = c.pose_drift * travelled * self._drift_dir[0] + c.pose_noise_xy * noise[0]
        ey = c.pose_drift * travelled * self._drift_dir[1] + c.pose_noise_xy * noise[1]
        eh = c.pose_heading_drift * travelled + c.pose_noise_heading * noise[2]
        self._pending.append((t, x + ex, y + ey, heading + eh))

    def deliver(self, t: float) -> tuple[float, float, float, float] | None:
        """The latest fix whose delivery time has come by ``t`` (older ones are superseded)."""
        ready = [p for p in self._pending if p[0] + self.config.pose_delay <= t + 1e-9]
        if not ready:
            return None
        self._pending = [p for p in self._pending if p[0] + self.config.pose_delay > t + 1e-9]
        return ready[-1]


class GyroBias:
    """The gyro's yaw-rate bias: a random walk (Brownian motion) from ``config.gyro_bias``.

    Parameters
    ----------
    config : SensorConfig
    seed : int
        Seeds the walk's own generator (``numpy.random.SeedSequence([seed, 1])``), independent
        of the measurement noise.
    """

    def __init__(self, config: SensorConfig, seed: int) -> None:
        self.density = config.gyro_bias_walk
        self.value = float(config.gyro_bias)
        self._rng = np.random.default_rng(np.random.SeedSequence([int(seed), 1]))

    def advance(self, dt: float) -> float:
        """Move the bias over ``dt`` seconds; returns the new bias, rad/s."""
        if self.density > 0.0:
            self.value += self.density * math.sqrt(dt) * float(self._rng.standard_normal())
        return self.value
