"""The controller's input boundary: every field of a measurement converted once, and the rule
that judges its time stamp and sequence number.

Conversion (:func:`read_measurements`)
--------------------------------------
:class:`rtctl.messages.Measurements` is a plain frozen dataclass: it does not check what it
holds, so a measurement may carry anything (a string, ``None``, a nested tuple, an int too
large for a float). :func:`read_measurements` turns one into an :class:`Inputs` of plain
Python floats and ints, once, at the top of :meth:`rtctl.controller.Controller.feedback`;
nothing after it sees the raw values, and nothing in it raises.

* A *real number* is an ``int``, ``float``, numpy integer or numpy floating scalar (any
  :class:`numbers.Real`) that is not a ``bool`` (nor ``numpy.bool_``), whose ``float()`` does
  not fail: ``10**400`` (an int beyond the float range) is rejected like a string, ``'1234'``
  is rejected (a string is never parsed), ``True`` is rejected. A *finite* real also is
  neither NaN nor infinite.
* ``t``: a finite real with ``|t| <= MAX_ABS_TIME`` (beyond it a float cannot resolve the
  control period: at 1e300, ``t + 0.2 == t``), else None.
* ``seq``: an ``int`` or numpy integer (not bool, not a float even if integral) with
  ``|seq| < 2**63`` (what a recording's int64 holds), else None.
* ``wheel_speed``, ``steer_angle`` (and ``motor_torque``): a tuple, list or 1-d numpy array of
  exactly one entry per wheel of the wheel set (four for the mini rover; the controller's
  tables' wheel set, :mod:`rtctl.wheel_set`), else the whole vector is rejected (None); each entry a finite real,
  else that entry is NaN (the controller takes the wheel out).
* ``yaw_rate``, ``roll``, ``pitch``: a finite real, else NaN.
* ``pose``: None, or a :class:`rtctl.messages.Pose` whose four fields are finite reals (the
  result holds plain floats); anything else is counted as an invalid pose.
* ``failures``: a tuple or list of :class:`rtctl.messages.FailureDeclaration` whose ``wheel``
  is a wheel name of the wheel set, whose ``kind`` is a string that looks like a kind's
  name (:data:`rtctl.failures.KIND_NAME`) and whose value is a real (NaN allowed: "no value";
  infinite not). Every other entry is counted and dropped; a ``failures`` field that is not a
  tuple or list counts once and declares nothing. Whether the value fits its kind (its range,
  whether the kind needs one) is judged by the controller against the kind's description in
  the tables (:mod:`rtctl.failures`).
* ``task``: None, or a :class:`rtctl.messages.Task` with a well-formed kind name, a known wheel
  and a finite value; anything else is counted and means "no task". Whether the kind is one a
  table describes, and its value within the described range, the controller checks against the
  tables' descriptions (:func:`rtctl.failures.read_task_kinds`).

Time stamps and sequence numbers (:class:`TickClock`)
-----------------------------------------------------
The controller has no clock of its own (it is pure, :mod:`rtctl.controller`); what it can
count is ticks. Its *own clock* is the last accepted measurement's time plus ``period`` per
sequence number since then. A measurement is judged against that reference (the last
*accepted* ``(t, seq)``; a rejected one never becomes the reference):

* duplicate: the same ``seq`` and ``t`` as the reference: rejected (``rejected_duplicate``);
* out of order: ``t <= t_ref`` or ``seq <= seq_ref``: rejected (``rejected_out_of_order``);
* implausible jump: with ``dt = t - t_ref`` and ``n = seq - seq_ref`` (both positive),
  rejected (``rejected_time_jump``) when the time stamp and the tick count disagree by more
  than a factor ``RATE_TOLERANCE`` plus ``SLACK_TICKS`` periods either way
  (``dt > RATE_TOLERANCE * n * period + SLACK_TICKS * period`` or
  ``n * period > RATE_TOLERANCE * dt + SLACK_TICKS * period``), or when ``dt > MAX_STEP_TIME``
  or ``n > MAX_STEP_SEQ`` even though they agree;
* anything else is accepted and becomes the reference (a gap ``n > 1`` is counted as
  ``sequence_gaps``; a ``dt`` beyond ``max_gap`` is the controller's stale gap).

Why this separates a glitch from a real gap: a real dropout of the link loses measurements
but not the rover's ticks, so ``seq`` and ``t`` advance together (50 sequence numbers in
10 s at 5 Hz): accepted at once, as a stale gap. A glitch changes one of them alone (a clock
jumped by an hour one tick after the last, a sequence number with a flipped high bit): the
two disagree by orders of magnitude and the measurement is held without moving the
reference, so the next valid measurement is judged against the last good one and accepted:
one poisoned tick costs that tick only.

A genuine discontinuity of the rover's clock or counter (a reboot restarts both near zero, a
paused process resumes with ``t`` an hour later and ``seq`` one higher, the clock is stepped
to a new epoch) looks like a glitch at its first tick, but it persists: the measurements after
it agree with *each other*. So the rejected measurements are kept (at most
``REBASE_AFTER``, a ring buffer), and when ``REBASE_AFTER`` consecutive measurements have been
rejected as out of order or as jumps and each pair of neighbours among them passes the
plausibility rule above, the newest becomes the reference (``clock_rebases``) and the
controller goes on as after a stale gap. A restart thus costs ``REBASE_AFTER - 1`` held ticks
(0.8 s at 5 Hz); an accepted measurement clears the buffer, so isolated glitches between valid
measurements never add up to a rebase.
"""

