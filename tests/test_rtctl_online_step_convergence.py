"""Convergence of the online step at a constant operating point (issue 20, weak spots).

At an off-grid rim-speed-cap point the table's interpolated Lagrangian Hessian carries a cell
corner whose capped wheel sits on the wheel model's zero-slip kink (fraction 1, cross slope 0:
1e5-1e6 on that wheel's omega and beta against 2-40 at the other corners), and the iterate crept
along the wheel's steering (4 deg off the NLP's optimum after five ticks, creeping ~0.05 deg a
tick). At an off-grid unpowered point the proximal terms (regularisation and command weight
1e-5 of the normalised objective, above the exact reduced curvature 1e-7-1e-6) held each tick's
step to a constant and the speeds were 6 % off after five ticks (10 % at today's point, on the
rebuilt table). The structured Hessian
(:meth:`rtctl.rti.RealTimeIteration._structured_hessian`) and the 1e-8 floors fix both; each
test fails with the previous settings (``PREVIOUS``), which the last test checks.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtctl.allocator import merge_bounds
from rtctl.config import QpSettings
from rtctl.rti import RealTimeIteration
from rtctl.table import load_table

ROOT = Path(__file__).resolve().parents[1]
TABLES = ROOT / "tables"
DEG = math.pi / 180

# strictly between grid values (tests/bench/bench_online_step.py accuracy --seed 0 drew them)
RIM_CAP = {"cross_slope": -0.062711, "rim_speed_cap_fraction": 0.939809, "slope": 0.039165, "speed": 0.032534}
UNPOWERED = {"cross_slope": -0.0009, "slope": 0.230956, "speed": 0.035716}
# (the shipped rr_unpowered rebuilt on 2026-11-28 starts closer to the optimum at the former point
# (-0.052187, 0.195404, 0.028582), where the previous settings now end 1.7 % off and pass; this one,
# drawn by a seeded search over the table (numpy default_rng(0), the 28th draw), is where they do not)

NO_CONTINUATION = replace(QpSettings(), restart_continuation_stages=0)
"""The restart without the parameter continuation from the cell's corners (issue 22): the tests of
the structured Hessian, the branch start and the restart tick's budget are about the iteration from
the table's own start."""

PREVIOUS = replace(NO_CONTINUATION, gauss_newton=False, regularization=1e-5, command_weight=1e-5,
                   restart_iterations=3, restart_iteration_step=0.05)
"""The settings before the structured Hessian (the table's interpolated Hessian, 1e-5 floors) and
before the restart tick's own budget (a restart's first tick as a jump's: 3 iterations, 0.05 scales)."""


def _optimum(t, op):
    from offline.rover.primitives import check_solution
    from offline.rover.table_builder import _problem, scenario_at
    from offline.rover.table_verify import spec_from_table

    spec = spec_from_table(t)
    pb = _problem(spec.scenario, spec.solver)
    sc = scenario_at(spec.scenario, spec.family, op)
    xsc = np.asarray(t.layout.variable_scale)
    loc = pb.solve(pb.bounds(sc), t.at(**op).x / xsc)
    assert loc["success"] and check_solution(pb, sc, loc["x"])[1], loc["status"]
    return np.asarray(loc["x"]) * xsc


def _ticks(t, op, n, settings):
    lay = t.layout
    xsc = np.asarray(lay.variable_scale)
    tp = t.at(**op)
    rti = RealTimeIteration(t, settings, [lay.index(f"wheel torque {w}") for w in lay.wheels])
    rti.prepare(tp)
    p = np.array(tp.p, dtype=float)
    for k in ("speed", "slope", "cross_slope"):
        p[lay.index(k)] = op[k]
    xs, steps = [], []
    for _ in range(n):
        x = rti.iterate
        box = merge_bounds(tp.lbx, tp.ubx, (x - settings.step_limit * xsc, x + settings.step_limit * xsc))
        res = rti.step(p, box)
        assert res.ok, res.status
        assert np.all(np.isfinite(res.x)) and np.all(res.x >= box[0]) and np.all(res.x <= box[1])
        xs.append(res.x)
        steps.append(rti.sqp_iterations)
    return tp, p, rti, xs, steps


