"""Benchmark: build every shipped table from scratch, then time load + check and interpolation.

Run from the repository root (one command; writes the tables, tables/index.json and the
results file)::

    nice python tests/bench/bench_tables.py [--jobs 2] [--out tables]

Per table: wall time, CPU time (this process and its worker processes), grid size, statuses,
feasible fraction, file size, and whether the new file is byte-identical to the one it replaces
(a rebuild of the same inputs must give the same bytes). Then for each table: load + hash/schema
check (median of 20), and ``Table.at`` at 2000 seeded random operating points (median per call).
Targets (issue 11): all tables <= 10 min on this 2-core machine (moonshot 2 min); load + check
<= 50 ms; interpolation <= 50 us (moonshot 10 us).
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import resource
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from offline.cli.tables import _folder_grids, _folder_refine  # noqa: E402
from offline.files import write_text  # noqa: E402
from offline.rover.table_builder import build_tables, table_spec, write_index  # noqa: E402
from rtctl.table import load_table  # noqa: E402


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tables"))
    ap.add_argument("--scenarios", default=str(ROOT / "tables" / "scenarios"))
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_tables.md"))
    ap.add_argument("--only", help="comma-separated table names to rebuild (default: all); the others are kept as "
                                   "they are and only their reading times are measured")
    args = ap.parse_args()
    src, out = Path(args.scenarios), Path(args.out)
    grids = _folder_grids(src)
    files = sorted(f for f in src.glob("*.toml") if f.name != "grids.toml")
    rows, paths, extra = [], [], []
    refines = _folder_refine(src)
    specs = [table_spec(f, grids.get(f.stem), refine=refines.get(f.stem)) for f in files]
    kept = []
    if args.only:
        names = set(args.only.split(","))
        kept = [s.name for s in specs if s.name not in names]
        specs = [s for s in specs if s.name in names]
    old = {s.name: (hashlib.sha256((out / f"{s.name}.npz").read_bytes()).hexdigest()
                    if (out / f"{s.name}.npz").is_file() else None) for s in specs}
    t_all, c_all = time.perf_counter(), _cpu()
    clock = [t_all, c_all]

    def done(path: Path, s: dict) -> None:
        # CPU of worker processes is counted when they exit (end of the run): per table, the
        # wall time is exact and the CPU time is this process's share only; the total is complete
        wall, cpu = time.perf_counter() - clock[0], _cpu() - clock[1]
        clock[:] = [time.perf_counter(), _cpu()]
        new_sha = hashlib.sha256(path.read_bytes()).hexdigest()
        prev = old[s["name"]]
        same = "no previous file" if prev is None else ("yes" if prev == new_sha else "NO")
        rows.append((s["name"], "x".join(map(str, s["shape"])), s["grid_points"], s["statuses"], s["feasible_fraction"],
                     s["bytes"], wall, cpu, same))
        t = load_table(path)
        ref = s.get("refinement")
        ins = ("; ".join(f"{k} +{len(v)}" for k, v in ref["inserted"].items()) or "none") + f" ({ref['stopped']})" \
            if ref else "not asked"
        errs = [c["error"] for c in ref["checks"]] if ref else []
        worst = max((e if e is not None else float("inf") for e in errs), default=float("nan"))
        trs = []
        if t.feasible.any():
            for n in ("slope", "speed", "cross_slope"):
                col = t.arrays["trust_radius"][t.feasible][:, t.layout.index(n)]
                unv = int(np.sum(t.arrays["trust_unverified"][t.feasible][:, t.layout.index(n)] > 0))
                trs.append(f"{n} {np.median(col):.3g} / {col.min():.3g} ({unv} unverified)")
        extra.append((s["name"], ins, worst, "; ".join(trs) or "-"))
        paths.append(path)
        print(f"{s['name']}: {wall:.1f} s wall, {s['statuses']}", flush=True)

    build_tables(specs, out, jobs=args.jobs, progress=True, inputs=files, on_done=done)
    wall_all, cpu_all = time.perf_counter() - t_all, _cpu() - c_all
    paths += [out / f"{n}.npz" for n in kept]
    write_index(out, paths)
    # load + check, interpolation
    rng = np.random.default_rng(0)
    perf = []
    for p in paths:
        ts = []
        for _ in range(20):
            t0 = time.perf_counter()
            t = load_table(p)
            ts.append(time.perf_counter() - t0)
        if not t.feasible.any():
            perf.append((t.name, statistics.median(ts), float("nan"), float("nan")))
            continue
        ops = [{k: float(rng.uniform(v[0], v[-1])) for k, v in t.axes.items()} for _ in range(2000)]
        per = []
        for op in ops:
            t0 = time.perf_counter()
            t.at(**op)
            per.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for op in ops:
            tp = t.at(**op)
            tp.x, tp.jac_g_x, tp.jac_g_p, tp.hess_lag, tp.hess_lag_xp, tp.grad_f, tp.dx_dp, tp.wrench_jac, tp.active, tp.controllers
        full = (time.perf_counter() - t0) / len(ops)
        perf.append((t.name, statistics.median(ts), statistics.median(per), full))
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Lookup-table benchmark",
        "",
        f"Written by `nice python tests/bench/bench_tables.py --jobs {args.jobs}` on {now}; {platform.machine()}, "
        f"Python {platform.python_version()}, {len(__import__('os').sched_getaffinity(0))} CPUs visible, machine shared "
        f"with other jobs (load average at the end {__import__('os').getloadavg()[0]:.1f}).",
        "",
        f"**{'All ' if not kept else ''}{len(rows)} tables from scratch: {wall_all:.0f} s wall ({wall_all / 60:.1f} min), "
        f"{cpu_all:.0f} s CPU** (target <= 10 min wall on 2 cores for all; moonshot 2 min). CPU time = this process + "
        "its worker processes." + (f" Not rebuilt in this run (`--only`): {', '.join(kept)}." if kept else ""),
        "",
        "| table | grid | points | statuses | feasible | file | wall [s] | CPU of the main process [s] | same bytes as before |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, shape, n, st, ff, b, w, c, same in rows:
        sts = ", ".join(f"{k} {v}" for k, v in st.items())
        lines.append(f"| {name} | {shape} | {n} | {sts} | {ff:.0%} | {b / 1e6:.2f} MB | {w:.0f} | {c:.0f} | {same} |")
    lines += ["", "Refinement (inserted axis values; largest checked midpoint error, variable scales) and trust radius "
              "(SI, median / min over the feasible points):", "",
              "| table | refinement | largest midpoint error | trust radius median / min |", "|---|---|---|---|"]
    for name, ins, worst, trs in extra:
        lines.append(f"| {name} | {ins} | {worst:.3g} | {trs} |")
    lines += ["", "Reading the tables (median; targets: load + check <= 50 ms, `at()` <= 50 us, moonshot 10 us):", "",
              "| table | load + hash/schema check [ms] | `at()` [us] | `at()` + reading every QP field [us] |",
              "|---|---|---|---|"]
    for name, lt, at, full in perf:
        lines.append(f"| {name} | {lt * 1e3:.1f} | {at * 1e6:.1f} | {full * 1e6:.1f} |")
    write_text(args.results, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