from __future__ import annotations

import math
import numbers
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .layout import WHEELS
from .failures import KIND_NAME
from .messages import FailureDeclaration, Pose, Task

__all__ = ["MAX_ABS_TIME", "MAX_ABS_SEQ", "RATE_TOLERANCE", "SLACK_TICKS", "MAX_STEP_TIME", "MAX_STEP_SEQ",
           "REBASE_AFTER", "real", "finite_real", "integer", "Inputs", "read_measurements", "TickClock",
           "safe_repr", "wheel_vector_problem"]

MAX_ABS_TIME = 1e9
"""s: largest time stamp magnitude (31 years of a monotonic clock; the float spacing there is
1.2e-7 s, far below a period)."""
MAX_ABS_SEQ = 2 ** 63
"""Sequence numbers must satisfy ``|seq| < MAX_ABS_SEQ`` (a recording stores them as int64)."""
RATE_TOLERANCE = 4.0
"""Largest ratio between the elapsed time and ``period`` times the sequence-number step (either
way) that is still a plausible measurement (a rover feeding at 10 Hz or 2.5 Hz a controller
configured for 5 Hz passes)."""
SLACK_TICKS = 2.0
"""Periods of absolute slack on top of :data:`RATE_TOLERANCE` (jitter of a single tick)."""
MAX_STEP_TIME = 600.0
"""s: longest gap between two accepted measurements taken as a continuation (a longer one
needs :data:`REBASE_AFTER` consistent measurements)."""
MAX_STEP_SEQ = 10 ** 5
"""Largest sequence-number step taken as a continuation (a :data:`MAX_STEP_TIME` gap at 5 Hz is
3,000; the bound matters at short periods only, where the rate rule allows more)."""
REBASE_AFTER = 5
"""Consecutive rejected but mutually consistent measurements after which the newest becomes the
reference (a restart or a stepped clock; 1 s at 5 Hz)."""

_MAX_REPR = 200


def safe_repr(v: Any) -> str:
    """``repr(v)`` cut to 200 characters; never raises (a huge int's repr can)."""
    try:
        s = repr(v)
    except Exception:  # noqa: BLE001 - any object may come in; the repr is only for a message
        s = f"<{type(v).__name__}>"
    return s if len(s) <= _MAX_REPR else s[:_MAX_REPR - 3] + "..."


def real(v: Any) -> float | None:
    """``float(v)`` if ``v`` is a real number (module docstring; NaN and inf allowed), else None."""
    if type(v) is float:
        return v
    if isinstance(v, (bool, np.bool_)) or not isinstance(v, numbers.Real):
        return None
    try:
        return float(v)
    except Exception:  # noqa: BLE001 - OverflowError (10**400) or a Real subclass that fails
        return None


def finite_real(v: Any) -> float:
    """``float(v)`` if ``v`` is a finite real number, else NaN."""
    f = real(v)
    return f if f is not None and math.isfinite(f) else math.nan


def integer(v: Any) -> int | None:
    """``int(v)`` if ``v`` is an int or numpy integer (not bool) with ``|v| < MAX_ABS_SEQ``, else None."""
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        return None
    i = int(v)
    return i if -MAX_ABS_SEQ < i < MAX_ABS_SEQ else None


