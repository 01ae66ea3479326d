"""The mirrored table against a directly built one (issue 21, "Mirror").

One command (from the repository root)::

    python tests/bench/bench_mirror.py DIRECT.npz [--mirror-of tables/rr_steer_stuck.npz] [--stuck-deg 50]

``DIRECT.npz`` is the left-side table built by the optimizer itself, e.g. for rear-left
steering stuck::

    offnominal tables build rl_steer_stuck.toml --grid "slope=0:20:5;cross_slope=0;steer_stuck=-90:90:15" --out DIR

(``rl_steer_stuck.toml``: ``tables/scenarios/rr_steer_stuck.toml`` with ``[wheels.RL]`` and an
absolute ``params`` path). It compares, at every grid point where both have a primitive, the
mirrored primitive and Jacobians with the direct build's, and drives the simulated rover (RL
stuck at ``--stuck-deg``, the section 7.3 world, 1.5 m, seed 1) once with rtctl on the mirrored
table and once on the direct one, reporting the largest difference of the two trajectories
(target: 0.5 mm and 0.05 deg). Results: ``tests/bench/results_mirror.md``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("direct", help="the directly built left-side table (.npz)")
    ap.add_argument("--mirror-of", default=str(ROOT / "tables" / "rr_steer_stuck.npz"))
    ap.add_argument("--stuck-deg", type=float, default=50.0)
    ap.add_argument("--distance", type=float, default=1.5)
    args = ap.parse_args()

    from offline.files import write_text
    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.simulator import RoverSimulator
    from offline.sim.truth import Truth
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.mirror import mirror_table
    from rtctl.table import load_index, load_table

    src = load_table(args.mirror_of)
    mir = mirror_table(src)
    direct = load_table(args.direct)
    lay = mir.layout
    xsc, gsc = np.asarray(lay.variable_scale), np.asarray(lay.constraint_scale)
    assert mir.axis_order == direct.axis_order and all(np.allclose(mir.axes[k], direct.axes[k]) for k in mir.axis_order)
    both = mir.feasible & direct.feasible
    only_m, only_d = int((mir.feasible & ~direct.feasible).sum()), int((direct.feasible & ~mir.feasible).sum())
    dx, dj = [], []
    for idx in np.argwhere(both):
        i = tuple(idx)
        dx.append(float(np.max(np.abs(mir.arrays["x"][i] - direct.arrays["x"][i]) / xsc)))
        J1, J2 = mir.arrays["jac_g_x"][i] * xsc / gsc[:, None], direct.arrays["jac_g_x"][i] * xsc / gsc[:, None]
        dj.append(float(np.max(np.abs(J1 - J2)) / max(np.max(np.abs(J2)), 1e-12)))

    # closed loop: the shipped tables with the mirror (as rtctl adds it) vs with the direct table
    shipped = {k: v.load() for k, v in load_index(ROOT / "tables" / "index.json").items()}
    sc_file = Path(args.direct).with_suffix(".scenario.toml")
    sc_file.write_text(f'[scenario]\nname = "rl_stuck"\nparams = "dissertation-ch7"\nspeed_m_s = 0.03\n\n'
                       f'[wheels.RL]\nsteer_stuck_deg = {args.stuck_deg}\n')
    sc = load_scenario(sc_file)
    runs = {}
    for label, tables in (("mirror", shipped), ("direct", {**shipped, direct.name: direct})):
        ctl = Controller(tables, ControllerConfig())
        assert ("rl_steer_stuck" in ctl.mirrored) == (label == "mirror")
        runs[label] = run_drive(RoverSimulator(sc, Truth.nominal(sc.params, sc.rover), seed=1), ctl,
                                distance=args.distance)
    n = min(len(runs["mirror"].truth), len(runs["direct"].truth))
    dy = max(abs(a.y - b.y) for a, b in zip(runs["mirror"].truth[:n], runs["direct"].truth[:n]))
    dh = max(abs(math.remainder(a.heading - b.heading, 2 * math.pi)) for a, b in
             zip(runs["mirror"].truth[:n], runs["direct"].truth[:n]))
    lines = ["# The mirrored table against a directly built one (issue 21)", "",
             f"`python tests/bench/bench_mirror.py {Path(args.direct).name} --mirror-of {Path(args.mirror_of).name} "
             f"--stuck-deg {args.stuck_deg:g}`", "",
             f"Grid points with a primitive in both: {int(both.sum())} (only in the mirror {only_m}, only in the direct "
             f"build {only_d}).", "",
             f"- primitive: largest difference {max(dx) if dx else float('nan'):.2e} variable scales "
             f"(median {float(np.median(dx)) if dx else float('nan'):.1e}); the builder's IPOPT tolerance is 1e-9 "
             "scaled, its independent check 1e-6 of the weight",
             f"- constraint Jacobian: largest difference {max(dj) if dj else float('nan'):.2e} of the block's largest entry",
             f"- closed loop, RL stuck at {args.stuck_deg:g} deg, {args.distance:g} m, seed 1: largest trajectory difference "
             f"{1000 * dy:.3f} mm cross-track, {math.degrees(dh):.4f} deg heading (target 0.5 mm, 0.05 deg)",
             f"- mirror drive: max heading {runs['mirror'].metrics['max_abs_heading_deg']:.2f} deg, max cross-track "
             f"{runs['mirror'].metrics['max_abs_cross_track_cm']:.2f} cm, speed {runs['mirror'].metrics['speed_error_pct']:+.1f} %; "
             f"direct: {runs['direct'].metrics['max_abs_heading_deg']:.2f} deg, "
             f"{runs['direct'].metrics['max_abs_cross_track_cm']:.2f} cm, {runs['direct'].metrics['speed_error_pct']:+.1f} %", ""]
    write_text(ROOT / "tests" / "bench" / "results_mirror.md", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
