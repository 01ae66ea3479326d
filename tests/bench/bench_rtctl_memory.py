"""Issue 25, bounded memory and time: an 8-hour drive at 5 Hz (144,000 ticks), simulated.

The controller runs in closed loop with the kinematic truth of ``bench_rtctl.py timing`` (noisy
encoders and gyro, a pose every 1 s arriving 0.4 s late; with the shipped tables the RR steering
is declared stuck in alternate blocks of 2000 ticks, so the table switches) under
:class:`rtctl.runner.Runner` (timed on this thread's CPU clock, ``time.thread_time``: the
controller's own cost, not the other jobs' on the shared machine). From tick 20,000 to 21,999
every tick brings a pose fix that the gate rejects, jumping back and forth by 3 m so that the
rejected fixes never agree (no pose reset): the case where the estimator's list of rejected
fixes grew without bound.

Measured:

* resident memory (``/proc/self/statm``) every 1000 ticks: its growth from tick 10,000 to the
  end, and a least-squares slope;
* the sizes of the controller's, estimator's and runner's buffers and the number of objects the
  garbage collector tracks, at tick 10,000 and at the end;
* allocation per tick with :mod:`tracemalloc`, on two windows of 1000 ticks (ticks 10,000-10,999
  and the 1000 ticks before the last 10,000; tracing is off elsewhere, so it does not slow the
  timed windows): the peak of traced memory within a tick above its level before the tick
  (transient allocation) and the net change over the tick (retained);
* step time (feedback + preparation, thread CPU): median and 99th percentile over the first
  10,000 and the last 10,000 ticks, the trend over the run, and, after it, the aged controller
  against a fresh one stepping in turn on the same measurements (the comparison the shared
  machine's varying load cannot spoil).

Writes ``tests/bench/results_rtctl_memory.md``::

    nice python tests/bench/bench_rtctl_memory.py [--steps 144000] [--out FILE]

``--allocation [--baseline REV]`` measures only the allocation per tick, for this tree and for
rtctl as of git revision ``REV`` (exported with ``git archive``; the same script, tables and
drive), each in its own process, in the same run: ``--ticks`` ticks of the drive above (without
the rejected fixes), the last 1000 traced, each tick's transient peak split into its two
phases (``Controller.feedback``, then ``Controller.prepare``, which is ``step``), and in a
second pass the peak of every ``Table.at`` call alone. Writes
``tests/bench/results_rtctl_memory_allocation.md``::

    nice python tests/bench/bench_rtctl_memory.py --allocation --baseline 4af126b
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Iterator

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
if os.environ.get("BENCH_RTCTL_ROOT"):  # --allocation's baseline worker: rtctl from an exported revision
    sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()]  # the editable install's finder
    sys.path.insert(0, str(HERE.parents[1]))  # offline and the tables from this tree
    sys.path.insert(0, os.environ["BENCH_RTCTL_ROOT"])  # rtctl from the baseline, first

import bench_rtctl as B  # noqa: E402
from offline.files import write_text  # noqa: E402
from rtctl.config import ControllerConfig  # noqa: E402
from rtctl.controller import Controller  # noqa: E402
from rtctl.messages import FailureDeclaration, Measurements, Pose  # noqa: E402
from rtctl.runner import Runner  # noqa: E402

PAGE = os.sysconf("SC_PAGE_SIZE")
AGED_TICKS = 6000
"""Ticks of the interleaved aged-versus-fresh comparison after the run (the first tenth not counted)."""


def rss_kb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE / 1024


def buffers(ctl: Controller, runner: Runner) -> dict[str, int]:
    """Sizes of every container the controller, its estimator and the runner keep across ticks."""
    ekf = ctl.ekf
    out = {"ekf history": len(ekf._history), "ekf rejected fixes": len(ekf._rejected),
           "controller counters": len(ctl._counters), "controller real-time iterations": len(ctl._rtis),
           "runner timings": len(runner.stats.timings)}
    clock = getattr(ctl, "_clock", None)
    if clock is not None:
        out["tick clock candidates"] = len(clock.candidates)
    out["gc-tracked objects"] = len(gc.get_objects())
    return out


_OWN = ("*/rtctl/runner.py", "*/bench_rtctl_memory.py", "*/tracemalloc.py")
"""Allocations not counted as kept by the controller: the runner's ring buffer of the last 3000
timings (bounded; during a 1000-tick window it replaces untraced entries with traced ones, which
looks like growth), this script's own lists, tracemalloc's."""


def _kept(snap: tracemalloc.Snapshot) -> tuple[int, list[str]]:
    """Bytes still alive at the end of a tracing window that were allocated in it, outside
    :data:`_OWN`, and the three largest allocation sites."""
    snap = snap.filter_traces([tracemalloc.Filter(False, f) for f in _OWN])
    stats = snap.statistics("lineno")
    top = [f"{s.traceback[0].filename.split('site-packages/')[-1].split('wt-i25/')[-1]}:{s.traceback[0].lineno} "
           f"({s.size} B in {s.count})" for s in stats[:3]]
    return sum(s.size for s in stats), top


def _drive_measurements(n: int, tables: dict) -> "Iterator[Measurements]":
    """The drive of :func:`main` without the rejected fixes, open loop on the commands of a
    controller that the caller steps (``send`` the commands back; None: the last ones)."""
    from test_rtctl_controller import ROCKER, RS, TRACK

    rng = np.random.default_rng(1)
    x, y, psi, slip = 0.0, -0.05, math.radians(5.0), 0.2
    rim, steer = np.full(4, 0.03 / 0.9), np.zeros(4)
    pending: list[tuple[int, Pose]] = []
    for k in range(n):
        t = 0.2 * k
        v = float(np.mean(rim * np.cos(steer))) * (1 - slip)
        r = (((rim[0] + rim[2]) - (rim[1] + rim[3])) / 2 / TRACK * (1 - slip)
             + v * (math.tan((steer[0] + steer[1]) / 2) - math.tan((steer[2] + steer[3]) / 2)) / ROCKER)
        if k:
            x += 0.2 * v * math.cos(psi)
            y += 0.2 * v * math.sin(psi)
            psi += 0.2 * r
        if k % 5 == 0:
            pending.append((k + 2, Pose(t, x + rng.normal(0, 0.005), y + rng.normal(0, 0.005), psi + rng.normal(0, 0.005))))
        pose = next((p for due, p in pending if due == k), None)
        pending = [(due, p) for due, p in pending if due > k]
        fails = (FailureDeclaration("RR", "steer_stuck"),) if (k // 2000) % 2 == 1 and len(tables) > 1 else ()
        cmd = yield Measurements(t, k, tuple(rim / RS + rng.normal(0, 0.02, 4)), tuple(steer + rng.normal(0, 0.005, 4)),
                                 r + 0.002 + rng.normal(0, 0.002), pose=pose, failures=fails)
        if cmd is not None:
            rim, steer = np.array(cmd.rim_speed), np.array(cmd.steer_angle)


def allocation_worker(ticks: int) -> dict[str, object]:
    """Per-tick transient peaks (bytes) over the last 1000 of ``ticks`` ticks: the tick, its
    feedback and preparation phases, and (second pass, same drive) every ``Table.at`` call."""
    import rtctl
    from rtctl.table import Table

    tables, note = B.load_tables()
    out: dict[str, object] = {"rtctl": str(Path(rtctl.__file__).parent), "tables": note}
    start = ticks - 1000
    for pass_ in ("phases", "table.at"):
        ctl = Controller(tables, ControllerConfig())
        at_peaks: list[int] = []
        orig_at = Table.at
        if pass_ == "table.at":
            def at(self: Table, **op: float) -> object:
                if not tracemalloc.is_tracing():
                    return orig_at(self, **op)
                b = tracemalloc.get_traced_memory()[0]
                tracemalloc.reset_peak()
                r = orig_at(self, **op)
                at_peaks.append(tracemalloc.get_traced_memory()[1] - b)
                return r
            Table.at = at  # type: ignore[method-assign]
        tick, fb, prep = [], [], []
        gen = _drive_measurements(ticks, tables)
        m = next(gen)
        try:
            for k in range(ticks):
                if k == start:
                    tracemalloc.start()
                if k >= start and pass_ == "phases":
                    b0 = tracemalloc.get_traced_memory()[0]
                    tracemalloc.reset_peak()
                    cmd, _ = ctl.feedback(m)
                    c1, p1 = tracemalloc.get_traced_memory()
                    tracemalloc.reset_peak()
                    ctl.prepare()
                    p2 = tracemalloc.get_traced_memory()[1]
                    fb.append(p1 - b0)
                    prep.append(p2 - c1)
                    tick.append(max(p1, p2) - b0)
                else:
                    cmd, _ = ctl.step(m)
                if k + 1 < ticks:
                    m = gen.send(cmd)
        finally:
            Table.at = orig_at  # type: ignore[method-assign]
            tracemalloc.stop()
        if pass_ == "phases":
            out.update(tick=tick, feedback=fb, prepare=prep)
        else:
            out["table_at"] = at_peaks
    return out


def allocation_compare(baseline: str | None, ticks: int, out_path: Path) -> str:
    """Run :func:`allocation_worker` for this tree and (if given) for rtctl at ``baseline``, each
    in its own process, and write the comparison."""
    import json
    import subprocess
    import tarfile
    import tempfile

    root = HERE.parents[1]
    runs: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="rtctl_base_") as tmp:
        env0 = {k: v for k, v in os.environ.items() if k != "BENCH_RTCTL_ROOT"}
        todo = [(f"this tree ({B._COMMIT_AT_START})", env0)]
        if baseline:
            rev = subprocess.run(["git", "rev-parse", "--short", baseline], cwd=root, capture_output=True, text=True,
                                 check=True).stdout.strip()
            arch = Path(tmp) / "rtctl.tar"
            subprocess.run(["git", "archive", "-o", str(arch), rev, "rtctl"], cwd=root, check=True)
            with tarfile.open(arch) as tf:
                tf.extractall(tmp, filter="data")
            todo.insert(0, (f"baseline {rev}", {**env0, "BENCH_RTCTL_ROOT": tmp}))
        for name, env in todo:
            r = subprocess.run([sys.executable, __file__, "--allocation-worker", "--ticks", str(ticks)], env=env,
                               capture_output=True, text=True)
            if r.returncode != 0:
                raise SystemExit(f"{name}: worker failed:\n{r.stderr[-3000:]}")
            runs[name] = json.loads(r.stdout.strip().splitlines()[-1])
    names = list(runs)
    lines = [B._header(f"rtctl allocation per tick (tracemalloc), {' against '.join(names[::-1])}", runs[names[-1]]["tables"]),
             f"Command: `nice python tests/bench/bench_rtctl_memory.py --allocation"
             f"{f' --baseline {baseline}' if baseline else ''} --ticks {ticks}`. Each version in its own process, in the "
             "same run, on the same drive (the memory benchmark's, without the rejected fixes; the RR steering declared "
             "stuck in alternate blocks of 2000 ticks); the last 1000 ticks traced. rtctl measured: "
             + "; ".join(f"{n}: {'exported by git archive' if 'rtctl_base_' in runs[n]['rtctl'] else 'this worktree'}"
                         for n in names) + ".", "",
             "Transient peak: the traced memory within the call above its level before it (median / p99 / max over "
             "the calls, kB). A tick's peak is the larger of its two phases' (the estimator, the exact residual and "
             "the QP in `feedback`; the table interpolation and the QP's matrices in `prepare`).", "",
             "| measured | " + " | ".join(names) + (" | after / before (median) |" if len(names) == 2 else " |"),
             "|---|" + "---|" * len(names) + ("---|" if len(names) == 2 else "")]
    for key, label in (("tick", "tick (feedback + prepare)"), ("feedback", "feedback phase"),
                       ("prepare", "prepare phase"), ("table_at", "one Table.at call")):
        cells, meds = [], []
        for n in names:
            arr = np.asarray(runs[n][key], dtype=float) / 1024
            meds.append(float(np.median(arr)))
            cells.append(f"{np.median(arr):.1f} / {np.percentile(arr, 99):.1f} / {arr.max():.1f} ({len(arr)} calls)")
        ratio = f" | {meds[1] / meds[0]:.3f} |" if len(names) == 2 and meds[0] > 0 else " |"
        lines.append(f"| {label} | " + " | ".join(cells) + ratio)
    lines += ["", "Where the remaining tick peak is: the `feedback` phase's exact residual and Jacobian of the shared "
              "physics (`rtctl.rti.RealTimeIteration.linearise`), not the table; the table gather no longer allocates its "
              "2**d corner rows (the interpolated row it returns, which the table point keeps, remains).", ""]
    text = "\n".join(lines) + "\n"
    write_text(out_path, text)
    return text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=144_000)
    ap.add_argument("--out", default=None, help="results file (default results_rtctl_memory.md, with --allocation "
                                                "results_rtctl_memory_allocation.md)")
    ap.add_argument("--no-trace", action="store_true", help="skip the tracemalloc windows (RSS without tracemalloc's own memory)")
    ap.add_argument("--allocation", action="store_true", help="only the allocation per tick (module docstring)")
    ap.add_argument("--baseline", help="with --allocation: also measure rtctl at this git revision, same run")
    ap.add_argument("--ticks", type=int, default=3500, help="with --allocation: ticks driven (the last 1000 traced)")
    ap.add_argument("--allocation-worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.allocation_worker:
        import json

        print(json.dumps(allocation_worker(a.ticks)))
        return
    if a.allocation:
        if a.ticks < 1000:
            raise SystemExit("--ticks must be >= 1000 (the traced window)")
        B._COMMIT_AT_START = B._commit()
        print(allocation_compare(a.baseline, a.ticks, Path(a.out or HERE / "results_rtctl_memory_allocation.md")))
        return
    a.out = a.out or str(HERE / "results_rtctl_memory.md")
    n = a.steps
    if n < 30_000:
        raise SystemExit("--steps must be >= 30000 (two 10,000-tick timing windows and the tracemalloc windows)")
    B._COMMIT_AT_START = B._commit()
    tables, note = B.load_tables()
    from test_rtctl_controller import ROCKER, RS, TRACK

    cfg = ControllerConfig()
    ctl = Controller(tables, cfg)
    runner = Runner(ctl, period=cfg.period, clock=time.thread_time)
    rng = np.random.default_rng(1)
    x, y, psi, slip = 0.0, -0.05, math.radians(5.0), 0.2
    rim, steer = np.full(4, 0.03 / 0.9), np.zeros(4)
    pending: list[tuple[int, Pose]] = []
    step_us = np.full(n, np.nan)  # every page touched now, not during the run (RSS)
    rss: list[tuple[int, float]] = []
    trace_windows = {"ticks 10,000-10,999": range(10_000, 11_000), f"ticks {n - 12_000:,}-{n - 11_001:,}": range(n - 12_000, n - 11_000)}
    if a.no_trace:
        trace_windows = {}
    traced: dict[str, list[tuple[int, int]]] = {k: [] for k in trace_windows}
    kept: dict[str, tuple[int, list[str]]] = {}
    bad_from, bad_to = 20_000, 22_000
    sizes0: dict[str, int] = {}
    sizes_peak: dict[str, int] = {}
    modes = {"qp": 0, "fallback": 0, "hold": 0}
    t_wall = time.perf_counter()
    for k in range(n):
        t = 0.2 * k
        v = float(np.mean(rim * np.cos(steer))) * (1 - slip)
        r = (((rim[0] + rim[2]) - (rim[1] + rim[3])) / 2 / TRACK * (1 - slip)
             + v * (math.tan((steer[0] + steer[1]) / 2) - math.tan((steer[2] + steer[3]) / 2)) / ROCKER)
        if k:
            x += 0.2 * v * math.cos(psi)
            y += 0.2 * v * math.sin(psi)
            psi += 0.2 * r
        if k % 5 == 0 and not bad_from <= k < bad_to:
            pending.append((k + 2, Pose(t, x + rng.normal(0, 0.005), y + rng.normal(0, 0.005), psi + rng.normal(0, 0.005))))
        pose = next((p for due, p in pending if due == k), None)
        pending = [(due, p) for due, p in pending if due > k]
        if bad_from <= k < bad_to:
            sign = 1.0 if k % 2 else -1.0
            pose = Pose(t, x + 3.0 * sign, y - 3.0 * sign, psi)
        fails = (FailureDeclaration("RR", "steer_stuck"),) if (k // 2000) % 2 == 1 and len(tables) > 1 else ()
        m = Measurements(t, k, tuple(rim / RS + rng.normal(0, 0.02, 4)), tuple(steer + rng.normal(0, 0.005, 4)),
                         r + 0.002 + rng.normal(0, 0.002), pose=pose, failures=fails)
        window = next((name for name, rg in trace_windows.items() if k in rg), None)
        if window is not None:
            if not tracemalloc.is_tracing():
                tracemalloc.start()
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
        cmd, diag, tick = runner.tick(m)
        if window is not None:
            cur, peak = tracemalloc.get_traced_memory()
            traced[window].append((peak - before, cur - before))
            if k + 1 not in trace_windows[window]:
                gc.collect()
                kept[window] = _kept(tracemalloc.take_snapshot())
                tracemalloc.stop()
        step_us[k] = tick.total * 1e6
        modes[diag.mode] += 1
        rim, steer = np.array(cmd.rim_speed), np.array(cmd.steer_angle)
        if k % 1000 == 999:
            rss.append((k + 1, rss_kb()))
        if k == 9_999:
            gc.collect()
            sizes0 = buffers(ctl, runner)
        if bad_from <= k < bad_to:
            for key, val in buffers(ctl, runner).items() if k % 500 == 499 else ():
                sizes_peak[key] = max(sizes_peak.get(key, 0), val)
    # the aged controller against a fresh one, tick by tick in turn on the same measurements (the
    # drive goes on with the aged controller's commands): both see the same load of the shared
    # machine, which the first-vs-last comparison above cannot promise
    fresh = Controller(tables, cfg)
    aged_us, fresh_us = [], []
    for k in range(n, n + AGED_TICKS):
        t = 0.2 * k
        v = float(np.mean(rim * np.cos(steer))) * (1 - slip)
        r = (((rim[0] + rim[2]) - (rim[1] + rim[3])) / 2 / TRACK * (1 - slip)
             + v * (math.tan((steer[0] + steer[1]) / 2) - math.tan((steer[2] + steer[3]) / 2)) / ROCKER)
        x += 0.2 * v * math.cos(psi)
        y += 0.2 * v * math.sin(psi)
        psi += 0.2 * r
        pose = Pose(t, x, y, psi) if k % 5 == 0 else None
        fails = (FailureDeclaration("RR", "steer_stuck"),) if (k // 2000) % 2 == 1 and len(tables) > 1 else ()
        m = Measurements(t, k, tuple(rim / RS + rng.normal(0, 0.02, 4)), tuple(steer + rng.normal(0, 0.005, 4)),
                         r + 0.002 + rng.normal(0, 0.002), pose=pose, failures=fails)
        pair = [(ctl, aged_us), (fresh, fresh_us)]
        for c, out in (pair if k % 2 else pair[::-1]):  # alternate which one goes first
            t0 = time.thread_time()
            cmd_k, _ = c.step(m)
            out.append((time.thread_time() - t0) * 1e6)
            if c is ctl:
                cmd = cmd_k
        rim, steer = np.array(cmd.rim_speed), np.array(cmd.steer_angle)
    aged_a, fresh_a = np.array(aged_us[AGED_TICKS // 10:]), np.array(fresh_us[AGED_TICKS // 10:])
    wall = time.perf_counter() - t_wall
    gc.collect()
    sizes1 = buffers(ctl, runner)
    r = np.array(rss)
    later = r[r[:, 0] >= 10_000]
    slope = float(np.polyfit(later[:, 0], later[:, 1], 1)[0]) if len(later) > 2 else math.nan
    first, last = step_us[:10_000], step_us[-10_000:]
    # trend of the step time over the run: medians of blocks of 1000 ticks, least squares, with
    # the slope's standard error from the residuals (thread CPU time still varies with the other
    # jobs' load on the shared cores: the blocks show how much)
    blocks = np.median(step_us[: n // 1000 * 1000].reshape(-1, 1000), axis=1)
    xb = np.arange(len(blocks)) * 1000.0 + 500.0
    untraced = np.array([not any(int(x) in rg for rg in trace_windows.values()) for x in xb])  # tracing slows its ticks
    blocks, xb = blocks[untraced], xb[untraced]
    coef, res, *_ = np.polyfit(xb, blocks, 1, full=True)
    resid = blocks - np.polyval(coef, xb)
    se = float(np.sqrt(np.sum(resid ** 2) / max(len(blocks) - 2, 1) / np.sum((xb - xb.mean()) ** 2)))
    trend = (100 * coef[0] * 1e5 / np.median(blocks), 100 * 2 * se * 1e5 / np.median(blocks))
    lines = [B._header(f"rtctl memory and time over {n:,} ticks ({n * 0.2 / 3600:.1f} simulated hours at 5 Hz)", note),
             f"Command: `nice python tests/bench/bench_rtctl_memory.py --steps {n}{' --no-trace' if a.no_trace else ''}` (wall {wall:.0f} s). "
             f"Modes: {modes}.", "",
             "## Resident memory", "",
             f"RSS at tick 10,000: {later[0, 1] / 1024:.2f} MB; at the end: {r[-1, 1] / 1024:.2f} MB; growth "
             f"{r[-1, 1] - later[0, 1]:+.0f} kB; least-squares slope from tick 10,000: {slope * 1e4:+.2f} kB per 10,000 ticks; "
             f"largest RSS after tick 10,000: {later[:, 1].max() / 1024:.2f} MB.", "",
             "## Buffers (tick 10,000 / largest while the fixes were rejected / end)", "",
             "| buffer | tick 10,000 | during ticks 20,000-21,999 | end |", "|---|---|---|---|"]
    for key in sizes1:
        lines.append(f"| {key} | {sizes0.get(key, '-')} | {sizes_peak.get(key, '-')} | {sizes1[key]} |")
    lines += ["", "## Allocation per tick (tracemalloc)", "",
              "| window | transient peak per tick, median (kB) | p99 (kB) | allocated in the window and alive at its "
              "end (kB) | largest sites of those |", "|---|---|---|---|---|"]
    for name, rows in traced.items():
        arr = np.array(rows, dtype=float)
        if len(arr):
            kb, top = kept.get(name, (0, []))
            lines.append(f"| {name} | {np.median(arr[:, 0]) / 1024:.1f} | {np.percentile(arr[:, 0], 99) / 1024:.1f} | "
                         f"{kb / 1024:.1f} | {'; '.join(top)} |")
    lines += ["", "Transient peak: traced memory within a tick above its level before the tick. Alive at the end: "
              "bytes allocated in the 1000-tick window and still alive at its end after a garbage collection, "
              "outside the runner's bounded ring buffer of timings and this script; that is the controller's "
              "current state (the table point, the QP's matrices, the EKF's history), replaced every tick, so "
              "it is the same in an early and a late window when nothing grows (an unbounded buffer would add "
              "its bytes per tick times 1000).", "",
              "## Step time (feedback + preparation, thread CPU, us)", "",
              "| ticks | median | p99 | mean |", "|---|---|---|---|",
              f"| first 10,000 | {np.median(first):.0f} | {np.percentile(first, 99):.0f} | {first.mean():.0f} |",
              f"| last 10,000 | {np.median(last):.0f} | {np.percentile(last, 99):.0f} | {last.mean():.0f} |",
              f"| ratio last / first | {np.median(last) / np.median(first):.3f} | "
              f"{np.percentile(last, 99) / np.percentile(first, 99):.3f} | {last.mean() / first.mean():.3f} |", "",
              f"Trend of the step time over the run (least squares on the medians of the {len(blocks)} untraced blocks "
              f"of 1000 ticks): {trend[0]:+.1f} % per 100,000 ticks (+/- {trend[1]:.1f} %, two standard errors); block medians "
              f"from {blocks.min():.0f} to {blocks.max():.0f} us.", "",
              f"## Aged against fresh, interleaved ({AGED_TICKS} more ticks, the first {AGED_TICKS // 10} not counted)", "",
              "After the run, the aged controller and a fresh one step in turn on the same measurements (which one "
              "goes first alternates), so both see the same load of the shared cores.", "",
              "| controller | median (us) | p99 (us) | mean (us) |", "|---|---|---|---|",
              f"| aged ({n:,} ticks) | {np.median(aged_a):.0f} | {np.percentile(aged_a, 99):.0f} | {aged_a.mean():.0f} |",
              f"| fresh | {np.median(fresh_a):.0f} | {np.percentile(fresh_a, 99):.0f} | {fresh_a.mean():.0f} |",
              f"| ratio aged / fresh | {np.median(aged_a) / np.median(fresh_a):.3f} | "
              f"{np.percentile(aged_a, 99) / np.percentile(fresh_a, 99):.3f} | {aged_a.mean() / fresh_a.mean():.3f} |", ""]
    text = "\n".join(lines) + "\n"
    print(text)
    write_text(Path(a.out), text)


if __name__ == "__main__":
    main()
