"""Steady states of rovers from their files solve: the MER-class six-wheel rocker-bogie and the
four-wheel skid-steer (rigid) balance of rtctl.physics.suspension with the numpy wheel model
(rtctl.physics.terramechanics.wrench_core) and scipy's least squares, driving straight at the
nominal speed on flat ground and up a 10 deg slope.

Unknowns: one common wheel speed (every wheel commanded alike, no steering), each wheel's
sinkage and load; equations: each wheel's F_z(h, omega) = W_i (5.34)/(7.19)-(7.22) and every
balance row, scaled by the weight (N) and the weight times 1 m (N m). Six wheels: 13 unknowns,
15 equations; four rigid wheels: 9 unknowns, 11 equations (with the height compatibility that
closes the indeterminate loads). A solution with zero residual is a steady state. Checked at
the solution: the total normal load is W cos(slope) (from the wheel model's F_z, not only the
loads), the rows of the independent free body of tests/test_suspension.py vanish (bogie,
differential; for the rigid frame the heights lie on a plane), the two sides are mirror images,
the loads shift downhill on the slope, the wheel speed is within the file's drive limit.

Not covered here: standing still (the wheel model's slip is undefined at zero speed), steering,
failures, the NLP's objective (7.24).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares
from test_suspension import FreeBody

from offline.physics.params import load_toml
from offline.rover.scenario import PARAM_PRESETS
from rtctl.physics.backend import NUMPY
from rtctl.physics.rover_file import shipped_rover
from rtctl.physics.suspension import SuspensionStatics
from rtctl.physics.terramechanics import ModelOptions, PhysParams, wrench_core

TOL_BALANCE_REL = 1e-10  # |row| / (W or W * 1 m) at the least-squares solution


@pytest.fixture(scope="module")
def mer():
    rv = shipped_rover("mer_class_rocker_bogie")
    ps = load_toml(rv.wheel_params("RF"))["parameter_set"]
    assert all(rv.wheel_params(w) == rv.wheel_params("RF") for w in rv.wheel_names)  # one wheel type
    return rv, PhysParams.from_sets(ps.soil, ps.wheel, ps.tuning), ps.wheel.radius + ps.wheel.grouser_height


def _wrenches(p, speed, omega, h):
    col = lambda v: np.asarray(v, dtype=float).reshape(-1, 1)  # noqa: E731
    n = len(h)
    w, diag = wrench_core(NUMPY, col(np.full(n, speed)), col(np.zeros(n)), col(omega), col(h), col(h), p, ModelOptions())
    return np.hstack([np.asarray(c, dtype=float).reshape(-1, 1) for c in w]), diag


def _solve(rv, p, rs, slope):
    st = SuspensionStatics(rv)
    names, n, W, v = st.wheels, len(st.wheels), rv.weight, rv.travel_speed

    def residual(x):
        omega, h, load = x[0], x[1:1 + n], x[1 + n:]
        wr, _ = _wrenches(p, v, np.full(n, omega), h)
        rows = st.balance(NUMPY, {k: tuple(wr[i]) for i, k in enumerate(names)}, {k: 0.0 for k in names},
                          dict(zip(names, h)), dict(zip(names, load)), slope, 0.0, 0.0)
        return np.concatenate([(wr[:, 2] - load) / W, [r / W for r in rows.values()]])

    x0 = np.concatenate([[1.05 * v / rs], np.full(n, 0.02), np.full(n, W / n)])
    lo = np.concatenate([[v / rs], np.full(n, 1e-4), np.zeros(n)])  # slip >= 0 (driving), positive sinkage
    sol = least_squares(residual, x0, bounds=(lo, np.inf), x_scale=np.concatenate([[0.1], np.full(n, 0.01), np.full(n, W / n)]),
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    omega, h, load = sol.x[0], sol.x[1:1 + n], sol.x[1 + n:]
    wr, diag = _wrenches(p, v, np.full(n, omega), h)
    return st, sol, omega, dict(zip(names, h)), dict(zip(names, load)), {k: tuple(wr[i]) for i, k in enumerate(names)}, diag


def _straight(rv, p, rs, slope_deg, rows, pairs):
    """Solve straight driving and check what every rover must satisfy: balanced, total normal
    load W cos(slope) (loads and the wheel model's F_z), the independent free body's ``rows``
    zero, the mirror ``pairs`` equal, every wheel slipping forward within the drive limit."""
    slope = math.radians(slope_deg)
    st, sol, omega, h, load, wr, diag = _solve(rv, p, rs, slope)
    W = rv.weight
    assert sol.success, sol.message
    assert np.abs(sol.fun).max() < TOL_BALANCE_REL
    assert sum(load.values()) == pytest.approx(W * math.cos(slope), rel=1e-12)
    assert sum(w[2] for w in wr.values()) == pytest.approx(W * math.cos(slope), rel=1e-9)
    free_body = FreeBody(rv)
    fb = free_body.rows(wr, {k: 0.0 for k in st.wheels}, h, load, slope, 0.0, 0.0, 0.0)
    for name in (rows or fb):
        assert abs(fb[name]) < TOL_BALANCE_REL * W, (name, fb[name])
    for r_, l_ in pairs:  # mirror image sides (nothing in the problem tells them apart)
        assert h[r_] == pytest.approx(h[l_], rel=1e-7) and load[r_] == pytest.approx(load[l_], rel=1e-7)
    assert np.all(diag["slip"] > 0) and omega <= rv.actuators.drive_speed_max
    return free_body, h, load, wr


@pytest.mark.parametrize("slope_deg", [0.0, 10.0])
def test_mer_class_drives_straight_in_steady_state(mer, slope_deg):
    rv, p, rs = mer
    _, h, load, wr = _straight(rv, p, rs, slope_deg,
                               ("My_bogie_right", "My_bogie_left", "My_differential", "My", "Fx", "Fz", "Mx", "Mz", "Fy"),
                               (("RF", "LF"), ("RM", "LM"), ("RR", "LR")))
    if slope_deg > 0:
        assert load["RR"] > load["RM"] > 0 and load["RR"] > load["RF"]  # load shifts downhill
        assert sum(w[0] for w in wr.values()) == pytest.approx(rv.weight * math.sin(math.radians(slope_deg)), rel=1e-9)


def test_the_slope_costs_slip_and_torque(mer):
    rv, p, rs = mer
    flat = _solve(rv, p, rs, 0.0)
    up = _solve(rv, p, rs, math.radians(10.0))
    assert up[2] > flat[2]  # a faster wheel for the same travel speed: more slip
    torque = lambda s: sum(w[4] ** 2 for w in s[5].values())  # noqa: E731  (7.24)
    assert torque(up) > torque(flat)


@pytest.fixture(scope="module")
def skid():
    rv = shipped_rover("skid_steer_4w")
    ps = PARAM_PRESETS[rv.wheel_params("FR")]
    assert all(w.params == "dissertation-ch7" for w in rv.wheels)
    return rv, PhysParams.from_sets(ps.soil, ps.wheel, ps.tuning), ps.wheel.radius + ps.wheel.grouser_height


@pytest.mark.parametrize("slope_deg", [0.0, 10.0])
def test_skid_steer_drives_straight_in_steady_state(skid, slope_deg):
    rv, p, rs = skid
    free_body, h, load, _ = _straight(rv, p, rs, slope_deg, None, (("FR", "FL"), ("RR", "RL")))
    assert np.abs(free_body.plane_residual(h)).max() < 1e-12  # the wheel centres of one rigid frame
    if slope_deg == 0.0:
        assert load["FR"] > load["RR"]  # the centre of mass is 2 cm ahead of the frame's centre
    else:
        assert load["RR"] > load["FR"]  # uphill: the load shifts to the rear
