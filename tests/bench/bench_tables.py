"""Benchmark: build every shipped table from scratch, then time load + check and interpolation.

Run from the repository root (one command; writes the tables, tables/index.json and the
results file)::

    nice python tests/bench/bench_tables.py [--jobs 2] [--out tables]

Old and new schedule side by side, in one run (each into its own folder under ``--out``; the
shipped tables are left alone; the first schedule named is built first)::

    nice python tests/bench/bench_tables.py --jobs 2 --schedules chains,continuation --seed-index none \
        --out /tmp/tables_bench

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
from offline.rover.table_builder import BuildOptions, build_tables, table_spec, write_index  # noqa: E402
from rtctl.table import load_table  # noqa: E402


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def _build(args: argparse.Namespace, schedule: str, out: Path) -> dict:
    """Build the tables with one schedule into ``out``; per-table rows, totals and the written paths."""
    src = Path(args.scenarios)
    grids = _folder_grids(src)
    files = sorted(f for f in src.glob("*.toml") if f.name != "grids.toml")
    rows, paths, extra = [], [], []
    refines = _folder_refine(src)
    build = BuildOptions(schedule=schedule, seed_index=args.seed_index)
    specs = [table_spec(f, grids.get(f.stem), refine=refines.get(f.stem), build=build) for f in files]
    kept = []
    if args.only:
        names = set(args.only.split(","))
        kept = [s.name for s in specs if s.name not in names]
        specs = [s for s in specs if s.name in names]
    shipped = ROOT / "tables"
    old = {s.name: (hashlib.sha256((shipped / f"{s.name}.npz").read_bytes()).hexdigest()
                    if (shipped / f"{s.name}.npz").is_file() else None) for s in specs}
    load_start = __import__("os").getloadavg()[0]
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
        print(f"[{schedule}] {s['name']}: {wall:.1f} s wall, {s['statuses']}", flush=True)

    build_tables(specs, out, jobs=args.jobs, progress=True, inputs=files, on_done=done)
    wall_all, cpu_all = time.perf_counter() - t_all, _cpu() - c_all
    paths += [out / f"{n}.npz" for n in kept]
    write_index(out, paths)
    return {"schedule": schedule, "rows": rows, "paths": paths, "extra": extra, "kept": kept, "wall": wall_all,
            "cpu": cpu_all, "load": (load_start, __import__("os").getloadavg()[0])}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "tables"),
                    help="output folder (with several --schedules: one sub-folder per schedule)")
    ap.add_argument("--scenarios", default=str(ROOT / "tables" / "scenarios"))
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_tables.md"))
    ap.add_argument("--only", help="comma-separated table names to rebuild (default: all); the others are kept as "
                                   "they are and only their reading times are measured")
    ap.add_argument("--schedules", default="continuation",
                    help="comma-separated build schedules, built one after the other in this run (continuation, "
                         "chains); the first is the baseline of the ratios, the last is the one whose reading times "
                         "are measured")
    ap.add_argument("--seed-index", default="shipped",
                    help="seed index of the continuation schedule (shipped | none | INDEX); 'none' for a build "
                         "from scratch")
    args = ap.parse_args()
    schedules = [x.strip() for x in args.schedules.split(",") if x.strip()]
    base_out = Path(args.out)
    runs = [_build(args, sc, base_out / sc if len(schedules) > 1 else base_out) for sc in schedules]
    last = runs[-1]
    paths, kept = last["paths"], last["kept"]
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
    cmd = f"nice python tests/bench/bench_tables.py --jobs {args.jobs}"
    if len(schedules) > 1 or schedules != ["continuation"]:
        cmd += f" --schedules {','.join(schedules)}"
    if args.seed_index != "shipped":
        cmd += f" --seed-index {args.seed_index}"
    if len(schedules) > 1:
        cmd += " --out <scratch folder>"
    lines = [
        "# Lookup-table benchmark",
        "",
        f"Written by `{cmd}` on {now}; {platform.machine()}, "
        f"Python {platform.python_version()}, {len(__import__('os').sched_getaffinity(0))} CPUs visible, machine shared "
        f"with other jobs (load average at the end {__import__('os').getloadavg()[0]:.1f}).",
        "",
    ]
    base = runs[0]
    for r in runs:
        ratio = (f" (wall {r['wall'] / base['wall']:.2f}, CPU {r['cpu'] / base['cpu']:.2f} of `{base['schedule']}`)"
                 if r is not base else "")
        lines.append(f"**Schedule `{r['schedule']}`: {'all ' if not r['kept'] else ''}{len(r['rows'])} tables from "
                     f"scratch: {r['wall']:.0f} s wall ({r['wall'] / 60:.1f} min), {r['cpu']:.0f} s CPU**{ratio}; "
                     f"1-min load average {r['load'][0]:.1f} at the start, {r['load'][1]:.1f} at the end.")
        lines.append("")
    lines += ["Target <= 10 min wall on 2 cores for all (moonshot 2 min). CPU time = this process + its worker "
              "processes." + (f" Not rebuilt in this run (`--only`): {', '.join(last['kept'])}." if last["kept"] else ""),
              ""]
    for r in runs:
        if len(runs) > 1:
            lines += [f"Schedule `{r['schedule']}`:", ""]
        lines += [
            "| table | grid | points | statuses | feasible | file | wall [s] | CPU of the main process [s] | "
            "same bytes as the shipped file |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for name, shape, n, st, ff, b_, w, c, same in r["rows"]:
            sts = ", ".join(f"{k} {v}" for k, v in st.items())
            lines.append(f"| {name} | {shape} | {n} | {sts} | {ff:.0%} | {b_ / 1e6:.2f} MB | {w:.0f} | {c:.0f} | {same} |")
        lines.append("")
    if len(runs) > 1:
        lines += ["Wall time per table, side by side:", "",
                  "| table | " + " | ".join(f"`{r['schedule']}` wall [s]" for r in runs) + " | ratio last / first |",
                  "|---|" + "---|" * len(runs) + "---|"]
        walls = [{row[0]: row[6] for row in r["rows"]} for r in runs]
        for name in walls[0]:
            ws = [w.get(name, float("nan")) for w in walls]
            lines.append(f"| {name} | " + " | ".join(f"{w:.0f}" for w in ws) + f" | {ws[-1] / ws[0]:.2f} |")
        lines.append("")
    lines += [f"Refinement (inserted axis values; largest checked midpoint error, variable scales) and trust radius "
              f"(SI, median / min over the feasible points), schedule `{last['schedule']}`:", "",
              "| table | refinement | largest midpoint error | trust radius median / min |", "|---|---|---|---|"]
    for name, ins, worst, trs in last["extra"]:
        lines.append(f"| {name} | {ins} | {worst:.3g} | {trs} |")
    lines += ["", f"Reading the tables of schedule `{last['schedule']}` (median; targets: load + check <= 50 ms, `at()` <= 50 us, moonshot 10 us):", "",
              "| table | load + hash/schema check [ms] | `at()` [us] | `at()` + reading every QP field [us] |",
              "|---|---|---|---|"]
    for name, lt, at, full in perf:
        lines.append(f"| {name} | {lt * 1e3:.1f} | {at * 1e6:.1f} | {full * 1e6:.1f} |")
    write_text(args.results, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
