"""Recorded drives with concealed effects, for testing and benchmarking the drive discrepancy tool.

:func:`calibration_drive` is an open-loop command script that excites what a rover team
would want to identify (straight, Ackermann turns both ways, crabs both ways at 57 deg, reverse:
the manoeuvres :meth:`offline.discrepancy.drive.diagnosis.DriveRecording.identification_advice` asks
for); it is the drive a team should run to calibrate (:data:`CALIBRATION_SEGMENTS` says why each
leg is there). :func:`record_drive` runs it on :class:`offline.sim.simulator.RoverSimulator`
with a truth the believed model does not know (slope, worn wheel, steering offset, tether,
soil) and realistic sensor noise, and writes an MCAP recording with
:class:`rtctl.recording.Recorder` -- the same files a rover writes. The tool under test is
told nothing of the truth: the truth is only in the ``/sim/truth`` channel and the
metadata, which :mod:`offline.discrepancy.drive.diagnosis` never reads.

A truth set through :class:`~offline.sim.truth.Truth` fields goes through the same plant
inputs the tool's candidates set (:func:`offline.discrepancy.drive.candidates.truth_from_terms`): a
drive made that way tests parameter recovery, not discovery. :func:`record_drive` therefore
also takes a disturbance hook (contract C5), an actuator path and a sensor path, through
which ``tests/concealed_effects.py`` conceals effects with code independent of the
candidates (a cable to a fixed anchor, a terrain plane given by its normal, a misaligned
steering encoder, hub drag, a soft patch, an undulation, a gyro bias step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from rtctl.messages import Commands, Measurements
from rtctl.recording import Recorder

from ...rover.scenario import Scenario
from ...sim.actuators import ActuatorConfig
from ...sim.sensors import SensorConfig
from ...sim.simulator import RoverSimulator, TruthState
from ...sim.truth import Truth

__all__ = ["DriveSegment", "CALIBRATION_SEGMENTS", "CALIBRATION_SPEED", "calibration_drive", "record_drive", "REALISTIC_SENSORS",
           "ActuatorPath", "SensorPath"]

ActuatorPath = Callable[[Commands], Commands]
"""What the actuators really receive for the recorded commands (e.g. a misaligned steering
encoder: the servo turns to commanded + offset while the recording keeps the commands)."""
SensorPath = Callable[[Measurements, TruthState], Measurements]
"""What the rover's sensors really report, from the simulator's readings and the true state
(e.g. an IMU on undulating terrain, a gyro whose bias steps)."""

REALISTIC_SENSORS = SensorConfig(wheel_speed_noise=0.01, steer_noise=0.003, gyro_bias=0.002, gyro_noise=0.002,
                                 tilt_noise=0.003, torque_noise=0.02, pose_period=0.2, pose_noise_xy=0.003,
                                 pose_noise_heading=0.003)
"""Sensor noise of the benchmark drives: encoders 0.01 rad/s, gyro 2 mrad/s (bias 2 mrad/s, known),
IMU tilt 3 mrad, motor torque 0.02 N m (from current), a 5 Hz pose source at 3 mm / 3 mrad
(about twice the simulator's defaults)."""


@dataclass(frozen=True)
class DriveSegment:
    """Constant commands over ``[start, end)`` s: rim speed per wheel (m/s) and steer angle per wheel (rad)."""

    start: float
    end: float
    rim_speed: tuple[float, float, float, float]
    steer: tuple[float, float, float, float]
    label: str = ""


def _ackermann(radius: float, speed: float, half_length: float = 0.16, half_track: float = 0.1655
               ) -> tuple[tuple[float, float, float, float], tuple[float, float, float, float]]:
    """Rim speeds and steer angles (FR, FL, RR, RL) of a turn about a centre ``radius`` to the left
    (negative: right) of the rover's middle at centre speed ``speed``: every wheel tangent to its
    circle and turning at its own rim speed (no skid)."""
    rim, steer = [], []
    for x, y in ((half_length, -half_track), (half_length, half_track), (-half_length, -half_track), (-half_length, half_track)):
        dy = radius - y
        rim.append(speed / abs(radius) * math.hypot(x, dy))
        steer.append(math.atan2(x, dy) if radius > 0 else -math.atan2(x, -dy))
    return tuple(rim), tuple(steer)  # type: ignore[return-value]


CALIBRATION_SPEED = 0.045
"""Travel speed of the calibration drive, m/s: 1.5 times the mini rover's 3 cm/s of Table 7.2
(the rover's own limit, :class:`~offline.sim.actuators.ActuatorConfig` ``max_rim_speed``, is 0.36 m/s).

A steering offset turns the rover at a yaw rate proportional to its travel speed, while the gyro
noise that carries most of its information does not scale with speed, so its standard error falls
as 1 / speed. Measured (``python tests/bench/bench_drive_discrepancy.py steer_seeds``, 40 s drives,
:data:`REALISTIC_SENSORS`): at 3 cm/s the four offsets had standard errors 0.27-0.29 deg, honest
(rms of error / standard error 0.95 over 100 fits of 20 seeds, no bias: noise-free fits within
0.2 %), so a 3 deg offset was within 20 % only at 2.1 sigma (seed 3 missed it: 20.6 %); at
4.5 cm/s 0.19-0.21 deg (3 sigma), at 6 cm/s 0.15-0.16 deg."""

_LEFT = _ackermann(0.35, CALIBRATION_SPEED)
_RIGHT = _ackermann(-0.5, 4.0 / 3.0 * CALIBRATION_SPEED)
_V = CALIBRATION_SPEED
CALIBRATION_SEGMENTS: tuple[DriveSegment, ...] = (
    DriveSegment(0.0, 10.0, (_V,) * 4, (0.0,) * 4, "straight"),
    DriveSegment(10.0, 24.0, *_LEFT, "Ackermann left, 0.35 m radius"),
    DriveSegment(24.0, 30.0, (_V,) * 4, (0.0,) * 4, "straight"),
    DriveSegment(30.0, 40.0, (_V,) * 4, (1.0,) * 4, "crab left, 57 deg (separates the front wheels' steering)"),
    DriveSegment(40.0, 50.0, (_V,) * 4, (-1.0,) * 4, "crab right, 57 deg"),
    DriveSegment(50.0, 58.0, *_RIGHT, "Ackermann right, 0.5 m radius"),
    DriveSegment(58.0, 62.0, (2.0 / 3.0 * _V,) * 4, (0.0,) * 4, "slow straight"),
    DriveSegment(62.0, 70.0, (-_V,) * 4, (0.0,) * 4, "reverse (last: the plant has no equilibrium through a reverse-to-forward change)"),
)
"""The calibration drive (70 s, mini rover of Table 7.2; wheel order FR, FL, RR, RL), designed for
identifiability, at :data:`CALIBRATION_SPEED` (why not 3 cm/s: there).

The crabs both ways at 57 deg separate one front wheel's steering offset from the other's: on
straight and gently steered legs an offset on FL and one on FR give the same front-axle lateral
force and yaw moment; with every wheel steered at ``s`` the offset's force on the wheel at
``(x, y)`` has a body-x component and a yaw moment ``F (x cos s + y sin s)``, whose ``y`` term
flips sign between FL and FR (at 57 deg one of them has almost no moment). Measured at 3 cm/s on a 40 s
drive with :data:`REALISTIC_SENSORS` (seed 3): FL/FR Jacobian correlation 0.90 and a chi-square
separation of a 3 deg FL offset from the best FR fit of 19.6 with the former single 20 deg
crab; 0.58 and 75.7 with these crabs (joint standard errors 0.68 / 0.64 deg -> 0.34 / 0.36 deg;
``python tests/bench/bench_drive_discrepancy.py fl_fr``).

No point turn: the plant (:mod:`offline.sim.plant`) has no quasi-static equilibrium when a
wheel's speed passes through zero or the rover stands still, and a point turn from a moving
start needs the left wheels to reverse (a drive with one fails in the recording's own
simulator). For the same reason the reverse leg is last."""


def calibration_drive(duration: float | None = None, segments: tuple[DriveSegment, ...] = CALIBRATION_SEGMENTS
                      ) -> tuple[float, Callable[[float], tuple[tuple[float, ...], tuple[float, ...]]]]:
    """The command script: ``(duration, commands_at(t) -> (rim_speed, steer))``.

    ``duration`` shortens the script (default: the end of the last segment); the segments
    are time-compressed proportionally so a short drive still contains every manoeuvre.
    """
    end = segments[-1].end
    d = end if duration is None else float(duration)
    if not (math.isfinite(d) and d > 0):
        raise ValueError(f"duration must be a positive number of seconds, got {duration!r}")
    f = end / d

    def at(t: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
        ts = t * f
        for s in segments:
            if s.start <= ts < s.end:
                return s.rim_speed, s.steer
        return segments[-1].rim_speed, segments[-1].steer

    return d, at


def record_drive(path: str | Path, scenario: Scenario, truth: Truth | None = None, seed: int = 0,
                 duration: float | None = None, sensors: SensorConfig = REALISTIC_SENSORS,
                 actuators: ActuatorConfig | None = None, period: float = 0.2, sim_dt: float = 0.1,
                 disturbance: Any = None, actuator_path: ActuatorPath | None = None,
                 sensor_path: SensorPath | None = None, segments: tuple[DriveSegment, ...] = CALIBRATION_SEGMENTS) -> Path:
    """Drive the calibration script on the truth simulator and write an MCAP recording.

    The truth state goes to the ``/sim/truth`` channel (for plots and metrics only); the
    metadata names the scenario and the seed, never the truth parameters.

    Concealed effects that the truth's parameters cannot express enter through three optional
    paths, so a test can generate them with code independent of the tool's candidates:
    ``disturbance`` (the simulator's disturbance hook, contract C5: extra forces and hub
    torques, evaluated by the simulator once per step), ``actuator_path`` (the commands the
    actuators really receive; the recording keeps the commanded ones) and ``sensor_path``
    (the readings the recording keeps, from the simulator's readings and the true state).
    ``segments``: another command script (default :data:`CALIBRATION_SEGMENTS`, the mini rover's; a
    rover file's drive needs its own, one value per wheel of the file, in its order). A rover
    file's recording carries its wheel set (:class:`rtctl.recording.Recorder` ``wheels``).
    """
    d, at = calibration_drive(duration, segments)
    kw = {} if disturbance is None else {"disturbance": disturbance}
    sim = RoverSimulator(scenario, truth, actuators=actuators, sensors=sensors, dt=sim_dt, seed=seed, **kw)
    to_act: ActuatorPath = actuator_path or (lambda c: c)
    rim, steer = at(0.0)
    sim.start(to_act(Commands(0.0, 0, rim, steer)))
    n = int(round(d / period))
    wheels = sim.wheels if sim.rover_file is not None else None  # the mini rover's: recorded as before
    with Recorder(path, {"scenario": scenario.name, "seed": seed, "script": "calibration_drive",
                         "period_s": period}, truth=True, wheels=wheels) as rec:
        for k in range(n + 1):
            m = sim.measure()
            ts = sim.truth_state()
            if sensor_path is not None:
                m = sensor_path(m, ts)
            rim, steer = at(m.t)
            c = Commands(m.t, m.seq, rim, steer)
            sim.apply(to_act(c))
            rec.measurements(m)
            rec.commands(c)
            rec.truth(m.t, ts)
            if k < n:
                sim.advance(period)
    return Path(path)
