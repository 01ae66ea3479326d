"""Rover commands: primitive, slope-sweep, envelope, chapter7 (steady-state optimizer, ch. 7)."""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from .common import load_scenario_or_fail, parameter_set_or_fail

__all__ = ["register"]


def cmd_primitive(args: argparse.Namespace) -> int:
    from ..rover.primitives import lowest_speed_cap, solve_primitive, steering_controllers

    sc = load_scenario_or_fail(args.scenario)
    if sc is None:
        return 2
    if args.params:
        ps, _ = parameter_set_or_fail(args.params)
        if ps is None:
            return 2
        sc = replace(sc, params=ps)
    r = solve_primitive(sc)
    print(f"scenario {sc.name}: {sc.description}")
    print(f"slope {math.degrees(sc.slope):.1f} deg, cross slope {math.degrees(sc.cross_slope):.1f} deg, "
          f"speed {sc.speed * 100:.2f} cm/s")
    if sc.rover_file is not None:
        rf = sc.rover_file
        print(f"rover {rf.name}: {len(rf.wheels)} wheels {', '.join(rf.wheel_names)}, suspension {rf.suspension}, "
              f"weight {rf.weight:.1f} N (file {rf.path})")
    print(f"status: {r.status}  ({r.stats['n_attempts']} IPOPT runs, {r.stats['iterations']} iterations, "
          f"{r.stats['seconds']:.2f} s)")
    print("  " + "\n  ".join(r.stats["attempts"]))
    print(r.table())
    print(f"independent numeric check: {'passed' if r.check_passed else 'FAILED'}; largest residuals: "
          + ", ".join(f"{k} {v:.2e}" for k, v in sorted(r.residuals.items(), key=lambda kv: -abs(kv[1]))[:3]))
    if r.trench is not None:
        t = r.trench
        print(f"trench: {t.shape}, depth {t.d * 1e3:.1f} mm, flat width {t.p * 1e3:.1f} mm, rim-side pile {t.h_R2 * 1e3:.1f} mm")
    if r.evidence:
        print("evidence: " + "; ".join(f"{k}: {v}" for k, v in r.evidence.items()))
    for k, f in sc.failures.items():
        if args.lowest_cap and (f.rim_speed_max < math.inf):
            cap, _ = lowest_speed_cap(sc, k)
            print(f"lowest rim-speed cap on {k} verified to solve: {cap * 100:.2f} cm/s "
                  "(see `offnominal chapter7` for the dissertation's 1.5 cm/s)")
    if args.controllers and r.ok:
        ctl = steering_controllers(sc, r)
        for name, gains in ctl.items():
            unit = "N m" if name.startswith("Mz") else "N"
            print(f"steering controller {name} (per {unit}): " + ", ".join(
                f"{k} d(rim) {g[0] * 100:+.3f} cm/s, d(steer) {math.degrees(g[1]):+.2f} deg" for k, g in gains.items()))
    # exit codes: 0 optimal, 1 infeasible (a verdict), 3 not found within the budget, 4 solver failure
    return {"optimal": 0, "infeasible": 1, "not_found": 3, "solver_failure": 4}[r.status]


