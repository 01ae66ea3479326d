"""Command line: ``offnominal <command>``.

Commands
--------
validate    Table 5.5 / Fig. 5.6 validation on single-wheel trials (the default main job).
calibrate   Fit the model to single-wheel trials and write a TOML parameter file.
discrepancy Locate model-data mismatch, name the missing physics, show the fit improve.
primitive   Solve a driving scenario (failures, trenching, slope) for a steady primitive.
slope-sweep Fig. 7.12: slip and power against slope.
envelope    Steepest feasible slope and the slope where slip crosses a limit.
chapter7    Reproduce chapter 7 beside the dissertation's numbers.
bekker      Fit Bekker's p = k z^n to static plate tests.
soil-flow   Draw the soil-flow phase map (Fig. 4.7) and one-at-a-time sweep (Fig. 4.6).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
import sys
import time
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np

__all__ = ["main", "DEFAULT_PARAMS"]

DEFAULT_PARAMS = "calibrated_grousered.toml"
"""Parameter file shipped in ``offline/data`` (written by ``offnominal calibrate``)."""
DEFAULT_PARAMS_SF = "calibrated_grousered_soil_flow.toml"
"""Soil-flow variant (``offnominal calibrate --exit-angle soil_flow``)."""

WHEELS = {
    "published-code": "WHEEL_GROUSERED_PUBLISHED_CODE",
    "table-5.2": "WHEEL_GROUSERED_T52",
}


def _shipped(name: str) -> Path:
    return Path(str(resources.files("offline").joinpath("data", name)))


def _fail(msg: str) -> int:
    print(f"offnominal: error: {msg}", file=sys.stderr)
    return 2


def _trials_or_fail(path: str | None) -> Any:
    """Load trials, or print the loader's message and return None."""
    from .dataset import DatasetError, load_trials


    try:
        return load_trials(path)
    except (DatasetError, FileNotFoundError) as exc:
        _fail(str(exc))
        return None


def _parameter_set_or_fail(path: str | None) -> tuple[Any, Path]:
    """Load a parameter set (default: the shipped calibrated file), or print why not."""
    from . import params as P

    params_path = Path(path) if path else _shipped(DEFAULT_PARAMS)
    try:
        loaded = P.load_toml(params_path)
    except P.ParameterError as exc:
        _fail(str(exc))
        return None, params_path
    if "parameter_set" not in loaded:
        _fail(f"{params_path}: needs [soil], [wheel] and [tuning] sections")
        return None, params_path
    return loaded["parameter_set"], params_path


def _soil_flow_available() -> bool:
    try:
        from . import soil_flow  # noqa: F401
    except ImportError:
        return False
    return True


