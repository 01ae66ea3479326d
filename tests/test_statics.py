"""Rover statics: the balance derived from the geometry against an independent free-body computation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from offline.physics.backend import CASADI, NUMPY
from offline.physics.params import ROVER_MINI_T72
from offline.rover.statics import WHEELS, FourWheelRocker, free_body_residuals

MIRROR = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}


def _random_state(seed: int):
    rng = np.random.default_rng(seed)
    wr = {k: tuple(rng.normal(size=6)) for k in WHEELS}
    beta = {k: rng.normal(0, 0.4) for k in WHEELS}
    h = {k: rng.uniform(0.003, 0.03) for k in WHEELS}
    load = {k: rng.uniform(2, 10) for k in WHEELS}
    return rng, wr, beta, h, load


def _cross_product_free_body(rover, wr, beta, h, load, slope, cross, fyo, mzo):
    """A second, hand-written free body (no shared helper): positions from the sinkages
    (wheel centre height r - h above flat ground), the nose-up angle measured from them,
    forces at the centres, moments about the body point at pivot height."""
    lr, hr, wr_, W = rover.rocker_length, rover.pivot_height, rover.track_width, rover.weight
    total_f = np.zeros(3)
    total_m = np.zeros(3)
    pitch = {}
    for side, (front, rear) in {"R": ("FR", "RR"), "L": ("FL", "RL")}.items():
        y = -wr_ / 2 if side == "R" else wr_ / 2
        # the rocker's axis points from rear to front centre; its length is l_r
        dz = (-h[front]) - (-h[rear])  # front centre height minus rear centre height
        dx = math.sqrt(lr**2 - dz**2)
        axis = np.array([dx, 0.0, dz]) / lr
        down = np.array([-axis[2], 0.0, axis[0]])  # perpendicular, pointing toward the pivot (up)
        mid = np.array([0.0, y, 0.0])
        pivot_to_wheel = {front: mid + axis * lr / 2 - down * hr, rear: mid - axis * lr / 2 - down * hr}
        pitch[side] = 0.0
        for k, pos in pivot_to_wheel.items():
            c, s = math.cos(beta[k]), math.sin(beta[k])
            f = np.array([c * wr[k][0] - s * wr[k][1], s * wr[k][0] + c * wr[k][1], wr[k][2]])
            m = np.array([c * wr[k][3] - s * wr[k][4], s * wr[k][3] + c * wr[k][4], wr[k][5]])
            mk = np.cross(pos, f) + m
            total_f += f
            total_m += mk
            pitch[side] += mk[1]
    g = W * np.array([-math.sin(slope), -math.cos(slope) * math.sin(cross), -math.cos(slope) * math.cos(cross)])
    return {"Fx": total_f[0] + g[0], "Fy": total_f[1] + g[1] - fyo, "Fz": sum(load.values()) + g[2],
            "Mx": total_m[0], "My_right": pitch["R"], "My_left": pitch["L"], "Mz": total_m[2] - mzo}


@pytest.mark.parametrize("seed", range(6))
def test_balance_equals_two_independent_free_body_computations(seed):
    rng, wr, beta, h, load = _random_state(seed)
    slope, cross = rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3)
    fyo, mzo = rng.normal(), rng.normal()
    st = FourWheelRocker(ROVER_MINI_T72)
    a = st.balance(NUMPY, wr, beta, h, load, slope, fyo, mzo, cross)
    b = free_body_residuals(ROVER_MINI_T72, wr, beta, h, load, slope, cross, fyo, mzo)
    c = _cross_product_free_body(ROVER_MINI_T72, wr, beta, h, load, slope, cross, fyo, mzo)
    for n in a:
        assert a[n] == pytest.approx(b[n], abs=1e-12), n
        assert a[n] == pytest.approx(c[n], abs=1e-12), n


def test_printed_sine_signs_disagree_with_the_geometry():
    """(7.16) as printed: (-Fx_F + Fx_R) sin(phi) l/2 + (Fz_F + Fz_R) sin(phi) h_r. With phi from
    (7.10) (nose up when the rear sinks more) the geometry has the opposite sine signs."""
    lr, hr = ROVER_MINI_T72.rocker_length, ROVER_MINI_T72.pivot_height
    h = {"FR": 0.005, "RR": 0.025, "FL": 0.01, "RL": 0.01}
    phi = math.asin((h["RR"] - h["FR"]) / lr)
    wr = {k: (0.0, 0.0, 0.0, 0.0, 0.0, 0.0) for k in WHEELS}
    wr["FR"] = (0.0, 0.0, 5.0, 0.0, 0.0, 0.0)
    wr["RR"] = (0.0, 0.0, 5.0, 0.0, 0.0, 0.0)
    st = FourWheelRocker(ROVER_MINI_T72)
    zero = {k: 0.0 for k in WHEELS}
    ours = st.balance(NUMPY, wr, zero, h, {k: 2.5 for k in WHEELS}, 0.0, 0.0, 0.0)["My_right"]
    printed = (10.0) * math.sin(phi) * hr  # the only non-zero printed term (equal vertical loads)
    assert ours == pytest.approx(-printed, rel=1e-12)
    # nose up: the front wheel centre is above the rear one
    f, r = st.wheel_centre(NUMPY, "FR", phi), st.wheel_centre(NUMPY, "RR", phi)
    assert f[2] - r[2] == pytest.approx(h["RR"] - h["FR"], rel=1e-12)


def test_yaw_balance_has_the_lateral_force_lever_arm():
    """Equal lateral forces on a tilted rocker give a yaw moment 2 Fy h_r sin(phi), absent from (7.18)."""
    lr, hr = ROVER_MINI_T72.rocker_length, ROVER_MINI_T72.pivot_height
    h = {"FR": 0.005, "RR": 0.02, "FL": 0.01, "RL": 0.01}
    phi = math.asin(0.015 / lr)
    wr = {k: (0.0,) * 6 for k in WHEELS}
    wr["FR"] = wr["RR"] = (0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
    zero = {k: 0.0 for k in WHEELS}
    mz = FourWheelRocker(ROVER_MINI_T72).balance(NUMPY, wr, zero, h, zero, 0.0, 0.0, 0.0)["Mz"]
    assert mz == pytest.approx(2 * hr * math.sin(phi), rel=1e-12)


def test_casadi_and_numpy_balances_agree_and_mirror():
    import casadi as ca

    rng, wr, beta, h, load = _random_state(11)
    st = FourWheelRocker(ROVER_MINI_T72)
    contact = {"FR": 1.0, "FL": 1.0, "RR": 0.0, "RL": 1.0}
    a = st.balance(NUMPY, wr, beta, h, load, 0.1, 0.2, 0.3, -0.15, contact)
    c = st.balance(CASADI, wr, beta, h, load, ca.DM(0.1), 0.2, 0.3, -0.15, contact)
    for n in a:
        assert float(c[n]) == pytest.approx(a[n], abs=1e-12)
    fb = free_body_residuals(ROVER_MINI_T72, wr, beta, h, load, 0.1, -0.15, 0.2, 0.3, contact)
    for n in a:
        assert fb[n] == pytest.approx(a[n], abs=1e-12)
    # a raised rear-right wheel: its sinkage does not move anything
    h2 = dict(h, RR=h["RR"] + 0.01)
    assert st.balance(NUMPY, wr, beta, h2, load, 0.1, 0.2, 0.3, -0.15, contact)["My_right"] == pytest.approx(a["My_right"])
    # mirror: y flips (Fy, Mx, Mz, beta, cross slope, offsets), sides swap
    flip = (1, -1, 1, -1, 1, -1)
    wr_m = {MIRROR[k]: tuple(s * v for s, v in zip(flip, wr[k])) for k in WHEELS}
    m = st.balance(NUMPY, wr_m, {MIRROR[k]: -beta[k] for k in WHEELS}, {MIRROR[k]: h[k] for k in WHEELS},
                   {MIRROR[k]: load[k] for k in WHEELS}, 0.1, -0.2, -0.3, 0.15)
    full = st.balance(NUMPY, wr, beta, h, load, 0.1, 0.2, 0.3, -0.15)
    assert m["Fy"] == pytest.approx(-full["Fy"]) and m["Mx"] == pytest.approx(-full["Mx"])
    assert m["Mz"] == pytest.approx(-full["Mz"]) and m["My_right"] == pytest.approx(full["My_left"])
