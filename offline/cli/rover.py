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
    from ..rover.primitives import (
        DISSERTATION_CH7,
        lowest_speed_cap,
        solve_primitive,
        steering_controllers,
    )

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
    print(f"status: {r.status}  ({r.stats['seconds']:.2f} s, {r.stats['iterations']} IPOPT iterations)")
    print("  " + "\n  ".join(r.stats["attempts"]))
    print(r.table())
    print(f"independent numeric check: {'passed' if r.check_passed else 'FAILED'}; largest residuals: "
          + ", ".join(f"{k} {v:.2e}" for k, v in sorted(r.residuals.items(), key=lambda kv: -abs(kv[1]))[:3]))
    if r.trench is not None:
        t = r.trench
        print(f"trench: {t.shape}, depth {t.d * 1e3:.1f} mm, flat width {t.p * 1e3:.1f} mm, rim-side pile {t.h_R2 * 1e3:.1f} mm")
    if r.evidence:
        print("evidence: " + "; ".join(f"{k}: {v}" for k, v in r.evidence.items()))
    if sc.name in DISSERTATION_CH7:
        print(f"dissertation: {DISSERTATION_CH7[sc.name]}")
    for k, f in sc.failures.items():
        if args.lowest_cap and (f.rim_speed_max < math.inf):
            cap, _ = lowest_speed_cap(sc, k)
            print(f"lowest reachable rim-speed cap on {k}: {cap * 100:.2f} cm/s (dissertation: 1.5 cm/s for RR)")
    if args.controllers and r.ok:
        ctl = steering_controllers(sc, r)
        for name, gains in ctl.items():
            unit = "N m" if name.startswith("Mz") else "N"
            print(f"steering controller {name} (per {unit}): " + ", ".join(
                f"{k} d(rim) {g[0] * 100:+.3f} cm/s, d(steer) {math.degrees(g[1]):+.2f} deg" for k, g in gains.items()))
    return 0 if r.ok else 1


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
        res = slope_sweep(sc, slopes, progress=None if args.quiet else (
            lambda a, r, n=n: print(f"  {n}: slope {a:5.1f} deg -> {r.status}", flush=True)))
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
    print("dissertation (Fig. 7.12): nominal 15 % slip flat, feasible to 24 deg, 50 % slip at 12.5 deg; stuck steer "
          "40 % mean flat, 50 % at 2.5 deg; speed-limited 69 % mean / 76 % max flat")
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
    """Reproduce the chapter-7 results side by side with the dissertation's numbers."""
    import csv

    from ..rover.primitives import envelope, lowest_speed_cap, solve_primitive

    t0 = time.perf_counter()
    rows: list[tuple[str, str, str, str]] = []

    def add(what: str, ours: str, theirs: str, note: str = "") -> None:
        rows.append((what, ours, theirs, note))
        print(f"{what:<46} ours: {ours:<28} dissertation: {theirs:<18} {note}", flush=True)

    sc = {n: load_scenario_or_fail(n) for n in ("nominal", "rr_speed_cap_half", "rr_steer_stuck_50",
                                                 "rr_trench_clean", "rr_trench_clean_mu01")}
    if any(v is None for v in sc.values()):
        return 2
    r = solve_primitive(sc["rr_trench_clean"])
    t = r.trench
    add("clean-sided trench, RR, depth >= b/2 (mu = 0.5)", f"{r.status}, depth {t.d * 100:.2f} cm" if r.ok else r.status,
        "2.6 cm predicted", f"RR {r.wheels['RR'].rim_speed * 100:.1f} cm/s at {math.degrees(r.wheels['RR'].steer):.0f} deg"
        if r.ok else "")
    r = solve_primitive(sc["rr_trench_clean_mu01"])
    add("clean-sided trench with mu = 0.1 (published code)", r.status, "(not studied)", r.evidence.get("most_violated_constraint", ""))
    for name, key in (("nominal", "nominal"), ("speed cap v/2 on RR", "rr_speed_cap_half"), ("RR steer stuck at 50 deg", "rr_steer_stuck_50")):
        e = envelope(sc[key], 0.5, step_deg=args.step_deg, max_deg=30.0)
        flat = e["sweep"][0]
        theirs = {"nominal": ("15 %", "-", "24 deg", "12.5 deg"), "rr_speed_cap_half": ("69 %", "76 %", "-", "none (> 50 % flat)"),
                  "rr_steer_stuck_50": ("40 %", "-", "-", "2.5 deg")}[key]
        if flat.ok:
            add(f"{name}: mean slip of unaffected wheels, flat", f"{flat.mean_slip() * 100:.1f} %", theirs[0])
            add(f"{name}: max slip, flat", f"{flat.max_slip() * 100:.1f} %", theirs[1])
        add(f"{name}: steepest feasible slope", f"{e['steepest_slope_deg']:.1f} deg", theirs[2])
        cross = e["slip_limit_slope_deg"]
        add(f"{name}: slope where mean slip reaches 50 %", f"{cross:.1f} deg" if math.isfinite(cross) else "n/a", theirs[3])
    cap, _ = lowest_speed_cap(sc["rr_speed_cap_half"], "RR")
    add("lowest reachable rim-speed cap on RR", f"{cap * 100:.2f} cm/s", "1.5 cm/s", "(theirs: hand continuation)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with (out / "chapter7.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["quantity", "ours", "dissertation", "note"])
        w.writerows(rows)
    print(f"wrote {out / 'chapter7.csv'}  ({time.perf_counter() - t0:.0f} s)")
    return 0


def register(sub: Any) -> None:
    """Add this module's commands to the ``offnominal`` sub-parser."""
    pr = sub.add_parser("primitive", help="solve a driving scenario (failures, trenching, slope) for a steady primitive",
                        description="Solve the steady-state NLP (7.25) for a scenario TOML (or the name of a shipped "
                                    "example) from the automatic start; print wheel speeds, angles, loads, sinkages, "
                                    "slips, torques, power, the independent check and, if infeasible, the evidence.")
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
    c7.set_defaults(func=cmd_chapter7)