def cmd_validate(args: argparse.Namespace) -> int:
    from . import params as P
    from .dataset import load_tuned_params
    from .terramechanics import ModelOptions
    from .validation import Variant, average_conditions, error_rows, format_table, plot_fig_5_6, predict, write_csv

    t0 = time.perf_counter()
    trials = _trials_or_fail(args.data)
    if trials is None:
        return 2
    ps, params_path = _parameter_set_or_fail(args.params)
    if ps is None:
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    data = trials if args.per_trial else average_conditions(trials)
    variants: list[tuple[str, Variant]] = []
    opts_sf = ModelOptions(exit_angle="soil_flow")
    if not args.skip_dissertation:
        tuned = {b: P.ContactTuning(*v, name=f"authors_{b:g}", source="data: grouser_tuned_params.csv")
                 for b, v in load_tuned_params(args.tuned).items()}
        diss = [
            Variant("dissertation: classic exit angle", P.SOIL_DISSERTATION_T53_GROUSERED, P.WHEEL_GROUSERED_PUBLISHED_CODE, tuned),
            Variant("dissertation: Ishigami 2007 sidewall", P.SOIL_DISSERTATION_T53_GROUSERED, P.WHEEL_GROUSERED_PUBLISHED_CODE,
                    tuned, ModelOptions(bulldozing="ishigami")),
        ]
        if _soil_flow_available():
            diss.insert(1, Variant("dissertation: soil-flow exit angle", P.SOIL_DISSERTATION_T53_GROUSERED,
                                   P.WHEEL_GROUSERED_PUBLISHED_CODE, tuned, opts_sf))
        variants += [("dissertation", v) for v in diss]
    cal = [
        Variant("calibrated: classic exit angle", ps.soil, ps.wheel, ps.tuning),
        Variant("calibrated: Ishigami 2007 sidewall", ps.soil, ps.wheel, ps.tuning, ModelOptions(bulldozing="ishigami")),
    ]
    sf_path = Path(args.params_soil_flow) if args.params_soil_flow else (None if args.params else _shipped(DEFAULT_PARAMS_SF))
    if sf_path is not None:
        try:
            loaded_sf = P.load_toml(sf_path)
        except P.ParameterError as exc:
            return _fail(str(exc))
        if "parameter_set" not in loaded_sf:
            return _fail(f"{sf_path}: needs [soil], [wheel] and [tuning] sections")
        ps_sf = loaded_sf["parameter_set"]
        cal.insert(1, Variant("calibrated: soil-flow exit angle", ps_sf.soil, ps_sf.wheel, ps_sf.tuning, opts_sf))
    variants += [("calibrated", v) for v in cal]

    rows, preds = [], []
    for _, v in variants:
        p = predict(data, v)
        preds.append(p)
        rows += error_rows(data, p, v.wheel.radius)
    print(f"Single-wheel validation, load given, sinkage predicted ({len(trials)} trials"
          f"{'' if args.per_trial else f', scored on {len(data)} condition means as Table 5.5'})")
    print(f"data: {trials.source}\nparameters: {params_path}  (wheel: {ps.wheel.name}, tuning: {ps.tuning.name})"
          + (f"; soil-flow variant: {sf_path}" if sf_path else "") + "\n")
    print("errors: prediction - measurement; forces in % of load, sinkage in % of wheel radius; mean ± sd, then mean |error|")
    print(format_table(rows))
    csv_path = write_csv(rows, out / "table_5_5.csv")
    print(f"wrote {csv_path}")
    for group in ("dissertation", "calibrated"):
        sel = [i for i, (g, _) in enumerate(variants) if g == group]
        if sel:
            png = plot_fig_5_6(data, [variants[i][1] for i in sel], out / f"fig_5_6_{group}.png", [preds[i] for i in sel],
                               title=f"{group} parameters: measured (condition means) and predicted, load given")
            print(f"wrote {png}")
    print(f"({time.perf_counter() - t0:.1f} s)")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from . import params as P
    from .calibration import JOINT_PARAMETERS, fit_joint
    from .validation import Variant, average_conditions, beats_table_5_5, error_rows, format_table, predict

    t0 = time.perf_counter()
    trials = _trials_or_fail(args.data)
    if trials is None:
        return 2
    max_beta = math.radians(args.max_beta_deg + 0.5)
    fit_set = trials.subset(np.abs(trials.beta_cmd) <= max_beta)
    if len(fit_set) == 0:
        return _fail(f"no trials with |beta| <= {args.max_beta_deg} deg")
    from .terramechanics import ModelOptions

    opts = ModelOptions(exit_angle=args.exit_angle)
    names = list(JOINT_PARAMETERS)
    if args.exit_angle == "soil_flow":  # b0, b1 are unused; the soil-flow model's own parameter is zeta
        names = [n for n in names if not n.startswith("b")] + ["zeta"]
    priors = None
    if args.free_k or args.plates:
        names.append("k")
    if args.plates:
        from .bekker import fit_bekker

        try:
            bf = fit_bekker(args.plates, "large_box_plates")
        except (OSError, ValueError) as exc:
            return _fail(f"--plates {args.plates}: {exc}")
        ks = np.array([t.k_nls for t in bf.tests])
        priors = {"k": (float(np.mean(ks)), float(np.std(ks, ddof=1)))}
        print(f"plate tests ({len(ks)} large-box plates): k = {priors['k'][0] / 1e3:.0f} ± {priors['k'][1] / 1e3:.0f} "
              f"kN/m^(n+2) (per-test nonlinear fits, mean ± sd; dissertation 8000), used as a prior on k")
    wheels = list(WHEELS) if args.wheel == "both" else [args.wheel]
    results = {}
    for wname in wheels:
        wheel = getattr(P, WHEELS[wname])
        bar = tqdm(total=args.max_evals, desc=f"joint fit, {wname} wheel", unit="eval", leave=False, disable=args.quiet)
        res = fit_joint(fit_set, P.SOIL_DISSERTATION_T53_GROUSERED, wheel, P.TUNING_T72_LINEAR, names, opts,
                        max_nfev=args.max_evals, progress=lambda i, c: (bar.update(1), bar.set_postfix(cost=f"{c:.0f}")),
                        priors=priors)
        bar.close()
        wheel = res.wheel or wheel
        avg = average_conditions(trials)
        label = f"calibrated, {wname} wheel" + (", soil-flow exit angle" if args.exit_angle == "soil_flow" else "")
        rows = error_rows(avg, predict(avg, Variant(label, res.soil, wheel, res.tuning, opts)), wheel.radius)
        results[wname] = (res, wheel, rows)
        print(f"\n{wname} wheel: rms normalised residual {res.rms:.3f} over {res.n_residuals} residuals, "
              f"{res.n_iterations} evaluations, {res.seconds:.1f} s ({res.message})")
        print(res.table())
        print(format_table(rows))
    best = min(results, key=lambda k: results[k][0].rms)
    res, wheel, rows = results[best]
    if len(results) > 1:
        print("wheel geometry supported by the data (lower rms after the same joint fit): "
              + ", ".join(f"{k}: {v[0].rms:.3f}" for k, v in results.items()) + f" -> {best}")
    ref = "with soil flow" if args.exit_angle == "soil_flow" else "without soil flow"
    beats = {r.beta_deg: beats_table_5_5(r, ref) for r in rows}
    meta = {
        "written_by": "offnominal calibrate",
        "data": str(trials.source),
        "fit_slip_angles_deg": f"<= {args.max_beta_deg}",
        "wheel_choice": best,
        "wheel_choice_reason": "; ".join(f"{k} rms {v[0].rms:.4f}" for k, v in results.items()),
        "free_parameters": ",".join(res.names),
        "rms_normalised_residual": res.rms,
        "noise_normalisation": json.dumps({k: round(v, 6) for k, v in trials.noise().items()}),
        "beats_table_5_5": json.dumps({f"{b:g}": v for b, v in beats.items() if v is not None}),
        "exit_angle": args.exit_angle,
        "notes": "Joint fit given the load (sinkage predicted); a0..b1 lines in |beta| per radian.",
    }
    out = Path(args.out)
    P.save_toml(out, meta=meta, soil=res.soil, wheel=wheel, tuning=res.tuning)
    print(f"wrote {out}  ({time.perf_counter() - t0:.1f} s)")
    if args.cv:
        from .calibration import leave_one_angle_out

        print("\nOut of sample: leave one slip angle out (fit on the others, score the held-out angle)")
        held = []
        for b in tqdm(sorted(set(np.round(np.degrees(fit_set.beta_cmd), 3))), desc="leave-one-angle-out", disable=args.quiet):
            cv = leave_one_angle_out(fit_set, P.SOIL_DISSERTATION_T53_GROUSERED, wheel, P.TUNING_T72_LINEAR, names, opts,
                                     angles_deg=[b], max_nfev=args.max_evals)[float(b)]
            sub = average_conditions(trials.subset(np.abs(np.degrees(trials.beta_cmd) - b) < 0.5))
            held += error_rows(sub, predict(sub, Variant("held-out angle", cv.soil, cv.wheel or wheel, cv.tuning, opts)),
                               wheel.radius)
        print(format_table(held))
        print("Out of sample: leave one repeat out (fit on two repeats of every condition, score the third)")
        held = []
        for rep in tqdm(sorted(set(fit_set.repeat.tolist())), desc="leave-one-repeat-out", disable=args.quiet):
            tr_ = fit_set.subset(fit_set.repeat != rep)
            te_ = trials.subset(trials.repeat == rep)
            cv = fit_joint(tr_, P.SOIL_DISSERTATION_T53_GROUSERED, wheel, P.TUNING_T72_LINEAR, names, opts,
                           max_nfev=args.max_evals)
            held += error_rows(te_, predict(te_, Variant(f"held-out repeat {rep}", cv.soil, cv.wheel or wheel, cv.tuning, opts)),
                               wheel.radius)
        print(format_table(held))
    return 0


