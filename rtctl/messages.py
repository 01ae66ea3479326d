"""What crosses the controller's boundary: measurements in, commands out (SI units).

These types are the contract between the rover (or the simulator) and :mod:`rtctl`, and the
records of a drive: the recorder writes them, replay reads them back. They are frozen and
hold plain floats and tuples so a step is reproducible bit for bit. Validation of values
(NaN, range, staleness, order) is the controller's job, not the constructor's: a
measurement with a NaN must still be representable so it can be recorded and rejected.

Wheel order everywhere: :data:`rtctl.layout.WHEELS` (FR, FL, RR, RL).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from .layout import WHEELS

__all__ = ["WHEELS", "FAILURE_KINDS", "FailureDeclaration", "Pose", "Measurements", "Commands"]

FAILURE_KINDS: tuple[str, ...] = ("steer_stuck", "rim_speed_cap", "locked", "unpowered", "raised", "torque_limit")
"""Failure kinds a rover can declare (see :class:`FailureDeclaration`)."""


@dataclass(frozen=True)
class FailureDeclaration:
    """One declared actuator failure.

    Attributes
    ----------
    wheel : str
        One of ``FR``, ``FL``, ``RR``, ``RL``.
    kind : str
        ``steer_stuck`` (value: the angle, rad, or NaN meaning "at the measured angle"),
        ``rim_speed_cap`` (value: the largest rim speed, m/s), ``locked`` (omega = 0),
        ``unpowered`` (zero drive torque, the wheel turns freely), ``raised`` (no contact),
        ``torque_limit`` (value: largest drive torque magnitude, N m).
    value : float
        Kind-specific value (above); NaN where the kind has none.
    """

    wheel: str
    kind: Literal["steer_stuck", "rim_speed_cap", "locked", "unpowered", "raised", "torque_limit"]
    value: float = math.nan


@dataclass(frozen=True)
class Pose:
    """A pose fix from visual odometry or a tracker (world frame, m and rad).

    ``t`` is when the pose was *taken* (it may arrive late: the measurement that carries it
    has a later time stamp).
    """

    t: float
    x: float
    y: float
    heading: float


@dataclass(frozen=True)
class Measurements:
    """Everything the controller reads at one tick.

    Attributes
    ----------
    t : float
        Time stamp of the tick, s (monotonic rover clock).
    seq : int
        Sequence number (increments by one per tick; gaps and repeats are detected).
    wheel_speed : tuple of 4 float
        Encoder wheel angular speed omega per wheel, rad/s.
    steer_angle : tuple of 4 float
        Encoder steering angle per wheel, rad (positive turns the wheel's heading left).
    yaw_rate : float
        IMU (gyro) yaw rate, rad/s.
    roll, pitch : float
        IMU tilt, rad (pitch positive nose up, roll positive left side up).
    motor_torque : tuple of 4 float or None
        Drive motor torque per wheel, N m, where the rover measures it.
    pose : Pose or None
        A pose fix, if one arrived at this tick.
    failures : tuple of FailureDeclaration
        The failures declared by the rover's fault management.
    """

    t: float
    seq: int
    wheel_speed: tuple[float, float, float, float]
    steer_angle: tuple[float, float, float, float]
    yaw_rate: float
    roll: float = 0.0
    pitch: float = 0.0
    motor_torque: tuple[float, float, float, float] | None = None
    pose: Pose | None = None
    failures: tuple[FailureDeclaration, ...] = field(default_factory=tuple)


@dataclass(frozen=True)
class Commands:
    """Actuator commands of one tick: always finite and within the actuator limits.

    Attributes
    ----------
    t : float
        Time stamp of the measurement they answer, s.
    seq : int
        Sequence number of that measurement.
    rim_speed : tuple of 4 float
        Commanded rim speed ``omega * r_s`` per wheel, m/s.
    steer_angle : tuple of 4 float
        Commanded steering angle per wheel, rad.
    """

    t: float
    seq: int
    rim_speed: tuple[float, float, float, float]
    steer_angle: tuple[float, float, float, float]

    def is_valid(self, max_rim_speed: float, max_steer: float) -> bool:
        """Finite, four wheels, within ``|rim_speed| <= max_rim_speed`` and ``|steer| <= max_steer``."""
        vals = (*self.rim_speed, *self.steer_angle)
        return (len(self.rim_speed) == len(WHEELS) == len(self.steer_angle)
                and all(math.isfinite(v) for v in vals)
                and all(abs(v) <= max_rim_speed for v in self.rim_speed)
                and all(abs(v) <= max_steer for v in self.steer_angle))
