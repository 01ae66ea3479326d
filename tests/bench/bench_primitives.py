"""Catalog benchmark of the steady-state optimizer (issue: driving primitives, "Targets").

Run on demand::

    python tests/bench/bench_primitives.py [--quick]

Solves every shipped example scenario and a generated catalog (each single failure on each
wheel at several severities, and pairs of failures) from the automatic start, checks every
optimal solution independently with the numeric model, and writes
``tests/bench/results_primitives.md`` (success rate, statuses, timings).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

from offline.rover.primitives import solve_primitive
from offline.rover.scenario import Scenario, WheelFailure, example_scenarios, load_scenario
from offline.rover.statics import WHEELS

HERE = Path(__file__).resolve().parent


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
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="examples and the first 10 catalog entries only")
    ap.add_argument("--out", default=str(HERE / "results_primitives.md"))
    args = ap.parse_args(argv)
    examples = [load_scenario(p) for p in example_scenarios()]
    base = next(s for s in examples if s.name == "nominal")
    scenarios = examples + catalog(base)
    if args.quick:
        scenarios = scenarios[: len(examples) + 10]
    rows = []
    t_all = time.perf_counter()
    for sc in scenarios:
        r = solve_primitive(sc)
        rows.append((sc.name, r.status, r.check_passed, r.stats["seconds"], r.stats["iterations"],
                     r.evidence.get("closest", "") if not r.ok else f"mean slip {r.mean_slip():.3f}, power {r.power * 1e3:.0f} mW"))
        print(f"{sc.name:<38} {r.status:<10} check={r.check_passed!s:<5} {r.stats['seconds']:6.2f} s", flush=True)
    times = [r[3] for r in rows]
    n_opt = sum(r[1] == "optimal" for r in rows)
    n_inf = sum(r[1] == "infeasible" for r in rows)
    n_fail = sum(r[1] == "failed" for r in rows)
    checked = sum(r[1] == "optimal" and r[2] for r in rows)
    opt_times = [r[3] for r in rows if r[1] == "optimal"]
    head = (f"# Driving-primitive catalog benchmark\n\nWritten by `python tests/bench/bench_primitives.py` on "
            f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; {platform.machine()}, Python {platform.python_version()}. "
            f"{len(rows)} scenarios ({len(examples)} shipped examples + {len(rows) - len(examples)} generated), "
            f"solved from the automatic start, total {time.perf_counter() - t_all:.0f} s (including NLP builds).\n\n"
            f"- optimal: {n_opt} (independent numeric check passed for {checked}); infeasible (with evidence): {n_inf}; "
            f"failed: {n_fail}\n"
            f"- solve time, all: median {statistics.median(times):.2f} s, max {max(times):.2f} s; "
            f"optimal only: median {statistics.median(opt_times) if opt_times else math.nan:.2f} s, "
            f"max {max(opt_times) if opt_times else math.nan:.2f} s\n"
            f"- targets: median <= 1 s, max <= 10 s; 'infeasible' is the tool's verdict after continuation and "
            f"restarts, not a proof of infeasibility\n\n")
    table = "| scenario | status | check | seconds | IPOPT iterations | result or closest compromise |\n|---|---|---|---|---|---|\n"
    table += "\n".join(f"| {a} | {b} | {c} | {d:.2f} | {e} | {f} |" for a, b, c, d, e, f in rows)
    Path(args.out).write_text(head + table + "\n")
    print(head)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
