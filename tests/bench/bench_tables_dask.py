"""Benchmark: one table built on a Dask ``LocalCluster`` of this machine's workers against ``--jobs 1``
(and the local process pool), in one run; and an estimate of a full sweep on a larger cluster.

Run from the repository root (one command; writes the results file)::

    nice python tests/bench/bench_tables_dask.py [--scenario tables/scenarios/rr_unpowered.toml]

Three builds of the same spec, one after the other, into a scratch folder (deleted at the end):

1. ``--jobs 1``: in this process, every task timed where it runs (``table_builder._run`` is
   wrapped): the per-point CPU cost and the build's waves (the task lists ``build_table``
   submits together and waits for).
2. Dask: a ``distributed.LocalCluster`` (``--workers`` worker processes, one thread each),
   started by another process before the timer and reached only through its ``tcp://``
   address, as ``offnominal tables build --scheduler tcp://...`` does (:func:`offline.rover.table_builder.build_table` with ``scheduler=``). Worker CPU is read
   on each worker (``getrusage``) before and after.
3. ``--jobs N`` local processes (the default executor of ``offnominal tables build``).

The three files must be byte-identical (checked). The estimate of a full sweep (every wheel of the
mini rover x every single-wheel failure kind, default grids) uses the measured per-point CPU cost
and the measured waves of build 1; it is printed and written as an estimate with its assumptions.
"""

from __future__ import annotations

import argparse
import heapq
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from offline.cli.tables import _folder_grids  # noqa: E402
from offline.files import write_text  # noqa: E402
from offline.rover import table_builder, table_refine  # noqa: E402
from offline.rover.table_builder import BuildOptions, build_table, table_spec  # noqa: E402

WHEELS = ("FR", "FL", "RR", "RL")
"""The mini rover's wheels (dissertation Fig. 7.2)."""
SWEEP_KINDS = {
    "steer_stuck": "steer_stuck_deg = -30.0",
    "rim_speed_cap": "rim_speed_max_m_s = 0.015",
    "locked": "locked = true",
    "unpowered": "unpowered = true",
    "raised": "raised = true",
    "torque_limit": "torque_limit_Nm = 0.2",
}
"""Every single-wheel failure kind a scenario file names by a shorthand (the steering range is a
limit, not a failure); the value is only a start: the family axis, where the kind has one, spans
its default range."""


CLUSTER_SCRIPT = """
import sys
from distributed import LocalCluster
with LocalCluster(n_workers=int(sys.argv[1]), threads_per_worker=1, processes=True, dashboard_address=None) as c:
    print(c.scheduler_address, flush=True)
    sys.stdin.read()  # until the benchmark closes the pipe
"""
"""Started with ``python -c``: a cluster in its own process, as an existing cluster would be."""


def _cpu_self() -> float:
    s = resource.getrusage(resource.RUSAGE_SELF)
    return s.ru_utime + s.ru_stime


def _cpu_children() -> float:
    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return c.ru_utime + c.ru_stime


def _worker_cpu() -> float:
    """CPU seconds of the calling process (run on each Dask worker)."""
    return _cpu_self()


def _lpt(durations: list[float], workers: int) -> float:
    """Makespan of the longest-processing-time-first schedule of independent tasks on ``workers``."""
    loads = [0.0] * min(workers, max(len(durations), 1))
    heapq.heapify(loads)
    for d in sorted(durations, reverse=True):
        heapq.heapreplace(loads, loads[0] + d)
    return max(loads)


