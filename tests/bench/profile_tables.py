"""Profile a table build: where the CPU seconds go, per phase of the builder.

Run from the repository root (one process, no workers, so every second is seen)::

    nice python tests/bench/profile_tables.py rr_rim_speed_cap [--grid "speed=3"] [--results FILE]
    nice python tests/bench/profile_tables.py path/to/fl_steer_stuck.toml --schedule chains --grid "cross_slope=0"

Phases (exclusive process time, IPOPT runs and iterations in each): the first solve of each
grid point (``solve_primitive`` from the chain's warm start, split by its verdict: optimal /
infeasible / not_found), the table data of a solved point (derivatives, KKT sensitivity,
wrenches), the steering-controller re-solves, the trust-radius re-solves, the retries of
unsolved points from their neighbours, the speed-twin pass, the neighbour pass, and grid
refinement; with the continuation schedule (:mod:`offline.rover.table_continuation`) also its
groups, warm starts, the relaxation decided first and the search of what is left, and
everywhere the optimizer's independent numeric check. The build is written to a temporary
folder and discarded.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from offline.cli.tables import _folder_grids, _folder_refine  # noqa: E402
from offline.rover import primitives as P  # noqa: E402
from offline.rover import table_builder as TB  # noqa: E402
from offline.rover import table_continuation as TC  # noqa: E402
from offline.rover import table_refine as TR  # noqa: E402
from rtctl.table import load_table  # noqa: E402

_STACK: list[str] = []
_T: dict[str, float] = defaultdict(float)
_RUNS: dict[str, int] = defaultdict(int)
_ITERS: dict[str, int] = defaultdict(int)
_CALLS: dict[str, int] = defaultdict(int)
_MARK = [time.process_time()]


def _switch(to: str | None, leave: bool = False) -> None:
    now = time.process_time()
    if _STACK:
        _T[_STACK[-1]] += now - _MARK[0]
    _MARK[0] = now
    if leave:
        _STACK.pop()
    elif to is not None:
        _STACK.append(to)


def _wrap(mod: Any, name: str, phase: str | Callable[..., str]) -> None:
    fn = getattr(mod, name)

    def inner(*a: Any, **k: Any) -> Any:
        ph = phase if isinstance(phase, str) else phase(*a, **k)
        _switch(ph)
        _CALLS[ph] += 1
        try:
            out = fn(*a, **k)
        finally:
            _switch(None, leave=True)
        return out

    setattr(mod, name, inner)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("table", help="a shipped table's name (tables/scenarios) or a scenario TOML file")
    ap.add_argument("--grid", help="override the grids.toml grid (display units)")
    ap.add_argument("--schedule", choices=("continuation", "chains"), default="continuation")
    ap.add_argument("--results", help="append the breakdown to this markdown file")
    ap.add_argument("--keep", help="copy the built table to this file (default: discarded)")
    ap.add_argument("--set", action="append", default=[], metavar="OPTION=VALUE",
                    help="a BuildOptions field (bool or int), e.g. --set polish_warm=false (repeatable)")
    args = ap.parse_args()
    src = ROOT / "tables" / "scenarios"
    overrides: dict[str, Any] = {}
    for item in args.set:
        key, _, val = item.partition("=")
        if key not in TB.BuildOptions.__dataclass_fields__:
            ap.error(f"--set {item}: no BuildOptions field {key!r}")
        overrides[key] = {"true": True, "false": False}.get(val.lower(), val)
        if isinstance(overrides[key], str):
            try:
                overrides[key] = int(val)
            except ValueError:
                ap.error(f"--set {item}: expected true, false or an integer")
    build = TB.BuildOptions(schedule=args.schedule, **overrides)
    if args.table.endswith(".toml"):
        grid = args.grid
        spec = TB.table_spec(args.table, grid, build=build)
    else:
        grid = args.grid or _folder_grids(src).get(args.table)
        spec = TB.table_spec(src / f"{args.table}.toml", grid, refine=_folder_refine(src).get(args.table), build=build)

    orig_solve = P.SteadyStateProblem.solve

    def solve(self: Any, *a: Any, **k: Any) -> Any:
        r = orig_solve(self, *a, **k)
        ph = _STACK[-1] if _STACK else "other"
        _RUNS[ph] += 1
        _ITERS[ph] += int(r["iterations"])
        return r

    P.SteadyStateProblem.solve = solve  # type: ignore[method-assign]
    orig_sp = P.solve_primitive
    depth = [0]

    def solve_primitive(*a: Any, **k: Any) -> Any:
        if depth[0]:
            return orig_sp(*a, **k)
        parent = _STACK[-1] if _STACK else "other"
        _switch(f"{parent}: solve_primitive")
        depth[0] += 1
        try:
            r = orig_sp(*a, **k)
        finally:
            depth[0] -= 1
            _switch(None, leave=True)
        # re-attribute by verdict
        key = f"{parent}: solve_primitive -> {r.status}"
        src_key = f"{parent}: solve_primitive"
        _T[key] += _T.pop(src_key, 0.0)
        _RUNS[key] += _RUNS.pop(src_key, 0)
        _ITERS[key] += _ITERS.pop(src_key, 0)
        _CALLS[key] += 1
        return r

    P.solve_primitive = solve_primitive  # type: ignore[assignment]
    _wrap(TB, "_solve_point", "grid point")
    _wrap(TB, "point_data", "point data (derivatives, sensitivity, wrenches, controllers)")
    _wrap(TB, "point_trust_radius", "trust radius")
    _wrap(TB, "retry_point", "retry from neighbours")
    _wrap(TB, "polish_point", "neighbour pass")
    _wrap(TB, "twin_resolve", "speed-twin pass")
    _wrap(TB, "relaxation_verdict", "relaxation verdict")
    _wrap(TC, "continuation_group", "continuation group")
    _wrap(TC, "_try_starts", "continuation: warm starts")
    _wrap(TC, "_order", "continuation: order")
    _wrap(TC, "search_group", "search of what is left")
    _wrap(P, "check_solution", "independent check")
    _wrap(TR, "_solve_point", "refinement: point")
    _wrap(TR, "retry_point", "refinement: retry")
    if hasattr(TR, "_midpoint"):
        _wrap(TR, "_midpoint", "refinement: midpoint check")
    t0, c0 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        path, summary = TB.build_table(spec, tmp, progress=False)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if args.keep:
            import shutil

            shutil.copyfile(path, args.keep)
        t = load_table(path)
        feas = t.status == 0
        radii = []
        for name in ("slope", "speed", "cross_slope", "fy_offset", "mz_offset"):
            j = t.layout.index(name)
            v = t.arrays["trust_radius"][feas][:, j]
            u = int(np.sum(t.arrays["trust_unverified"][feas][:, j] > 0))
            radii.append(f"{name} {np.median(v):.3g} / {np.min(v):.3g} ({u} unverified)" if v.size else f"{name} -")
    lines = [f"### {Path(args.table).stem}, schedule {args.schedule}"
             + (f", {' '.join('--set ' + s for s in args.set)}" if args.set else "")
             + f" (grid {grid!r}: {summary['grid_points']} points, {summary['statuses']})", "",
             f"process CPU {cpu:.1f} s, wall {wall:.1f} s (one process); trust radius median / min: "
             + "; ".join(radii), "",
             "| phase | calls | CPU [s] | share | IPOPT runs | IPOPT iterations |", "|---|---|---|---|---|---|"]
    for k in sorted(_T, key=lambda k: -_T[k]):
        lines.append(f"| {k} | {_CALLS.get(k, 0)} | {_T[k]:.1f} | {100 * _T[k] / cpu:.0f}% | {_RUNS.get(k, 0)} | "
                     f"{_ITERS.get(k, 0)} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.results:
        with open(args.results, "a") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
