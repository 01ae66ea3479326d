"""The online step is a real-time iteration of (7.25) at the measured parameters (issue 20).

Each assertion here fails with the previous design put back: the QP linearised around the
interpolated table primitive with the interpolated residual ``g`` (about zero between grid
points, so the QP believed the interpolated primitive balanced) and the parameters clipped to the
table's trust radius (a 6 deg cross slope on a table built at 0 deg reached the QP as < 1 deg).
References are not the table: the NLP solved at the same point (IPOPT) and the optimizer's
independent check (numpy wheel model, free-body balance). The full-size comparison is
``tests/bench/bench_online_step.py``.
"""

from __future__ import annotations

from dataclasses import replace

import math
from pathlib import Path

import numpy as np
import pytest

from rtctl.allocator import merge_bounds
from rtctl.config import ControllerConfig, QpSettings
from rtctl.controller import Controller
from rtctl.messages import FailureDeclaration, Measurements
from rtctl.rti import RealTimeIteration
from rtctl.table import load_index, load_table

ROOT = Path(__file__).resolve().parents[1]
TABLES = ROOT / "tables"
DEG = math.pi / 180

# operating points of rr_steer_stuck (built at cross slope 0 only), strictly between grid values;
# the second has a 6 deg cross slope, beyond the table's axis
BETWEEN = {"cross_slope": 0.0, "slope": 0.230157, "speed": 0.035129, "steer_stuck": 0.204401}
BEYOND = {"cross_slope": 6 * DEG, "slope": 0.129852, "speed": 0.026788, "steer_stuck": -0.868879}


@pytest.fixture(scope="module")
def steer_table():
    return load_table(TABLES / "rr_steer_stuck.npz")


_PROBLEMS: dict = {}
"""Per table object: (the table, kept alive so its id stays its own; its spec; its NLP)."""


def _problem_at(t, op):
    """The scenario at ``op``, its NLP and the independent check (largest force, moment and load
    residual of a physical ``x``)."""
    from offline.rover.primitives import check_solution
    from offline.rover.table_builder import _problem, scenario_at
    from offline.rover.table_verify import spec_from_table

    hit = _PROBLEMS.get(id(t))
    if hit is None:  # one NLP per table: its casadi graph is most of a reference's cost
        spec = spec_from_table(t)
        hit = _PROBLEMS[id(t)] = (t, spec, _problem(spec.scenario, spec.solver))
    _, spec, pb = hit
    sc = scenario_at(spec.scenario, spec.family, op)
    xsc = np.asarray(t.layout.variable_scale)

    def check(x):
        res, _ = check_solution(pb, sc, np.asarray(x) / xsc)
        return (max(abs(res[f"balance {n}"]) for n in ("Fx", "Fy", "Fz")),
                max(abs(v) for k, v in res.items() if k.startswith("balance M")),
                max(abs(v) for k, v in res.items() if k.startswith(("load ", "zero-slip load "))))

    return pb, sc, check


def _reference(t, op):
    """The local optimum at ``op`` from the table's interpolated primitive (physical, IPOPT) and
    the independent check."""
    from offline.rover.primitives import check_solution

    pb, sc, check = _problem_at(t, op)
    xsc = np.asarray(t.layout.variable_scale)
    loc = pb.solve(pb.bounds(sc), t.at(**op).x / xsc)
    assert loc["success"] and check_solution(pb, sc, loc["x"])[1], loc["status"]
    return np.asarray(loc["x"]) * xsc, check


def _iterate(t, op, ticks, settings=None):
    lay = t.layout
    xsc = np.asarray(lay.variable_scale)
    tp = t.at(**op)  # clamped into the axes: the Hessian, bounds and start come from there
    settings = settings or QpSettings()
    rti = RealTimeIteration(t, settings, [lay.index(f"wheel torque {w}") for w in lay.wheels])
    rti.prepare(tp)
    p = np.array(tp.p, dtype=float)
    for k in ("speed", "slope", "cross_slope"):
        p[lay.index(k)] = op[k]  # the measured parameters, never clipped
    xs = []
    for _ in range(ticks):
        x = rti.iterate
        sl = settings.step_limit  # the controller's trust region (rtctl.controller._bounds)
        res = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - sl * xsc, x + sl * xsc)))
        assert res.ok, res.status
        xs.append(res.x)
    return tp, p, rti, xs


