"""Freeze the rover's exact linearisation at seeded off-grid points (issue 20, step time).

One command (from the repository root)::

    python tests/data/make_online_step_reference.py

For every shipped table whose header defines the physics, six seeded points (the interpolated
primitive of a random feasible cell moved by up to 5 % of each variable's scale, parameters
moved between and beyond the axes) and, per table, 48 seeded wheel states over slip, skid,
locked and reversed travel. It stores ``SteadyStateResidual.evaluate`` (``g``, ``f``,
``grad_f``, ``jac_g_x``) and :func:`rtctl.physics.terramechanics.wrench_core` at those
points in ``tests/data/online_step_reference.npz``, with the commit that computed them.
``tests/test_rtctl_linearisation_reference.py`` checks that a faster evaluation of the same
physics still gives these values (to 1e-12 relative to each quantity's scale). The file was
written by the code before the step-time work of issue 20 (commit 98a77ab); regenerate only
after a deliberate change of the physics.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from rtctl.physics.backend import NUMPY  # noqa: E402
from rtctl.physics.steady_state import SteadyStateModel, SteadyStateResidual  # noqa: E402
from rtctl.physics.terramechanics import wrench_core  # noqa: E402
from rtctl.table import load_index  # noqa: E402

OUT = ROOT / "tests" / "data" / "online_step_reference.npz"
POINTS = 6
STATES = 48


def points(t, rng):
    lay = t.layout
    sx = np.asarray(lay.variable_scale, dtype=float)
    feas = np.argwhere(t.feasible)
    out = []
    for _ in range(POINTS):
        k = feas[rng.integers(len(feas))]
        op = t.grid_point(tuple(k))
        for i, a in enumerate(t.axis_order):
            ax = t.axes[a]
            if len(ax) > 1:
                op[a] = float(np.clip(op[a] + rng.uniform(-0.5, 0.5) * (ax[1] - ax[0]), ax[0], ax[-1]))
        tp = t.at(**op)
        x = tp.x + rng.uniform(-0.05, 0.05, lay.nx) * sx
        p = tp.p.copy()
        names = list(lay.parameter_names)
        for n, d in (("slope", 0.03), ("cross_slope", 0.1), ("fy_offset", 0.5), ("mz_offset", 0.05)):
            if n in names:
                p[names.index(n)] += rng.uniform(-d, d)
        out.append((x, p))
    return out


def wheel_states(model, rng):
    r = float(model.shearing_radius[0])
    v = rng.uniform(0.005, 0.06, STATES)
    beta = rng.uniform(-1.2, 1.2, STATES)
    slip = rng.uniform(-0.8, 0.9, STATES)
    omega = v / r / (1.0 - slip)
    omega[:4] = 0.0  # locked
    vx = v * np.cos(beta)
    vx[4:8] *= -1.0  # reversed travel
    vy = -v * np.sin(beta)
    h = rng.uniform(0.002, 0.03, STATES)
    h0 = h * rng.uniform(0.6, 1.2, STATES)
    return np.stack([vx, vy, omega, h, h0], axis=1)


def main() -> None:
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    rng = np.random.default_rng(20)
    data: dict[str, np.ndarray] = {"commit": np.array(rev)}
    names = []
    for name, entry in sorted(load_index(ROOT / "tables" / "index.json").items()):
        t = entry.load()
        if not t.feasible.any():
            continue
        lay = t.layout
        try:
            model = SteadyStateModel.from_table_header(t.header, lay.wheels)
        except Exception:  # a table without physics: nothing to freeze
            continue
        res = SteadyStateResidual(model, lay)
        X, Pm, G, F, GR, J = [], [], [], [], [], []
        for x, p in points(t, rng):
            g, f, grad, jac = res.evaluate(x, p, jacobian=True)
            X.append(x), Pm.append(p), G.append(g), F.append(f), GR.append(grad), J.append(jac)
        S = wheel_states(model, rng)
        w, _ = wrench_core(NUMPY, *(S[:, i:i + 1] for i in range(5)), model.phys[0], model.options)
        data.update({f"{name}/x": np.array(X), f"{name}/p": np.array(Pm), f"{name}/g": np.array(G),
                     f"{name}/f": np.array(F), f"{name}/grad_f": np.array(GR), f"{name}/jac_g_x": np.array(J),
                     f"{name}/states": S, f"{name}/wrench": np.concatenate([np.asarray(q) for q in w], axis=1)})
        names.append(name)
    data["tables"] = np.array(names)
    np.savez_compressed(OUT, **data)
    print(f"wrote {OUT.relative_to(ROOT)}: {', '.join(names)} (commit {rev})")


if __name__ == "__main__":
    main()