def _per_wheel(v: Any, n: int) -> tuple[float, ...] | None:
    """``n`` finite reals (NaN where an entry is not one) from a tuple, list or 1-d array of ``n``
    (one per wheel of the wheel set); None for anything else (another count, another type)."""
    if isinstance(v, np.ndarray):
        if v.ndim != 1 or v.shape[0] != n:
            return None
        items: list[Any] = list(v)
    elif isinstance(v, (tuple, list)):
        if len(v) != n:
            return None
        items = list(v)
    else:
        return None
    return tuple(finite_real(x) for x in items)


def wheel_vector_problem(v: Any, wheels: Sequence[str]) -> str:
    """Why a per-wheel vector is rejected (count or type against the wheel set), "" if it is not.

    Parameters
    ----------
    v : any
        The raw field.
    wheels : sequence of str
        The wheel set's names, in order.
    """
    n = len(wheels)
    if isinstance(v, np.ndarray):
        if v.ndim == 1 and v.shape[0] == n:
            return ""
        return f"an array of shape {v.shape}, expected ({n},): one entry per wheel {', '.join(wheels)}"
    if isinstance(v, (tuple, list)):
        if len(v) == n:
            return ""
        return f"{len(v)} entries, expected {n}: one per wheel {', '.join(wheels)}"
    return f"a {type(v).__name__}, expected a tuple of {n} numbers (wheels {', '.join(wheels)})"


def _get(obj: Any, name: str, default: Any) -> Any:
    try:
        return getattr(obj, name, default)
    except Exception:  # noqa: BLE001 - a property of a foreign object may raise anything
        return default


@dataclass(frozen=True)
class Inputs:
    """One measurement after :func:`read_measurements` (plain floats and ints only).

    Attributes
    ----------
    t : float or None
        Time stamp, s (None: not a finite real within :data:`MAX_ABS_TIME`).
    seq : int or None
        Sequence number (None: not an integer within :data:`MAX_ABS_SEQ`).
    wheel_speed, steer_angle : tuple of float (one per wheel) or None
        Per-wheel readings (NaN: that entry rejected; None: the vector rejected).
    yaw_rate, roll, pitch : float
        NaN where rejected.
    motor_torque : tuple of float (one per wheel) or None
        As ``wheel_speed`` (None also when not measured).
    pose : Pose or None
        The fix with float fields; None when none came or it was rejected (``pose_invalid``).
    pose_invalid : bool
        A pose came but was not a :class:`Pose` of four finite reals.
    failures : tuple of FailureDeclaration
        The well-formed declarations (float values).
    rejected_failures : int
        Declarations dropped (or 1 for a ``failures`` field that is not a tuple or list).
    task : Task or None
        The well-formed task.
    rejected_task : str
        ``repr`` (cut) of a task that was rejected; empty when none was.
    """

    t: float | None
    seq: int | None
    wheel_speed: tuple[float, ...] | None
    steer_angle: tuple[float, ...] | None
    yaw_rate: float
    roll: float
    pitch: float
    motor_torque: tuple[float, ...] | None
    pose: Pose | None
    pose_invalid: bool
    failures: tuple[FailureDeclaration, ...]
    rejected_failures: int
    task: Task | None
    rejected_task: str


def _failure(f: Any, wheels: Sequence[str]) -> FailureDeclaration | None:
    if not isinstance(f, FailureDeclaration):
        return None
    w, k = _get(f, "wheel", None), _get(f, "kind", None)
    if not (isinstance(w, str) and w in wheels and isinstance(k, str) and KIND_NAME.match(k)):
        return None
    v = real(_get(f, "value", None))
    if v is None or math.isinf(v):
        return None
    return FailureDeclaration(w, k, v)


def _task(task: Any, wheels: Sequence[str]) -> Task | None:
    if not isinstance(task, Task):
        return None
    k, w = _get(task, "kind", None), _get(task, "wheel", None)
    v = finite_real(_get(task, "value", None))
    if not (isinstance(k, str) and KIND_NAME.match(k) and isinstance(w, str) and w in wheels and math.isfinite(v)):
        return None  # the kind and its value's range are checked against the tables' descriptions
    return Task(k, w, v)


