"""Actuator models: steering servos with rate and position limits, wheel-speed servos with a
first-order lag and a torque limit, and the injected failures (stuck, capped, locked,
unpowered, raised).

The mini rover's Dynamixel servos close their own position and speed loops far faster than
the 5 Hz controller (section 7.3); what the controller sees of them is a rate-limited
steering angle, a lagging wheel speed, and a torque ceiling beyond which the wheel slows.

Wheel-speed servo with wheel inertia: the lag acts on the speed *reference*
(``omega_servo``, first order with ``wheel_lag``, exact exponential per step); the speed loop
itself (closed inside the Dynamixel at kHz rates) is modelled as stiff: the wheel follows the
reference exactly while the torque this takes, ``J (omega - omega_prev)/dt`` plus the soil's
and any hub drag's torque, stays within the limit. Beyond it the motor gives its limit torque
and the wheel's speed follows its spin dynamics (:mod:`offline.sim.plant`); the reference
is then reset to the speed reached (no wind-up). So a free wheel's step response is the
first-order lag while its acceleration torque is below the limit, and a ramp at
``T_limit / J`` while not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ..rover.scenario import WheelFailure

__all__ = ["ActuatorConfig", "Actuators", "ActuatorError", "WHEELS"]

WHEELS = ("FR", "FL", "RR", "RL")


class ActuatorError(ValueError):
    """An actuator configuration or failure the simulator cannot represent."""


@dataclass(frozen=True)
class ActuatorConfig:
    """Actuator limits (SI).

    Parameters
    ----------
    steer_rate_max : float
        Steering servo slew rate, rad/s.
    steer_limit : float
        Steering range +-, rad.
    wheel_lag : float
        Time constant of the wheel-speed servo, s.
    torque_limit : float
        Largest drive torque magnitude of a healthy motor, N m.
    max_rim_speed : float
        Largest commanded rim speed, m/s (the optimizer's bound: 12x the travel speed).
    """

    steer_rate_max: float = 1.0
    steer_limit: float = math.pi / 2
    wheel_lag: float = 0.05
    torque_limit: float = 1.5
    max_rim_speed: float = 0.36

    def __post_init__(self) -> None:
        for name in ("steer_rate_max", "steer_limit", "torque_limit", "max_rim_speed"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ActuatorError(f"ActuatorConfig.{name} must be finite and > 0, got {v!r}")
        if not (math.isfinite(self.wheel_lag) and self.wheel_lag >= 0):
            raise ActuatorError(f"ActuatorConfig.wheel_lag must be >= 0 s, got {self.wheel_lag!r}")


@dataclass
class Actuators:
    """Servo states of the wheels (four for the mini rover, a rover file's wheel set) and the failures acting on them.

    Parameters
    ----------
    config : ActuatorConfig
    failures : mapping of wheel name to WheelFailure
        Injected failures (from the scenario file); at most one raised wheel.
    rs_nominal : float
        Shearing radius the rover software uses to turn a rim-speed command into a wheel
        speed (``omega = rim / r_s``): a worn wheel of the truth still gets this conversion.
    steer, omega_servo : ndarray, shape (N,)
        Servo states (rad, rad/s), zero at the start.
    steer_cmd, omega_cmd : ndarray, shape (N,)
        The latched commands (rad, rad/s), zero at the start.
    wheels : tuple of str
        Wheel names in layout order (default: the mini rover's FR, FL, RR, RL).
    """

    config: ActuatorConfig
    failures: Mapping[str, WheelFailure]
    rs_nominal: float
    steer: NDArray[np.float64] = field(default_factory=lambda: np.zeros(4))
    omega_servo: NDArray[np.float64] = field(default_factory=lambda: np.zeros(4))
    steer_cmd: NDArray[np.float64] = field(default_factory=lambda: np.zeros(4))
    omega_cmd: NDArray[np.float64] = field(default_factory=lambda: np.zeros(4))
    wheels: tuple[str, ...] = WHEELS
    """Wheel names in layout order (a rover file's; the mini rover's FR, FL, RR, RL by default)."""

    def __post_init__(self) -> None:
        n = len(self.wheels)
        if n != 4:  # the servo state vectors follow the wheel set
            self.steer, self.omega_servo = np.zeros(n), np.zeros(n)
            self.steer_cmd, self.omega_cmd = np.zeros(n), np.zeros(n)
        for k, f in self.failures.items():
            if k not in self.wheels:
                raise ActuatorError(f"failure on unknown wheel {k!r}; use one of {list(self.wheels)}")
        if sum(bool(f.raised) for f in self.failures.values()) > 1:
            raise ActuatorError("more than one raised wheel: a 4-wheel rover cannot stand on two wheels")

    def contact(self) -> NDArray[np.float64]:
        """Ground contact per wheel: 1 on the ground, 0 raised."""
        return np.array([0.0 if self.failure(i).raised else 1.0 for i in range(len(self.wheels))])

    def failure(self, i: int) -> WheelFailure:
        """The failure on wheel ``i`` (nominal when none)."""
        return self.failures.get(self.wheels[i], WheelFailure())

    def command(self, rim_speed: tuple[float, ...], steer: tuple[float, ...]) -> None:
        """Latch new commands (clipped to the actuator limits, non-finite values ignored)."""
        c = self.config
        for i in range(len(self.wheels)):
            s, w = float(steer[i]), float(rim_speed[i])
            if math.isfinite(s):
                self.steer_cmd[i] = min(max(s, -c.steer_limit), c.steer_limit)
            if math.isfinite(w):
                w = min(max(w, -c.max_rim_speed), c.max_rim_speed)
                f = self.failure(i)
                if math.isfinite(f.rim_speed_max):
                    w = min(w, f.rim_speed_max)
                if f.locked:
                    w = 0.0
                self.omega_cmd[i] = w / self.rs_nominal

    def reset(self, rim_speed: tuple[float, ...], steer: tuple[float, ...]) -> None:
        """Start with the servos settled at these commands (stuck wheels at their stuck angle)."""
        self.command(rim_speed, steer)
        self.steer = self.steer_cmd.copy()
        for i in range(len(self.wheels)):
            f = self.failure(i)
            if f.steer_stuck is not None:
                self.steer[i] = f.steer_stuck
        self.omega_servo = self.omega_cmd.copy()

    def advance(self, dt: float) -> None:
        """Move the servos over ``dt``: steering at most ``steer_rate_max dt``, wheel speed by the lag."""
        c = self.config
        step = c.steer_rate_max * dt
        for i in range(len(self.wheels)):
            if self.failure(i).steer_stuck is None:
                self.steer[i] += min(max(self.steer_cmd[i] - self.steer[i], -step), step)
        decay = math.exp(-dt / c.wheel_lag) if c.wheel_lag > 0 else 0.0
        self.omega_servo = self.omega_cmd + (self.omega_servo - self.omega_cmd) * decay

    def drive_modes(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per wheel: speed mode (1) or torque mode (0), and the fixed motor torque in torque mode."""
        mode, torque = np.ones(len(self.wheels)), np.zeros(len(self.wheels))
        for i in range(len(self.wheels)):
            if self.failure(i).unpowered:
                mode[i], torque[i] = 0.0, 0.0
        return mode, torque

    def torque_limit(self, i: int) -> float:
        """Torque ceiling of wheel ``i`` (a torque-limit failure lowers it; a lock holds any torque)."""
        f = self.failure(i)
        if f.locked:
            return math.inf
        return min(self.config.torque_limit, f.torque_limit)