def cmd_slope_sweep(args: argparse.Namespace) -> int:
    import csv

    from ..rover.primitives import slope_sweep

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = args.scenarios or ["nominal", "rr_speed_cap_half", "rr_steer_stuck_50"]
    slopes = list(np.arange(0.0, args.max_deg + 1e-9, args.step_deg))
    rows, results = [], {}
    for n in names:
        sc = load_scenario_or_fail(n)
        if sc is None:
            return 2
        t0 = time.perf_counter()

        def say(a: float, r: Any, n: str = n) -> None:
            print(f"  {n}: slope {a:5.1f} deg -> {r.status}", flush=True)

        res = slope_sweep(sc, slopes, progress=None if args.quiet else say)
        results[n] = res
        for r in res:
            rows.append([n, math.degrees(r.scenario.slope), r.status, r.mean_slip() if r.ok else math.nan,
                         r.max_slip() if r.ok else math.nan, r.power if r.ok else math.nan, r.stats["seconds"]])
        feas = [r for r in res if r.ok]
        steep = math.degrees(feas[-1].scenario.slope) if feas else math.nan
        cross = next((math.degrees(r.scenario.slope) for r in feas if r.mean_slip() >= 0.5), math.nan)
        print(f"{n}: flat-ground mean slip {feas[0].mean_slip() if feas else math.nan:.3f}, max slip "
              f"{feas[0].max_slip() if feas else math.nan:.3f}; steepest solved slope {steep:.1f} deg; "
              f"mean slip >= 0.5 from {cross:.1f} deg  ({time.perf_counter() - t0:.1f} s)")
    with (out / "slope_sweep.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["scenario", "slope_deg", "status", "mean_slip_unaffected", "max_slip", "power_W", "seconds"])
        w.writerows(rows)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for n, res in results.items():
        feas = [r for r in res if r.ok]
        a = [math.degrees(r.scenario.slope) for r in feas]
        line, = ax[0].plot(a, [r.mean_slip() for r in feas], "-o", ms=3, label=f"{n} (mean, unaffected)")
        ax[0].plot(a, [r.max_slip() for r in feas], "--", color=line.get_color(), label=f"{n} (max)")
        ax[1].plot(a, [r.power * 1e3 for r in feas], "-o", ms=3, color=line.get_color(), label=n)
    ax[0].axhline(0.5, color="k", lw=0.8, ls=":")
    ax[0].set(xlabel="slope [deg]", ylabel="slip ratio", title="slip vs slope (cf. Fig. 7.12)")
    ax[1].set(xlabel="slope [deg]", ylabel="mechanical power sum(T w) [mW]", title="power vs slope")
    for a_ in ax:
        a_.grid(alpha=0.3)
        a_.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "slope_sweep.png", dpi=110)
    plt.close(fig)
    from ..rover.reference import CHAPTER7

    print("dissertation (Fig. 7.12): " + "; ".join(f"{r.quantity} {r.value:g} {r.unit}" for r in CHAPTER7
                                                   if "slip" in r.key or "slope" in r.key))
    print(f"wrote {out / 'slope_sweep.csv'} and {out / 'slope_sweep.png'}")
    return 0


def cmd_envelope(args: argparse.Namespace) -> int:
    from ..rover.primitives import envelope

    sc = load_scenario_or_fail(args.scenario)
    if sc is None:
        return 2
    e = envelope(sc, args.slip_limit, step_deg=args.step_deg, max_deg=args.max_deg)
    print(f"{sc.name}: steepest feasible slope {e['steepest_slope_deg']:.2f} deg "
          f"(bracket {e.get('steepest_slope_bracket_deg')}); mean slip of unaffected wheels reaches "
          f"{args.slip_limit:.2f} at {e['slip_limit_slope_deg']:.2f} deg")
    return 0


def cmd_chapter7(args: argparse.Namespace) -> int:
    """The chapter-7 reference table (:mod:`offline.rover.reference`) beside our numbers."""
    import csv

    from ..files import check_output_dir, write_text
    from ..rover.reference import CHAPTER7, QUICK, compare, compute

    out = check_output_dir(args.out, names=["chapter7.csv"])
    t0 = time.perf_counter()
    rows = []
    refs = [r for r in CHAPTER7 if not args.quick or r.key in QUICK]
    print(f"{'quantity':<66} {'dissertation':>14} {'ours':>10}  verdict")
    failed = 0
    for ref in refs:
        ours = compute(ref.key, step_deg=args.step_deg) if not args.table_only else math.nan
        ok, why = compare(ref, ours)
        failed += (not ok) and not args.table_only
        shown = f"{ours:.2f}" if math.isfinite(ours) else "-"
        print(f"{ref.quantity:<66} {ref.value:>9g} {ref.unit:<4} {shown:>10}  "
              + ("(table only)" if args.table_only else ("ok: " if ok else "CHECK: ") + why) + f"  [{ref.source}]",
              flush=True)
        rows.append([ref.key, ref.quantity, ref.value, ref.unit, shown, ref.tolerance, ref.matched, ok, ref.why, ref.source])
    import io

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["key", "quantity", "dissertation", "unit", "ours", "tolerance", "matched", "rule_passed", "why", "source"])
    w.writerows(rows)
    write_text(out / "chapter7.csv", buf.getvalue())
    print(f"wrote {out / 'chapter7.csv'}  ({time.perf_counter() - t0:.0f} s)")
    return 1 if failed else 0