def _close(lay, x, xstar):
    om = [lay.var("omega", w) for w in lay.wheels]
    be = [lay.var("beta", w) for w in lay.wheels]
    return (float(np.max(np.abs(x[om] - xstar[om]) / np.abs(xstar[om]))),
            float(np.max(np.abs(x[be] - xstar[be]))) / DEG)


def test_between_grid_points_one_tick_balances_and_iterates_reach_the_nlp(steer_table):
    t = steer_table
    xstar, check = _reference(t, BETWEEN)
    tp, p, rti, xs = _iterate(t, BETWEEN, 8)
    # the interpolated primitive (what the previous QP took as balanced) is not
    f0, m0, l0 = check(tp.x)
    assert f0 > 0.3, f0
    # one tick: the independent check's residual within 0.1 N, 0.01 N m, 0.2 N (measured 0.04 N, 0.002 N m, 0.02 N)
    f1, m1, l1 = check(xs[0])
    assert f1 <= 0.1 and m1 <= 0.01 and l1 <= 0.2, (f1, m1, l1)
    # eight ticks at the same point: the NLP's optimum (speeds 2 %, steering 0.3 deg, objective 0.5 %)
    ds, db = _close(t.layout, xs[-1], xstar)
    fx, fstar = rti.residual.residual(xs[-1], p)[1], rti.residual.residual(xstar, p)[1]
    assert ds <= 0.02 and db <= 0.3 and abs(fx - fstar) <= 0.005 * fstar, (ds, db, fx, fstar)


def test_beyond_the_axis_the_parameter_enters_through_the_exact_residual(steer_table):
    t = steer_table
    assert list(t.axes["cross_slope"]) == [0.0]  # the table knows no cross slope at all
    xstar, check = _reference(t, BEYOND)
    tp, p, rti, xs = _iterate(t, BEYOND, 8)
    assert check(tp.x)[0] > 2.0  # the table's primitive at cross slope 0: the rover's weight is not balanced
    # the first tick (a fresh iterate) iterates while its steps are long: balanced at once
    f1, m1, l1 = check(xs[0])
    assert f1 <= 0.1 and m1 <= 0.01 and l1 <= 0.2, (f1, m1, l1)
    f8, m8, l8 = check(xs[-1])
    assert f8 <= 0.1 and m8 <= 0.01 and l8 <= 0.2, (f8, m8, l8)
    ds, db = _close(t.layout, xs[-1], xstar)
    fx, fstar = rti.residual.residual(xs[-1], p)[1], rti.residual.residual(xstar, p)[1]
    assert ds <= 0.02 and db <= 0.3 and abs(fx - fstar) <= 0.005 * fstar, (ds, db, fx, fstar)


def test_slack_is_zero_only_when_the_linearised_step_meets_the_exact_residual(steer_table):
    t = steer_table
    lay = t.layout
    tp, p, rti, _ = _iterate(t, BEYOND, 0, replace(QpSettings(), iterations_per_tick=1, restart_iterations=1))  # one linearisation
    x = rti.iterate
    g, _, jac = rti.linearise(x, p)
    res = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - 2 * np.asarray(lay.variable_scale), x + 2 * np.asarray(lay.variable_scale))))
    eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
    lin = (g + jac @ res.dx) / np.asarray(lay.constraint_scale)
    assert res.slack <= 1e-4 and np.max(np.abs(lin[eq])) <= 1e-4
    # every variable pinned where it is: the exact residual (2.5 N off at 6 deg) cannot be met
    rti2 = RealTimeIteration(t, QpSettings(), [lay.index(f"wheel torque {w}") for w in lay.wheels])
    rti2.prepare(tp)
    res2 = rti2.step(p, (x.copy(), x.copy()))
    assert res2.slack > 0.01
    assert np.max(np.abs(g[eq] / np.asarray(lay.constraint_scale)[eq])) >= res2.slack - 1e-6


