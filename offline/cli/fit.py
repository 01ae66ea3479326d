"""Single-wheel fitting commands: validate, calibrate, bekker."""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from .common import (
    DEFAULT_PARAMS,
    DEFAULT_PARAMS_SF,
    WHEELS,
    fail,
    parameter_set_or_fail,
    shipped,
    soil_flow_available,
    trials_or_fail,
)

__all__ = ["register"]


def cmd_validate(args: argparse.Namespace) -> int:
    from ..fit.dataset import load_tuned_params
    from ..fit.validation import (
        Variant,
        average_conditions,
        error_rows,
        format_table,
        plot_fig_5_6,
        predict,
        write_csv,
    )
    from ..physics import params as P
    from ..physics.terramechanics import ModelOptions

    t0 = time.perf_counter()
    trials = trials_or_fail(args.data)
    if trials is None:
        return 2
    ps, params_path = parameter_set_or_fail(args.params)
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
        if soil_flow_available():
            diss.insert(1, Variant("dissertation: soil-flow exit angle", P.SOIL_DISSERTATION_T53_GROUSERED,
                                   P.WHEEL_GROUSERED_PUBLISHED_CODE, tuned, opts_sf))
        variants += [("dissertation", v) for v in diss]
    cal = [
        Variant("calibrated: classic exit angle", ps.soil, ps.wheel, ps.tuning),
        Variant("calibrated: Ishigami 2007 sidewall", ps.soil, ps.wheel, ps.tuning, ModelOptions(bulldozing="ishigami")),
    ]
    sf_path = Path(args.params_soil_flow) if args.params_soil_flow else (None if args.params else shipped(DEFAULT_PARAMS_SF))
    if sf_path is not None:
        try:
            loaded_sf = P.load_toml(sf_path)
        except P.ParameterError as exc:
            return fail(str(exc))
        if "parameter_set" not in loaded_sf:
            return fail(f"{sf_path}: needs [soil], [wheel] and [tuning] sections")
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

    from ..fit.calibration import JOINT_PARAMETERS, fit_joint
    from ..fit.validation import (
        Variant,
        average_conditions,
        beats_table_5_5,
        error_rows,
        format_table,
        predict,
    )
    from ..physics import params as P

    t0 = time.perf_counter()
    trials = trials_or_fail(args.data)
    if trials is None:
        return 2
    max_beta = math.radians(args.max_beta_deg + 0.5)
    fit_set = trials.subset(np.abs(trials.beta_cmd) <= max_beta)
    if len(fit_set) == 0:
        return fail(f"no trials with |beta| <= {args.max_beta_deg} deg")
    from ..physics.terramechanics import ModelOptions

    opts = ModelOptions(exit_angle=args.exit_angle)
    names = list(JOINT_PARAMETERS)
    if args.exit_angle == "soil_flow":  # b0, b1 are unused; the soil-flow model's own parameter is zeta
        names = [n for n in names if not n.startswith("b")] + ["zeta"]
    priors = None
    if args.free_k or args.plates:
        names.append("k")
    if args.plates:
        from ..fit.bekker import fit_bekker

        try:
            bf = fit_bekker(args.plates, "large_box_plates")
        except (OSError, ValueError) as exc:
            return fail(f"--plates {args.plates}: {exc}")
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
        from ..fit.calibration import leave_one_angle_out

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



def cmd_bekker(args: argparse.Namespace) -> int:
    from ..fit.bekker import main as bekker_main

    return int(bekker_main(args.rest) or 0)


def register(sub: Any) -> None:
    """Add this module's commands to the ``offnominal`` sub-parser."""
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


    b = sub.add_parser("bekker", help="fit p = k z^n to static plate tests", add_help=False)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=cmd_bekker)