def cmd_discrepancy(args: argparse.Namespace) -> int:
    from .discrepancy import diagnose
    from .terramechanics import ModelOptions

    t0 = time.perf_counter()
    trials = _trials_or_fail(args.data)
    if trials is None:
        return 2
    if args.max_beta_deg is not None:
        trials = trials.subset(np.abs(trials.beta_cmd) <= math.radians(args.max_beta_deg + 0.5))
        if len(trials) == 0:
            return _fail(f"no trials with |beta| <= {args.max_beta_deg} deg")
    ps, _ = _parameter_set_or_fail(args.params)
    if ps is None:
        return 2
    try:
        opts = ModelOptions(exit_angle=args.exit_angle, bulldozing=args.bulldozing)
    except ValueError as exc:
        return _fail(str(exc))
    verdict = diagnose(trials, ps, opts, seed=args.seed,
                       progress=None if args.quiet else (lambda s: print(f"  [{time.perf_counter() - t0:5.1f} s] {s}", flush=True)))
    out = verdict.write(args.out)
    print(verdict.summary())
    print(f"wrote {out / 'report.md'}, {out / 'verdict.json'} and plots  ({time.perf_counter() - t0:.1f} s)")
    return 0


def _load_scenario_or_fail(path: str) -> Any:
    from .scenario import ScenarioError, example_scenarios, load_scenario

    p = Path(path)
    if not p.exists():
        shipped = {q.stem: q for q in example_scenarios()}
        if path in shipped:
            p = shipped[path]
    try:
        return load_scenario(p)
    except ScenarioError as exc:
        print(f"offnominal: error: {exc}", file=sys.stderr)
        return None


