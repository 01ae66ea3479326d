"""Discrepancy on drive recordings: the recording path of ``offnominal discrepancy`` (issue 14).

``offnominal discrepancy --recording DRIVE.mcap [more.mcap | folder ...]`` runs the same engine
as on single-wheel trials (:func:`offline.discrepancy.drive.diagnosis.diagnose_drives`) and writes the
same report folder (report.md, PNGs, verdict.json) plus the drive plots and the accepted terms
as a simulator truth file. :mod:`offline.cli.discrepancy` adds these options to its parser and
hands over to :func:`run_recording` when ``--recording`` is given.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from .common import fail, load_scenario_or_fail

__all__ = ["add_recording_arguments", "run_recording"]

DEFAULT_DRIVE_SCENARIO = "nominal"


def add_recording_arguments(d: argparse.ArgumentParser) -> None:
    """The options of the recording path (they share ``--params``, ``--out``, ``--seed``, ``--quiet``
    with the trials path)."""
    g = d.add_argument_group("drive recordings (issue 14)")
    g.add_argument("--recording", nargs="+", metavar="MCAP_OR_FOLDER",
                   help="recorded drive(s) (MCAP from 'offnominal drive' or a rover), or folders of them; "
                        "switches the command to drive recordings")
    g.add_argument("--scenario", default=DEFAULT_DRIVE_SCENARIO,
                   help="believed scenario (rover, parameter set, declared failures): TOML or shipped name "
                        "(default: %(default)s)")
    g.add_argument("--believed-truth", help="believed world as a truth TOML (slope, wheels, tether) if not flat and nominal")
    g.add_argument("--segment", type=int, default=5, help="ticks per row (time segment), default %(default)s")
    g.add_argument("--per-wheel-actuators", action="store_true",
                   help="fit every per-wheel actuator term (wheel-speed saturation, shortfall, slew-rate limit and extra servo lag, "
                        "steering saturation of each wheel) on every drive; by default they are fitted only on the "
                        "wheels the located regions or their own encoders implicate (slower)")
    g.add_argument("--workers", type=int, default=None,
                   help="processes for the independent re-simulations (default: every core this process may use); "
                        "the verdict is the same for any number")


def run_recording(args: argparse.Namespace) -> int:
    """Diagnose drive recordings and write the report folder."""
    from dataclasses import replace

    from ..files import OutputError, check_output_dir
    from ..discrepancy.drive.candidates import DriveCandidateError
    from ..discrepancy.drive.diagnosis import DriveDataError, diagnose_drives
    from ..discrepancy.drive.report import write_drive_report
    from ..physics.params import ParameterError, load_toml
    from ..sim.truth import Truth, TruthError, load_truth

    t0 = time.perf_counter()
    try:
        check_output_dir(args.out, inputs=[*args.recording, args.params, args.believed_truth],
                         names=["report.md", "verdict.json", "accepted_truth.toml", "recalibrated.toml"])
    except OutputError as exc:
        return fail(str(exc))
    sc = load_scenario_or_fail(args.scenario)
    if sc is None:
        return 2
    params_file = ""
    if args.params:
        try:
            loaded = load_toml(args.params)
        except (ParameterError, OSError) as exc:
            return fail(f"{args.params}: {exc}")
        if "parameter_set" not in loaded:
            return fail(f"{args.params}: no [soil], [wheel] and [tuning] sections (a full parameter file is needed)")
        sc = replace(sc, params=loaded["parameter_set"])
        params_file = str(args.params)  # the path: the accepted truth names it relative to its own folder
    try:
        truth = (load_truth(args.believed_truth, sc.rover_file or sc.rover, sc.params) if args.believed_truth
                 else None if sc.rover_file is not None else Truth.nominal(sc.params, sc.rover))  # a rover file: its own world
    except TruthError as exc:
        return fail(str(exc))
    if args.segment < 2:
        return fail(f"--segment {args.segment}: at least 2 ticks per segment")
    from ..discrepancy.parallel import available_workers

    workers = available_workers() if args.workers is None else args.workers
    if workers < 1:
        return fail(f"--workers {args.workers}: at least 1")
    say = None if args.quiet else (lambda s: print(f"  [{time.perf_counter() - t0:5.1f} s] {s}", flush=True))
    try:
        from ..discrepancy.drive.candidates import DRIVE_CANDIDATES, DRIVE_CANDIDATES_WITH_ACTUATORS

        lib = DRIVE_CANDIDATES_WITH_ACTUATORS if getattr(args, "per_wheel_actuators", False) else DRIVE_CANDIDATES
        v = diagnose_drives(args.recording, sc, truth, segment=args.segment, seed=args.seed, progress=say, candidates=lib,
                            workers=workers)
    except (DriveDataError, DriveCandidateError) as exc:
        return fail(str(exc))
    except ValueError as exc:  # the engine's DiscrepancyError (too few rows, model fails on most rows)
        return fail(str(exc))
    out = write_drive_report(v, args.out, params_file or getattr(sc.params, "name", ""))
    print(v.summary())
    print(f"wrote {out / 'report.md'}, {out / 'verdict.json'} and plots  ({time.perf_counter() - t0:.1f} s)")
    return 0

