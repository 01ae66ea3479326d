"""Every shipped failure kind on every wheel, and pairs of failures, in closed loop (issue 21).

One command (from the repository root; ~10 min on a loaded 2-core machine, use ``nice``)::

    nice python tests/bench/bench_failures_every_wheel.py [--distance 1.5] [--seed 1]

For the four failure kinds the shipped tables are built for (stuck steering, rim speed capped at
half the travel speed, locked wheel, unpowered wheel) on each of the four wheels (16 cases) and
three pairs, it asks the optimizer whether a primitive exists (:func:`offline.rover.primitives.solve_primitive`
on the scenario, as ``offnominal primitive`` does) and drives the simulated mini rover (the section
7.3 world, 1.5 m at 3 cm/s) with rtctl on the shipped tables. Per case: which table rtctl drove,
whether it was an exact match, the mirror of a shipped table or the failure imposed on another
table (and that it was flagged), every command finite and within the actuator limits, and the
heading, cross-track and speed against 3 deg / 3 cm / 10 % where a primitive exists. Stuck angles
point outwards (right wheels -50 deg, left +50 deg). Results: ``tests/bench/results_failures_every_wheel.md``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

WHEELS = ("FR", "FL", "RR", "RL")
KINDS = {
    "steer_stuck": lambda w: f"steer_stuck_deg = {-50.0 if w[1] == 'R' else 50.0}",
    "rim_speed_cap": lambda w: "rim_speed_max_m_s = 0.015",
    "locked": lambda w: "locked = true",
    "unpowered": lambda w: "unpowered = true",
}
PAIRS = [(("RR", "steer_stuck_deg = -50.0"), ("FL", "rim_speed_max_m_s = 0.018")),
         (("FR", "unpowered = true"), ("RL", "steer_stuck_deg = 30.0")),
         (("RR", "unpowered = true"), ("FL", "steer_stuck_deg = -20.0"))]


def _scenario(tmp: Path, name: str, wheels: list[tuple[str, str]], params: str = "dissertation-ch7") -> Path:
    text = f'[scenario]\nname = "{name}"\nparams = "{params}"\nspeed_m_s = 0.03\n'
    for w, line in wheels:
        text += f"\n[wheels.{w}]\n{line}\n"
    p = tmp / f"{name}.toml"
    p.write_text(text)
    return p


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--distance", type=float, default=1.5)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--tables", default=None,
                    help="table index for rtctl (default: the shipped tables, on the calibrated sand; "
                         "tests/data/tables/index.json: tables on the world's own soil)")
    ap.add_argument("--params", default="dissertation-ch7",
                    help="the simulated world's wheel and soil parameters (a preset): dissertation-ch7 (section 7.3's "
                         "world, default) or calibrated-sand (the shipped tables' own soil)")
    args = ap.parse_args()

    import tempfile

    from offline.files import write_text
    from offline.rover.primitives import solve_primitive
    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.rtctl_bridge import rtctl_factory
    from offline.sim.simulator import RoverSimulator
    from offline.sim.truth import Truth
    from drive_helpers import FlagRecorder
    from rtctl.config import ControllerConfig

    act = ControllerConfig().actuators
    cases = [(f"{w.lower()}_{k}", [(w, f(w))]) for k in KINDS for w, f in ((w, KINDS[k]) for w in WHEELS)]
    cases += [("pair_" + "_".join(w.lower() for w, _ in pair), list(pair)) for pair in PAIRS]
    rows = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for name, wheels in cases:
            sc = load_scenario(_scenario(Path(tmp), name, wheels, args.params))
            prim = solve_primitive(sc)
            ctl = rtctl_factory(args.tables)(sc)
            row = {"case": name, "failures": "; ".join(f"{w} {line}" for w, line in wheels), "primitive": prim.status}
            rec = FlagRecorder()
            try:
                res = run_drive(RoverSimulator(sc, Truth.nominal(sc.params, sc.rover), seed=args.seed), ctl,
                                distance=args.distance, recorder=rec)
            except Exception as exc:  # the plant's own failure (no equilibrium) is reported, not hidden
                row["drive"] = f"simulator: {str(exc).splitlines()[0][:120]}"
                rows.append(row)
                print(name, row["drive"], flush=True)
                continue
            valid = all(all(math.isfinite(v) and act.min_rim_speed - 1e-12 <= v <= act.max_rim_speed + 1e-12
                            for v in c.rim_speed) and all(math.isfinite(b) and abs(b) <= act.max_steer + 1e-12
                                                          for b in c.steer_angle) for c in res.commands)
            tables_used = sorted({getattr(ctl, "_prep").table}) if getattr(ctl, "_prep", None) else []
            m = res.metrics
            flags = sorted({f for tick in rec.flags for f in tick})  # every flag raised during the drive
            how = ("imposed on another table" if any(f.startswith("no table for the declared failures") for f in flags)
                   else "mirror" if any("left-right mirror" in f for f in flags) else "exact table")
            ok = (m["max_abs_heading_deg"] <= 3 and m["max_abs_cross_track_cm"] <= 3 and abs(m["speed_error_pct"]) <= 10)
            row["stuck"] = (f"stuck at t = {m['stuck_at_s']:.1f} s, x = {100 * m['distance_m']:.1f} cm: "
                            + res.stuck.split("the rover is stuck, ")[-1].split(" (x =")[0]) if res.stuck else (
                f"drive ended at t = {m['ended_at_s']:.1f} s, x = {100 * m['distance_m']:.1f} cm: "
                + res.ended.split(" s: ", 1)[-1].split(" (no equilibrium")[0]) if res.ended else ""
            ok = ok and not res.ended
            row.update(table=",".join(tables_used), how=how, flagged=how != "exact table" and bool(flags), valid=valid,
                       heading=m["max_abs_heading_deg"], y=m["max_abs_cross_track_cm"], speed=m["speed_error_pct"],
                       unreachable=any(f.startswith(("target unreachable", "unreachable")) for f in flags), ok=ok)
            rows.append(row)
            print(name, row, flush=True)
    same = args.params == "calibrated-sand"
    world = ("calibrated-sand world (the shipped tables' own soil)" if same else
             f"Section 7.3 world ({args.params}: dissertation ch. 7 soil)" if args.params == "dissertation-ch7" else
             f"world {args.params}")
    if args.tables is None:
        where = ("rtctl on the shipped tables (calibrated sand" + ("" if same else ": the model differs from the world")
                 + "; rear-right failures and fr_locked: the left wheels by their mirrors, the other front failures "
                   "imposed on the nominal table)")
    else:
        where = (f"rtctl on the tables of `{Path(args.tables).as_posix()}` (front wheels imposed on the nominal table, "
                 "rear-left by mirrors)")
    cmd = (f"`nice python tests/bench/bench_failures_every_wheel.py --distance {args.distance:g} --seed {args.seed}"
           + (f" --tables {Path(args.tables).as_posix()}" if args.tables else "")
           + (f" --params {args.params}" if args.params != "dissertation-ch7" else "") + "`")
    lines = ["# Every shipped failure kind on every wheel, and pairs (issue 21)", "",
             f"{cmd}, {time.perf_counter() - t0:.0f} s. {world}; {where}.", "",
             "| case | failures | optimizer | table driven | how | flagged | commands valid | max heading [deg] | "
             "max y [cm] | speed [%] | 3/3/10 |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "drive" in r:
            lines.append(f"| {r['case']} | {r['failures']} | {r['primitive']} | | | | | {r['drive']} | | | |")
            continue
        verdict = (("pass" if r["ok"] else "FAIL") + ("; said unreachable" if r["unreachable"] else "")
                   if r["primitive"] == "optimal" else ("no primitive" + (
            ", said unreachable" if r["unreachable"] else ", NOT said unreachable")))
        if r["stuck"]:
            verdict += f"; {r['stuck']}"
        lines.append(f"| {r['case']} | {r['failures']} | {r['primitive']} | {r['table']} | {r['how']} | "
                     f"{'yes' if r['flagged'] else ('n/a' if r['how'] == 'exact table' else 'NO')} | {'yes' if r['valid'] else 'NO'} | "
                     f"{r['heading']:.2f} | {r['y']:.2f} | {r['speed']:+.1f} | {verdict} |")
    out = ("results_failures_every_wheel.md" if args.tables is None else "results_failures_every_wheel_world_tables.md")
    if args.params != "dissertation-ch7":
        out = out.replace(".md", f"_{args.params.replace('-', '_')}.md")
    write_text(ROOT / "tests" / "bench" / out, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
