"""Single-wheel fitting commands: validate, calibrate, bekker.

Every output is written atomically (:mod:`offline.files`), output paths are checked before
any work, and an output that would replace one of the run's inputs is refused.
"""

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
    TUNED_SETS,
    WHEELS,
    fail,
    parameter_set_or_fail,
    provenance,
    shipped,
    soil_flow_available,
    trials_or_fail,
)

__all__ = ["register", "VALIDATE_OUTPUTS", "REFERENCE_DEFAULT"]

VALIDATE_OUTPUTS = ("table_5_5.csv", "fig_5_6_dissertation.png", "fig_5_6_calibrated.png")
"""Files ``validate`` writes into its ``--out`` folder."""

REFERENCE_DEFAULT = "table-5.5"
"""Reference rows ``validate`` and ``calibrate`` compare with unless ``--reference`` says otherwise."""


def _library_errors() -> tuple[type[Exception], ...]:
    """Exceptions that carry a user-facing message (printed, exit 2, no traceback)."""
    from ..files import OutputError
    from ..fit.calibration import CalibrationError
    from ..fit.dataset import DatasetError
    from ..fit.validation import ValidationError
    from ..physics.params import ParameterError

    return OutputError, CalibrationError, DatasetError, ValidationError, ParameterError


def _reference(spec: str | None) -> Any:
    """``--reference``: a built-in name, a CSV file, or 'none' (no comparison)."""
    from ..fit.validation import load_reference

    if spec is not None and spec.lower() == "none":
        return None
    return load_reference(spec or REFERENCE_DEFAULT)


def _reference_input(spec: str | None) -> str | None:
    """The reference file among the run's inputs (None for a built-in set)."""
    from ..fit.validation import REFERENCE_SETS

    return None if spec is None or spec.lower() == "none" or spec in REFERENCE_SETS else spec


def _tuned_variants(spec: str | None, wheel_kind: str, calibrated_ps: Any, explicit_params: bool) -> tuple[str, Any, Any, Any, str]:
    """The per-angle tuned model for the 'dissertation' / 'tuned' rows of ``validate``.

    Returns ``(group label, soil, wheel, tuning, source description)``. A TOML ``--tuned``
    brings its own soil and wheel when it has them; otherwise the soil and wheel are the
    validated parameter file's (``--params``), or the authors' grousered set by default.
    """
    from ..fit.dataset import load_tuned_params
    from ..physics import params as P

    if spec is None:
        spec = "authors-grousered" if wheel_kind == "grousered" else "table-5.4-smooth"
    builtin = spec in TUNED_SETS
    path = shipped(TUNED_SETS[spec]) if builtin else Path(spec)
    src = f"{spec} ({path.name}, sha256 {provenance(path)['sha256'][:12]})" if builtin else \
        f"{path.name} (sha256 {provenance(path)['sha256'][:12]})" if path.exists() else str(path)
    label = "dissertation" if builtin else f"tuned {path.name}"
    if path.suffix.lower() == ".toml":
        loaded = P.load_toml(path)
        if "tuning" not in loaded:
            raise P.ParameterError(f"{path}: --tuned needs a [tuning] section (a per-angle table or one tuning)")
        tuning = loaded["tuning"]
        soil, wheel = loaded.get("soil"), loaded.get("wheel")
    else:
        table = load_tuned_params(path)
        tuning = {b: P.ContactTuning(*v, name=f"{path.stem}_{b:g}", source=src) for b, v in table.items()}
        soil = wheel = None
    if soil is None or wheel is None:
        if builtin or not explicit_params:  # the authors' per-angle values go with their wheel and soil
            soil = soil or P.SOIL_DISSERTATION_T53_GROUSERED
            wheel = wheel or P.WHEEL_GROUSERED_PUBLISHED_CODE
        else:
            soil = soil or calibrated_ps.soil
            wheel = wheel or calibrated_ps.wheel
    return label, soil, wheel, tuning, src


def cmd_validate(args: argparse.Namespace) -> int:
    try:
        return _validate(args)
    except _library_errors() as exc:
        return fail(str(exc))


