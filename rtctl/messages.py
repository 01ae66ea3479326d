"""What crosses the controller's boundary: measurements in, commands out (SI units).

These types are the contract between the rover (or the simulator) and :mod:`rtctl`, and the
records of a drive: the recorder writes them, replay reads them back. They are frozen and
hold plain floats and tuples so a step is reproducible bit for bit. Validation of values
(type, NaN, range, staleness, order) is the controller's job, not the constructor's: a
measurement with a NaN must still be representable so it can be recorded and rejected. The
controller converts every field once at its boundary (:mod:`rtctl.inputs`: a field that is not
a finite real number of the right type -- a string, None, a bool, an int beyond the float
range -- is rejected and counted, never parsed and never an exception).

Wheel order everywhere: the tables' wheel set (:mod:`rtctl.wheel_set`, the controller's
:attr:`~rtctl.controller.Controller.wheels`): the mini rover's :data:`rtctl.layout.WHEELS` (FR, FL,
RR, RL), or a rover file's wheels in file order (N per-wheel entries).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from .layout import WHEELS

__all__ = ["WHEELS", "MODES", "FailureDeclaration", "Task", "Pose", "Measurements",
           "Commands", "Diagnostics"]

MODES: tuple[str, ...] = ("qp", "fallback", "hold")
"""What produced a tick's commands: the QP; the safe fallback (the interpolated primitive,
rate-limited) after a failed, infeasible or refused QP; or the previous commands held because
the measurement itself was rejected (duplicate, out of order, no valid time, an implausible jump
of the time stamp or sequence number: :mod:`rtctl.inputs`)."""


@dataclass(frozen=True)
class FailureDeclaration:
    """One declared actuator failure.

    Attributes
    ----------
    wheel : str
        One of ``FR``, ``FL``, ``RR``, ``RL``.
    kind : str
        A failure kind described by the loaded tables (their headers' ``failure_kinds``,
        :mod:`rtctl.failures`: rtctl has no list of its own). The optimizer's built-in kinds:
        ``steer_stuck`` (value: the angle, rad, encoder terms, or NaN meaning "at the measured
        angle"), ``rim_speed_cap`` (value: the largest rim speed, m/s), ``locked`` (omega = 0),
        ``unpowered`` (zero drive torque, the wheel turns freely), ``raised`` (no contact),
        ``torque_limit`` (value: largest drive torque magnitude, N m), ``steer_range`` (value:
        the largest steering magnitude, rad). A kind no table describes is flagged and nothing is
        imposed for it.
    value : float
        Kind-specific value (above); NaN where the kind has none.
    """

    wheel: str
    kind: str
    value: float = math.nan


@dataclass(frozen=True)
class Task:
    """The driving task the operator (or the rover's sequence engine) has set, besides
    following the line: what the rover should *do*, where :class:`FailureDeclaration` says
    what is *broken*. It comes with every measurement, so a recording carries it and the
    task may start or end mid-drive.

    Attributes
    ----------
    kind : str
        A task kind described by the loaded tables (a task table's header ``task.description``,
        written offline by the task's own class; rtctl keeps no list of kinds). The shipped
        one is ``trench``: dig a clean-sided trench with ``wheel`` (section 7.2.5, eqs.
        (7.28)-(7.29)).
    wheel : str
        One of ``FR``, ``FL``, ``RR``, ``RL``.
    value : float
        The kind's value in its described unit and range: for ``trench`` the target trench
        depth below the surface, m.

    Examples
    --------
    >>> Task("trench", "RR", 0.02)   # a 20 mm deep trench with the rear-right wheel
    Task(kind='trench', wheel='RR', value=0.02)
    """

    kind: str
    wheel: str
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
        Time stamp of the tick, s (monotonic rover clock, ``|t| <= 1e9``).
    seq : int
        Sequence number (increments by one per tick; gaps and repeats are detected). A time
        stamp and sequence number that jump implausibly from the last accepted measurement are
        rejected; a restart is taken up after a few consistent ticks (:mod:`rtctl.inputs`).
    wheel_speed : tuple of float (one per wheel)
        Encoder wheel angular speed omega per wheel, rad/s.
    steer_angle : tuple of float (one per wheel)
        Encoder steering angle per wheel, rad (positive turns the wheel's heading left).
    yaw_rate : float
        IMU (gyro) yaw rate, rad/s.
    roll, pitch : float
        IMU tilt, rad (pitch positive nose up, roll positive left side up).
    motor_torque : tuple of float (one per wheel) or None
        Drive motor torque per wheel, N m, where the rover measures it.
    pose : Pose or None
        A pose fix, if one arrived at this tick.
    failures : tuple of FailureDeclaration
        The failures declared by the rover's fault management.
    task : Task or None
        The operator's driving task (a trench to dig), None: just drive the line.
    """

    t: float
    seq: int
    wheel_speed: tuple[float, ...]
    steer_angle: tuple[float, ...]
    yaw_rate: float
    roll: float = 0.0
    pitch: float = 0.0
    motor_torque: tuple[float, ...] | None = None
    pose: Pose | None = None
    failures: tuple[FailureDeclaration, ...] = field(default_factory=tuple)
    task: Task | None = None


@dataclass(frozen=True)
class Commands:
    """Actuator commands of one tick: always finite and within the actuator limits.

    Attributes
    ----------
    t : float
        Time stamp of the measurement they answer, s.
    seq : int
        Sequence number of that measurement.
    rim_speed : tuple of float (one per wheel)
        Commanded rim speed ``omega * r_s`` per wheel, m/s.
    steer_angle : tuple of float (one per wheel)
        Commanded steering angle per wheel, rad.
    """

    t: float
    seq: int
    rim_speed: tuple[float, ...]
    steer_angle: tuple[float, ...]

    def is_valid(self, max_rim_speed: float, max_steer: float, n_wheels: int = len(WHEELS)) -> bool:
        """Finite, ``n_wheels`` entries in each vector (default the mini rover's four), within
        ``|rim_speed| <= max_rim_speed`` and ``|steer| <= max_steer``."""
        vals = (*self.rim_speed, *self.steer_angle)
        return (len(self.rim_speed) == n_wheels == len(self.steer_angle)
                and all(math.isfinite(v) for v in vals)
                and all(abs(v) <= max_rim_speed for v in self.rim_speed)
                and all(abs(v) <= max_steer for v in self.steer_angle))


@dataclass(frozen=True)
class Diagnostics:
    """What the controller did at one tick (recorded beside the commands).

    Attributes
    ----------
    t, seq : float, int
        Time stamp and sequence number of the measurement (as received; may be NaN if rejected).
    mode : str
        One of :data:`MODES`.
    reason : str
        Why the mode is not ``qp`` (empty otherwise).
    table : str
        Name of the table in use; ``table_status`` its interpolation status.
    table_status : str
        ``interpolated``, ``extrapolated``, ``nearest feasible grid point`` (see :mod:`rtctl.table`).
    operating_point : tuple of (str, float)
        Axis values the table was interpolated at (SI).
    qp_status : str
        Solver status text; ``qp_iterations`` ADMM iterations; ``qp_slack`` largest model-row slack.
    qp_iterations : int
        See ``qp_status``.
    qp_slack : float
        See ``qp_status``.
    heading_error, crosstrack_error : float
        Outer-loop errors, rad and m (positive: turn / move left).
    mz_offset, fy_offset : float
        Offsets of eqs. (7.26)-(7.27) given to the QP, N m and N (outer loop plus slip correction).
    speed_factor : float
        Operating-point shift of the table speed from the EKF's slip (1: none).
    state : tuple of 6 float
        EKF estimate (x, y, heading, slip, crab, gyro bias), :data:`rtctl.estimator.STATE`.
    state_sigma : tuple of 6 float
        Its 1-sigma uncertainties.
    pose_verdict : str
        What happened to a pose fix at this tick (``''`` if none came).
    counters : tuple of (str, int)
        Cumulative counts of rejected or down-weighted inputs and of fallbacks, sorted by name.
    crab_commanded : float
        Crab angle the commands of the previous tick asked for, rad, given to the EKF's motion
        model over this tick (:mod:`rtctl.estimator`): the rover's crab is ``state[4]`` plus it.
    flags : tuple of str
        Conditions of this tick the operator must know about, each a sentence: a declared task
        or failure value outside the table's axis (read at the nearest end), a task without a
        table, a target the table's primitives cannot reach. Empty when none.
    """

    t: float
    seq: int
    mode: str
    reason: str
    table: str
    table_status: str
    operating_point: tuple[tuple[str, float], ...]
    qp_status: str
    qp_iterations: int
    qp_slack: float
    heading_error: float
    crosstrack_error: float
    mz_offset: float
    fy_offset: float
    speed_factor: float
    state: tuple[float, ...]
    state_sigma: tuple[float, ...]
    pose_verdict: str
    counters: tuple[tuple[str, int], ...]
    crab_commanded: float = 0.0
    flags: tuple[str, ...] = ()

    def counter(self, name: str) -> int:
        """A counter's value (0 if it never counted)."""
        return dict(self.counters).get(name, 0)
