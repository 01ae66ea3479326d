"""Discrepancy command: locate model-data mismatch, name the missing physics (or say the parameters
are off), show the fit improve."""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np

from . import drive_discrepancy
from .common import DEFAULT_PARAMS, fail, parameter_set_or_fail, shipped, trials_or_fail

__all__ = ["register"]

REPORT_FILES = ("report.md", "verdict.json", "residual_map.png", "measured_vs_predicted.png", "recalibrated.toml")


def cmd_discrepancy(args: argparse.Namespace) -> int:
    """Run :func:`offline.discrepancy.engine.diagnose` on a trials file (or, with ``--recording``, on
    drive recordings: :func:`offline.cli.drive_discrepancy.run_recording`) and write the report folder."""
    if args.recording:
        return drive_discrepancy.run_recording(args)
    from tqdm import tqdm

    from ..files import OutputError, check_output_dir
    from ..discrepancy.engine import DiscrepancyError, diagnose
    from ..discrepancy.report import write_report
    from ..physics.terramechanics import ModelOptions

    t0 = time.perf_counter()
    try:
        check_output_dir(args.out, inputs=[args.data, args.params or shipped(DEFAULT_PARAMS)], names=REPORT_FILES)
    except OutputError as exc:
        return fail(str(exc))
    if not 0.0 < args.alpha < 0.5:
        return fail(f"--alpha {args.alpha}: expected a false-alarm level in (0, 0.5), e.g. 0.01")
    if args.bootstrap < 100:
        return fail(f"--bootstrap {args.bootstrap}: at least 100 null draws are needed (default 2000)")
    trials = trials_or_fail(args.data)
    if trials is None:
        return 2
    if args.max_beta_deg is not None:
        trials = trials.subset(np.abs(trials.beta_cmd) <= math.radians(args.max_beta_deg + 0.5))
        if len(trials) == 0:
            return fail(f"no trials with |beta| <= {args.max_beta_deg} deg")
    ps, _ = parameter_set_or_fail(args.params)
    if ps is None:
        return 2
    try:
        opts = ModelOptions(exit_angle=args.exit_angle, bulldozing=args.bulldozing)
    except ValueError as exc:
        return fail(str(exc))
    with tqdm(total=None, desc="discrepancy", unit="step", leave=False, disable=args.quiet) as bar:
        def progress(s: str) -> None:
            bar.set_postfix_str(s[:40])
            bar.update(1)

        try:
            verdict = diagnose(trials, ps, opts, seed=args.seed, alpha=args.alpha, n_boot=args.bootstrap, progress=progress)
        except DiscrepancyError as exc:
            return fail(str(exc))
    out = write_report(verdict, args.out)
    print(verdict.summary())
    extra = ", recalibrated.toml" if verdict.recalibrated is not None else ""
    print(f"wrote {out / 'report.md'}, {out / 'verdict.json'}{extra} and plots  ({time.perf_counter() - t0:.1f} s)")
    return 0


def register(sub: Any) -> None:
    """Add the ``discrepancy`` command to the ``offnominal`` sub-parser."""
    d = sub.add_parser(
        "discrepancy", help="locate model-data mismatch, name the missing physics or say the parameters are off",
        description="Run the model on every recorded condition, locate significant residual regions, fit a library of "
                    "candidate physics and a recalibration of the model's own parameters, accept by held-out improvement "
                    "against a bootstrap null (family-wise false-alarm level --alpha), and write a report folder "
                    "(report.md, PNGs, verdict.json; recalibrated.toml when the verdict is 'parameters off'). Verdicts: "
                    "agree, explained, parameters off, partly explained, ambiguous (drives: explanations that fit "
                    "equally, nothing named, with the manoeuvre that would separate them), unexplained; explanations the "
                    "data cannot tell apart are reported together with the experiment that would separate them.")
    d.add_argument("--data", help="trials CSV in the single-wheel format (default: the shipped grousered trials)")
    d.add_argument("--params", help=f"parameter TOML (default: shipped {DEFAULT_PARAMS})")
    d.add_argument("--out", default="out/discrepancy", help="report folder (default: %(default)s)")
    d.add_argument("--exit-angle", choices=["classic", "soil_flow"], default="classic", help="model variant")
    d.add_argument("--bulldozing", choices=["pavlov", "hegedus", "ishigami", "none"], default="pavlov",
                   help="sidewall model of the model under test ('none' to study a model without it)")
    d.add_argument("--max-beta-deg", type=float, default=None, help="only conditions up to this slip angle")
    d.add_argument("--alpha", type=float, default=0.01, help="family-wise false-alarm level of a single-wheel diagnosis (default: %(default)s; drives use 0.001 before and 0.01 after an explanation, offline.discrepancy.drive.diagnosis.DRIVE_ALPHA)")
    d.add_argument("--bootstrap", type=int, default=2000, help="null draws of the single-wheel bootstrap (default: %(default)s; drives: 3 / level)")
    d.add_argument("--seed", type=int, default=0, help="seed of the bootstrap and the region test")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    drive_discrepancy.add_recording_arguments(d)
    d.set_defaults(func=cmd_discrepancy)