def _sweep_specs(tmp: Path) -> list[tuple[str, int]]:
    """(name, grid points) of every wheel x kind table with the default grid and family axis."""
    out = []
    for w in WHEELS:
        for kind, line in SWEEP_KINDS.items():
            f = tmp / f"{w.lower()}_{kind}.toml"
            write_text(f, f'[scenario]\nname = "{w.lower()}_{kind}"\nparams = "calibrated-sand"\n'
                          f'rover = "mini-rover-t72"\nspeed_m_s = 0.03\n\n[wheels.{w}]\n{line}\n')
            out.append((f.stem, table_spec(f).grid.size))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default=str(ROOT / "tables" / "scenarios" / "rr_unpowered.toml"))
    ap.add_argument("--grid", help="grid override (default: the scenario folder's grids.toml, else the default grid)")
    ap.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)),
                    help="Dask workers and local processes (default: the CPUs visible)")
    ap.add_argument("--sweep-workers", type=int, default=64, help="cluster size of the full-sweep estimate")
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_tables_dask.md"))
    args = ap.parse_args()
    from distributed import Client

    scen = Path(args.scenario)
    grid = args.grid or _folder_grids(scen.parent).get(scen.stem)
    spec = table_spec(scen, grid, build=BuildOptions(seed_index="none"))
    tmp = Path(tempfile.mkdtemp(prefix="bench_tables_dask_"))
    rows = []
    try:
        # 1. --jobs 1, every task timed in this process
        waves: list[list[float]] = []
        run0 = table_builder._run

        def timed_run(tasks, ex, done):  # noqa: ANN001, ANN202 - same signature as table_builder._run
            if ex is not None:
                raise RuntimeError("the timed build must run in this process (jobs=1)")
            ds = []
            for fn, a, tid in tasks:
                t0 = time.process_time()
                r = fn(*a)
                ds.append(time.process_time() - t0)
                done(tid, r)
            waves.append(ds)

        table_builder._run = table_refine._run = timed_run
        try:
            load0, t0, c0 = os.getloadavg()[0], time.perf_counter(), _cpu_self()
            p1, s1 = build_table(spec, tmp / "jobs1", jobs=1, progress=False)
            rows.append(("`--jobs 1` (this process)", time.perf_counter() - t0, _cpu_self() - c0, load0,
                         os.getloadavg()[0]))
        finally:
            table_builder._run = table_refine._run = run0
        # 2. Dask LocalCluster of worker processes, started by another process and reached only
        #    through its tcp:// address (as `offnominal tables build --scheduler tcp://...`)
        starter = subprocess.Popen([sys.executable, "-c", CLUSTER_SCRIPT, str(args.workers)], stdin=subprocess.PIPE,
                                   stdout=subprocess.PIPE, text=True, cwd=str(ROOT))
        try:
            address = starter.stdout.readline().strip()
            if not address.startswith("tcp://"):
                raise RuntimeError(f"the cluster process printed {address!r}, not a tcp:// address")
            with Client(address) as client:
                client.wait_for_workers(args.workers)
                w0 = sum(client.run(_worker_cpu).values())
                load0, t0, c0 = os.getloadavg()[0], time.perf_counter(), _cpu_self()
                p2, _ = build_table(spec, tmp / "dask", scheduler=address, progress=False)
                wall = time.perf_counter() - t0
                cpu = _cpu_self() - c0 + sum(client.run(_worker_cpu).values()) - w0
            rows.append((f"Dask `LocalCluster` in another process, {args.workers} worker processes x 1 thread, "
                         "`scheduler=tcp://...`", wall, cpu, load0, os.getloadavg()[0]))
        finally:
            starter.stdin.close()
            starter.wait(timeout=60)
        # 3. local process pool
        load0, t0, c0 = os.getloadavg()[0], time.perf_counter(), _cpu_self() + _cpu_children()
        p3, _ = build_table(spec, tmp / "pool", jobs=args.workers, progress=False)
        rows.append((f"`--jobs {args.workers}` (local process pool)", time.perf_counter() - t0,
                     _cpu_self() + _cpu_children() - c0, load0, os.getloadavg()[0]))
        same = p1.read_bytes() == p2.read_bytes() == p3.read_bytes()
        sweep = _sweep_specs(tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    n = s1["grid_points"]
    task_cpu = sum(sum(w) for w in waves)
    per_point = rows[0][2] / n
    crit = sum(max(w) for w in waves if w)
    n_sweep = sum(k for _, k in sweep)
    sw = args.sweep_workers
    lpt_one = sum(_lpt(w, sw) for w in waves if w)
    # tables in sequence (build_tables today): each table's waves on the whole cluster; a table with
    # k times the points of the measured one taken as k times as many tasks of the same durations
    seq, seq_long = 0.0, 0.0
    for _, k in sweep:
        scale = k / n
        whole, frac = int(scale), scale - int(scale)
        seq += sum(_lpt(w * whole + w[:round(frac * len(w))], sw) for w in waves if w)
        seq_long += sum(_lpt([d * scale for d in w], sw) for w in waves if w)
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    cmd = "nice python tests/bench/bench_tables_dask.py" + (
        f" --scenario {scen.relative_to(ROOT) if scen.resolve().is_relative_to(ROOT) else scen.name}"
        if scen.resolve() != (ROOT / "tables" / "scenarios" / "rr_unpowered.toml").resolve() else "")
    if args.grid:
        cmd += f' --grid "{args.grid}"'
    base_wall = rows[0][1]
    lines = [
        "# Table build on a Dask cluster",
        "",
        f"Written by `{cmd}` on {now}; {platform.machine()}, Python {platform.python_version()}, "
        f"{len(os.sched_getaffinity(0))} CPUs visible, machine shared with other jobs.",
        "",
        f"Table `{spec.name}` ({'x'.join(map(str, spec.grid.shape))} = {n} points, statuses "
        f"{', '.join(f'{k} {v}' for k, v in s1['statuses'].items())}), continuation schedule, no seed index, "
        "built three times one after the other in this run. The cluster is started by another process "
        "before the timer (its start-up is not counted) and reached only through its `tcp://` address, as "
        "`offnominal tables build --scheduler tcp://...` does.",
        "",
        "| build | wall [s] | speed-up vs `--jobs 1` | CPU [s] | 1-min load at start / end |",
        "|---|---|---|---|---|",
    ]
    for name, wall, cpu, la, lb in rows:
        lines.append(f"| {name} | {wall:.1f} | {base_wall / wall:.2f} | {cpu:.1f} | {la:.1f} / {lb:.1f} |")
    lines += [
        "",
        f"Byte-identical table files from the three builds: **{'yes' if same else 'NO'}**.",
        "",
        "## Where the time goes (from the `--jobs 1` build)",
        "",
        f"- CPU per grid point: **{per_point:.2f} s** ({rows[0][2]:.1f} s / {n} points; the tasks themselves "
        f"{task_cpu:.1f} s, the rest is this process's own work between waves).",
        f"- {len(waves)} waves (task lists submitted together and waited for), "
        f"{sum(len(w) for w in waves)} tasks; tasks per wave: {', '.join(str(len(w)) for w in waves)}.",
        f"- Critical path (sum over waves of the longest task): {crit:.1f} s, so no cluster builds this table "
        f"in less than about {crit:.0f} s of wall time; the measured wall times above are bounded the same way.",
        "",
        f"## ESTIMATE (not measured): a full sweep on {sw} workers",
        "",
        f"Every wheel ({', '.join(WHEELS)}) x every single-wheel failure kind ({', '.join(SWEEP_KINDS)}) with the "
        f"default grid and the kind's family axis: {len(sweep)} tables, {n_sweep} grid points "
        f"({', '.join(f'{k}' for _, k in sweep[:len(SWEEP_KINDS)])} points per wheel).",
        "",
        f"- CPU: {n_sweep} points x {per_point:.2f} s = **{n_sweep * per_point / 3600:.1f} CPU-hours** "
        f"(assumes every kind costs per point what `{spec.name}` cost here; the worked example "
        "(stuck steering) measured 681 CPU-s for 252 points, 2.7 s per point, in results_new_failure.md).",
        f"- Perfect division over {sw} workers: {n_sweep * per_point / sw / 60:.1f} min.",
        f"- Tables one after the other, as `build_tables` runs them today, each table's waves on all {sw} "
        f"workers (a table with k times the points of `{spec.name}` taken as k times as many tasks of the "
        f"measured durations per wave; LPT schedule): about **{seq / 60:.1f} min** "
        f"({spec.name} alone: {lpt_one:.0f} s). If instead the same number of tasks each take k times as long "
        f"(a family axis walked inside one task): about **{seq_long / 60:.1f} min**. The gap to the perfect "
        "division is the waves: within a table the build waits for each wave before the next.",
        f"- Not included: the cluster's start-up, shipping the spec to the workers, and load from others on the "
        "workers. With tables submitted concurrently (not implemented) the sweep would approach the perfect "
        "division.",
    ]
    write_text(args.results, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
