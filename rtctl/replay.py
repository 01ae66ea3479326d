"""Replay a recorded drive through the controller and compare its commands bit for bit.

The controller is pure (``step(measurements) -> (commands, diagnostics)``, no clock, no
randomness), so feeding a recording's measurements to a freshly built controller must give
the recorded commands *exactly*: any change in the controller's code, tables or configuration
that alters its output shows up as a divergence, reported at its first occurrence (time,
sequence number, wheel, field, both values) with the step-time statistics of the replay.

Bit for bit holds on the machine and library versions that recorded the drive. On another
architecture (or numpy, osqp, Python) the last bits of a float may differ, and a warm-started
QP amplifies that up to its own tolerance; the tolerance mode (``rtol``/``atol``, ``offnominal
replay --rtol/--atol``) then reports the first command that differs by more than
``atol + rtol * |recorded|`` and the largest difference seen. Bit-exact stays the default.
A recording's provenance (:func:`rtctl.recording.compare_provenance`) says which of the two
applies.

Usage::

    rec = read_recording("drive.mcap")
    report = replay(rec, Controller(tables, config))
    print(report.summary())
"""

from __future__ import annotations

import math
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .layout import WHEELS
from .messages import Commands
from .recording import Recording, read_recording

__all__ = ["Divergence", "ReplayReport", "replay", "compare_commands", "step_time_stats", "ReplayError"]


class ReplayError(ValueError):
    """A recording that cannot be replayed (no measurements, commands missing)."""


@dataclass(frozen=True)
class Divergence:
    """Where a replayed command first differs from the recorded one."""

    index: int
    t: float
    seq: int
    wheel: str
    field: str
    recorded: float
    replayed: float

    def __str__(self) -> str:
        return (f"tick {self.index} (t = {self.t:.3f} s, seq {self.seq}): {self.wheel} {self.field} recorded "
                f"{self.recorded!r}, replayed {self.replayed!r} (difference {self.replayed - self.recorded:.3g})")


def _bits(x: float) -> bytes:
    return struct.pack("<d", float(x))


def _differ(x: float, y: float, rtol: float | None, atol: float | None) -> bool:
    if rtol is None and atol is None:
        return _bits(x) != _bits(y)
    if math.isnan(x) or math.isnan(y):
        return math.isnan(x) != math.isnan(y)
    return not abs(y - x) <= (atol or 0.0) + (rtol or 0.0) * abs(x)


def compare_commands(index: int, recorded: Commands, replayed: Commands, rtol: float | None = None,
                     atol: float | None = None, wheels: Sequence[str] = WHEELS) -> Divergence | None:
    """First field (rim speed then steering angle, wheels in order) whose bits differ (or, with
    ``rtol``/``atol``, that differs by more than ``atol + rtol * |recorded|``); ``t`` and ``seq``
    must match exactly (reported as field ``t`` / ``seq`` on wheel ``-``); a different number of
    wheels is a divergence of field ``<name> count``. ``wheels`` names the entries (default the
    mini rover's; a recording's :attr:`rtctl.recording.Recording.wheels`)."""
    if recorded.seq != replayed.seq:
        return Divergence(index, recorded.t, recorded.seq, "-", "seq", float(recorded.seq), float(replayed.seq))
    if _bits(recorded.t) != _bits(replayed.t):
        return Divergence(index, recorded.t, recorded.seq, "-", "t", recorded.t, replayed.t)
    for name in ("rim_speed", "steer_angle"):
        a, b = getattr(recorded, name), getattr(replayed, name)
        if len(a) != len(b):
            return Divergence(index, recorded.t, recorded.seq, "-", f"{name} count", float(len(a)), float(len(b)))
        names = list(wheels) if len(wheels) == len(a) else [str(i) for i in range(len(a))]
        for w, x, y in zip(names, a, b):
            if _differ(float(x), float(y), rtol, atol):
                return Divergence(index, recorded.t, recorded.seq, w, name, float(x), float(y))
    return None


def _largest_difference(recorded: Commands, replayed: Commands) -> float:
    d = [abs(float(y) - float(x)) for name in ("rim_speed", "steer_angle")
         for x, y in zip(getattr(recorded, name), getattr(replayed, name))]
    return max(d) if d else 0.0


def step_time_stats(seconds: Sequence[float], deadline: float = 0.2) -> dict[str, float]:
    """Median, p99 and max step time (s) and the number of steps over ``deadline``."""
    if not seconds:
        return {"steps": 0, "median_s": math.nan, "p99_s": math.nan, "max_s": math.nan, "over_deadline": 0}
    a = np.asarray(seconds, dtype=float)
    return {"steps": int(a.size), "median_s": float(np.median(a)), "p99_s": float(np.percentile(a, 99)),
            "max_s": float(a.max()), "over_deadline": int(np.sum(a > deadline))}


