"""The exact active-set QP solve (rtctl.active_set) against an interior-point solver (clarabel,
through qpsolvers) on seeded random QPs shaped like the allocation QP, and its place in the
allocator (the same QP's minimiser as OSQP's, OSQP taking over when slack is needed)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from rtctl.active_set import ActiveSet, solve_active_set

qpsolvers = pytest.importorskip("qpsolvers")


def _random_qp(rng: np.random.Generator, nx: int = 20, ng: int = 12, n_eq: int = 6):
    A = rng.normal(size=(nx, nx))
    H = A @ A.T / nx + 1e-3 * np.eye(nx)
    q = rng.normal(size=nx)
    J = rng.normal(size=(ng, nx))
    z_feas = rng.uniform(-0.3, 0.3, size=nx)  # a point inside every bound: the QP is feasible
    v = J @ z_feas
    lg = v - rng.uniform(0.0, 2.0, size=ng)
    ug = v + rng.uniform(0.0, 2.0, size=ng)
    lg[:n_eq] = ug[:n_eq] = v[:n_eq]  # equality rows
    free = rng.random(ng) < 0.15
    lg[free & (np.arange(ng) >= n_eq)] = -1e30
    zlo = z_feas - rng.uniform(0.0, 1.5, size=nx)
    zhi = z_feas + rng.uniform(0.0, 1.5, size=nx)
    fix = rng.random(nx) < 0.1
    zlo[fix] = zhi[fix] = z_feas[fix]
    return H, q, J, lg, ug, zlo, zhi


def _reference(H, q, J, lg, ug, zlo, zhi):
    eq = lg == ug
    up = ~eq & (ug < 1e20)
    lo = ~eq & (lg > -1e20)
    G = np.vstack([J[up], -J[lo]])
    h = np.concatenate([ug[up], -lg[lo]])
    import scipy.sparse as sp

    return qpsolvers.solve_qp(sp.csc_matrix(H), q, sp.csc_matrix(G), h, sp.csc_matrix(J[eq]), ug[eq], lb=zlo, ub=zhi,
                              solver="clarabel",
                              tol_feas=1e-11, tol_gap_abs=1e-11, tol_gap_rel=1e-11)


def test_cold_start_reaches_the_interior_point_minimiser():
    """From no guess: whenever the method says solved, it is clarabel's minimiser and the KKT
    conditions hold; it says so on most of these QPs (the rest: budget spent, said, and the
    allocator's OSQP takes over)."""
    solved = 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        qp = _random_qp(rng)
        ref = _reference(*qp)
        assert ref is not None
        r = solve_active_set(*qp, guess=None, max_iter=40)
        if not r.ok:
            assert "after 40" in r.why or "singular" in r.why
            continue
        solved += 1
        assert np.max(np.abs(r.z - ref)) < 1e-6, seed
        H, q, J, lg, ug, zlo, zhi = qp
        # KKT: stationarity with the returned multipliers, signs on the active side
        assert np.max(np.abs(H @ r.z + q + J.T @ r.y + r.nu)) < 1e-8
        ineq = lg < ug
        assert np.all(r.y[ineq & (r.active.rows > 0)] >= -1e-9) and np.all(r.y[ineq & (r.active.rows < 0)] <= 1e-9)
        assert np.all(r.nu[(r.active.box < 0) & (zlo < zhi)] <= 1e-9) and np.all(r.nu[r.active.box > 0] >= -1e-9)
        assert np.all(J @ r.z >= lg - 1e-8) and np.all(J @ r.z <= ug + 1e-8)
    assert solved >= 9


def test_warm_start_from_the_last_set_takes_one_system():
    """A small change of the data (one tick later) keeps the active set: one KKT system."""
    done = 0
    for seed in range(100, 112):
        rng = np.random.default_rng(seed)
        H, q, J, lg, ug, zlo, zhi = _random_qp(rng)
        first = solve_active_set(H, q, J, lg, ug, zlo, zhi, max_iter=40)
        if not first.ok:
            continue
        q2 = q + 1e-6 * rng.normal(size=q.size)
        r = solve_active_set(H, q2, J, lg, ug, zlo, zhi, guess=first.active, max_iter=40)
        assert r.ok and r.iterations == 1
        assert np.max(np.abs(r.z - _reference(H, q2, J, lg, ug, zlo, zhi))) < 1e-6
        done += 1
    assert done >= 6


def test_a_vanishing_row_is_harmless_when_met_and_refused_when_not():
    """A wheel out of contact makes a row ``0 * z = 0``: solvable (zero multiplier); ``0 * z = 1``
    is infeasible: never reported as solved with a finite small multiplier."""
    rng = np.random.default_rng(7)
    H, q, J, lg, ug, zlo, zhi = _random_qp(rng)
    J[0] = 0.0
    lg[0] = ug[0] = 0.0
    r = solve_active_set(H, q, J, lg, ug, zlo, zhi, max_iter=40)
    assert r.ok and abs(r.y[0]) < 1e-6
    lg[0] = ug[0] = 1.0
    r = solve_active_set(H, q, J, lg, ug, zlo, zhi, max_iter=40)
    assert not r.ok or abs(r.y[0]) > 1e6  # the allocator's penalty test refuses a huge multiplier


def test_budget_spent_is_said():
    rng = np.random.default_rng(3)
    qp = _random_qp(rng)
    r = solve_active_set(*qp, guess=ActiveSet.empty(20, 12), max_iter=1)
    if not r.ok:
        assert "after 1" in r.why


def test_allocator_exact_step_equals_osqp_on_a_built_table():
    """On the nominal test table, one real-time iteration off the grid: the active-set answer
    equals OSQP's (same QP, same settings) to OSQP's tolerance, and it is the path taken."""
    from pathlib import Path

    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_table

    t = load_table(Path(__file__).parent / "data" / "tables" / "nominal.npz")
    lay = t.layout
    xsc = np.asarray(lay.variable_scale)
    feas = np.argwhere(t.feasible)
    op = t.grid_point(tuple(int(i) for i in feas[len(feas) // 2]))
    tp = t.at(**op)
    p = np.array(tp.p, dtype=float)
    p[lay.index("slope")] += 0.02
    out = {}
    for n in (0, 8):
        rti = RealTimeIteration(t, replace(QpSettings(), eps=1e-9, max_iter=20000, active_set_iterations=n, iterations_per_tick=1,
                                           restart_iterations=1),
                                [lay.index(f"wheel torque {w}") for w in lay.wheels])
        rti.prepare(tp)
        x = rti.iterate
        res = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - 0.5 * xsc, x + 0.5 * xsc)))
        assert res.ok
        out[n] = (res.x, rti.allocator.last_solver, res.slack)
    assert out[8][1] == "active set" and out[0][1] == "osqp"
    assert out[8][2] == 0.0
    assert np.max(np.abs(out[8][0] - out[0][0]) / xsc) < 1e-5


def test_a_last_set_that_does_not_settle_is_restarted_from_the_equality_rows():
    """A stale guess (every bound active, as when the last tick's active bounds were rate and
    step limits that moved) over-determines the KKT system and does not settle within
    ``active_set_iterations``: without the restart OSQP takes the tick; with it the exact solve
    from the equality rows does, with zero slack and OSQP's answer to OSQP's tolerance."""
    from pathlib import Path

    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_table

    t = load_table(Path(__file__).parent / "data" / "tables" / "rr_steer_stuck_50.npz")
    lay = t.layout
    xsc = np.asarray(lay.variable_scale)
    feas = np.argwhere(t.feasible)
    tp = t.at(**t.grid_point(tuple(int(i) for i in feas[len(feas) // 2])))
    p = np.array(tp.p, dtype=float)
    p[lay.index("slope")] += 0.01
    out = {}
    for restart in (0, 6):
        rti = RealTimeIteration(t, replace(QpSettings(), eps=1e-9, max_iter=20000, active_set_iterations=2,
                                           active_set_restart_iterations=restart, iterations_per_tick=1, restart_iterations=1),
                                [lay.index(f"wheel torque {w}") for w in lay.wheels])
        rti.prepare(tp)
        x = rti.iterate
        rti.allocator._active = ActiveSet(np.zeros(lay.ng, dtype=np.int8), np.full(lay.nx, -1, dtype=np.int8))
        res = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - 0.5 * xsc, x + 0.5 * xsc)))
        assert res.ok
        out[restart] = (res.x, rti.allocator.last_solver, res.slack, rti.allocator.last_active_set_iterations)
    assert out[0][1] == "osqp" and out[6][1] == "active set"
    assert out[6][2] == 0.0 and 2 < out[6][3] <= 8
    assert np.max(np.abs(out[6][0] - out[0][0]) / xsc) < 1e-5


def test_starts_alike_reads_the_start_the_solve_takes():
    """A guess that only repeats the equality rows and the fixed variables starts where no
    guess does (the allocator then goes on from where the first solve stopped instead of
    repeating it); a guessed free bound or inequality row does not."""
    from rtctl.active_set import starts_alike

    lg = np.array([0.0, -1.0, -1e20])
    ug = np.array([0.0, 1.0, 1e20])
    zlo, zhi = np.array([-1.0, 0.5, -1.0]), np.array([1.0, 0.5, 1.0])  # the second variable fixed
    same = ActiveSet(np.array([1, 0, 0], dtype=np.int8), np.array([0, -1, 0], dtype=np.int8))
    assert starts_alike(same, None, lg, ug, zlo, zhi)
    assert starts_alike(ActiveSet(np.array([0, 0, 1], dtype=np.int8), np.zeros(3, dtype=np.int8)), None, lg, ug, zlo, zhi)
    assert not starts_alike(ActiveSet(np.array([1, -1, 0], dtype=np.int8), np.zeros(3, dtype=np.int8)), None, lg, ug, zlo, zhi)
    assert not starts_alike(ActiveSet(np.zeros(3, dtype=np.int8), np.array([1, 0, 0], dtype=np.int8)), None, lg, ug, zlo, zhi)


def test_a_row_no_free_variable_moves_is_left_to_its_slack_on_the_skid_steer():
    """The rigid skid-steer (no steering) at zero wheel slip angle: no free variable moves its
    ``balance Fy`` row (7.13), and a measured cross slope of 0.5 mrad leaves it violated by the
    lateral weight. The step is the whole soft QP's minimiser (clarabel on the recorded QP, slacks
    included): the active set solves it without that row in one KKT system and the row's slack is
    its violation. Before, the active set's multiplier there was violation / 1e-12 (refused) and
    OSQP took every such tick (50-4000 iterations in closed loop). OSQP alone (the C flight path's
    solver) is handed the row at the value it cannot leave: the same step and slack."""
    from pathlib import Path

    from rtctl.allocator import merge_bounds, solve_with_qpsolvers
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_table

    t = load_table(Path(__file__).parent / "data" / "tables" / "rovers" / "skid_fr_unpowered.npz")
    lay = t.layout
    xsc, gsc = np.asarray(lay.variable_scale), np.asarray(lay.constraint_scale)
    tp = t.at(slope=0.0, cross_slope=0.0, speed=0.03)
    p = np.array(tp.p, dtype=float)
    p[lay.index("cross_slope")] += 5e-4
    iy = list(lay.constraint_names).index("balance Fy")
    out = {}
    for n in (0, 5):
        rti = RealTimeIteration(t, replace(QpSettings(), eps=1e-9, max_iter=20000, iterations_per_tick=1, restart_iterations=1,
                                           active_set_iterations=n),
                                [lay.index(f"wheel torque {w}") for w in lay.wheels])
        rti.prepare(tp)
        x = rti.iterate
        out[n] = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - 0.5 * xsc, x + 0.5 * xsc)))
    g = rti.linearise(x, p)[0]
    res, a = out[5], rti.allocator
    assert res.ok and a.last_solver == "active set" and a.last_active_set_iterations == 1, res.status
    violation = abs(g[iy]) / gsc[iy]
    assert violation > 1e-4 and res.slack == pytest.approx(violation, rel=1e-9)
    ref = solve_with_qpsolvers(a.problem(), "clarabel")
    assert ref is not None
    nx, ng = lay.nx, lay.ng
    assert np.max(np.abs(ref[:nx] - (res.x - x) / xsc)) < 1e-6
    assert ref[nx + iy] + ref[nx + ng + iy] == pytest.approx(violation, rel=1e-5)
    assert np.allclose(a.last_solution, ref, atol=1e-6)
    assert out[0].ok and out[0].status == "solved" and out[0].slack == pytest.approx(violation, rel=1e-3)
    assert np.max(np.abs(out[0].x - res.x) / xsc) < 1e-5
