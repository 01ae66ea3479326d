"""Benchmark: several tables on one Dask ``LocalCluster``, one after another against all at once
(``build_tables(..., tables_at_once=)``, ``offnominal tables build FOLDER --scheduler ...``).

Run from the repository root (one command; writes the results file)::

    nice python tests/bench/bench_tables_at_once.py [--workers 2] [--grid "slope=0,5;cross_slope=0;speed=2,4"]

Four shipped scenarios (nominal, rr_unpowered, rr_steer_stuck, rr_rim_speed_cap) on one small grid,
built three ways in this run, into scratch folders (deleted at the end):

1. ``--jobs 1`` in this process (the CPU the tables cost);
2. on a ``LocalCluster`` of ``--workers`` worker processes (one thread each), reached by its
   ``tcp://`` address, the tables one after another (``tables_at_once=1``: the code before this
   option);
3. on a fresh cluster of the same size, every table at once (the default now).

The files of the three builds must be byte-identical (checked). Wall time is the measure of 2
against 3 (fresh clusters of the same size, same run); the machine's 1-minute load is written beside each.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from offline.files import write_text  # noqa: E402
from offline.rover.table_builder import BuildOptions, build_tables, table_spec  # noqa: E402

SCENARIOS = ("nominal", "rr_unpowered", "rr_steer_stuck", "rr_rim_speed_cap")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)))
    ap.add_argument("--grid", default="slope=0,5;cross_slope=0;speed=2,4")
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_tables_at_once.md"))
    a = ap.parse_args()
    from distributed import LocalCluster

    specs = []
    for name in SCENARIOS:
        path = ROOT / "tables" / "scenarios" / f"{name}.toml"
        grid = a.grid + (";steer_stuck=-50" if name == "rr_steer_stuck" else "")
        grid += ";rim_speed_cap_fraction=0.5" if name == "rr_rim_speed_cap" else ""
        specs.append(table_spec(path, grid=grid, build=BuildOptions(seed_index="none")))
    tmp = Path(tempfile.mkdtemp(prefix="bench_at_once_"))
    rows = []
    files: dict[str, dict[str, bytes]] = {}
    try:
        c0, w0, l0 = time.process_time(), time.perf_counter(), os.getloadavg()[0]
        built = build_tables(specs, tmp / "jobs1", jobs=1, progress=False)
        rows.append(("`--jobs 1` in this process", time.perf_counter() - w0, time.process_time() - c0, l0, os.getloadavg()[0]))
        files["jobs1"] = {p.name: p.read_bytes() for p, _ in built}
        for label, at_once in (("one after another", 1), ("all at once", None)):
            # a fresh cluster for each (its workers build their NLPs anew: neither run inherits the
            # other's warm workers), started before the timer
            with LocalCluster(n_workers=a.workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
                w0, l0 = time.perf_counter(), os.getloadavg()[0]
                built = build_tables(specs, tmp / label.replace(" ", "_"), scheduler=cluster.scheduler_address,
                                     progress=False, tables_at_once=at_once)
                rows.append((f"LocalCluster, {a.workers} workers, tables {label}", time.perf_counter() - w0, float("nan"),
                             l0, os.getloadavg()[0]))
                files[label] = {p.name: p.read_bytes() for p, _ in built}
                print(rows[-1], flush=True)
        same = all(files[k] == files["jobs1"] for k in files)
        seq, par = rows[1][1], rows[2][1]
        lines = [
            "# Several tables on one Dask cluster: one after another against all at once", "",
            f"Written by `nice python tests/bench/bench_tables_at_once.py --workers {a.workers} --grid \"{a.grid}\"` on "
            f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; {platform.machine()}, Python {platform.python_version()}, "
            f"{len(os.sched_getaffinity(0))} CPUs visible.", "",
            f"Tables: {', '.join(s.name for s in specs)} ({', '.join(str(s.grid.size) for s in specs)} points), no seed index.", "",
            "| build | wall [s] | CPU of this process [s] | 1-min load at start / end |", "|---|---|---|---|",
            *[f"| {r[0]} | {r[1]:.1f} | {r[2]:.1f} | {r[3]:.1f} / {r[4]:.1f} |" for r in rows], "",
            f"All at once against one after another (a fresh cluster each): **{seq / par:.2f}x** faster (wall, same run).",
            f"Byte-identical table files from the three builds: **{'yes' if same else 'NO'}**.", "",
        ]
        write_text(a.results, "\n".join(lines) + "\n")
        print("\n".join(lines))
        return 0 if same else 1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