def register(sub: Any) -> None:
    """Add this module's commands to the ``offnominal`` sub-parser."""
    pr = sub.add_parser("primitive", help="solve a driving scenario (failures, trenching, slope) for a steady primitive",
                        description="Solve the steady-state NLP (7.25) for a scenario TOML (or the name of a shipped "
                                    "example) from the automatic start; print wheel speeds, angles, loads, sinkages, "
                                    "slips, torques, power, the independent check and, if infeasible, the evidence. Budgets count "
                                    "IPOPT iterations and attempts (same verdict on any machine load). Exit code: 0 "
                                    "optimal, 1 infeasible, 3 not found within the budget, 4 solver failure.")
    pr.add_argument("scenario", help="scenario TOML path, or a shipped example name (e.g. rr_steer_stuck_50)")
    pr.add_argument("--params", help="parameter TOML replacing the scenario's (e.g. offline/data/calibrated_grousered.toml)")
    pr.add_argument("--controllers", action="store_true", help="also the steering controllers of section 7.2.4")
    pr.add_argument("--lowest-cap", action="store_true", help="bisect the lowest reachable rim-speed cap")
    pr.set_defaults(func=cmd_primitive)

    ss = sub.add_parser("slope-sweep", help="Fig. 7.12: slip and power against slope for several scenarios (CSV, PNG)")
    ss.add_argument("scenarios", nargs="*", help="scenario files or shipped names (default: nominal, "
                                                 "rr_speed_cap_half, rr_steer_stuck_50)")
    ss.add_argument("--max-deg", type=float, default=25.0, help="largest slope (default: %(default)s)")
    ss.add_argument("--step-deg", type=float, default=2.5, help="slope step (default: %(default)s)")
    ss.add_argument("--out", default="out/slope_sweep", help="output folder (default: %(default)s)")
    ss.add_argument("--quiet", action="store_true", help="no progress lines")
    ss.set_defaults(func=cmd_slope_sweep)

    en = sub.add_parser("envelope", help="steepest feasible slope and the slope where slip crosses a limit")
    en.add_argument("scenario", help="scenario TOML path or shipped name")
    en.add_argument("--slip-limit", type=float, default=0.5, help="slip limit (default: %(default)s)")
    en.add_argument("--step-deg", type=float, default=2.5, help="sweep step (default: %(default)s)")
    en.add_argument("--max-deg", type=float, default=40.0, help="largest slope tried (default: %(default)s)")
    en.set_defaults(func=cmd_envelope)

    c7 = sub.add_parser("chapter7", help="reproduce the chapter-7 results beside the dissertation's numbers",
                        description="Trench, speed-limited wheel, stuck steering and the slope limits of Fig. 7.12, "
                                    "printed beside the dissertation's numbers and written to CSV.")
    c7.add_argument("--out", default="out/chapter7", help="output folder (default: %(default)s)")
    c7.add_argument("--step-deg", type=float, default=2.5, help="slope step of the envelopes (default: %(default)s)")
    c7.add_argument("--quick", action="store_true", help="only the numbers computed by single solves (seconds)")
    c7.add_argument("--table-only", action="store_true", help="print the reference table without solving")
    c7.set_defaults(func=cmd_chapter7)
