"""Hardware-in-the-loop style runs: the controller in its own process, fed over a local
transport at the real 5 Hz clock, with its deadline misses counted.

The controller runs in a child process (``multiprocessing``, ``spawn`` by default: a clean
interpreter, as on a separate computer) built by a picklable ``factory()``. The parent holds
the clock: every ``period`` seconds it sends one :class:`rtctl.messages.Measurements` over a
pipe and waits at most until the deadline for the :class:`rtctl.messages.Commands`. A reply
that comes later is a *deadline miss*: in closed loop the plant keeps the previous commands
(as the rover's servos would), and the late reply is still collected and reported.

Two sources of measurements:

* a recording (:func:`run_hil` with ``measurements=``): open loop, the commands can then be
  compared bit for bit with the recorded ones (:func:`rtctl.replay.compare_commands`);
* a plant (``plant=``, any object with ``measure()``, ``apply(commands)`` and
  ``advance(seconds)``, e.g. :class:`offline.sim.simulator.RoverSimulator`): closed loop.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from .messages import Commands, Measurements
from .replay import step_time_stats

__all__ = ["HilReport", "run_hil", "HilError", "load_controller"]


class HilError(RuntimeError):
    """The controller process could not be started or died (the message says which)."""


def load_controller(tables: str, config: str | None = None, names: Sequence[str] | None = None) -> Any:
    """Build :class:`rtctl.controller.Controller` from files (a picklable factory for the child
    process: ``functools.partial(load_controller, "tables/index.json", "rover.toml")``).

    Parameters
    ----------
    tables : str
        A table index (``index.json``), a folder holding one, or one table file.
    config : str, optional
        Controller TOML (default: :class:`rtctl.config.ControllerConfig` defaults).
    names : sequence of str, optional
        Only these tables of the index.
    """
    from pathlib import Path

    from .config import ControllerConfig
    from .controller import Controller, load_tables_tolerant
    from .table import TableError, load_table

    p = Path(tables)
    if p.is_dir():
        p = p / "index.json"
    gaps: dict[str, str] = {}
    if p.suffix == ".json":
        loaded, gaps = load_tables_tolerant(p, names)
        if not loaded:
            raise TableError(f"{p}: no table loads: " + "; ".join(f"{k}: {v}" for k, v in gaps.items()))
    else:
        loaded = {p.stem: load_table(p)}
    cfg = ControllerConfig.from_toml(config) if config else ControllerConfig()
    return Controller(loaded, cfg, gaps)


def _serve(conn: Any, factory: Callable[[], Any]) -> None:
    """Child process: build the controller, then answer every measurement until ``None``."""
    try:
        ctl = factory()
        if hasattr(ctl, "reset"):
            ctl.reset()  # a run starts from a fresh controller, as a replay does
    except Exception as exc:  # report the cause to the parent instead of dying silently
        conn.send(("error", f"controller factory failed: {type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", None))
    while True:
        msg = conn.recv()
        if msg is None:
            break
        t0 = time.perf_counter()
        try:
            cmd, _diag = ctl.step(msg)
        except Exception as exc:
            conn.send(("error", f"controller step failed at seq {getattr(msg, 'seq', '?')}: {type(exc).__name__}: {exc}"))
            return
        conn.send(("cmd", (cmd, time.perf_counter() - t0)))
    conn.close()


@dataclass
class HilReport:
    """Outcome of a HIL run (times in s).

    Its lists hold one entry per tick of the run (``late_seqs``: per late tick), so their bound is
    the run's ``ticks``: the HIL runner is a ground-side bench harness with a given length, not
    part of the rover's loop (:class:`rtctl.runner.Runner` is, and its memory is bounded)."""

    ticks: int
    deadline_misses: int
    commands: list[Commands] = field(default_factory=list, repr=False)
    step_times: list[float] = field(default_factory=list, repr=False)
    round_trips: list[float] = field(default_factory=list, repr=False)
    late_seqs: list[int] = field(default_factory=list)
    clock_overruns: int = 0

    def stats(self, deadline: float = 0.2) -> dict[str, Any]:
        """Controller step time (measured in the child) and round-trip statistics."""
        return {"ticks": self.ticks, "deadline_misses": self.deadline_misses, "clock_overruns": self.clock_overruns,
                "step": step_time_stats(self.step_times, deadline), "round_trip": step_time_stats(self.round_trips, deadline)}