def _agreement(t, rti, p, x, xstar):
    lay = t.layout
    om = [lay.var("omega", w) for w in lay.wheels]
    be = [lay.var("beta", w) for w in lay.wheels]
    floor = 0.05 * np.asarray(lay.variable_scale)[om]
    ds = float(np.max(np.abs(x[om] - xstar[om]) / np.maximum(np.abs(xstar[om]), floor)))
    db = float(np.max(np.abs(x[be] - xstar[be]))) / DEG
    f, fstar = rti.residual.residual(x, p)[1], rti.residual.residual(xstar, p)[1]
    return ds, db, abs(f - fstar) / fstar


@pytest.fixture(scope="module")
def rim_cap():
    t = load_table(TABLES / "rr_rim_speed_cap.npz")
    return t, _optimum(t, RIM_CAP)


@pytest.fixture(scope="module")
def unpowered():
    t = load_table(TABLES / "rr_unpowered.npz")
    return t, _optimum(t, UNPOWERED)


def test_the_kink_corner_is_left_out_of_the_curvature(rim_cap):
    t, _ = rim_cap
    tp = t.at(**RIM_CAP)
    rti = RealTimeIteration(t, QpSettings(), [t.layout.index(f"wheel torque {w}") for w in t.layout.wheels])
    sx = np.asarray(t.layout.variable_scale)
    interpolated = float(np.abs(tp.hess_lag * np.outer(sx, sx)).max())
    assert interpolated > 1e4, interpolated  # the kink corners, interpolated (measured 2.1e5)
    A = rti._table_curvature(tp)
    assert float(np.abs(A).max()) < 1e3, float(np.abs(A).max())  # the other corners': tens
    # on a grid point away from the kink, every corner weight sits on it: its own curvature
    q = {k: float(t.axes[k][i]) for k, i in (("cross_slope", 0), ("rim_speed_cap_fraction", 2), ("slope", 1), ("speed", 0))}
    tq = t.at(**q)
    assert np.allclose(rti._table_curvature(tq), rti._corner_curvature(tq.hess_lag, tq.jac_g_x), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("case", ["rim_cap", "unpowered"])
def test_five_ticks_at_a_constant_point_reach_the_nlp_optimum(case, request):
    t, xstar = request.getfixturevalue(case)
    op = RIM_CAP if case == "rim_cap" else UNPOWERED
    _, p, rti, xs, _ = _ticks(t, op, 5, NO_CONTINUATION)
    ds, db, df = _agreement(t, rti, p, xs[-1], xstar)
    # issue-20 targets: speeds 2 %, steering 0.3 deg, objective 0.5 % (measured: rim cap 0.02 %,
    # 0.003 deg; unpowered 0.01 %, 0.06 deg)
    assert ds <= 0.02 and db <= 0.3 and df <= 0.005, (ds, db, df)


@pytest.mark.parametrize("case", ["rim_cap", "unpowered"])
def test_the_previous_settings_do_not(case, request):
    """The assertion above fails with the previous settings (it can fail)."""
    t, xstar = request.getfixturevalue(case)
    op = RIM_CAP if case == "rim_cap" else UNPOWERED
    _, p, rti, xs, _ = _ticks(t, op, 5, PREVIOUS)
    ds, db, df = _agreement(t, rti, p, xs[-1], xstar)
    assert not (ds <= 0.02 and db <= 0.3 and df <= 0.005), (ds, db, df)


def test_a_steady_tick_is_deterministic_bounded_and_settles(rim_cap):
    t, _ = rim_cap
    a = _ticks(t, RIM_CAP, 20, QpSettings())
    b = _ticks(t, RIM_CAP, 20, QpSettings())
    assert all(np.array_equal(x, y) for x, y in zip(a[3], b[3]))  # bit for bit
    steps = a[4]
    s0 = QpSettings()
    assert steps[0] <= max(s0.restart_iterations, s0.iterations_per_tick) and all(s == 1 for s in steps[1:])  # a budget in iterations
    sx = np.asarray(t.layout.variable_scale)
    assert float(np.max(np.abs(a[3][-1] - a[3][-2]) / sx)) < 1e-3  # settled: the last step is short


# rr_steer_stuck between grid values (bench_online_step.py accuracy --seed 0): two of the cell's
# eight corners (52 % of the weight) steer RL at -89 deg, the others at -26 to -39 deg
TWO_BRANCHES = {"cross_slope": 0.0, "slope": 0.026200, "speed": 0.028747, "steer_stuck": 0.718941}


def test_a_restart_starts_on_one_branch_not_between_two():
    """From the whole cell's interpolation (the previous start, put back by hand) the iterate
    sits between two branches of optima: after five ticks out of balance, its objective about
    three times the NLP's (measured 4.2 N after one tick, 3.2 times the verified optimum's
    objective after five). From the start of :meth:`rtctl.rti.RealTimeIteration.start` it
    balances and reaches the optimum's objective (measured 2e-5 relative)."""
    t = load_table(TABLES / "rr_steer_stuck.npz")
    lay = t.layout
    sx = np.asarray(lay.variable_scale)
    tp = t.at(**TWO_BRANCHES)
    out = {}
    for start in ("branch", "interpolated"):
        rti = RealTimeIteration(t, NO_CONTINUATION, [lay.index(f"wheel torque {w}") for w in lay.wheels])
        rti.prepare(tp)
        if start == "interpolated":
            rti.iterate = rti.allocator.x0
        else:
            assert rti.start_status.startswith("branch of 6 of 8 corners"), rti.start_status
            be = lay.var("beta", "RL")
            assert abs(rti.iterate[be] / DEG + 89.0) > 30.0  # not the -89 deg branch
        p = np.array(tp.p, dtype=float)
        for _ in range(5):
            x = rti.iterate
            res = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - 2.0 * sx, x + 2.0 * sx)))
            assert res.ok and np.all(np.isfinite(res.x)), res.status
        g, f = rti.residual.residual(res.x, p)
        viol = np.maximum(tp.lbg - g, 0.0) + np.maximum(g - tp.ubg, 0.0)
        out[start] = (float(np.max(viol / rti.allocator.sg)), f)
    # balanced: every row within 0.3 % of its scale (force rows: the rover's weight, 34 N: 0.1 N);
    # measured 3e-5 from the branch, 0.16 (5.6 N) from the interpolation
    assert out["branch"][0] <= 3e-3 < out["interpolated"][0], out
    # the verified NLP optimum there: objective 1.08740 (solve_primitive's multi-start; the
    # bench's reference); measured 1.08738 from the branch, 3.51 from the interpolation
    assert out["branch"][1] == pytest.approx(1.08740, rel=0.005), out
    assert out["interpolated"][1] > 1.5 * out["branch"][1], out


