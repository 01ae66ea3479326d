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
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable

import numpy as np

from .messages import Commands, Diagnostics, Measurements

__all__ = ["TickTiming", "RunStats", "Runner"]


@dataclass(frozen=True)
class TickTiming:
    """Wall-clock durations of one tick, s."""

    feedback: float
    prepare: float

    @property
    def total(self) -> float:
        """Feedback plus preparation."""
        return self.feedback + self.prepare


@dataclass
class RunStats:
    """Timing statistics of a run.

    Attributes
    ----------
    deadline : float
        The deadline each tick is measured against, s.
    timings : list of TickTiming
    overruns : int
        Ticks whose whole step exceeded the deadline.
    late_commands : int
        Ticks whose feedback phase (measurement to command) exceeded the deadline.
    """

    deadline: float
    timings: list[TickTiming] = field(default_factory=list)
    overruns: int = 0
    late_commands: int = 0

    def summary(self) -> dict[str, float]:
        """Median, 99th percentile and maximum of feedback, preparation and total time (s)."""
        out: dict[str, float] = {"ticks": float(len(self.timings)), "overruns": float(self.overruns),
                                 "late_commands": float(self.late_commands)}
        if not self.timings:
            return out
        for name in ("feedback", "prepare", "total"):
            a = np.array([getattr(t, name) for t in self.timings])
            out[f"{name}_median"] = float(np.median(a))
            out[f"{name}_p99"] = float(np.percentile(a, 99))
            out[f"{name}_max"] = float(a.max())
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
    """

    def __init__(self, controller: Any, period: float = 0.2, deadline: float | None = None,
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep) -> None:
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"period must be finite and > 0 s, got {period}")
        self.controller = controller
        self.period = float(period)
        self.deadline = float(deadline) if deadline is not None else self.period
        self.clock, self.sleep = clock, sleep
        self.stats = RunStats(self.deadline)

    def tick(self, m: Measurements) -> tuple[Commands, Diagnostics, TickTiming]:
        """One timed tick: feedback (commands out), then preparation."""
        t0 = self.clock()
        cmd, diag = self.controller.feedback(m)
        t1 = self.clock()
        self.controller.prepare()
        t2 = self.clock()
        timing = TickTiming(t1 - t0, t2 - t1)
        self.stats.timings.append(timing)
        if timing.feedback > self.deadline:
            self.stats.late_commands += 1
        if timing.total > self.deadline:
            self.stats.overruns += 1
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
