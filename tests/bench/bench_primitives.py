"""Catalog benchmark and verdict audit of the steady-state optimizer (issue 8).

Run on demand::

    nice python tests/bench/bench_primitives.py [--quick]

Solves every shipped example scenario and a generated catalog (each single failure on each
wheel at several severities, pairs of failures, slopes, a cross slope, the calibrated
parameters downhill, a 40 deg slope) from the automatic start and checks every optimal
solution independently. Verdict audit: every "infeasible" is re-run with a longer and
differently seeded search (larger per-attempt iteration limit, other seed, more confirmation
starts); an audit that finds a primitive overturns the verdict. Writes
``tests/bench/results_primitives.md`` (statuses, audit counts, median and maximum solve time,
share of the time spent building NLPs, iterations).
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

from offline.files import write_text
from offline.physics.params import load_toml
from offline.rover.primitives import SolverOptions, get_problem, solve_primitive
from offline.rover.scenario import Scenario, WheelFailure, example_scenarios, load_scenario
from offline.rover.statics import WHEELS

HERE = Path(__file__).resolve().parent
NEW_EXAMPLES = ("hillside_traverse_10",)
"""Examples shipped after the 'before' measurement."""
CALIBRATED = HERE.parents[1] / "offline" / "data" / "calibrated_grousered.toml"
AUDIT = SolverOptions(max_iter=400, max_attempts=80, max_iterations=12000, confirm_starts=8, seed=101)
"""The audit's longer, differently started search."""


def catalog(base: Scenario) -> list[Scenario]:
    """Single failures on every wheel at several severities, plus pairs."""
    out = []
    v = base.speed
    for k in WHEELS:
        for frac in (0.75, 0.5):
            out.append(replace(base, name=f"{k} rim speed <= {frac:.2f} v", failures={k: WheelFailure(rim_speed_max=frac * v)}))
        for ang in (-50.0, 20.0, 50.0):
            out.append(replace(base, name=f"{k} steer stuck {ang:+.0f} deg", failures={k: WheelFailure(steer_stuck=math.radians(ang))}))
        out.append(replace(base, name=f"{k} unpowered", failures={k: WheelFailure(unpowered=True)}))
        out.append(replace(base, name=f"{k} locked", failures={k: WheelFailure(locked=True)}))
        out.append(replace(base, name=f"{k} raised", failures={k: WheelFailure(raised=True)}))
        out.append(replace(base, name=f"{k} torque <= 0.03 N m", failures={k: WheelFailure(torque_limit=0.03)}))
    pairs = [
        ("RR", WheelFailure(rim_speed_max=0.5 * v), "FR", WheelFailure(steer_stuck=math.radians(20))),
        ("RR", WheelFailure(unpowered=True), "RL", WheelFailure(torque_limit=0.1)),
        ("FL", WheelFailure(steer_stuck=math.radians(-30)), "RL", WheelFailure(rim_speed_max=0.75 * v)),
        ("FR", WheelFailure(unpowered=True), "FL", WheelFailure(unpowered=True)),
        ("RR", WheelFailure(steer_stuck=math.radians(-50)), "RL", WheelFailure(steer_stuck=math.radians(50))),
        ("FR", WheelFailure(torque_limit=0.03), "RL", WheelFailure(torque_limit=0.03)),
    ]
    for a, fa, b, fb in pairs:
        out.append(replace(base, name=f"pair {a}+{b}", failures={a: fa, b: fb}))
    for slope in (5.0, 10.0):
        out.append(replace(base, name=f"RR rim speed <= 0.75 v on {slope:.0f} deg", slope=math.radians(slope),
                           failures={"RR": WheelFailure(rim_speed_max=0.75 * v)}))
    # the cases: caps the old time budget got wrong, a steep slope, downhill skid, hillside
    for frac in (0.3, 1.0):
        out.append(replace(base, name=f"RR rim speed <= {frac:.2f} v", failures={"RR": WheelFailure(rim_speed_max=frac * v)}))
    out.append(replace(base, name="nominal on 40 deg", slope=math.radians(40.0)))
    out.append(replace(base, name="nominal on -10 deg (downhill)", slope=math.radians(-10.0)))
    cal = load_toml(CALIBRATED)["parameter_set"]
    out.append(replace(base, name="calibrated params on -10 deg", params=cal, slope=math.radians(-10.0)))
    out.append(replace(base, name="calibrated params on 10 deg", params=cal, slope=math.radians(10.0)))
    out.append(replace(base, name="cross slope 10 deg", cross_slope=math.radians(10.0)))
    out.append(replace(base, name="RR steer stuck -50 deg, cross slope 5 deg", cross_slope=math.radians(5.0),
                       failures={"RR": WheelFailure(steer_stuck=math.radians(-50))}))
    return out