def test_controller_feeds_the_measured_cross_slope_unclipped():
    """Also (2026-11-28): the restart the first tick's declared failure begins (a new table) is
    spread over ticks, at most ``restart_work_per_tick`` units of its work in a tick (4 here; with
    the default 12 this restart fits in its tick: measured, no fallback tick), while the controller commands its
    fallback (the table's primitive with the failure, in the limits); then the QP. Before, the
    whole restart ran in the first tick (no such fallback tick)."""
    tables = {k: v.load() for k, v in load_index(TABLES / "index.json").items()}
    cfg = ControllerConfig()
    cfg = replace(cfg, qp=replace(cfg.qp, restart_work_per_tick=4))
    ctl = Controller(tables, cfg)
    fail = (FailureDeclaration("RR", "steer_stuck", -50 * DEG),)
    om = 0.03 / 0.0625
    modes, work = [], []
    for k in range(60):  # 12 s: the tilt filter (1 s) has settled on the 6 deg roll
        m = Measurements(t=0.2 * (k + 1), seq=k, wheel_speed=(om,) * 4, steer_angle=(0.0, 0.0, -50 * DEG, 0.0),
                         yaw_rate=0.0, pitch=0.0, roll=6 * DEG, pose=None, failures=fail)
        cmd, d = ctl.step(m)
        modes.append(d.mode if d.mode == "qp" else f"{d.mode}: {d.reason}")
        work.append(ctl._rtis["rr_steer_stuck"].restart_work if "rr_steer_stuck" in ctl._rtis else 0)
        assert all(math.isfinite(v) for v in (*cmd.rim_speed, *cmd.steer_angle))
        assert abs(cmd.steer_angle[2] + 50 * DEG) <= 1e-9  # the stuck wheel's declared angle, every tick
    spread = [i for i, md in enumerate(modes) if "restart in progress" in md]
    assert spread and spread == list(range(len(spread))), modes[:8]
    assert set(modes[len(spread):]) == {"qp"}, modes[:8]
    assert 0 < max(work) <= cfg.qp.restart_work_per_tick, work[:8]
    assert d.table == "rr_steer_stuck" and d.mode == "qp"
    lay = tables["rr_steer_stuck"].layout
    assert ctl._last_p is not None
    assert ctl._last_p[lay.index("cross_slope")] == pytest.approx(6 * DEG, rel=0.01)  # was clipped to < 1 deg


def test_closed_loop_on_a_cross_slope_the_table_was_not_built_for(tmp_path):
    """RR stuck at -65 deg on a 6 deg cross slope (the simulated world's truth), the shipped
    rr_steer_stuck table built at cross slope 0, 1.5 m at 3 cm/s. The previous design ran 21 %
    fast and left the path by 3.7 cm; measured now (the rebuilt table, exact active-set QP) 1.80 deg,
    2.29 cm, -1.4 %."""
    from drive_helpers import drive_rtctl

    m = drive_rtctl(tmp_path, '[scenario]\nname = "rr_stuck_65"\nparams = "dissertation-ch7"\nspeed_m_s = 0.03\n\n'
                    '[wheels.RR]\nsteer_stuck_deg = -65.0\n', distance=1.5,
                    truth_toml='[truth]\nparams = "dissertation-ch7"\ncross_slope_deg = 6.0\n')
    assert m["max_abs_cross_track_cm"] <= 3.0, m
    assert m["max_abs_heading_deg"] <= 2.5, m  # target 2 deg; 0.5 deg of margin for another machine's arithmetic
    assert abs(m["mean_speed_cm_s"] / 3.0 - 1.0) <= 0.05, m


def test_a_tick_iterates_again_only_after_a_jump(steer_table):
    """More than one SQP iteration in a tick only when the iterate starts or the operating point
    jumped (speed 10 %, slope or cross slope 1 deg): the steady ticks of a drive take one. With
    one iteration a tick, the first tick beyond the axis is not balanced (the behaviour before)."""
    t = steer_table
    lay = t.layout
    xsc = np.asarray(lay.variable_scale)
    _, _, check = _problem_at(t, BEYOND)  # the independent check alone (no NLP solve)
    tp, p, rti, xs = _iterate(t, BEYOND, 3)
    assert rti.sqp_iterations == 1  # ticks 2 and 3 at the same point
    x = rti.iterate
    p2 = p.copy()
    p2[lay.index("cross_slope")] -= 2 * DEG  # a jump of the measured cross slope
    rti.step(p2, merge_bounds(tp.lbx, tp.ubx, (x - xsc, x + xsc)))
    assert rti.sqp_iterations >= 2
    p3 = p2.copy()
    p3[lay.index("cross_slope")] += 0.2 * DEG  # a small move: one iteration
    x = rti.iterate
    rti.step(p3, merge_bounds(tp.lbx, tp.ubx, (x - xsc, x + xsc)))
    assert rti.sqp_iterations == 1
    _, _, _, one = _iterate(t, BEYOND, 1, replace(QpSettings(), iterations_per_tick=1, restart_iterations=1))
    assert check(one[0])[0] > 0.1
