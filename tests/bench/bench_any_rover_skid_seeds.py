"""The skid-steer's closed-loop drive on a given table, over seeds (issue 23, target T2).

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_any_rover_skid_seeds.py [--table T.npz] [--seeds 1 2 3]

rtctl (default :class:`rtctl.config.ControllerConfig` at 3 cm/s) drives the four-wheel skid-steer
with its front-right drive motor dead (``offline/scenarios/rovers/skid_fr_unpowered.toml``) 5 m
along world X in the simulator (default sensors, the seed given), as
``bench_any_rover_drives.py``'s ``skid-steer, FR unpowered`` rtctl case does for seed 1. The table
defaults to the shipped test table ``tests/data/tables/rovers/skid_fr_unpowered.npz``. Prints one
row per seed: the issue's targets (heading within 3 deg, cross-track within 5 cm), the mean speed,
the mean per-tick change of the commanded rim speeds (the chatter of ``results_any_rover_audit.md``;
all wheels, then the free-rolling FR alone), the CPU seconds of the drive, and a second table of the
QP per tick (from the diagnostics): ticks whose QP the exact active set solved (the KKT systems
of those ticks: median and largest, summed over a tick's SQP iterations), ticks OSQP solved
(the ADMM iterations of those ticks: median and largest; a tick of several SQP iterations reports
their sum), and ticks that took the fallback (a refused QP). Writes nothing. Which ``rtctl`` runs is
whatever ``PYTHONPATH`` gives (its folder is printed), so another tree's controller can be driven
on the same table, side by side.

Diagnoses of the command chatter (not rtctl's behaviour; each patches the controller in this
process only): ``--diagnose no-speed-shift`` holds the slip correction's speed factor (a) at 1;
``--diagnose table-primitive-slip`` takes the factor's model slip from the table point's primitive
instead of the real-time iteration's iterate (what rtctl did before the real-time iteration; its
module notes say why it changed); ``--diagnose balanced-slip`` keeps the last tick's model slip
whenever the last QP was not the exact active set's (a tick held by a rate limit: its iterate is
not a model solution); ``--command-weight W`` sets ``[qp] command_weight`` (the QP's pull toward
the previous command).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))


def main(argv: list[str] | None = None) -> int:
    """Drive the seeds and print the rows."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", default=str(ROOT / "tests" / "data" / "tables" / "rovers" / "skid_fr_unpowered.npz"))
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--distance", type=float, default=5.0, help="m along world X (default 5)")
    ap.add_argument("--diagnose", choices=("none", "no-speed-shift", "table-primitive-slip", "balanced-slip"), default="none")
    ap.add_argument("--command-weight", type=float, default=None, help="[qp] command_weight (default: rtctl's)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from dataclasses import replace

    from bench_any_rover_drives import CROSSTRACK_CM, HEADING_DEG, ROVERS
    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.simulator import RoverSimulator
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.table import load_table

    import rtctl
    import rtctl.controller as rc

    if args.diagnose == "no-speed-shift":
        rc._SPEED_SHIFT = (1.0, 1.0)  # type: ignore[attr-defined]
    elif args.diagnose == "table-primitive-slip":
        own = rc.Controller._primitive_slip
        rc.Controller._primitive_slip = (  # type: ignore[method-assign]
            lambda self, x, tp, ix, carried=False: own(self, np.asarray(tp.x, dtype=float), tp, ix, False))
    elif args.diagnose == "balanced-slip":
        own_b = rc.Controller._primitive_slip

        def balanced(self, x, tp, ix, carried=False):  # type: ignore[no-untyped-def]
            prev = self._prep
            if carried and prev is not None and prev.rti.allocator.last_solver != "active set":
                return prev.primitive_slip
            return own_b(self, x, tp, ix, carried)

        rc.Controller._primitive_slip = balanced  # type: ignore[method-assign]
    speed = 0.03
    print(f"rtctl from {Path(rtctl.__file__).parent}; diagnosis {args.diagnose}; command_weight "
          f"{args.command_weight if args.command_weight is not None else 'default'}")
    table = load_table(Path(args.table))
    print(f"table {args.table}: axes {dict((a, [float(v) for v in vals]) for a, vals in table.axes.items())}")
    print("| seed | distance [m] | max abs heading [deg] | max abs cross-track [cm] | mean speed [cm/s] | on the path "
          f"({HEADING_DEG:g} deg, {CROSSTRACK_CM:g} cm) | mean rim change per tick [mm/s], all / FR | CPU [s] |\n"
          "|---|---|---|---|---|---|---|---|")
    qp_rows: list[str] = []
    for seed in args.seeds:
        sc = load_scenario(ROVERS / "skid_fr_unpowered.toml").with_(speed=speed)
        cfg = ControllerConfig()
        qp = cfg.qp if args.command_weight is None else replace(cfg.qp, command_weight=args.command_weight)
        ctl = Controller({"skid_fr_unpowered": table}, replace(cfg, drive=replace(cfg.drive, speed=speed), qp=qp))
        rims: list[tuple[float, ...]] = []
        diags: list = []  # type: ignore[type-arg]
        step = ctl.step

        def logged(m, step=step):  # type: ignore[no-untyped-def]
            cmd, d = step(m)
            rims.append(tuple(cmd.rim_speed))
            diags.append(d)
            return cmd, d

        ctl.step = logged  # type: ignore[method-assign]
        c0 = time.process_time()
        res = run_drive(RoverSimulator(sc, seed=seed), ctl, distance=args.distance, max_time=3.0 * args.distance / speed)
        cpu = time.process_time() - c0
        m = res.metrics
        on = (m["max_abs_heading_deg"] <= HEADING_DEG and m["max_abs_cross_track_cm"] <= CROSSTRACK_CM
              and m["distance_m"] >= args.distance - 1e-9 and not res.ended)
        change = np.abs(np.diff(np.asarray(rims), axis=0))
        fr = list(table.layout.wheels).index("FR")
        print(f"| {seed} | {m['distance_m']:.2f} | {m['max_abs_heading_deg']:.2f} | {m['max_abs_cross_track_cm']:.2f} | "
              f"{m['mean_speed_cm_s']:.2f} | {'yes' if on else 'NO'} | {1e3 * float(np.mean(change)):.3f} / "
              f"{1e3 * float(np.mean(change[:, fr])):.3f} | {cpu:.1f} |", flush=True)
        ticks = diags[1:]  # the first tick has no feedback QP of its own
        exact = [d.mode == "qp" and d.qp_status.startswith("solved (active set)") for d in ticks]
        osqp = np.array([d.qp_iterations for d, e in zip(ticks, exact) if d.mode == "qp" and not e] or [0])
        refused = sum(d.mode != "qp" for d in ticks)
        kkt = np.array([d.qp_iterations for d, e in zip(ticks, exact) if e] or [0])
        qp_rows.append(f"| {seed} | {len(ticks)} | {sum(exact)} | {np.median(kkt):.0f} / {kkt.max()} | "
                       f"{len(ticks) - sum(exact) - refused} | {np.median(osqp):.0f} / {osqp.max()} | {refused} |")
    print("\n| seed | ticks | active set | its KKT systems median / max | OSQP | OSQP iterations median / max | "
          "fallback (refused) |\n|---|---|---|---|---|---|---|")
    print("\n".join(qp_rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