def read_measurements(m: Any, wheels: Sequence[str] = WHEELS) -> Inputs:
    """Convert every field of a measurement (module docstring); never raises.

    Parameters
    ----------
    m : any
        The measurement (:class:`rtctl.messages.Measurements` or anything with its fields).
    wheels : sequence of str
        The wheel set (default the mini rover's :data:`rtctl.layout.WHEELS`): the count of every
        per-wheel vector and the names a failure or a task may name.
    """
    t = finite_real(_get(m, "t", None))
    seq = integer(_get(m, "seq", None))
    raw_pose = _get(m, "pose", None)
    pose: Pose | None = None
    pose_invalid = False
    if raw_pose is not None:
        vals = [finite_real(_get(raw_pose, k, None)) for k in ("t", "x", "y", "heading")] \
            if isinstance(raw_pose, Pose) else [math.nan]
        if all(math.isfinite(v) for v in vals):
            pose = Pose(*vals)
        else:
            pose_invalid = True
    raw_f = _get(m, "failures", ())
    fails: list[FailureDeclaration] = []
    n_bad = 0
    if isinstance(raw_f, (tuple, list)):
        for f in raw_f:
            ok = _failure(f, wheels)
            if ok is None:
                n_bad += 1
            else:
                fails.append(ok)
    else:
        n_bad = 1
    raw_task = _get(m, "task", None)
    task = _task(raw_task, wheels)
    n = len(wheels)
    return Inputs(
        t=t if abs(t) <= MAX_ABS_TIME else None, seq=seq,
        wheel_speed=_per_wheel(_get(m, "wheel_speed", None), n),
        steer_angle=_per_wheel(_get(m, "steer_angle", None), n),
        yaw_rate=finite_real(_get(m, "yaw_rate", None)), roll=finite_real(_get(m, "roll", None)),
        pitch=finite_real(_get(m, "pitch", None)), motor_torque=_per_wheel(_get(m, "motor_torque", None), n),
        pose=pose, pose_invalid=pose_invalid, failures=tuple(fails), rejected_failures=n_bad, task=task,
        rejected_task="" if raw_task is None or task is not None else safe_repr(raw_task))


def plausible_step(dt: float, n: int, period: float) -> bool:
    """Whether a step of ``dt`` seconds and ``n`` sequence numbers (both > 0) is a plausible
    continuation at the control ``period`` (module docstring)."""
    if not (dt > 0 and n > 0) or dt > MAX_STEP_TIME or n > MAX_STEP_SEQ:
        return False
    slack = SLACK_TICKS * period
    return dt <= RATE_TOLERANCE * n * period + slack and n * period <= RATE_TOLERANCE * dt + slack


@dataclass
class TickClock:
    """The time and sequence-number rule of the module docstring.

    Parameters
    ----------
    period : float
        The control period, s.

    Attributes
    ----------
    t, seq : float or None, int or None
        The reference: the last accepted measurement (None before the first).
    candidates : deque of (float, int)
        The last rejected measurements since the last accepted one (bound: :data:`REBASE_AFTER`).
    """

    period: float
    t: float | None = field(default=None, init=False)
    seq: int | None = field(default=None, init=False)
    candidates: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=REBASE_AFTER), init=False)

    def judge(self, t: float, seq: int) -> str:
        """Verdict on a measurement with a valid ``t`` and ``seq``: ``first``, ``ok``, ``gap``
        (accepted, sequence numbers skipped), ``rebase`` (accepted as the new reference after a
        run of consistent rejected ones), or ``duplicate``, ``out_of_order``, ``jump``
        (rejected, the reference unchanged). Accepted verdicts move the reference."""
        if self.t is None or self.seq is None:
            self._accept(t, seq)
            return "first"
        if seq == self.seq and t == self.t:
            return "duplicate"
        dt, n = t - self.t, seq - self.seq
        if dt > 0 and n > 0 and plausible_step(dt, n, self.period):
            self._accept(t, seq)
            return "ok" if n == 1 else "gap"
        verdict = "out_of_order" if (dt <= 0 or n <= 0) else "jump"
        c = self.candidates
        if c and not plausible_step(t - c[-1][0], seq - c[-1][1], self.period):
            c.clear()
        c.append((t, seq))
        if len(c) >= REBASE_AFTER:
            self._accept(t, seq)
            return "rebase"
        return verdict

    def _accept(self, t: float, seq: int) -> None:
        self.t, self.seq = t, seq
        self.candidates.clear()
