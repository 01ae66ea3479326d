"""Discrepancy command: locate model-data mismatch, name the missing physics, show the fit improve."""

from __future__ import annotations

import argparse
import math
import time
from typing import Any

import numpy as np

from .common import DEFAULT_PARAMS, fail, parameter_set_or_fail, trials_or_fail

__all__ = ["register"]

def cmd_discrepancy(args: argparse.Namespace) -> int:
    from ..fit.discrepancy import diagnose
    from ..physics.terramechanics import ModelOptions

    t0 = time.perf_counter()
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
    verdict = diagnose(trials, ps, opts, seed=args.seed,
                       progress=None if args.quiet else (lambda s: print(f"  [{time.perf_counter() - t0:5.1f} s] {s}", flush=True)))
    out = verdict.write(args.out)
    print(verdict.summary())
    print(f"wrote {out / 'report.md'}, {out / 'verdict.json'} and plots  ({time.perf_counter() - t0:.1f} s)")
    return 0


def register(sub: Any) -> None:
    """Add the ``discrepancy`` command to the ``offnominal`` sub-parser."""
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
