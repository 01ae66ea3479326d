"""The 5 Hz runner: supplies the clock the controller does not have, times every tick.

:class:`Runner` feeds measurements to a :class:`rtctl.controller.Controller` one tick at a
time, runs the feedback phase (measurement -> commands) and then the preparation phase for the
next tick, and measures both against the deadline (200 ms at 5 Hz). A tick whose feedback phase
or whole step (feedback + preparation) exceeds the deadline is an overrun and is counted; the
commands of a late tick are still delivered (the caller decides what a late command means on
its vehicle). With ``realtime=True`` it paces the ticks on the wall clock (sleeping to the next
period boundary); with ``realtime=False`` it runs as fast as it can (replay, benchmarks).

The clock and the sleep are injectable, so the bookkeeping is testable without timing.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, Iterable

import numpy as np

from .messages import Commands, Diagnostics, Measurements

__all__ = ["WINDOW", "TickTiming", "RunStats", "Runner"]


@dataclass(frozen=True)
class TickTiming:
    """Wall-clock durations of one tick, s."""

    feedback: float
    prepare: float

    @property
    def total(self) -> float:
        """Feedback plus preparation."""
        return self.feedback + self.prepare


WINDOW = 3000
"""Ticks whose timings :class:`RunStats` keeps for its percentiles (10 min at 5 Hz)."""


class RunStats:
    """Timing statistics of a run, in bounded memory.

    Counts, sums and maxima are kept over the whole run (a few numbers, whatever its length);
    the medians and 99th percentiles are over the last ``window`` ticks, kept in a ring buffer
    (``window`` :class:`TickTiming` objects at most: 3000 by default, about 0.4 MB). An 8-hour
    drive at 5 Hz thus holds the same memory as a 10-minute one (it kept 144 B per tick, 21 MB
    over 8 hours, before issue 25).

    Parameters
    ----------
    deadline : float
        The deadline each tick is measured against, s.
    window : int
        Ticks kept for the percentiles (>= 1).

    Attributes
    ----------
    timings : deque of TickTiming
        The last ``window`` ticks' timings (bound: ``window``).
    ticks : int
        Ticks of the whole run.
    overruns : int
        Ticks whose whole step exceeded the deadline.
    late_commands : int
        Ticks whose feedback phase (measurement to command) exceeded the deadline.
    """

    def __init__(self, deadline: float, window: int = WINDOW) -> None:
        if not (isinstance(window, int) and window >= 1):
            raise ValueError(f"window must be an integer >= 1, got {window!r}")
        self.deadline = float(deadline)
        self.window = window
        self.timings: deque[TickTiming] = deque(maxlen=window)
        self.ticks = 0
        self.overruns = 0
        self.late_commands = 0
        self._sum = {"feedback": 0.0, "prepare": 0.0, "total": 0.0}
        self._max = {"feedback": 0.0, "prepare": 0.0, "total": 0.0}

    def add(self, timing: TickTiming) -> None:
        """Count one tick's timing against the deadline."""
        self.timings.append(timing)
        self.ticks += 1
        for name, v in (("feedback", timing.feedback), ("prepare", timing.prepare), ("total", timing.total)):
            self._sum[name] += v
            if v > self._max[name]:
                self._max[name] = v
        if timing.feedback > self.deadline:
            self.late_commands += 1
        if timing.total > self.deadline:
            self.overruns += 1

    def summary(self) -> dict[str, float]:
        """Ticks, overruns and late commands, and per phase (feedback, prepare, total) the mean and
        maximum over the whole run and the median and 99th percentile over the last ``window``
        ticks (s)."""
        out: dict[str, float] = {"ticks": float(self.ticks), "overruns": float(self.overruns),
                                 "late_commands": float(self.late_commands), "window": float(len(self.timings))}
        if not self.ticks:
            return out
        for name in ("feedback", "prepare", "total"):
            a = np.array([getattr(t, name) for t in self.timings])
            out[f"{name}_median"] = float(np.median(a))
            out[f"{name}_p99"] = float(np.percentile(a, 99))
            out[f"{name}_max"] = self._max[name]
            out[f"{name}_mean"] = self._sum[name] / self.ticks
        return out


class Runner:
    """Run a controller at a fixed period and time it.

    Parameters
    ----------
    controller
        Anything with ``feedback(m) -> (Commands, Diagnostics)`` and ``prepare()``.
    period : float
        Tick period, s (0.2 for 5 Hz).
    deadline : float, optional
        Deadline per tick, s (default: the period).
    clock, sleep : callables
        Monotonic clock (s) and sleep; default :func:`time.perf_counter` and :func:`time.sleep`.
    window : int, optional
        Ticks kept for the timing percentiles (:class:`RunStats`; memory is bounded by it).
    """

    def __init__(self, controller: Any, period: float = 0.2, deadline: float | None = None,
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep,
                 window: int = WINDOW) -> None:
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"period must be finite and > 0 s, got {period}")
        self.controller = controller
        self.period = float(period)
        self.deadline = float(deadline) if deadline is not None else self.period
        self.clock, self.sleep = clock, sleep
        self.stats = RunStats(self.deadline, window)

    def tick(self, m: Measurements) -> tuple[Commands, Diagnostics, TickTiming]:
        """One timed tick: feedback (commands out), then preparation."""
        t0 = self.clock()
        cmd, diag = self.controller.feedback(m)
        t1 = self.clock()
        self.controller.prepare()
        t2 = self.clock()
        timing = TickTiming(t1 - t0, t2 - t1)
        self.stats.add(timing)
        return cmd, diag, timing

    def run(self, source: Iterable[Measurements], sink: Callable[[Commands, Diagnostics], None] | None = None,
            realtime: bool = True) -> RunStats:
        """Run every measurement of ``source`` through the controller; ``sink`` gets the outputs.

        With ``realtime`` the ticks start on the period grid of the clock (a tick that overran
        makes the next one start at once, not two at a time).
        """
        next_start = self.clock()
        for m in source:
            if realtime:
                wait = next_start - self.clock()
                if wait > 0:
                    self.sleep(wait)
            cmd, diag, _ = self.tick(m)
            if sink is not None:
                sink(cmd, diag)
            next_start = max(next_start + self.period, self.clock()) if realtime else next_start
        return self.stats