def _problems() -> list:
    """The NLPs built during the run (the cache of get_problem)."""
    import gc

    from offline.rover.primitives import SteadyStateProblem

    return [o for o in gc.get_objects() if isinstance(o, SteadyStateProblem)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="examples and the first 10 catalog entries only")
    ap.add_argument("--out", default=str(HERE / "results_primitives.md"))
    args = ap.parse_args(argv)
    examples = [load_scenario(p) for p in example_scenarios()]
    base = next(s for s in examples if s.name == "nominal")
    cat = catalog(base)
    scenarios = examples + cat
    # the 54 scenarios of the benchmark before this change: the 10 examples then shipped and 44 generated
    before = [sc.name not in NEW_EXAMPLES for sc in examples] + [i < 44 for i in range(len(cat))]
    if args.quick:
        scenarios = scenarios[: len(examples) + 10]
        before = before[: len(scenarios)]
    rows = []
    t_all = time.perf_counter()
    get_problem.cache_clear()
    audit = {"confirmed": 0, "overturned": 0}
    for sc in scenarios:
        r = solve_primitive(sc)
        note = r.evidence.get("closest", "") if not r.ok else f"mean slip {r.mean_slip():.3f}, power {r.power * 1e3:.0f} mW"
        if r.status == "infeasible":
            a = solve_primitive(sc, AUDIT)
            if a.ok:
                audit["overturned"] += 1
                note += f" -- AUDIT OVERTURNED: optimal with the longer search ({a.stats['iterations']} iterations)"
            else:
                audit["confirmed"] += 1
                note += f" -- audit: {a.status} after {a.stats['iterations']} iterations"
        rows.append((sc.name, r.status, r.check_passed, r.stats["seconds"], r.stats["iterations"], note))
        print(f"{sc.name:<44} {r.status:<14} check={r.check_passed!s:<5} {r.stats['seconds']:6.2f} s "
              f"{r.stats['iterations']:6d} it", flush=True)
    wall = time.perf_counter() - t_all
    build = sum(pb.build_seconds for pb in _problems())
    times = [r[3] for r in rows]
    same = [t for t, b in zip(times, before) if b]
    counts = {st: sum(r[1] == st for r in rows) for st in ("optimal", "infeasible", "not_found", "solver_failure")}
    checked = sum(r[1] == "optimal" and r[2] for r in rows)
    opt_times = [r[3] for r in rows if r[1] == "optimal"]
    head = (f"# Driving-primitive catalog benchmark and verdict audit\n\nWritten by "
            f"`nice python tests/bench/bench_primitives.py` on {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; "
            f"{platform.machine()}, Python {platform.python_version()}, {os.cpu_count()} cores shared with other jobs. "
            f"{len(rows)} scenarios ({len(examples)} shipped examples + {len(rows) - len(examples)} generated), "
            f"solved from the automatic start with the default iteration/attempt budgets (no wall-clock limit).\n\n"
            f"- statuses: optimal {counts['optimal']} (independent check passed for {checked}); infeasible "
            f"{counts['infeasible']}; not_found {counts['not_found']}; solver_failure {counts['solver_failure']}\n"
            f"- verdict audit (each infeasible re-run with max_iter 400, 12000 iterations, 8 confirmation starts, "
            f"seed 101): confirmed {audit['confirmed']}, overturned {audit['overturned']}\n"
            f"- solve time (audits excluded), all: median {statistics.median(times):.2f} s, max {max(times):.2f} s; "
            f"optimal only: median {statistics.median(opt_times) if opt_times else math.nan:.2f} s, "
            f"max {max(opt_times) if opt_times else math.nan:.2f} s; sum {sum(times):.1f} s, of which NLP builds "
            f"{build:.1f} s ({100 * build / max(sum(times), 1e-9):.1f} %); whole run with audits {wall:.0f} s\n"
            f"- after, on the same {len(same)} scenarios as before: median {statistics.median(same):.2f} s, "
            f"max {max(same):.2f} s, sum {sum(same):.1f} s\n"
            f"- before this change (commit 74411c7, 6.5 s wall-clock budget, same 54 first scenarios): median 0.07 s, "
            f"max 7.15 s, NLP builds 4.7 s of 70.8 s (6.6 %); statuses optimal 46, infeasible 8\n\n")
    table = "| scenario | status | check | seconds | IPOPT iterations | result or closest compromise |\n|---|---|---|---|---|---|\n"
    table += "\n".join(f"| {a} | {b} | {c} | {d:.2f} | {e} | {f} |" for a, b, c, d, e, f in rows)
    write_text(args.out, head + table + "\n")
    print(head)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