def cmd_primitive(args: argparse.Namespace) -> int:
    from .primitives import DISSERTATION_CH7, lowest_speed_cap, solve_primitive, steering_controllers

    sc = _load_scenario_or_fail(args.scenario)
    if sc is None:
        return 2
    if args.params:
        ps, _ = _parameter_set_or_fail(args.params)
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

    from .primitives import slope_sweep

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = args.scenarios or ["nominal", "rr_speed_cap_half", "rr_steer_stuck_50"]
    slopes = list(np.arange(0.0, args.max_deg + 1e-9, args.step_deg))
    rows, results = [], {}
    for n in names:
        sc = _load_scenario_or_fail(n)
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
    from .primitives import envelope

    sc = _load_scenario_or_fail(args.scenario)
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

    from .primitives import envelope, lowest_speed_cap, solve_primitive

    t0 = time.perf_counter()
    rows: list[tuple[str, str, str, str]] = []

    def add(what: str, ours: str, theirs: str, note: str = "") -> None:
        rows.append((what, ours, theirs, note))
        print(f"{what:<46} ours: {ours:<28} dissertation: {theirs:<18} {note}", flush=True)

    sc = {n: _load_scenario_or_fail(n) for n in ("nominal", "rr_speed_cap_half", "rr_steer_stuck_50",
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


def cmd_bekker(args: argparse.Namespace) -> int:
    from .bekker import main as bekker_main

    return int(bekker_main(args.rest) or 0)


def cmd_soil_flow(args: argparse.Namespace) -> int:
    if not _soil_flow_available():
        return _fail("the soil-flow model is not available in this build")
    from .plots_soil_flow import plot_phase_map, plot_sweep

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.what in ("phase-map", "both"):
        print(f"wrote {plot_phase_map(out / 'fig_4_7_phase_map.png', h0=args.h0_mm * 1e-3)}")
    if args.what in ("sweep", "both"):
        print(f"wrote {plot_sweep(out / 'fig_4_6_sweep.png')}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="offnominal",
        description="Off-nominal rover driving: wheel-soil physics, calibration and validation.",
        epilog="Run 'offnominal <command> -h' for a command's options.",
    )
    sub = ap.add_subparsers(dest="command", metavar="command")

    v = sub.add_parser("validate", help="Table 5.5 / Fig. 5.6 validation (load given, sinkage predicted)",
                       description="Solve each condition's sinkage from its measured load, predict Fx, Fy and sinkage, "
                                   "and report errors per slip angle beside the dissertation's Table 5.5.")
    v.add_argument("--data", help="trials CSV in the single-wheel format (default: the shipped grousered trials)")
    v.add_argument("--params", help=f"parameter TOML (default: shipped {DEFAULT_PARAMS})")
    v.add_argument("--params-soil-flow", help=f"parameter TOML for the soil-flow variant (default: shipped {DEFAULT_PARAMS_SF})")
    v.add_argument("--tuned", help="per-angle a0..b1 CSV for the dissertation rows (default: shipped authors' values)")
    v.add_argument("--out", default="out/validation", help="output folder for CSV and PNG (default: %(default)s)")
    v.add_argument("--per-trial", action="store_true", help="score every trial instead of condition means")
    v.add_argument("--skip-dissertation", action="store_true", help="only the calibrated parameters")
    v.set_defaults(func=cmd_validate)

    c = sub.add_parser("calibrate", help="joint fit of soil and contact-angle parameters; writes TOML",
                       description="Fit soil parameters and a0..b1 lines in |beta| jointly, given each trial's load "
                                   "(sinkage predicted), and write the parameter file the rest of the library reads.")
    c.add_argument("--data", help="trials CSV (default: the shipped grousered trials)")
    c.add_argument("--out", default="calibrated.toml", help="parameter file to write (default: %(default)s)")
    c.add_argument("--wheel", choices=[*WHEELS, "both"], default="both",
                   help="wheel geometry: the published code's, the dissertation's Table 5.2, or both (pick the better)")
    c.add_argument("--max-beta-deg", type=float, default=60.0,
                   help="fit only slip angles up to this (the authors exclude 75 and 90: no steady state)")
    c.add_argument("--free-k", action="store_true", help="also fit the pressure-sinkage modulus k")
    c.add_argument("--plates", help="single-wheel data folder with pressure_sinkage/: fit k as well, with the "
                                    "large-box plate tests' k as a prior")
    c.add_argument("--exit-angle", choices=["classic", "soil_flow"], default="classic",
                   help="model variant to calibrate (soil_flow fits zeta instead of b0, b1)")
    c.add_argument("--max-evals", type=int, default=100, help="least-squares evaluations per fit")
    c.add_argument("--cv", action="store_true", help="also report out-of-sample errors (leave one angle / repeat out)")
    c.add_argument("--quiet", action="store_true", help="no progress bars")
    c.set_defaults(func=cmd_calibrate)

    d = sub.add_parser("discrepancy", help="locate model-data mismatch, name the missing physics, show the fit improve",
                       description="Run the model on every recorded condition, locate significant residual regions, fit a "
                                   "library of candidate physics, rank them by held-out improvement and write a report folder "
                                   "(report.md, PNGs, verdict.json).")
    d.add_argument("--data", help="trials CSV in the single-wheel format (default: the shipped grousered trials)")
    d.add_argument("--params", help=f"parameter TOML (default: shipped {DEFAULT_PARAMS})")
    d.add_argument("--out", default="out/discrepancy", help="report folder (default: %(default)s)")
    d.add_argument("--exit-angle", choices=["classic", "soil_flow"], default="classic", help="model variant")
    d.add_argument("--bulldozing", choices=["pavlov", "hegedus", "ishigami", "none"], default="pavlov",
                   help="sidewall model of the model under test ('none' to study a model without it)")
    d.add_argument("--max-beta-deg", type=float, default=None, help="only conditions up to this slip angle")
    d.add_argument("--seed", type=int, default=0, help="seed of the randomisation test")
    d.add_argument("--quiet", action="store_true", help="no progress lines")
    d.set_defaults(func=cmd_discrepancy)

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

    b = sub.add_parser("bekker", help="fit p = k z^n to static plate tests", add_help=False)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=cmd_bekker)

    s = sub.add_parser("soil-flow", help="draw the soil-flow phase map (Fig. 4.7) and sweep (Fig. 4.6)")
    s.add_argument("what", choices=["phase-map", "sweep", "both"], nargs="?", default="both")
    s.add_argument("--h0-mm", type=float, default=10.0, help="sinkage for the phase map, mm (default: %(default)s)")
    s.add_argument("--out", default="out/soil_flow", help="output folder (default: %(default)s)")
    s.set_defaults(func=cmd_soil_flow)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``offnominal`` command."""
    ap = build_parser()
    args = ap.parse_args(argv)
    if not getattr(args, "command", None):
        ap.print_help()
        return 0
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("\ninterrupted: files already written are complete (each is written whole)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