# rr_rim_speed_cap between grid values (bench_online_step.py accuracy --seed 0), the capped wheel
# slipping: the interpolated primitive lies far from the optimum in its flat directions
RIM_CAP_FAR = {"cross_slope": -0.071285, "rim_speed_cap_fraction": 0.655398, "slope": 0.021570, "speed": 0.027286}


def test_the_first_tick_after_a_restart_iterates_until_balanced():
    """The first tick after a restart takes up to ``restart_iterations`` SQP iterations while its
    steps are longer than ``restart_iteration_step``; with a jump tick's budget (3 iterations,
    0.05 scales: the behaviour before) the commanded point was out of balance (measured by the
    independent check: 0.83 N force, 1.9 N load; target 0.1 N, 0.2 N)."""
    t = load_table(TABLES / "rr_rim_speed_cap.npz")
    out = {}
    for name, settings in (("restart budget", NO_CONTINUATION),
                           ("jump budget", replace(NO_CONTINUATION, restart_iterations=3, restart_iteration_step=0.05))):
        tp, p, rti, xs, steps = _ticks(t, RIM_CAP_FAR, 1, settings)
        g, _ = rti.residual.residual(xs[0], p)
        viol = np.maximum(tp.lbg - g, 0.0) + np.maximum(g - tp.ubg, 0.0)
        out[name] = (float(np.max(viol / rti.allocator.sg)), steps[0])
    assert out["restart budget"][1] <= QpSettings().restart_iterations, out  # bounded
    # every row within 0.3 % of its scale (force rows: the rover's weight, 34 N: 0.1 N); measured
    # 2e-6 after 7 iterations, 0.22 after the jump budget's 3
    assert out["restart budget"][0] <= 3e-3 < out["jump budget"][0], out


