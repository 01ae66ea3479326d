"""The allocation QP against closed forms and another solver (issue 12).

Table points here are hand-made from small problems whose answer is known in closed form
(equality-constrained quadratic: one linear KKT solve), so the QP assembly (scaling, parameter
shift, slacks, box merging) is checked without a built table.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rtctl.allocator import AllocatorError, QpAllocator, merge_bounds, solve_with_qpsolvers
from rtctl.config import QpSettings
from rtctl.layout import NlpLayout

VAR_SCALES = {"omega": 0.5, "beta": 0.3, "W": 8.6, "h": 0.016, "h0": 0.016}
CON_SCALES = {"force": 34.3, "moment": 11.0, "load": 8.6, "torque": 0.5}
LAYOUT = NlpLayout.build(VAR_SCALES, CON_SCALES)
NX, NG, NP = LAYOUT.nx, LAYOUT.ng, LAYOUT.np_
EQ_ROWS = LAYOUT.rows("balance")  # the 7 balance rows are equalities, the rest free here


@dataclass
class Point:
    """A TablePoint-like record (contract C2 field names, physical units)."""

    x: np.ndarray
    p: np.ndarray
    g: np.ndarray
    jac_g_x: np.ndarray
    jac_g_p: np.ndarray
    grad_f: np.ndarray
    hess_lag: np.ndarray
    lbx: np.ndarray
    ubx: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    dx_dp: np.ndarray


def make_point(seed: int, kkt: bool = True) -> tuple[Point, np.ndarray]:
    """A random strictly convex problem; with ``kkt`` the primitive x0 is its optimum (grad_f =
    -J' lambda for a multiplier lambda), as a table's primitive is. Returns (point, lambda)."""
    rng = np.random.default_rng(seed)
    sx = LAYOUT.variable_scale
    M = rng.normal(size=(NX, NX))
    Hs = M @ M.T / NX + 0.5 * np.eye(NX)  # in scaled variables
    H = Hs / sx[:, None] / sx[None, :]
    J = np.zeros((NG, NX))
    J[EQ_ROWS] = rng.normal(size=(len(EQ_ROWS), NX)) * LAYOUT.constraint_scale[EQ_ROWS, None] / sx[None, :] * 0.3
    Jp = np.zeros((NG, NP))
    Jp[LAYOUT.index("balance Fy"), LAYOUT.index("fy_offset")] = -1.0  # (7.27)
    Jp[LAYOUT.index("balance Mz"), LAYOUT.index("mz_offset")] = -1.0  # (7.26)
    lam = np.zeros(NG)
    lam[EQ_ROWS] = rng.normal(size=len(EQ_ROWS)) * 0.2
    grad = -J.T @ lam if kkt else rng.normal(size=NX) / sx
    lbg = np.full(NG, -np.inf)
    ubg = np.full(NG, np.inf)
    lbg[EQ_ROWS] = ubg[EQ_ROWS] = 0.0
    x0 = rng.normal(size=NX) * sx + 1.0
    p0 = np.zeros(NP)
    p0[LAYOUT.index("speed")] = 0.03
    return Point(x0, p0, np.zeros(NG), J, Jp, grad, H, x0 - 100 * sx, x0 + 100 * sx, lbg, ubg, np.zeros((NX, NP))), lam


def kkt_step(pt: Point, dp: np.ndarray) -> np.ndarray:
    """Closed form: min 1/2 dx'H dx + g'dx s.t. J_eq dx + Jp_eq dp = 0."""
    J = pt.jac_g_x[EQ_ROWS]
    K = np.block([[pt.hess_lag, J.T], [J, np.zeros((len(EQ_ROWS), len(EQ_ROWS)))]])
    rhs = np.concatenate([-pt.grad_f, -pt.jac_g_p[EQ_ROWS] @ dp])
    return np.linalg.solve(K, rhs)[:NX]


TIGHT = QpSettings(regularization=1e-9, command_weight=0.0, eps=1e-9, max_iter=20000, slack_l1=1e3)


def wide_box(pt: Point) -> tuple[np.ndarray, np.ndarray]:
    return pt.lbx.copy(), pt.ubx.copy()


@pytest.mark.parametrize("seed", range(5))
def test_qp_step_equals_closed_form_kkt_step(seed):
    pt, _ = make_point(seed, kkt=False)
    alloc = QpAllocator(LAYOUT, TIGHT)
    alloc.prepare(pt)
    p = pt.p.copy()
    p[LAYOUT.index("fy_offset")] = 0.7
    p[LAYOUT.index("mz_offset")] = -0.15
    res = alloc.solve(p, wide_box(pt))
    assert res.ok, res.status
    ref = kkt_step(pt, p - pt.p)
    sx = LAYOUT.variable_scale
    np.testing.assert_allclose(res.dx / sx, ref / sx, atol=1e-5 * max(1.0, np.abs(ref / sx).max()))
    assert res.slack < 1e-6


def test_primitive_is_a_fixed_point_and_offsets_move_it_linearly():
    """At the table's optimum (KKT point) with zero offsets the step is zero (the exact L1
    penalty keeps the balance rows hard); with an offset the step is the KKT step, linear in it."""
    pt, _ = make_point(7, kkt=True)
    alloc = QpAllocator(LAYOUT, TIGHT)
    alloc.prepare(pt)
    res0 = alloc.solve(pt.p, wide_box(pt))
    assert np.abs(res0.dx / LAYOUT.variable_scale).max() < 1e-5  # ADMM accuracy at eps = 1e-9
    dxs = []
    for fy in (0.5, 1.0):
        p = pt.p.copy()
        p[LAYOUT.index("fy_offset")] = fy
        dxs.append(alloc.solve(p, wide_box(pt)).dx)
    sx = LAYOUT.variable_scale
    np.testing.assert_allclose(dxs[1] / sx, 2 * dxs[0] / sx, atol=1e-4 * np.abs(dxs[1] / sx).max())
    assert np.abs(dxs[0]).max() > 0


def test_fixed_variable_and_soft_rows_keep_the_qp_feasible():
    """A failure fixes one steering angle far from the primitive: the box wins, the balance rows
    take slack (flagged), and the result is finite and inside the box."""
    pt, _ = make_point(3)
    alloc = QpAllocator(LAYOUT, replace(TIGHT, balance_tolerance=1e-3))
    alloc.prepare(pt)
    lo, hi = wide_box(pt)
    # fix every variable: the balance can only be met if dp = 0 -> demand an offset
    lo[:] = hi[:] = pt.x
    p = pt.p.copy()
    p[LAYOUT.index("fy_offset")] = 5.0
    res = alloc.solve(p, (lo, hi))
    assert np.all(np.isfinite(res.x)) and np.array_equal(res.x, pt.x)
    assert res.slack == pytest.approx(5.0 / CON_SCALES["force"], rel=1e-3)
    assert not res.ok and "slack" in res.status


def test_indefinite_hessian_is_convexified():
    pt, _ = make_point(4)
    pt.hess_lag = -pt.hess_lag  # a Lagrangian Hessian can be indefinite away from convex rows
    alloc = QpAllocator(LAYOUT, QpSettings())
    alloc.prepare(pt)
    res = alloc.solve(pt.p, wide_box(pt))
    assert res.ok and np.all(np.isfinite(res.x))


def test_bad_table_point_and_order_errors():
    pt, _ = make_point(1)
    alloc = QpAllocator(LAYOUT, QpSettings())
    with pytest.raises(AllocatorError, match="before prepare"):
        alloc.solve(pt.p, wide_box(pt))
    bad = replace(pt, jac_g_x=pt.jac_g_x[:-1])
    with pytest.raises(AllocatorError, match="jac_g_x.*shape"):
        alloc.prepare(bad)
    bad = replace(pt, hess_lag=pt.hess_lag * np.nan)
    with pytest.raises(AllocatorError, match="hess_lag.*not finite"):
        alloc.prepare(bad)


def test_nonfinite_parameters_are_refused_not_raised():
    pt, _ = make_point(2)
    alloc = QpAllocator(LAYOUT, QpSettings())
    alloc.prepare(pt)
    p = pt.p.copy()
    p[3] = np.nan
    res = alloc.solve(p, wide_box(pt))
    assert not res.ok and np.array_equal(res.x, pt.x)


def test_matches_clarabel_on_random_qps():
    """OSQP (warm, set up once, values updated) against clarabel through qpsolvers."""
    pytest.importorskip("clarabel")
    alloc = QpAllocator(LAYOUT, replace(QpSettings(), eps=1e-8, max_iter=20000))
    rng = np.random.default_rng(11)
    worst = 0.0
    for k in range(40):
        pt, _ = make_point(100 + k)
        alloc.prepare(pt)
        p = pt.p.copy()
        p[LAYOUT.index("fy_offset")] = rng.uniform(-2, 2)
        p[LAYOUT.index("mz_offset")] = rng.uniform(-0.4, 0.4)
        lo, hi = pt.x - rng.uniform(0.05, 2, NX) * LAYOUT.variable_scale, pt.x + rng.uniform(0.05, 2, NX) * LAYOUT.variable_scale
        res = alloc.solve(p, (lo, hi), x_ref=pt.x + 0.1 * LAYOUT.variable_scale)
        z = solve_with_qpsolvers(alloc.problem(), "clarabel")
        assert z is not None
        worst = max(worst, float(np.abs(res.dx / LAYOUT.variable_scale - z[:NX]).max()))
    assert worst < 1e-4, worst


@settings(max_examples=60, deadline=None, derandomize=True)
@given(st.lists(st.tuples(st.floats(-5, 5), st.floats(0, 3), st.floats(-5, 5), st.floats(0, 3)), min_size=1, max_size=6))
def test_merge_bounds_never_empty_and_inside_hard_box(boxes):
    lo_h = np.array([b[0] for b in boxes])
    hi_h = lo_h + np.array([b[1] for b in boxes])
    a = np.array([b[2] for b in boxes])
    b_ = a + np.array([b[3] for b in boxes])
    lo, hi = merge_bounds(lo_h, hi_h, (a, b_))
    assert np.all(lo <= hi) and np.all(lo >= lo_h) and np.all(hi <= hi_h)
    overlap = (np.maximum(lo_h, a) <= np.minimum(hi_h, b_))
    np.testing.assert_array_equal(lo[overlap], np.maximum(lo_h, a)[overlap])
    np.testing.assert_array_equal(hi[overlap], np.minimum(hi_h, b_)[overlap])


def test_merge_bounds_rejects_empty_hard_box():
    with pytest.raises(AllocatorError, match="hard bounds empty"):
        merge_bounds(np.array([1.0]), np.array([0.0]))
