"""Benchmark: a new failure's table on a small grid, with and without the relaxation pass (issue 22).

Run from the repository root::

    nice python tests/bench/bench_new_failure.py [--jobs 2] [--grid "slope=20,25;cross_slope=0;speed=2,4;steer_stuck=-30,0"]

README's worked example (front-left steering stuck, the calibrated sand by preset name) on a
small grid, built twice in fresh folders in the same run: ``BuildOptions(relaxation_evidence=False)``
(the build before issue 22's relaxation pass) and the default (a point still ``not_found`` becomes
``infeasible`` when the same operating point without the failure is confirmed infeasible). Per
build: wall and CPU time (this process and its workers), statuses. Writes
``tests/bench/results_new_failure.md``; the times are a ratio of two builds in the same run, so
the machine's load cancels to first order (it is recorded too).
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from offline.files import write_text  # noqa: E402
from offline.rover.table_builder import BuildOptions, build_table, table_spec  # noqa: E402

SCENARIO = """[scenario]
name = "fl_steer_stuck"
description = "Front-left steering actuator stuck at -30 deg"
params = "calibrated-sand"
rover = "mini-rover-t72"
speed_m_s = 0.03

[wheels.FL]
steer_stuck_deg = -30.0
"""


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--grid", default="slope=20,25;cross_slope=0;speed=2,4;steer_stuck=-30,0")
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_new_failure.md"))
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        sc = Path(tmp) / "elsewhere" / "fl_steer_stuck.toml"
        sc.parent.mkdir()
        sc.write_text(SCENARIO)
        for label, build in (("before (no relaxation pass)", BuildOptions(relaxation_evidence=False)),
                             ("after (relaxation pass)", BuildOptions())):
            spec = table_spec(sc, args.grid, build=build)
            load0 = os.getloadavg()[0]
            t0, c0 = time.perf_counter(), _cpu()
            _, summ = build_table(spec, Path(tmp) / label.split()[0], jobs=args.jobs, progress=False)
            wall, cpu = time.perf_counter() - t0, _cpu() - c0
            rows.append((label, wall, cpu, summ["statuses"], summ["grid_points"], summ.get("relaxed", 0), load0))
            print(rows[-1], flush=True)
    base = rows[0]
    lines = [
        "# A new failure's table on a small grid: relaxation pass before/after (issue 22)",
        "",
        f"`nice python tests/bench/bench_new_failure.py --jobs {args.jobs} --grid \"{args.grid}\"`; "
        f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.node()}, {os.cpu_count()} cores, "
        "shared machine (load average at each build's start in the table).",
        "",
        "| build | wall s | CPU s | wall / before | statuses | not_found | made infeasible | load |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for label, wall, cpu, st, n, relaxed, load in rows:
        nf = st.get("not_found", 0)
        lines.append(f"| {label} | {wall:.1f} | {cpu:.1f} | {wall / base[1]:.2f} | "
                     f"{', '.join(f'{k} {v}' for k, v in st.items())} | {nf}/{n} ({nf / n:.0%}) | {relaxed} | {load:.1f} |")
    write_text(Path(args.results), "\n".join(lines) + "\n")
    print(f"wrote {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
