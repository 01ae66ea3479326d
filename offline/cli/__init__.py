"""Command line: ``offnominal <command>``.

One module per subject registers its commands (:mod:`.fit`, :mod:`.discrepancy` (trials and drive
recordings), :mod:`.rover`, :mod:`.physics`, :mod:`.tables`, :mod:`.sim`);
this module only builds the parser and dispatches.

Commands
--------
validate    Table 5.5 / Fig. 5.6 validation on single-wheel trials (the default main job).
calibrate   Fit the model to single-wheel trials and write a TOML parameter file.
discrepancy Locate model-data mismatch, name the missing physics, show the fit improve
            (single-wheel trials, or drive recordings with --recording).
primitive   Solve a driving scenario (failures, trenching, slope) for a steady primitive.
slope-sweep Fig. 7.12: slip and power against slope.
envelope    Steepest feasible slope and the slope where slip crosses a limit.
chapter7    Reproduce chapter 7 beside the dissertation's numbers.
bekker      Fit Bekker's p = k z^n to static plate tests.
soil-flow   Draw the soil-flow phase map (Fig. 4.7) and one-at-a-time sweep (Fig. 4.6).
tables      Build, inspect and verify lookup tables for the on-rover QP.
drive       Closed-loop drive of the simulated rover (section 7.3), plots and MCAP recordings.
replay      Replay a recording through rtctl bit for bit (or HIL style at 5 Hz); CSV export.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from . import discrepancy, fit, physics, rover, sim, tables
from .common import DEFAULT_PARAMS

__all__ = ["main", "build_parser", "DEFAULT_PARAMS"]

COMMAND_MODULES = (fit, discrepancy, rover, physics, tables, sim)
"""Modules whose ``register(sub)`` adds commands, in help order."""


def build_parser() -> argparse.ArgumentParser:
    """The ``offnominal`` argument parser with every command module registered."""
    ap = argparse.ArgumentParser(
        prog="offnominal",
        description="Off-nominal rover driving: wheel-soil physics, calibration and validation.",
        epilog="Run 'offnominal <command> -h' for a command's options.",
    )
    sub = ap.add_subparsers(dest="command", metavar="command")

    for module in COMMAND_MODULES:
        module.register(sub)
    return ap


GROUND_PACKAGES = ("casadi", "matplotlib", "tqdm", "dask", "distributed", "qpsolvers")
"""Packages of the ``ground`` extra (``pip install 'offnominal-rover[ground]'``); the rover install
(``pip install .``) has rtctl's only."""


def _ground_missing(exc: ModuleNotFoundError) -> int:
    """A clear error for a ground-side command on the rover install (else re-raise)."""
    if (exc.name or "").split(".")[0] not in GROUND_PACKAGES:
        raise exc
    print(f"offnominal: this command needs the ground-side dependencies ({exc.name} is not installed); this "
          "looks like the rover install (pip install .), which has rtctl's only: install "
          "'offnominal-rover[ground]' (from the repository: pip install '.[ground]')", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``offnominal`` command."""
    try:
        ap = build_parser()
    except ModuleNotFoundError as exc:
        return _ground_missing(exc)
    args = ap.parse_args(argv)
    if not getattr(args, "command", None):
        ap.print_help()
        return 0
    try:
        return int(args.func(args))
    except ModuleNotFoundError as exc:
        return _ground_missing(exc)
    except KeyboardInterrupt:
        # only commands that write every output through offline.files (temporary file, then
        # rename) set atomic_outputs; for the others a file being written may be cut short
        if getattr(args, "atomic_outputs", False):
            msg = ("interrupted: every output file is either complete or absent (each is written to a temporary "
                   "name and renamed into place); files not yet written are missing")
        else:
            msg = ("interrupted: a file that was being written may be incomplete; run the command again before "
                   "using its outputs")
        print(f"\n{msg}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

