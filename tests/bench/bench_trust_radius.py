"""The trust-radius phase alone, on a built table: :func:`point_trust_radius` at every optimal
point from its stored primal-dual point, in one process; CPU seconds, IPOPT runs and iterations.

Run from the repository root (per-wheel compiled NLP, as ``tables build`` uses)::

    nice python tests/bench/bench_trust_radius.py TABLE.npz [RADII.npy]

For an A/B of the phase on the same inputs, run each checkout's own copy of this script (it puts
its own repository first on ``sys.path``; for a checkout without it, copy it there). The radii are written to ``RADII.npy`` (optimal points in flat order x parameters);
they agree with the table's own to rounding (the scaled point is rebuilt from the stored
physical one), not bit for bit.
"""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from offline.rover import primitives as P  # noqa: E402
from offline.rover import table_builder as TB  # noqa: E402
from offline.rover.table_verify import spec_from_table  # noqa: E402
from rtctl.table import load_table  # noqa: E402


def main() -> int:
    t = load_table(sys.argv[1])
    spec = spec_from_table(t)
    spec = replace(spec, solver=replace(spec.solver or P.SolverOptions(), compile="on", nlp_structure="per_wheel"))
    lay = t.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    runs = [0, 0]
    orig = P.SteadyStateProblem.solve

    def solve(self: Any, *a: Any, **k: Any) -> Any:
        r = orig(self, *a, **k)
        runs[0] += 1
        runs[1] += int(r["iterations"])
        return r

    P.SteadyStateProblem.solve = solve  # type: ignore[method-assign]
    feas = [f for f in range(spec.grid.size) if t.status.ravel()[f] == 0]
    if feas:  # the problem (and its compiled library) built outside the clock
        TB._problem(TB.scenario_at(spec.scenario, spec.family, spec.grid.point(feas[0])), spec.solver)
    out, unv = np.zeros((len(feas), lay.np_)), np.zeros((len(feas), lay.np_))
    c0 = time.process_time()
    for i, f in enumerate(feas):
        idx = np.unravel_index(f, t.shape)
        a = {k: t.arrays[k][idx] for k in ("x", "lam_x", "lam_g", "dx_dp")}
        sc = TB.scenario_at(spec.scenario, spec.family, spec.grid.point(f))
        pb = TB._problem(sc, spec.solver)
        out[i], unv[i] = TB.point_trust_radius(spec, pb, sc, a["x"] / xsc, a["lam_x"] * xsc, a["lam_g"] * csc,
                                               a["x"], a["dx_dp"])
    cpu = time.process_time() - c0
    print(f"{sys.argv[1]}: {len(feas)} optimal points: trust radius CPU {cpu:.1f} s, IPOPT runs {runs[0]}, "
          f"iterations {runs[1]}, unverified {int(unv.sum())}")
    if len(sys.argv) > 2:
        np.save(sys.argv[2], out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