def run_hil(factory: Callable[[], Any], *, measurements: Sequence[Measurements] | None = None, plant: Any = None,
            ticks: int | None = None, period: float = 0.2, deadline: float | None = None,
            start_method: str = "spawn", startup_timeout: float = 60.0,
            until: Callable[[], bool] | None = None) -> HilReport:
    """Run the controller in its own process at the real clock.

    Parameters
    ----------
    factory : callable
        Picklable, no arguments, returns the controller (e.g. ``functools.partial``).
    measurements : sequence of Measurements, optional
        Open loop: sent one per tick.
    plant : object, optional
        Closed loop: ``measure() -> Measurements``, ``apply(Commands)``, ``advance(seconds)``.
    ticks : int, optional
        Number of ticks (default: all measurements; required with a plant).
    period, deadline : float
        Clock period and the reply deadline after sending (default: the period), s.
    start_method : str
        ``multiprocessing`` start method.
    startup_timeout : float
        Seconds allowed for the child to import and build the controller (a safety net only).
    until : callable, optional
        Checked after every tick; ``True`` ends the run early (e.g. the rover reached its goal).

    Raises
    ------
    HilError
        Neither or both sources, the child failed to start, or it reported an error.
    """
    if (measurements is None) == (plant is None):
        raise HilError("give exactly one source: measurements= (open loop) or plant= (closed loop)")
    n = ticks if ticks is not None else (len(measurements) if measurements is not None else None)
    if n is None or n < 0:
        raise HilError("ticks must be given (>= 0) with a plant")
    if measurements is not None:
        n = min(n, len(measurements))
    deadline = period if deadline is None else deadline
    ctx: Any = mp.get_context(start_method)  # typeshed's BaseContext lacks Process
    parent, child = ctx.Pipe(duplex=True)
    proc = ctx.Process(target=_serve, args=(child, factory), daemon=True, name="rtctl-controller")
    proc.start()
    child.close()
    try:
        if not parent.poll(startup_timeout):
            raise HilError(f"the controller process did not report ready within {startup_timeout:.0f} s")
        kind, info = parent.recv()
        if kind != "ready":
            raise HilError(f"controller process: {info}")
        rep = HilReport(ticks=0, deadline_misses=0)
        held: Commands | None = None
        t_next = time.perf_counter()
        for k in range(n):
            now = time.perf_counter()
            if now < t_next:
                time.sleep(t_next - now)
            elif now - t_next > period:
                rep.clock_overruns += 1  # the parent itself fell behind the clock
            t_next += period
            m = measurements[k] if measurements is not None else plant.measure()
            t_send = time.perf_counter()
            parent.send(m)
            on_time = parent.poll(max(0.0, t_send + deadline - time.perf_counter()))
            if not on_time:
                rep.deadline_misses += 1
                rep.late_seqs.append(m.seq)
                if plant is not None and held is not None:
                    plant.apply(held)  # the servos keep the last commands
            kind, info = parent.recv()  # a late reply is still collected before the next tick
            if kind != "cmd":
                raise HilError(f"controller process: {info}")
            cmd, step_s = info
            rep.round_trips.append(time.perf_counter() - t_send)
            rep.step_times.append(step_s)
            rep.commands.append(cmd)
            if plant is not None:
                if on_time:
                    plant.apply(cmd)
                    held = cmd
                plant.advance(period)
            rep.ticks += 1
            if until is not None and until():
                break
        parent.send(None)
        proc.join(timeout=5.0)
        return rep
    except (EOFError, BrokenPipeError) as exc:
        raise HilError(f"the controller process died ({type(exc).__name__}); exit code {proc.exitcode}") from None
    finally:
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=5.0)
        parent.close()
