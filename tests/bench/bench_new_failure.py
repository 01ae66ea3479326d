"""Benchmark: README's worked example (a new failure's table), former schedule against the continuation.

Run from the repository root::

    nice python tests/bench/bench_new_failure.py [--jobs 2] [--grid default] [--builds chains,continuation]

README's worked example (front-left steering stuck, the calibrated sand by preset name), built
in fresh folders in the same run, one build after the other with the same worker count:

* ``chains``: ``BuildOptions(schedule="chains")``, the schedule before issue 22's continuation
  (chains along the slope axis from the optimizer's automatic start, every speed searched, then
  retries, speed twins, neighbour pass and relaxation pass);
* ``continuation``: the default (:mod:`offline.rover.table_continuation`);
* ``norelax``: the former schedule without the relaxation pass (the first version of this bench).

``--grid default`` is the scenario's default grid (252 points, README's example); any other value
is a ``--grid`` string. Per build: wall and CPU time (this process and its workers), statuses,
``not_found`` share, and an independent re-check of every optimal point (the optimizer's numeric
check, :func:`offline.rover.primitives.check_solution`, on the stored primitive); between the
first build and each other one: at points optimal in both, the largest difference of the
primitives (variable scales) and of the objectives. Writes ``tests/bench/results_new_failure.md``
(``--results``); the times are ratios of builds in the same run, so the machine's load cancels to
first order (the load average at each start is recorded too).
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
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from offline.files import write_text  # noqa: E402
from offline.rover import primitives as P  # noqa: E402
from offline.rover.table_builder import (BuildOptions, _problem, build_table, scenario_at,  # noqa: E402
                                         table_spec)
from rtctl.table import load_table  # noqa: E402

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


BUILDS = {
    "chains": ("former schedule (chains along slope, every speed searched)", BuildOptions(schedule="chains")),
    "continuation": ("continuation (seed table, failure axis, speed twins, relaxation first)", BuildOptions()),
    "norelax": ("former schedule, no relaxation pass", BuildOptions(schedule="chains", relaxation_evidence=False)),
}


def recheck(spec: Any, path: Path) -> tuple[int, int]:
    """(optimal points, of them passing the optimizer's independent numeric check again)."""
    t = load_table(path)
    xsc = t.layout.variable_scale
    n = ok = 0
    for idx in np.ndindex(*t.shape):
        if t.status_at(idx) != "optimal":
            continue
        flat = int(np.ravel_multi_index(idx, t.shape))
        sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
        n += 1
        ok += bool(P.check_solution(_problem(sc, spec.solver), sc, t.arrays["x"][idx] / xsc)[1])
    return n, ok


def compare(a: Path, b: Path) -> dict[str, Any]:
    """At points optimal in both tables: largest |x_a - x_b| (variable scales), objective differences."""
    ta, tb = load_table(a), load_table(b)
    both = (ta.status == 0) & (tb.status == 0)
    if not both.any():
        return {"both": 0}
    dx = np.max(np.abs(ta.arrays["x"][both] - tb.arrays["x"][both]) / ta.layout.variable_scale, axis=1)
    df = tb.arrays["objective"][both] - ta.arrays["objective"][both]
    tol = 1e-6 * np.maximum(np.abs(ta.arrays["objective"][both]), 1e-3)
    return {"both": int(both.sum()), "same_x": int(np.sum(dx <= 1e-4)), "max_dx": float(dx.max()),
            "lower": int(np.sum(df < -tol)), "higher": int(np.sum(df > tol)), "max_rel_higher": float(np.max(df / np.maximum(
                np.abs(ta.arrays["objective"][both]), 1e-3)))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--grid", default="default", help="'default' (252 points) or a --grid string")
    ap.add_argument("--builds", default="chains,continuation", help=f"comma list of {sorted(BUILDS)}")
    ap.add_argument("--dask-workers", type=int, default=0,
                    help="build on a Dask LocalCluster of this many single-threaded worker processes "
                         "(--scheduler's path) instead of --jobs local processes")
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_new_failure.md"))
    args = ap.parse_args()
    cluster = None
    if args.dask_workers:
        from distributed import LocalCluster

        cluster = LocalCluster(n_workers=args.dask_workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
    grid = None if args.grid == "default" else args.grid
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        sc = Path(tmp) / "elsewhere" / "fl_steer_stuck.toml"
        sc.parent.mkdir()
        sc.write_text(SCENARIO)
        paths = []
        for key in args.builds.split(","):
            label, build = BUILDS[key]
            spec = table_spec(sc, grid, build=build)
            load0 = os.getloadavg()[0]
            t0, c0 = time.perf_counter(), _cpu()
            path, summ = build_table(spec, Path(tmp) / key, jobs=args.jobs, progress=False,
                                     scheduler=cluster.scheduler_address if cluster is not None else None)
            wall, cpu = time.perf_counter() - t0, _cpu() - c0
            n_opt, n_ok = recheck(spec, path)
            paths.append(path)
            cmp_ = compare(paths[0], path) if len(paths) > 1 else None
            rows.append((key, label, wall, cpu, summ["statuses"], summ["grid_points"], summ.get("relaxed", 0), load0,
                         (n_opt, n_ok), cmp_, summ.get("continuation")))
            print(rows[-1], flush=True)
    if cluster is not None:
        cluster.close()
    base = rows[0]
    how = f"--dask-workers {args.dask_workers}" if args.dask_workers else f"--jobs {args.jobs}"
    lines = [
        "# README's worked example: former schedule against the continuation (issue 22)",
        "",
        f"`nice python tests/bench/bench_new_failure.py {how} --grid \"{args.grid}\" --builds {args.builds}`; "
        f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.node()}, {os.cpu_count()} cores, "
        "shared machine (load average at each build's start in the table). Builds one after the other in one run"
        + (" on a Dask LocalCluster (CPU: this process only; the workers' CPU is not counted)." if args.dask_workers else "."),
        "",
        "| build | wall s | CPU s | wall / first | CPU / first | statuses | not_found | made infeasible (relaxation pass) "
        "| optimal re-checked | load |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, label, wall, cpu, st, n, relaxed, load, (n_opt, n_ok), _, _ in rows:
        nf = st.get("not_found", 0)
        lines.append(f"| {key}: {label} | {wall:.1f} | {cpu:.1f} | {wall / base[2]:.2f} | {cpu / base[3]:.2f} | "
                     f"{', '.join(f'{k} {v}' for k, v in st.items())} | {nf}/{n} ({nf / n:.1%}) | {relaxed} | "
                     f"{n_ok}/{n_opt} pass | {load:.1f} |")
    lines.append("")
    for key, _, _, _, _, _, _, _, _, cmp_, cont in rows[1:]:
        if cmp_ and cmp_.get("both"):
            lines.append(f"- {key} against {base[0]}: {cmp_['both']} points optimal in both; the same primitive "
                         f"(within 1e-4 of the variable scales) at {cmp_['same_x']}, largest difference "
                         f"{cmp_['max_dx']:.3g} scales; objective lower at {cmp_['lower']}, higher at {cmp_['higher']} "
                         f"(largest relative increase {cmp_['max_rel_higher']:.3g}).")
        if cont:
            lines.append(f"- {key}: primitives continued from {cont}.")
    write_text(Path(args.results), "\n".join(lines) + "\n")
    print(f"wrote {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
