"""Regenerate the small closed-loop recordings that tests/test_replay.py replays.

One command (from the repository root)::

    python tests/data/make_recordings.py

For each of the three section 7.3 scenarios (clean-sided trench with RR, RR rim speed capped
at half, RR steering stuck at -50 deg) it drives the simulated mini rover for ``--ticks``
control ticks (5 Hz) with the controller and writes ``tests/data/rec_<scenario>_<controller>.mcap``
(measurements, commands, diagnostics, timing and the simulator truth). The controller is
rtctl on the tables in ``tests/data/tables`` (``--controller rtctl``, the default when that
folder holds an index), or the dissertation's feed-forward + PID with its "optimal" steering
controllers (``--controller ff+optfb``). The metadata records the controller, the seed and the
sha256 of every table file, so a replay knows what it must be built from.

Regenerate them when a change to the controller is *meant* to change its commands; the
replay test fails on any change that is not.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
SCENARIOS = ("rr_trench_clean", "rr_speed_cap_half", "rr_steer_stuck_50")


def _sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def main(argv: list[str] | None = None) -> int:
    from offline.sim.experiments import build_controller, run_drive, scenario_by_name
    from offline.sim.rtctl_bridge import rtctl_factory
    from offline.sim.simulator import RoverSimulator
    from rtctl.recording import Recorder

    tables = HERE / "tables"
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="rtctl" if (tables / "index.json").exists() else "ff+optfb",
                    help="rtctl (tables in tests/data/tables) or one of none, ff, fb, ff+fb, ff+optfb")
    ap.add_argument("--ticks", type=int, default=25, help="5 Hz ticks per recording (default: %(default)s)")
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args(argv)
    factory = rtctl_factory(str(tables)) if args.controller == "rtctl" else None
    for name in SCENARIOS:
        sc = scenario_by_name(name)
        ctl = build_controller(args.controller, sc, rtctl_factory=factory)
        meta = {"scenario": sc.name, "controller": args.controller, "seed": args.seed, "ticks": args.ticks,
                "regenerate": "python tests/data/make_recordings.py"}
        if args.controller == "rtctl":
            meta["tables"] = {p.name: _sha(p) for p in sorted(tables.iterdir()) if p.is_file()}
        out = HERE / f"rec_{name}_{args.controller.replace('+', '_')}.mcap"
        with Recorder(out, meta, truth=True) as rec:
            sim = RoverSimulator(sc, seed=args.seed)
            run_drive(sim, ctl, distance=1e9, max_time=0.2 * (args.ticks - 1) + 1e-9, recorder=rec)
        print(f"wrote {out.relative_to(HERE.parent.parent)} ({out.stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
