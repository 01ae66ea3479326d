"""Benchmarks of the on-rover controller (issue 12, "Light and fast" and "Bad input").

Run on demand (one command each; results go to ``tests/bench/results_rtctl_<part>.md``)::

    python tests/bench/bench_rtctl.py timing   [--steps 10000] [--table FILE]   # step time, shares, phases
    python tests/bench/bench_rtctl.py import                       # cold import time and RSS
    python tests/bench/bench_rtctl.py soak     [--steps 1000000] [--seed N]   # fuzzed input, zero invalid commands

Tables: the shipped ones (``tables/index.json``) when present, otherwise the synthetic
linear-rover tables of ``tests/rtctl_synthetic.py`` (the results say which).
Timing drives the controller in closed loop with the kinematic truth of
``tests/test_rtctl_controller.py`` (noisy encoders and gyro, a pose every second, 0.4 s late).
The soak feeds random corruptions (NaN, inf, huge values, duplicates, time going back, gaps,
missing wheels, bogus failures and poses, pose jumps) and checks every command.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE.parent))

from offline.files import write_text  # noqa: E402
from rtctl.config import ControllerConfig  # noqa: E402
from rtctl.controller import Controller  # noqa: E402
from rtctl.messages import FailureDeclaration, Measurements, Pose  # noqa: E402
from rtctl.runner import Runner  # noqa: E402

INDEX = ROOT / "tables" / "index.json"


TABLE_FILE: Path | None = None


def load_tables() -> tuple[dict, str]:
    """``--table FILE`` if given, else the shipped tables if any, else synthetic ones; and a note
    saying which."""
    if TABLE_FILE is not None:
        from rtctl.table import load_table

        t = load_table(TABLE_FILE)
        return {t.name: t}, f"{TABLE_FILE.name} (built by the NLP; {t!r})"
    if INDEX.is_file():
        from rtctl.table import load_index

        idx = load_index(INDEX)
        return {k: v.load() for k, v in idx.items()}, f"shipped tables ({', '.join(sorted(idx))})"
    from rtctl_synthetic import synthetic_tables

    folder = Path(tempfile.mkdtemp())
    return synthetic_tables(folder), "SYNTHETIC linear-rover tables (tests/rtctl_synthetic.py): no tables/index.json yet"


def _commit() -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "rtctl"], cwd=ROOT, capture_output=True, text=True).stdout
        return out.stdout.strip() + (" (rtctl modified)" if dirty.strip() else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


_COMMIT_AT_START = None


def _header(title: str, note: str) -> str:
    return (f"# {title}\n\n{datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC')}, commit {_COMMIT_AT_START}, "
            f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, "
            f"2 cores shared with other jobs (run under `nice`).\n\nTables: {note}.\n\n")


CLOCK = time.perf_counter


class _Timer:
    """Wraps a bound method and accumulates its time (on :data:`CLOCK`) per tick."""

    def __init__(self, obj: object, name: str) -> None:
        self.obj, self.name, self.fn = obj, name, getattr(obj, name)
        self.acc = 0.0
        setattr(obj, name, self)

    def __call__(self, *a, **k):
        t = CLOCK()
        try:
            return self.fn(*a, **k)
        finally:
            self.acc += CLOCK() - t

    def take(self) -> float:
        v, self.acc = self.acc, 0.0
        return v


def timing(steps: int) -> str:
    """Both clocks: wall time (what a deadline sees, including preemption by the other jobs on
    this shared machine) and this thread's CPU time (the controller's own cost)."""
    global CLOCK
    parts = []
    for name, clock in (("thread CPU time (`time.thread_time`): the controller's own cost", time.thread_time),
                        ("wall time (`time.perf_counter`): includes preemption on the shared machine", time.perf_counter)):
        CLOCK = clock
        parts.append(f"## {name}\n\n" + _timing(steps))
    tables, note = load_tables()
    return (_header("rtctl step timing", note)
            + f"Command: `nice python tests/bench/bench_rtctl.py timing --steps {steps}"
            + (f" --table {TABLE_FILE.relative_to(ROOT) if TABLE_FILE.is_absolute() else TABLE_FILE}" if TABLE_FILE else "")
            + f"`. {steps} closed-loop ticks per clock (kinematic truth, noisy sensors, a pose every 1 s arriving 0.4 s "
            "late; with several tables the RR steering is declared stuck in alternate blocks of 2000 ticks, so the "
            "table switches).\n\n" + "\n".join(parts))


def _timing(steps: int) -> str:
    tables, note = load_tables()
    from test_rtctl_controller import ROCKER, RS, TRACK

    cfg = ControllerConfig()
    ctl = Controller(tables, cfg)
    rng = np.random.default_rng(1)
    ekf_p, ekf_u = _Timer(ctl.ekf, "predict"), _Timer(ctl.ekf, "update_pose")
    runner = Runner(ctl, period=cfg.period, clock=CLOCK)
    x, y, psi, slip = 0.0, -0.05, math.radians(5.0), 0.2
    rim, steer = np.full(4, 0.03 / 0.9), np.zeros(4)
    pending = []
    rows = []
    qp_timers: dict[str, tuple[_Timer, _Timer]] = {}
    for k in range(steps):
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
        fails = (FailureDeclaration("RR", "steer_stuck"),) if (k // 2000) % 2 == 1 and len(tables) > 1 else ()
        m = Measurements(t, k, tuple(rim / RS + rng.normal(0, 0.02, 4)), tuple(steer + rng.normal(0, 0.005, 4)),
                         r + 0.002 + rng.normal(0, 0.002), pose=pose, failures=fails)
        for name, it_ in ctl._rtis.items():  # time every real-time iteration's QP solve and prepare
            a = it_.allocator
            if name not in qp_timers:
                qp_timers[name] = (_Timer(a, "solve_at"), _Timer(a, "prepare"))
        cmd, diag, tick = runner.tick(m)
        qs = sum(tm[0].take() for tm in qp_timers.values())
        qprep = sum(tm[1].take() for tm in qp_timers.values())
        rows.append((tick.feedback, tick.prepare, ekf_p.take() + ekf_u.take(), qs, qprep, diag.mode, diag.qp_iterations))
        rim, steer = np.array(cmd.rim_speed), np.array(cmd.steer_angle)
    a = np.array([r[:5] for r in rows]) * 1e6
    total = a[:, 0] + a[:, 1]
    modes = [r[5] for r in rows]
    its = np.array([r[6] for r in rows])

    def line(name: str, v: np.ndarray) -> str:
        return f"| {name} | {np.median(v):.0f} | {np.percentile(v, 99):.0f} | {v.max():.0f} | {v.mean():.0f} |"

    s = runner.stats.summary()
    out = "| phase (us) | median | p99 | max | mean |\n|---|---|---|---|---|\n"
    out += "\n".join([line("whole step (feedback + preparation)", total), line("feedback: measurement -> command", a[:, 0]),
                      line("  of which EKF (predict + pose update)", a[:, 2]), line("  of which QP solve (OSQP, warm)", a[:, 3]),
                      line("preparation: table + QP matrices + refactorisation", a[:, 1]),
                      line("  of which allocator prepare", a[:, 4])]) + "\n\n"
    out += (f"Shares of the mean whole step: EKF {100 * a[:, 2].mean() / total.mean():.0f} %, QP solve "
            f"{100 * a[:, 3].mean() / total.mean():.0f} %, QP preparation {100 * a[:, 4].mean() / total.mean():.0f} %.\n\n")
    out += (f"Target p99 <= 1000 us (whole step): {'met' if np.percentile(total, 99) <= 1000 else 'NOT met'} "
            f"({np.percentile(total, 99):.0f} us); moonshot 200 us: "
            f"{'met' if np.percentile(total, 99) <= 200 else 'not met'}.\n\n")
    out += (f"Modes: {modes.count('qp')} qp, {modes.count('fallback')} fallback, {modes.count('hold')} hold. "
            f"OSQP iterations: median {np.median(its):.0f}, p99 {np.percentile(its, 99):.0f}, max {its.max()}. "
            f"Deadline (200 ms) overruns: {int(s['overruns'])}.\n")
    return out


# peak resident set of this process in kB (VmHWM: per address space, so a fresh exec starts
# from zero, unlike ru_maxrss, which Linux carries over from the forking parent)
_HWM = "[l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0]"


def import_cost() -> str:
    if TABLE_FILE is not None:
        tables_code = (f"from rtctl.table import load_table; t = load_table({str(TABLE_FILE.resolve())!r}); tabs = {{t.name: t}}; "
                       "from rtctl.controller import Controller; from rtctl.config import ControllerConfig; "
                       "c = Controller(tabs, ControllerConfig()); ")
        what = f"{TABLE_FILE.name}"
    elif INDEX.is_file():
        tables_code = (f"from rtctl.controller import load_tables; tabs = load_tables({str(INDEX)!r}); "
                       "from rtctl.controller import Controller; from rtctl.config import ControllerConfig; "
                       "c = Controller(tabs, ControllerConfig()); ")
        what = "the shipped tables"
    else:
        tables_code, what = "", "no tables (none shipped yet): import only"
    code = ("import time; t0 = time.perf_counter(); import rtctl.controller, rtctl.table, rtctl.runner; "
            "t1 = time.perf_counter(); " + tables_code + "t2 = time.perf_counter(); "
            "print(t1 - t0, t2 - t1, " + _HWM + ")")
    base = "print(" + _HWM + ")"
    runs = []
    for _ in range(5):
        t = time.perf_counter()
        o = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        wall = time.perf_counter() - t
        imp, load, rss = o.stdout.split()
        runs.append((float(imp), float(load), int(rss), wall))
    rss0 = int(subprocess.run([sys.executable, "-c", base], capture_output=True, text=True, check=True).stdout)
    a = np.array(runs)
    out = _header("rtctl cold import and memory", what)
    cmd = "python tests/bench/bench_rtctl.py import" + (f" --table {TABLE_FILE}" if TABLE_FILE else "")
    out += (f"Command: `{cmd}`. Five fresh processes each import "
            "`rtctl.controller`, `rtctl.table`, `rtctl.runner`" + (f" and load {what} and build a Controller" if tables_code else "")
            + ".\n\n| quantity | median | max |\n|---|---|---|\n")
    out += f"| import time (s) | {np.median(a[:, 0]):.3f} | {a[:, 0].max():.3f} |\n"
    out += f"| table load + Controller (s) | {np.median(a[:, 1]):.3f} | {a[:, 1].max():.3f} |\n"
    out += f"| whole process wall time (s) | {np.median(a[:, 3]):.3f} | {a[:, 3].max():.3f} |\n"
    out += f"| max RSS (MB) | {np.median(a[:, 2]) / 1024:.1f} | {a[:, 2].max() / 1024:.1f} |\n"
    out += f"\nA bare interpreter's max RSS: {rss0 / 1024:.1f} MB.\n"
    return out


def soak(steps: int, seed: int = 2026) -> str:
    tables, note = load_tables()
    cfg = ControllerConfig()
    ctl = Controller(tables, cfg)
    a = cfg.actuators
    rng = np.random.default_rng(seed)
    from test_rtctl_controller import RS

    om = 0.03 / (RS * 0.9)
    bad_values = np.array([np.nan, np.inf, -np.inf, 1e9, -1e9, 1e300, 0.0, -5.0, 50.0])
    kinds = ["ok"] * 12 + ["dup", "back", "nan_t", "gap", "big_gap", "missing_wheel", "leap"]
    fkinds = ["steer_stuck", "rim_speed_cap", "locked", "unpowered", "raised", "torque_limit", "bogus"]
    invalid = 0
    modes = {"qp": 0, "fallback": 0, "hold": 0}
    t, seq = 0.0, 0
    t0 = time.perf_counter()
    est = (0.0, 0.0, 0.0)
    nonfinite_state = 0
    for k in range(steps):
        kind = kinds[rng.integers(len(kinds))]
        if kind in ("ok", "missing_wheel"):
            t, seq = t + 0.2, seq + 1
        elif kind == "back":
            t, seq = t - 0.4, seq - 2
        elif kind == "gap":
            t, seq = t + 0.6, seq + 3
        elif kind == "big_gap":
            t, seq = t + 5.0, seq + 25
        elif kind == "leap":  # the rover clock jumps by a day
            t, seq = t + 86400.0, seq + 1
        tt = math.nan if kind == "nan_t" else t
        w = om + rng.normal(0, 0.05, 4)
        s = rng.normal(0, 0.1, 4)
        if rng.random() < 0.1:
            w[rng.integers(4)] = bad_values[rng.integers(len(bad_values))]
        if rng.random() < 0.05:
            s[rng.integers(4)] = bad_values[rng.integers(len(bad_values))]
        yaw = rng.normal(0, 0.01) if rng.random() > 0.05 else bad_values[rng.integers(len(bad_values))]
        pitch = rng.normal(0.05, 0.01) if rng.random() > 0.05 else bad_values[rng.integers(len(bad_values))]
        pose = None
        u = rng.random()
        if u < 0.2:  # near the controller's own estimate: accepted, late, gated or too old
            pose = Pose(t - 0.2 * rng.integers(0, 4), est[0] + rng.normal(0, 0.01), est[1] + rng.normal(0, 0.01),
                        est[2] + rng.normal(0, 0.01))
        elif u < 0.22:
            pose = Pose(t, 5.0 + rng.normal(0, 1), -3.0, 2.0)  # a jump
        elif u < 0.23:
            pose = Pose(*(bad_values[rng.integers(len(bad_values), size=4)]))
        fails = ()
        if rng.random() < 0.3:
            fails = tuple(FailureDeclaration(str(rng.choice(["FR", "FL", "RR", "RL", "XX"])), fkinds[rng.integers(len(fkinds))],
                                             float(rng.choice([np.nan, 0.01, 0.02, -0.5, 0.7, np.inf, -1.0])))
                          for _ in range(rng.integers(1, 3)))
        wheels = tuple(w) if kind != "missing_wheel" else tuple(w[:3])
        m = Measurements(tt, seq, wheels, tuple(s), float(yaw), pitch=float(pitch), pose=pose, failures=fails)  # type: ignore[arg-type]
        cmd, d = ctl.step(m)
        ok = cmd.is_valid(a.max_rim_speed, a.max_steer) and min(cmd.rim_speed) >= a.min_rim_speed
        invalid += not ok
        modes[d.mode] += 1
        if all(math.isfinite(v) for v in d.state):
            est = d.state
        else:
            nonfinite_state += 1
    wall = time.perf_counter() - t0
    counters = dict(d.counters)
    out = _header("rtctl soak: fuzzed measurements", note)
    out += (f"Command: `nice python tests/bench/bench_rtctl.py soak --steps {steps} --seed {seed}`. "
            f"{steps} ticks in {wall:.0f} s ({1e6 * wall / steps:.0f} us per tick).\n\n"
            f"**Invalid commands: {invalid}** (finite, within |rim speed| <= {a.max_rim_speed} m/s, >= {a.min_rim_speed}, "
            f"|steer| <= {math.degrees(a.max_steer):.0f} deg). Ticks with a non-finite EKF state: {nonfinite_state}.\n\n"
            f"Modes: {json.dumps(modes)}.\n\n"
            "Counters at the end:\n\n| counter | count |\n|---|---|\n")
    out += "\n".join(f"| {k} | {v} |" for k, v in sorted(counters.items())) + "\n"
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("part", choices=["timing", "import", "soak"])
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument("--table", type=Path, default=None, help="one table file to use instead of tables/index.json")
    ap.add_argument("--seed", type=int, default=2026, help="soak: seed of the fuzzer")
    a = ap.parse_args()
    global TABLE_FILE
    TABLE_FILE = a.table
    global _COMMIT_AT_START
    _COMMIT_AT_START = _commit()  # the code measured is the code at the start
    if a.part == "timing":
        text = timing(a.steps or 10_000)
    elif a.part == "import":
        text = import_cost()
    else:
        text = soak(a.steps or 1_000_000, a.seed)
    suffix = ('_' + a.table.stem if a.table else '') + (f"_seed{a.seed}" if a.part == "soak" else "")
    path = HERE / f"results_rtctl_{a.part}{suffix}.md"
    write_text(path, text)
    print(text)
    print(f"written {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
