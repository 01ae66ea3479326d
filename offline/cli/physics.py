"""Physics commands: soil-flow (Fig. 4.6 / 4.7)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import fail, soil_flow_available

__all__ = ["register"]


def cmd_soil_flow(args: argparse.Namespace) -> int:
    if not soil_flow_available():
        return fail("the soil-flow model is not available in this build")
    from ..physics.plots_soil_flow import plot_phase_map, plot_sweep

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.what in ("phase-map", "both"):
        print(f"wrote {plot_phase_map(out / 'fig_4_7_phase_map.png', h0=args.h0_mm * 1e-3)}")
    if args.what in ("sweep", "both"):
        print(f"wrote {plot_sweep(out / 'fig_4_6_sweep.png')}")
    return 0


def register(sub: Any) -> None:
    """Add this module's commands to the ``offnominal`` sub-parser."""
    s = sub.add_parser("soil-flow", help="draw the soil-flow phase map (Fig. 4.7) and sweep (Fig. 4.6)")
    s.add_argument("what", choices=["phase-map", "sweep", "both"], nargs="?", default="both")
    s.add_argument("--h0-mm", type=float, default=10.0, help="sinkage for the phase map, mm (default: %(default)s)")
    s.add_argument("--out", default="out/soil_flow", help="output folder (default: %(default)s)")
    s.set_defaults(func=cmd_soil_flow)