@dataclass
class ReplayReport:
    """Outcome of a replay."""

    steps: int
    identical: bool
    first_divergence: Divergence | None
    diverged_steps: int
    step_times: dict[str, float]
    commands: list[Commands] = field(default_factory=list, repr=False)
    rtol: float | None = None
    """The tolerance mode's relative tolerance (None with ``atol``: bit for bit)."""
    atol: float | None = None
    """The tolerance mode's absolute tolerance (None with ``rtol``: bit for bit)."""
    largest_difference: float = 0.0
    """Largest absolute difference of a command (rim speed m/s, steering rad) over the replay."""
    bit_identical_steps: int = 0
    """Steps whose commands are identical bit for bit."""

    @property
    def tolerant(self) -> bool:
        """Whether the comparison used a tolerance."""
        return self.rtol is not None or self.atol is not None

    def summary(self) -> str:
        """One paragraph for a terminal."""
        st = self.step_times
        if self.tolerant:
            tol = f"within rtol {self.rtol or 0:g}, atol {self.atol or 0:g}"
            head = (f"{self.steps} steps replayed: commands equal {tol} ({self.bit_identical_steps} of them bit for bit; "
                    f"largest difference {self.largest_difference:.3g})" if self.identical else
                    f"{self.steps} steps replayed: {self.diverged_steps} differ beyond rtol {self.rtol or 0:g}, atol "
                    f"{self.atol or 0:g}; first: {self.first_divergence}")
        else:
            head = (f"{self.steps} steps replayed: commands identical bit for bit" if self.identical else
                    f"{self.steps} steps replayed: {self.diverged_steps} differ; first: {self.first_divergence} "
                    f"(largest difference {self.largest_difference:.3g})")
        return (f"{head}\nstep time median {1e6 * st['median_s']:.0f} us, p99 {1e6 * st['p99_s']:.0f} us, "
                f"max {1e6 * st['max_s']:.0f} us, {st['over_deadline']} over the deadline")


def replay(recording: Recording | str | Path, controller: Any, reset: bool = True, deadline: float = 0.2,
           rtol: float | None = None, atol: float | None = None) -> ReplayReport:
    """Feed every recorded measurement to ``controller`` and compare its commands with the recorded ones.

    Parameters
    ----------
    recording : Recording or path
    controller : object with ``step(m) -> (Commands, diagnostics)`` (and ``reset()``)
        Built the same way as the one that made the recording (same tables and config).
    reset : bool
        Call ``controller.reset()`` first (a recording starts from a fresh controller).
    deadline : float
        Step-time budget for the statistics, s.
    rtol, atol : float, optional
        Tolerance mode (module docstring): a command differs when ``|replayed - recorded| >
        atol + rtol * |recorded|``; both None (the default): bit for bit.

    Raises
    ------
    ReplayError
        No measurements, fewer commands than measurements, a negative or non-finite tolerance, or
        a controller whose wheel set is not the recording's.
    """
    for name, tol in (("rtol", rtol), ("atol", atol)):
        if tol is not None and not (math.isfinite(tol) and tol >= 0):
            raise ReplayError(f"{name} must be finite and >= 0, got {tol}")
    rec = read_recording(recording) if isinstance(recording, (str, Path)) else recording
    if not rec.measurements:
        raise ReplayError(f"{rec.path or 'recording'}: no measurements to replay")
    if len(rec.commands) < len(rec.measurements):
        raise ReplayError(f"{rec.path or 'recording'}: {len(rec.measurements)} measurements but only "
                          f"{len(rec.commands)} commands; was the recorder fed every tick?")
    ctl_wheels = getattr(controller, "wheels", None)
    if isinstance(ctl_wheels, tuple) and ctl_wheels != rec.wheels:
        raise ReplayError(f"{rec.path or 'recording'}: recorded with wheels {', '.join(rec.wheels)}, but the controller "
                          f"drives {', '.join(ctl_wheels)}: replay it with the tables of the recorded rover")
    if reset and hasattr(controller, "reset"):
        controller.reset()
    first: Divergence | None = None
    n_div = n_bits = 0
    largest = 0.0
    times: list[float] = []
    out: list[Commands] = []
    for i, (m, c) in enumerate(zip(rec.measurements, rec.commands)):
        t0 = time.perf_counter()
        cmd, _diag = controller.step(m)
        times.append(time.perf_counter() - t0)
        out.append(cmd)
        d = compare_commands(i, c, cmd, rtol, atol, rec.wheels)
        if d is not None:
            n_div += 1
            first = first or d
        if compare_commands(i, c, cmd, wheels=rec.wheels) is None:
            n_bits += 1
        elif d is None or d.field not in ("t", "seq"):
            largest = max(largest, _largest_difference(c, cmd))
    return ReplayReport(len(out), n_div == 0, first, n_div, step_time_stats(times, deadline), out, rtol, atol,
                        largest, n_bits)