def _validate(args: argparse.Namespace) -> int:
    from ..files import check_output_dir
    from ..fit.dataset import check_force_units
    from ..fit.validation import (
        ValidationError,
        Variant,
        average_conditions,
        error_rows,
        failed_conditions,
        format_table,
        plot_fig_5_6,
        predict,
        wheel_kind,
        write_csv,
    )
    from ..physics import params as P
    from ..physics.terramechanics import ModelOptions

    t0 = time.perf_counter()
    data_path = args.data or str(shipped("grouser_trials.csv"))
    inputs = [data_path, args.params, args.params_soil_flow, args.tuned, _reference_input(args.reference)]
    out = check_output_dir(args.out, inputs, VALIDATE_OUTPUTS)  # before any work
    trials = trials_or_fail(args.data)
    if trials is None:
        return 2
    ps, params_path = parameter_set_or_fail(args.params)
    if ps is None:
        return 2
    check_force_units(trials, ps.wheel)
    reference = _reference(args.reference)
    data = trials if args.per_trial else average_conditions(trials)
    variants: list[tuple[str, Variant]] = []
    opts_sf = ModelOptions(exit_angle="soil_flow")
    kind = wheel_kind(ps.wheel)
    tuned_src = ""
    if not args.skip_dissertation:
        group, t_soil, t_wheel, tuned, tuned_src = _tuned_variants(args.tuned, kind, ps, args.params is not None)
        diss = [
            Variant(f"{group}: classic exit angle", t_soil, t_wheel, tuned),
            Variant(f"{group}: Ishigami 2007 sidewall", t_soil, t_wheel, tuned, ModelOptions(bulldozing="ishigami")),
        ]
        if soil_flow_available():
            diss.insert(1, Variant(f"{group}: soil-flow exit angle", t_soil, t_wheel, tuned, opts_sf))
        variants += [("dissertation", v) for v in diss]
    cal = [
        Variant("calibrated: classic exit angle", ps.soil, ps.wheel, ps.tuning),
        Variant("calibrated: Ishigami 2007 sidewall", ps.soil, ps.wheel, ps.tuning, ModelOptions(bulldozing="ishigami")),
    ]
    sf_path = Path(args.params_soil_flow) if args.params_soil_flow else (None if args.params else shipped(DEFAULT_PARAMS_SF))
    if sf_path is not None:
        loaded_sf = P.load_toml(sf_path)
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
    refs = {v.name: (reference.match(v.wheel, v.options) if reference is not None else None) for _, v in variants}
    print(f"Single-wheel validation, load given, sinkage predicted ({len(trials)} trials"
          f"{'' if args.per_trial else f', scored on {len(data)} condition means as Table 5.5'})")
    print(f"data: {Path(data_path).name}\nparameters: {params_path.name}  (wheel: {ps.wheel.name}, {kind}; "
          f"tuning: {ps.tuning.name})" + (f"; soil-flow variant: {sf_path.name}" if sf_path else "")
          + (f"\ntuned per angle: {tuned_src}" if tuned_src else ""))
    print(f"reference rows: {reference.source if reference is not None else 'none'} (each variant marked only against "
          "the rows of its own wheel kind and model)\n")
    print("errors: prediction - measurement; forces in % of load, sinkage in % of wheel radius; mean ± sd, then mean |error|")
    print(format_table(rows, refs if reference is not None else None))
    failed = {k: v for k, v in failed_conditions(rows).items() if v[1] and v[0] > 0.5 * v[1]}
    if failed:
        statuses = {p.variant: sorted(set(p.status.tolist()) - {"ok"}) for p in preds}
        raise ValidationError(
            "most conditions failed for " + "; ".join(f"{k}: {f} of {n} ({', '.join(statuses.get(k, []))})"
                                                      for k, (f, n) in failed.items())
            + ": no validation (nothing written). Check the force units, the wheel (radius, width) and the parameters")
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
    try:
        return _calibrate(args)
    except _library_errors() as exc:
        return fail(str(exc))


