"""The rover's exact residual of (7.25) is the NLP's: one source of the rows, two backends.

:class:`rtctl.physics.steady_state.SteadyStateResidual` (numpy, built from a table header
alone) is compared with the casadi graph IPOPT solves (``SteadyStateProblem.eval_g``, built by
the ground side from the decoded scenario) at points *off* the table's grid: perturbed
primitives and parameters between and beyond the axes. The objective gradient is compared
with casadi's exact gradient. A residual that silently fell back to interpolated table values
(the old behaviour) would fail the off-grid comparison by the interpolation error.
"""

from __future__ import annotations

import sys
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rtctl.physics.steady_state import SteadyStateModel, SteadyStateResidual
from rtctl.table import load_table

TABLES = Path(__file__).resolve().parents[1] / "tables"


def _casadi_reference(t):
    import casadi as ca

    from offline.rover.table_builder import _problem
    from offline.rover.table_verify import spec_from_table

    spec = spec_from_table(t)
    pb = _problem(spec.scenario, spec.solver)
    xs, ps = pb.symbols["x"], pb.symbols["p"]
    grad = ca.Function("grad", [xs, ps], [ca.gradient(pb.symbols["f"], xs), ca.jacobian(pb.symbols["g"], xs)])
    return pb, grad


@pytest.mark.parametrize("name", ["nominal", "rr_steer_stuck", "rr_trench_clean"])
def test_numpy_residual_equals_the_nlp_graph_off_the_grid(name):
    t = load_table(TABLES / f"{name}.npz")
    lay = t.layout
    res = SteadyStateResidual(SteadyStateModel.from_table_header(t.header, lay.wheels), lay)
    pb, grad = _casadi_reference(t)
    free = (t.at(**t.grid_point(tuple(np.argwhere(t.feasible)[0]))).lbg <= -1e20)  # rows without bounds
    free &= t.at(**t.grid_point(tuple(np.argwhere(t.feasible)[0]))).ubg >= 1e20
    xsc, gsc = np.asarray(lay.variable_scale), np.asarray(lay.constraint_scale)
    rng = np.random.default_rng(7)
    feas = np.argwhere(t.feasible)
    checked = 0
    for k in rng.choice(len(feas), size=3, replace=False):
        tp = t.at(**t.grid_point(tuple(feas[k])))
        x = tp.x * (1 + 0.02 * rng.standard_normal(lay.nx))  # off the primitive
        p = np.array(tp.p, dtype=float)
        p[lay.index("speed")] *= 1.13  # between and beyond grid speeds
        p[lay.index("slope")] += np.radians(1.7)
        p[lay.index("cross_slope")] += np.radians(6.0)  # beyond a table built at cross slope 0
        p[lay.index("fy_offset")] = 0.4
        p[lay.index("mz_offset")] = -0.07
        g, f, gf, jac = res.evaluate(x, p, jacobian=True)
        g1, f1 = res.residual(x, p)
        assert np.array_equal(g, g1) and f == f1  # the batched differences' base column is the plain evaluation
        g_ref, f_ref = (np.asarray(v, dtype=float).ravel() for v in pb.eval_g(x / xsc, p))
        g_ref = g_ref * gsc
        # same expressions in the same order: agreement to rounding, row by row in its own scale
        assert np.max(np.abs(g - g_ref) / gsc) < 1e-9, (name, np.abs(g - g_ref) / gsc)
        assert f == pytest.approx(float(f_ref[0]), rel=1e-10)
        gf_ref, jac_ref = (np.asarray(v, dtype=float) for v in grad(x / xsc, p))
        gf_ref = gf_ref.ravel() / xsc  # d f / d x_phys
        jac_ref = jac_ref * gsc[:, None] / xsc[None, :]  # d g_phys / d x_phys
        # the rows' Jacobian by the structured differences, in each row's and variable's scale
        # (rows without bounds constrain nothing and are dropped by the controller: the trench's
        # flat width has a kink at the pointy/flat switch)
        err = np.abs(jac - jac_ref) * xsc[None, :] / gsc[:, None]
        assert np.max(err[~free]) < 1e-4, (name, np.unravel_index(np.argmax(err), err.shape))
        # forward differences of step 1e-7 variable scales: ~1e-6 of the gradient's largest entry
        assert np.max(np.abs(gf - gf_ref)) <= 2e-6 * np.max(np.abs(gf_ref)), (gf, gf_ref)
        # and it is not the table: the interpolated g of the grid point is ~0 on the equality rows
        eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
        assert np.max(np.abs(g[eq]) / gsc[eq]) > 1e-3
        checked += 1
    assert checked == 3


def test_header_without_params_is_refused_by_name():
    from rtctl.physics.parameters import ParameterError

    t = load_table(TABLES / "nominal.npz")
    h = dict(t.header)
    h["params"] = {"soil": {"k": 1.0}}
    with pytest.raises(ParameterError, match=r"params\.soil\.n0"):
        SteadyStateModel.from_table_header(h, t.layout.wheels)
    h.pop("params")
    with pytest.raises(ParameterError, match="no 'params' record"):
        SteadyStateModel.from_table_header(h, t.layout.wheels)


def test_shared_physics_imports_numpy_only():
    code = ("import sys, rtctl.physics.steady_state, rtctl.physics.soil_flow; bad = [m for m in sys.modules if "
            "m.split('.')[0] in ('casadi', 'offline', 'scipy', 'osqp', 'matplotlib', 'dask')]; print(bad); "
            "sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