def test_a_candidate_start_with_a_non_finite_residual_is_never_chosen():
    """A branch whose interpolated start gives a non-finite residual (the wheel model outside its
    domain) is skipped, and the restart still succeeds: ``prepare`` never raises for it."""
    t = load_table(TABLES / "rr_steer_stuck.npz")
    lay = t.layout
    tp = t.at(**TWO_BRANCHES)
    rti = RealTimeIteration(t, NO_CONTINUATION, [lay.index(f"wheel torque {w}") for w in lay.wheels])
    linearise = rti.linearise
    rl = lay.var("beta", "RL")

    def poisoned(x, p):  # the 6-corner branch (RL steered above -60 deg) evaluates to NaN
        g, grad, jac = linearise(x, p)
        return (g * np.nan, grad, jac * np.nan) if x[rl] > -60 * DEG else (g, grad, jac)

    rti.linearise = poisoned  # type: ignore[method-assign]
    rti.prepare(tp)
    assert rti.start_status.startswith("branch of 2 of 8 corners"), rti.start_status  # the one finite branch
    assert np.all(np.isfinite(rti.iterate))


# the centre of rr_rim_speed_cap's cell (0, 0, 0, 2) (tables verify's check 4,
# tests/bench/bench_tables_online.py): cap 0.75-1, the capped wheel near its zero-slip kink
CYCLE_CENTRE = {"slope": 2.5 * DEG, "cross_slope": -5.0 * DEG, "speed": 0.03, "rim_speed_cap_fraction": 0.875}


def test_a_restart_by_continuation_from_the_corners_converges_where_the_table_start_cycles():
    """From the table's start (the interpolated primitive, no continuation: the step before issue
    22's check 4) the iteration cycles with period 2 (measured 0.8, 1.2, 0.76, 1.2, 0.75 variable
    scales from the optimum; first command 3.1 N out of balance by the independent check). The
    restart by parameter continuation from the cell's corners starts balanced and converges to
    the best verified optimum there (objective 0.614301: ``table_verify.check_interpolation``'s
    best of every start and a continuation from each corner; the other optimum found is 0.617469)."""
    t = load_table(TABLES / "rr_rim_speed_cap.npz")
    out = {}
    for name, settings in (("continuation", QpSettings()), ("table start", NO_CONTINUATION)):
        tp, p, rti, xs, steps = _ticks(t, CYCLE_CENTRE, 5, settings)
        sx = np.asarray(t.layout.variable_scale)
        g, f = rti.residual.residual(xs[0], p)
        viol = np.maximum(tp.lbg - g, 0.0) + np.maximum(g - tp.ubg, 0.0)
        last = float(np.max(np.abs(xs[-1] - xs[-2]) / sx))
        out[name] = (float(np.max(viol / rti.allocator.sg)), last, rti.residual.residual(xs[-1], p)[1], steps[0])
    s0 = QpSettings()
    assert out["continuation"][3] <= max(s0.restart_iterations, s0.iterations_per_tick), out  # bounded
    # balanced at tick 1 (every row within 0.3 % of its scale), settled at tick 5, at the best optimum
    assert out["continuation"][0] <= 3e-3 and out["continuation"][1] < 1e-3, out
    assert out["continuation"][2] == pytest.approx(0.614301, rel=1e-3), out
    # the table's start: still moving by more than 0.3 scales a tick after five (the cycle)
    assert out["table start"][1] > 0.3, out


def test_a_restart_spread_over_ticks_does_the_same_work_within_its_budget():
    """``prepare(tp, budget)`` runs at most ``budget`` units of the restart's work a call and
    refuses the tick meanwhile (``ok`` False, finite, no iterate); its start is the one-call
    restart's (to 1e-4 variable scales: the later calls load the table point again, which sets
    the QP's normalisation), after work // budget + 1 calls (the last one ends it)."""
    t = load_table(TABLES / "rr_rim_speed_cap.npz")
    lay = t.layout
    keep = [lay.index(f"wheel torque {w}") for w in lay.wheels]
    tp = t.at(**CYCLE_CENTRE)
    p = np.array(tp.p, dtype=float)
    one = RealTimeIteration(t, QpSettings(), keep)
    one.prepare(tp)
    spread = RealTimeIteration(t, QpSettings(), keep)
    calls, box = 0, (np.asarray(tp.lbx, dtype=float), np.asarray(tp.ubx, dtype=float))
    while True:
        spread.prepare(tp, 5)
        calls += 1
        assert spread.restart_work <= 5
        if not spread.restarting:
            break
        assert spread.iterate is None
        res = spread.step(p, box)
        assert not res.ok and np.all(np.isfinite(res.x)) and "restart in progress" in res.status
    assert spread.restart_work_total > 5 and calls == spread.restart_work_total // 5 + 1
    sx = np.asarray(lay.variable_scale)
    assert float(np.max(np.abs(spread.iterate - one.iterate) / sx)) <= 1e-4