def _calibrate(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..files import check_output_path
    from ..fit.calibration import JOINT_PARAMETERS, CalibrationError, check_fit_data, fit_joint
    from ..fit.validation import (
        Variant,
        average_conditions,
        compare_with_reference,
        error_rows,
        failed_conditions,
        format_table,
        predict,
        wheel_kind,
    )
    from ..physics import params as P
    from ..physics.terramechanics import ModelOptions

    t0 = time.perf_counter()
    data_path = args.data or str(shipped("grouser_trials.csv"))
    out = check_output_path(args.out, [data_path, args.wheel_file, args.soil_file, args.plates,
                                       _reference_input(args.reference)])  # before any work
    trials = trials_or_fail(args.data)
    if trials is None:
        return 2
    # wheels: a file, or built-in names
    if args.wheel_file:
        loaded_w = P.load_toml(args.wheel_file)
        if "wheel" not in loaded_w:
            return fail(f"{args.wheel_file}: needs a [wheel] section (radius_m, width_m, grouser_height_m, "
                        "grouser_area_ratio, grouser_volume_fraction)")
        wheels = {Path(args.wheel_file).stem: loaded_w["wheel"]}
        file_soil = loaded_w.get("soil")
    else:
        names_w = list(WHEELS) if args.wheel == "both" else [args.wheel]
        wheels = {n: getattr(P, WHEELS[n]) for n in names_w}
        file_soil = None
    if args.soil_file:
        loaded_s = P.load_toml(args.soil_file)
        if "soil" not in loaded_s:
            return fail(f"{args.soil_file}: needs a [soil] section")
        start_soil = loaded_s["soil"]
        soil_src = Path(args.soil_file).name
    elif file_soil is not None:
        start_soil, soil_src = file_soil, Path(args.wheel_file).name
    else:
        kinds = {wheel_kind(w) for w in wheels.values()}
        start_soil = P.SOIL_DISSERTATION_T53_SMOOTH if kinds == {"smooth"} else P.SOIL_DISSERTATION_T53_GROUSERED
        soil_src = f"built-in {start_soil.name} ({start_soil.source})"
    start_tuning = P.TUNING_T72_LINEAR
    reference = _reference(args.reference)

    max_beta = math.radians(args.max_beta_deg + 0.5)
    fit_set = trials.subset(np.abs(trials.beta_cmd) <= max_beta)
    if len(fit_set) == 0:
        return fail(f"no trials with |beta| <= {args.max_beta_deg} deg")
    opts = ModelOptions(exit_angle=args.exit_angle)
    names = list(JOINT_PARAMETERS)
    if args.exit_angle == "soil_flow":  # b0, b1 are unused; the soil-flow model's own parameter is zeta
        names = [n for n in names if not n.startswith("b")] + ["zeta"]
    if args.free_k or args.plates:
        names.append("k")
    for w in wheels.values():  # clear errors before the (long) fit: too few trials, force units
        check_fit_data(fit_set, names, w)
    priors = None
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
    print(f"data: {Path(data_path).name} ({len(fit_set)} trials with |beta| <= {args.max_beta_deg:g} deg); "
          f"start soil: {soil_src}")
    results = {}
    avg = average_conditions(trials)
    for wname, wheel in wheels.items():
        bar = tqdm(total=args.max_evals, desc=f"joint fit, {wname} wheel", unit="eval", leave=False, disable=args.quiet)

        def progress(i: int, c: float, bar: Any = bar) -> None:
            bar.update(1)
            bar.set_postfix(cost=f"{c:.0f}")

        res = fit_joint(fit_set, start_soil, wheel, start_tuning, names, opts, max_nfev=args.max_evals,
                        progress=progress, priors=priors)
        bar.close()
        fitted_wheel = res.wheel or wheel
        label = f"calibrated, {wname} wheel" + (", soil-flow exit angle" if args.exit_angle == "soil_flow" else "")
        v = Variant(label, res.soil, fitted_wheel, res.tuning, opts)
        rows = error_rows(avg, predict(avg, v), fitted_wheel.radius)
        matched = reference.match(fitted_wheel, opts) if reference is not None else None
        results[wname] = (res, fitted_wheel, rows, matched)
        print(f"\n{wname} wheel: rms normalised residual {res.rms:.3f} over {res.n_residuals} residuals, "
              f"{res.n_iterations} evaluations, {res.seconds:.1f} s ({res.message})")
        print(res.table())
        if res.not_determined:
            print(f"  not determined by these data: {', '.join(res.not_determined)} (no effect on the residuals, "
                  "or only together with other parameters); written at the start value")
        print(format_table(rows, {label: matched}))
    best = min(results, key=lambda k: results[k][0].rms)
    res, wheel, rows, matched = results[best]
    failed = {k: v for k, v in failed_conditions(rows).items() if v[1] and v[0] > 0.5 * v[1]}
    if failed:
        raise CalibrationError(
            f"the calibrated model fails on most conditions ({'; '.join(f'{f} of {n}' for f, n in failed.values())}): "
            "no calibration written. Check the force units, the wheel file and the starting soil")
    if len(results) > 1:
        print("wheel geometry supported by the data (lower rms after the same joint fit): "
              + ", ".join(f"{k}: {v[0].rms:.3f}" for k, v in results.items()) + f" -> {best}")
    data_prov = provenance(data_path)
    meta: dict[str, Any] = {
        "written_by": "offnominal calibrate",
        "data": data_prov["name"],
        "data_sha256": data_prov["sha256"],
        "fit_slip_angles_deg": f"<= {args.max_beta_deg}",
        "wheel_choice": best,
        "wheel_choice_reason": "; ".join(f"{k} rms {v[0].rms:.4f}" for k, v in results.items()),
    }
    if args.wheel_file:
        meta["wheel_file"], meta["wheel_file_sha256"] = provenance(args.wheel_file).values()
    if args.soil_file:
        meta["start_soil_file"], meta["start_soil_file_sha256"] = provenance(args.soil_file).values()
    meta.update({
        "free_parameters": ",".join(res.names),
        "not_determined": ",".join(res.not_determined),
        "std_errors_si": json.dumps({n: (None if not math.isfinite(e) else float(f"{e:.4g}"))
                                     for n, e in zip(res.names, res.std_errors)}),
        "rms_normalised_residual": res.rms,
        "noise_normalisation": json.dumps({k: round(v, 6) for k, v in fit_set.noise().items()})
        if _has_repeats(fit_set) else "no repeats: 5 % of the median load, 2 mm",
        "reference": matched.label if matched else "none matching this wheel and model",
    })
    if matched is not None:
        beats = {r.beta_deg: compare_with_reference(r, matched.rows) for r in rows}
        key = "beats_table_5_5" if reference is not None and reference.name == REFERENCE_DEFAULT else "beats_reference"
        meta[key] = json.dumps({f"{b:g}": v for b, v in beats.items() if v is not None})
    meta["exit_angle"] = args.exit_angle
    meta["notes"] = "Joint fit given the load (sinkage predicted); a0..b1 lines in |beta| per radian."
    P.save_toml(out, meta=meta, soil=res.soil, wheel=wheel, tuning=res.tuning)
    print(f"wrote {out}  ({time.perf_counter() - t0:.1f} s)")
    if args.cv:
        _cross_validate(args, trials, fit_set, start_soil, wheel, start_tuning, names, opts, matched)
    return 0


def _has_repeats(trials: Any) -> bool:
    from ..fit.dataset import DatasetError

    try:
        trials.noise()
    except DatasetError:
        return False
    return True


def _cross_validate(args: argparse.Namespace, trials: Any, fit_set: Any, soil: Any, wheel: Any, tuning: Any,
                    names: list[str], opts: Any, matched: Any) -> None:
    """Out-of-sample tables, marked against the same reference rows as the fit (its model's)."""
    from tqdm import tqdm

    from ..fit.calibration import fit_joint, leave_one_angle_out
    from ..fit.validation import Variant, average_conditions, error_rows, format_table, predict

    print("\nOut of sample: leave one slip angle out (fit on the others, score the held-out angle)")
    held = []
    for b in tqdm(sorted(set(np.round(np.degrees(fit_set.beta_cmd), 3))), desc="leave-one-angle-out", disable=args.quiet):
        cv = leave_one_angle_out(fit_set, soil, wheel, tuning, names, opts, angles_deg=[b], max_nfev=args.max_evals)[float(b)]
        sub = average_conditions(trials.subset(np.abs(np.degrees(trials.beta_cmd) - b) < 0.5))
        held += error_rows(sub, predict(sub, Variant("held-out angle", cv.soil, cv.wheel or wheel, cv.tuning, opts)),
                           wheel.radius)
    print(format_table(held, {"held-out angle": matched}))
    print("Out of sample: leave one repeat out (fit on two repeats of every condition, score the third)")
    held = []
    refs = {}
    for rep in tqdm(sorted(set(fit_set.repeat.tolist())), desc="leave-one-repeat-out", disable=args.quiet):
        tr_ = fit_set.subset(fit_set.repeat != rep)
        te_ = trials.subset(trials.repeat == rep)
        cv = fit_joint(tr_, soil, wheel, tuning, names, opts, max_nfev=args.max_evals)
        name = f"held-out repeat {rep}"
        refs[name] = matched
        held += error_rows(te_, predict(te_, Variant(name, cv.soil, cv.wheel or wheel, cv.tuning, opts)), wheel.radius)
    print(format_table(held, refs))


def cmd_bekker(args: argparse.Namespace) -> int:
    from ..fit.bekker import main as bekker_main

    return int(bekker_main(args.rest) or 0)


def register(sub: Any) -> None:
    """Add this module's commands to the ``offnominal`` sub-parser."""
    v = sub.add_parser("validate", help="Table 5.5 / Fig. 5.6 validation (load given, sinkage predicted)",
                       description="Solve each condition's sinkage from its measured load, predict Fx, Fy and sinkage, "
                                   "and report errors per slip angle beside reference rows (Table 5.5) of the same "
                                   "wheel kind (grousered / smooth) and model.")
    v.add_argument("--data", help="trials CSV in the single-wheel format (default: the shipped grousered trials)")
    v.add_argument("--params", help=f"parameter TOML (default: shipped {DEFAULT_PARAMS})")
    v.add_argument("--params-soil-flow", help=f"parameter TOML for the soil-flow variant (default: shipped {DEFAULT_PARAMS_SF} "
                                              "when --params is not given)")
    v.add_argument("--tuned", help="per-angle tuned model for the 'dissertation' rows: a built-in set "
                                   f"({', '.join(TUNED_SETS)}), a TOML with a [tuning] table (and optionally its [soil] "
                                   "and [wheel]), or a CSV beta_deg,a0,a1,b0,b1 (default: authors-grousered for a "
                                   "grousered wheel, table-5.4-smooth for a smooth one)")
    v.add_argument("--reference", help=f"reference rows: a built-in set ({REFERENCE_DEFAULT}: Table 5.5, grousered and "
                                       "smooth), a CSV in the same layout, or 'none' (default: %(default)s)",
                   default=REFERENCE_DEFAULT)
    v.add_argument("--out", default="out/validation", help="output folder for CSV and PNG (default: %(default)s)")
    v.add_argument("--per-trial", action="store_true", help="score every trial instead of condition means")
    v.add_argument("--skip-dissertation", action="store_true", help="only the calibrated parameters")
    v.set_defaults(func=cmd_validate, atomic_outputs=True)

    c = sub.add_parser("calibrate", help="joint fit of soil and contact-angle parameters; writes TOML",
                       description="Fit soil parameters and a0..b1 lines in |beta| jointly, given each trial's load "
                                   "(sinkage predicted), and write the parameter file the rest of the library reads. "
                                   "A new wheel: --wheel-file my_wheel.toml (a [wheel] section; a [soil] section there "
                                   "or --soil-file gives the starting soil).")
    c.add_argument("--data", help="trials CSV (default: the shipped grousered trials)")
    c.add_argument("--out", default="calibrated.toml", help="parameter file to write (default: %(default)s)")
    wg = c.add_mutually_exclusive_group()
    wg.add_argument("--wheel", choices=[*WHEELS, "both"], default="both",
                    help="built-in wheel geometry: the published code's, the dissertation's Table 5.2, or both (pick "
                         "the better)")
    wg.add_argument("--wheel-file", help="TOML with a [wheel] section (radius_m, width_m, grouser_height_m, "
                                         "grouser_area_ratio, grouser_volume_fraction)")
    c.add_argument("--soil-file", help="TOML with a [soil] section: the starting soil (default: the wheel file's [soil], "
                                       "else dissertation Table 5.3 for the wheel's kind)")
    c.add_argument("--reference", default=REFERENCE_DEFAULT,
                   help="reference rows to compare with (built-in name, CSV, or 'none'; default: %(default)s)")
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
    c.set_defaults(func=cmd_calibrate, atomic_outputs=True)

    b = sub.add_parser("bekker", help="fit p = k z^n to static plate tests", add_help=False)
    b.add_argument("rest", nargs=argparse.REMAINDER)
    b.set_defaults(func=cmd_bekker, atomic_outputs=True)
