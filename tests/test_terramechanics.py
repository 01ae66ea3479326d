"""Physics tests of the 3D terramechanics model (dissertation ch. 5)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import RTOL_AD_FD, RTOL_BACKENDS, RTOL_QUADRATURE, RTOL_SINKAGE_LOAD, RTOL_SWITCH
from offline.physics.backend import NUMPY
from offline.physics.params import (
    SOIL_DISSERTATION_T53_GROUSERED,
    TUNING_T72_LINEAR,
    WHEEL_GROUSERED_PUBLISHED_CODE,
    ParameterError,
    Wheel,
)
from offline.physics.terramechanics import (
    ModelOptions,
    WheelModel,
    bulldozing_resistance,
    shear_kinematics,
    state_from_slip,
)

WHEEL = WHEEL_GROUSERED_PUBLISHED_CODE
RS = WHEEL.shearing_radius
V = 0.01  # testbed carriage speed, m/s


def states(model: WheelModel, slip, beta, h, speed=V):
    vx, vy, w = state_from_slip(slip, beta, speed, model.wheel)
    return vx, vy, w, np.broadcast_to(h, np.shape(vx)).astype(float)


# ---------------------------------------------------------------- limits and symmetry
@pytest.mark.parametrize("slip", [-1.0, -0.5, -0.1, 0.0, 0.2, 0.6, 0.9])
def test_zero_slip_angle_gives_no_lateral_force_or_moment(model, slip):
    w = model.wrench(*states(model, slip, 0.0, 0.02))
    scale = abs(float(w.Fz)) + 1.0
    assert abs(float(w.Fy)) < 1e-12 * scale
    assert abs(float(w.Mx)) < 1e-12 * scale
    assert abs(float(w.Mz)) < 1e-12 * scale
    assert float(w.Fz) > 0.1  # and the wheel does carry load


@settings(max_examples=60, deadline=None)
@given(
    slip=st.floats(-1.0, 0.95),
    beta=st.floats(0.0, math.pi / 2),
    h=st.floats(0.002, 0.08),
)
def test_mirrored_beta_mirrors_lateral_components(model, slip, beta, h):
    a = model.wrench(*states(model, slip, beta, h))
    b = model.wrench(*states(model, slip, -beta, h))
    scale = 1.0 + abs(float(a.Fz)) + abs(float(a.Fy))
    for same in ("Fx", "Fz", "My"):
        assert abs(float(getattr(a, same)) - float(getattr(b, same))) <= 1e-12 * scale
    for flip in ("Fy", "Mx", "Mz"):
        assert abs(float(getattr(a, flip)) + float(getattr(b, flip))) <= 1e-12 * scale


@settings(max_examples=40, deadline=None)
@given(slip=st.floats(-1.0, 0.95), beta=st.floats(-1.5, 1.5), h=st.floats(0.002, 0.08))
def test_reverse_travel_is_the_x_mirror(model, slip, beta, h):
    vx, vy, w, hh = states(model, slip, beta, h)
    a = model.wrench(vx, vy, w, hh)
    b = model.wrench(-vx, vy, -w, hh)
    scale = 1.0 + abs(float(a.Fz))
    np.testing.assert_allclose(
        [float(b.Fx), float(b.Fy), float(b.Fz), float(b.Mx), float(b.My), float(b.Mz)],
        [-float(a.Fx), float(a.Fy), float(a.Fz), float(a.Mx), -float(a.My), -float(a.Mz)],
        atol=1e-12 * scale,
    )


@pytest.mark.parametrize("beta_deg", [0.0, 30.0, 60.0])
def test_traction_rises_with_slip_at_fixed_load(model, beta_deg):
    """Drawbar pull rises with slip under a fixed load up to moderate slip. (Past s ~ 0.7
    slip-sinkage, n = n0 + n1 s and the deeper rut, bends the curve down: not asserted.)"""
    slips = np.linspace(0.0, 0.6, 13)
    vx, vy, w, _ = states(model, slips, math.radians(beta_deg), 0.0)
    sol = model.sinkage_from_load(20.0, vx, vy, w)
    fx = model.wrench(vx, vy, w, sol.h, sol.h_zero_slip).Fx
    assert np.all(np.diff(fx) > 0), fx
    assert fx[0] < 0 < fx[-1]  # resistance at zero slip, traction at 60 %


def test_locked_wheel_is_strongly_resisted_and_finite(model):
    load = 20.0
    vx, vy, w, _ = states(model, np.array([-1.0, 0.0, 0.5]), 0.0, 0.02)
    sol = model.sinkage_from_load(load, vx, vy, w)
    assert sol.ok
    wr = model.wrench(vx, vy, w, sol.h, sol.h_zero_slip)
    assert wr.Fx[0] < -0.2 * load  # locked: large motion resistance
    assert wr.Fx[0] < wr.Fx[1] < wr.Fx[2]
    assert np.isfinite(wr.as_array()).all()
    # the analytic limit: omega = 0 and a tiny omega agree
    tiny = model.wrench(vx[0], vy[0], 1e-7, sol.h[0], sol.h_zero_slip[0])
    np.testing.assert_allclose(tiny.as_array(), wr.as_array()[0], rtol=1e-4, atol=1e-6)


def test_locked_wheel_lateral_shear_saturates(model):
    """omega = 0: j_L is infinite (section 5.2.3), so tau_L = c + sigma tan(phi) whatever the
    shear modulus K; a rolling wheel's lateral shear does depend on K."""
    vx, vy, w0 = state_from_slip(0.0, math.radians(60.0), V, model.wheel)
    stiff = WheelModel(replace(model.soil, shear_modulus=model.soil.shear_modulus / 100), model.wheel, model.tuning)
    locked = [mm.wrench(vx, vy, 0.0, 0.03).Fy for mm in (model, stiff)]
    rolling = [mm.wrench(vx, vy, w0, 0.03).Fy for mm in (model, stiff)]
    assert float(locked[0]) == pytest.approx(float(locked[1]), rel=1e-12)
    assert abs(float(rolling[0]) - float(rolling[1])) > 0.05 * abs(float(rolling[1]))


def test_free_rolling_wheel_has_small_rolling_resistance(model):
    """An unpowered wheel (M_y = 0) rolls at a small skid with a small resisting F_x."""
    load = 20.0
    slips = np.linspace(-0.6, 0.3, 91)
    vx, vy, w, _ = states(model, slips, 0.0, 0.02)
    sol = model.sinkage_from_load(load, vx, vy, w)
    wr = model.wrench(vx, vy, w, sol.h, sol.h_zero_slip)
    sign_change = np.flatnonzero(np.diff(np.sign(wr.My)))
    assert sign_change.size == 1
    i = sign_change[0]
    s_free = slips[i]
    assert -0.4 < s_free <= 0.0
    assert -0.3 * load < wr.Fx[i] < 0.0
    # driving torque at 50 % slip is much larger than at free rolling
    drive = model.wrench(*states(model, 0.5, 0.0, float(sol.h[i])))
    assert abs(wr.My[i]) < 0.1 * abs(float(drive.My))


@pytest.mark.parametrize("slip", [-0.7, 0.0, 0.5])
@pytest.mark.parametrize("beta_deg", [0.0, 45.0])
def test_vertical_force_grows_with_sinkage(model, slip, beta_deg):
    h = np.linspace(0.02, 0.08, 30)  # skid sinkage >= the zero-slip sinkage (0.02)
    vx, vy, w, _ = states(model, np.full_like(h, slip), math.radians(beta_deg), 0.0)
    fz = model.wrench(vx, vy, w, h, np.full_like(h, 0.02)).Fz
    assert np.all(np.diff(fz) > 0)


@pytest.mark.parametrize("slip", [-0.5, 0.0, 0.5])
def test_lateral_force_grows_with_slip_angle_at_fixed_load(model, slip):
    betas = np.radians(np.linspace(0.0, 90.0, 10))
    vx, vy, w, _ = states(model, np.full_like(betas, slip), betas, 0.0)
    sol = model.sinkage_from_load(12.0, vx, vy, w)
    assert sol.ok
    fy = model.wrench(vx, vy, w, sol.h, sol.h_zero_slip).Fy
    assert np.all(np.diff(fy) > 0), fy


# ---------------------------------------------------------------- continuity
@pytest.mark.parametrize("beta_deg", [0.0, 30.0, 75.0])
def test_continuous_across_slip_skid_switch(model, beta_deg):
    eps = 1e-9
    vx, vy, w, h = states(model, np.array([-eps, 0.0, eps]), math.radians(beta_deg), 0.02)
    wr = model.wrench(vx, vy, w, h, h).as_array()
    scale = np.abs(wr).max()
    assert np.abs(wr[0] - wr[1]).max() < RTOL_SWITCH * scale
    assert np.abs(wr[2] - wr[1]).max() < RTOL_SWITCH * scale


def test_continuous_in_slip_over_a_fine_sweep(model):
    slips = np.linspace(-1.0, 0.9, 4001)
    wr = model.wrench(*states(model, slips, math.radians(40.0), 0.02)).as_array()
    jumps = np.abs(np.diff(wr, axis=0)).max(axis=0)
    # a smooth curve sampled at ds = 4.75e-4 changes by about |dF/ds| ds: no step
    assert np.all(jumps < 0.01 * np.abs(wr).max(axis=0) + 1e-9), jumps


@pytest.mark.parametrize("load", [12.0, 25.0])
def test_straight_braking_is_smooth_in_slip(model, load):
    """beta = 0 in skid: tau_T ~ v_jT / |v_j| jumps where v_jT changes sign; the quadrature
    breakpoints at those zeros keep F_x and M_y smooth (review finding: 10 % jumps before)."""
    s = np.linspace(-0.1, -0.01, 2000)
    vx, vy, w = state_from_slip(s, 0.0, V, model.wheel)
    h = np.full_like(s, 0.02 * load / 12.0)
    wr = model.wrench(vx, vy, w, h, 0.75 * h)
    for comp in (wr.Fx, wr.My, wr.Fz):
        steps = np.abs(np.diff(comp))
        neighbours = 0.5 * (steps[:-2] + steps[2:])
        # no step is out of line with its neighbours (a jump would be, a steepening curve is not)
        assert np.all(steps[1:-1] <= 3.0 * neighbours + 1e-9 * np.abs(comp).max())
    fine = WheelModel(model.soil, model.wheel, model.tuning, ModelOptions(nodes_per_segment=40))
    sub = slice(None, None, 50)
    ref = fine.wrench(vx[sub], vy[sub], w[sub], h[sub], 0.75 * h[sub])
    np.testing.assert_allclose(wr.Fx[sub], ref.Fx, atol=2e-3 * np.abs(ref.Fx).max())
    np.testing.assert_allclose(wr.My[sub], ref.My, atol=1e-2 * np.abs(ref.My).max())  # measured 5.5e-3


def test_locked_wheel_at_zero_slip_angle_matches_fine_quadrature(model):
    fine = WheelModel(model.soil, model.wheel, model.tuning, ModelOptions(nodes_per_segment=60))
    a = model.wrench(V, 0.0, 0.0, 0.05, 0.015).as_array()
    b = fine.wrench(V, 0.0, 0.0, 0.05, 0.015).as_array()
    np.testing.assert_allclose(a[[0, 2, 4]], b[[0, 2, 4]], rtol=2e-3)


# ---------------------------------------------------------------- shear derivation (5.17)
def test_tangential_deformation_derivation_pins_garbled_5_17():
    """(5.20) integrates the shear velocities: d(w j_T)/d theta = -v_jT, j_T(theta_f) = 0,
    j_T continuous (zero) at theta_0 from both sides."""
    theta_f, slip, vx = 0.8, -0.4, 0.01
    theta_0 = theta_f * (1 + slip / 2)
    rw = vx * (1 + slip)
    sin_f, sin_0 = math.sin(theta_f), math.sin(theta_0)
    S = (sin_f - sin_0) / (theta_f - theta_0)
    th = np.linspace(-0.3, theta_f, 20001).reshape(1, -1)
    vjT, _, jt_w, _ = shear_kinematics(
        NUMPY, th, np.cos(th), np.sin(th), theta_f, theta_0, sin_f, sin_0, S, True, vx, rw, 0.0
    )
    djdth = np.gradient(jt_w[0], th[0])
    mask = np.abs(th[0] - theta_0) > 1e-3
    np.testing.assert_allclose(djdth[mask][2:-2], -vjT[0][mask][2:-2], atol=1e-8)
    assert abs(jt_w[0, -1]) < 1e-15  # zero where soil enters (theta_f)
    i0 = np.searchsorted(th[0], theta_0)
    assert abs(jt_w[0, i0]) < 1e-6 and abs(jt_w[0, i0 - 1]) < 1e-6
    # K_v of (5.16) reproduces (5.18): r_s w + K_v v_x = S v_x
    k_v = (S * vx - rw) / vx
    v16 = rw - vx * np.cos(th[0]) + k_v * vx
    front = th[0] > theta_0
    np.testing.assert_allclose(v16[front], vjT[0][front], atol=1e-15)


# ---------------------------------------------------------------- bulldozing forms
def test_bulldozing_forms_relate_as_section_5_2_4_states():
    rho, c, phi = 13.03e3, 1.0e3, math.radians(29.0)
    h = np.linspace(0.0, 0.05, 11)
    cot_x = 1 / math.tan(math.pi / 4 - phi / 2)
    pav = bulldozing_resistance(NUMPY, h, rho, c, phi, "pavlov")
    heg = bulldozing_resistance(NUMPY, h, rho, c, phi, "hegedus")
    ish = bulldozing_resistance(NUMPY, h, rho, c, phi, "ishigami")
    np.testing.assert_allclose(heg - pav, 0.25 * rho * h**2 * cot_x**3 * math.tan(phi), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ish - heg, 0.5 * rho * h**2 * cot_x**2 * (1 + cot_x * math.tan(phi)), rtol=1e-12, atol=1e-12)
    # tan(X_c + phi) = cot(X_c), the identity the text uses
    assert math.tan(math.pi / 4 - phi / 2 + phi) == pytest.approx(cot_x, rel=1e-12)


def test_ishigami_sidewall_is_larger_in_cohesionless_soil(model):
    """With c = 0 the [58] blade resistance is 2 (1 + cot tan) / (1 + cot tan / 2) ~ 2.6 times
    (5.24), so the Ishigami 2007 sidewall (5.29) gives the larger lateral force."""
    soil = replace(model.soil, cohesion=0.0)
    pav = WheelModel(soil, model.wheel, model.tuning)
    ish = WheelModel(soil, model.wheel, model.tuning, ModelOptions(bulldozing="ishigami"))
    args = states(model, 0.0, math.radians(60.0), 0.05)
    assert float(ish.wrench(*args).Fy) > float(pav.wrench(*args).Fy) > 0


# ---------------------------------------------------------------- numerics
def test_batched_and_single_evaluation_agree_exactly(model, rng):
    n = 50
    vx, vy, w, h = states(model, rng.uniform(-1, 0.9, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.003, 0.06, n))
    batch = model.wrench(vx, vy, w, h).as_array()
    for i in range(n):
        single = model.wrench(vx[i], vy[i], w[i], h[i]).as_array()
        assert np.array_equal(single, batch[i])


def test_numpy_and_casadi_agree(model, rng):
    f = model.casadi_function()
    n = 30
    vx, vy, w, h = states(model, rng.uniform(-1, 0.9, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.003, 0.06, n))
    h0 = h * rng.uniform(0.7, 1.0, n)
    num = model.wrench(vx, vy, w, h, h0).as_array()
    for i in range(n):
        cas = np.asarray(f([vx[i], vy[i], w[i], h[i], h0[i]])).ravel()
        np.testing.assert_allclose(cas, num[i], rtol=RTOL_BACKENDS, atol=RTOL_BACKENDS * np.abs(num[i]).max())


def test_ad_jacobian_matches_central_differences(model, rng):
    checked = 0
    while checked < 12:
        slip = rng.uniform(-0.95, 0.9)
        if abs(slip) < 0.05:  # the slip/skid switch: one-sided derivatives differ
            continue
        beta = rng.uniform(0.05, 1.45) * rng.choice([-1, 1])
        vx, vy, w = state_from_slip(slip, beta, V, model.wheel)
        x = np.array([vx, vy, w, rng.uniform(0.01, 0.05), 0.0])
        x[4] = x[3] * 0.9
        f, J = model.wrench_and_jacobian(x, compiled=False)
        steps = np.array([1e-6 * V, 1e-6 * V, 1e-6 * abs(w), 1e-7, 1e-7])
        Jfd = np.empty((6, 5))
        for j in range(5):
            xp, xm = x.copy(), x.copy()
            xp[j] += steps[j]
            xm[j] -= steps[j]
            Jfd[:, j] = (model.wrench(*xp).as_array() - model.wrench(*xm).as_array()) / (2 * steps[j])
        # relative to the largest Jacobian entry of the state (measured: at most 3e-9)
        assert np.abs(J - Jfd).max() <= RTOL_AD_FD * np.abs(J).max(), np.abs(J - Jfd).max() / np.abs(J).max()
        checked += 1


def test_ad_jacobian_tight_at_smooth_states(model):
    """Away from every switch, AD and central differences agree to RTOL_AD_FD."""
    for slip, beta_deg, h in [(0.4, 30.0, 0.02), (-0.5, 50.0, 0.03), (0.7, 10.0, 0.015), (-0.9, 70.0, 0.04)]:
        vx, vy, w = state_from_slip(slip, math.radians(beta_deg), V, model.wheel)
        x = np.array([vx, vy, w, h, 0.9 * h])
        _, J = model.wrench_and_jacobian(x, compiled=False)
        for j in range(5):
            step = 1e-5 * max(abs(x[j]), 1e-3)
            xp, xm = x.copy(), x.copy()
            xp[j] += step
            xm[j] -= step
            col = (model.wrench(*xp).as_array() - model.wrench(*xm).as_array()) / (2 * step)
            np.testing.assert_allclose(J[:, j], col, rtol=RTOL_AD_FD, atol=RTOL_AD_FD * np.abs(J).max())


def test_ad_derivatives_finite_for_locked_wheel(model):
    vx, vy, _ = state_from_slip(0.0, 0.7, V, model.wheel)
    _, J = model.wrench_and_jacobian(np.array([vx, vy, 0.0, 0.03, 0.02]), compiled=False)
    assert np.isfinite(J).all()


def test_quadrature_converged(model, rng):
    ref = WheelModel(model.soil, model.wheel, model.tuning, ModelOptions(nodes_per_segment=100))
    n = 40
    vx, vy, w, h = states(model, rng.uniform(-1, 0.9, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.005, 0.06, n))
    a = model.wrench(vx, vy, w, h).as_array()
    b = ref.wrench(vx, vy, w, h).as_array()
    scale = np.abs(b[:, :3]).max(axis=1, keepdims=True)
    assert np.abs(a[:, :3] - b[:, :3]).max() / 1.0 <= RTOL_QUADRATURE * scale.max()
    np.testing.assert_array_less(np.abs(a[:, :3] - b[:, :3]) / scale, RTOL_QUADRATURE)


# ---------------------------------------------------------------- sinkage from load
def test_sinkage_from_load_inverts_vertical_force(model, rng):
    n = 200
    vx, vy, w, _ = states(model, rng.uniform(-1, 0.9, n), rng.uniform(-1.5, 1.5, n), 0.0)
    load = rng.uniform(5.0, 40.0, n)
    sol = model.sinkage_from_load(load, vx, vy, w)
    ok = sol.converged
    assert ok.mean() > 0.9
    # failures are only loads the wheel cannot carry, and they really cannot
    assert set(sol.status[~ok]) <= {"load_exceeds_capacity"}
    hmax = np.full((~ok).sum(), model.h_max)
    assert np.all(model.wrench(vx[~ok], vy[~ok], w[~ok], hmax, hmax).Fz < load[~ok])
    fz = model.wrench(vx[ok], vy[ok], w[ok], sol.h[ok], sol.h_zero_slip[ok]).Fz
    np.testing.assert_allclose(fz, load[ok], rtol=RTOL_SINKAGE_LOAD)


def test_sinkage_round_trip(model):
    vx, vy, w, h = states(model, np.array([-0.8, 0.0, 0.5]), 0.6, 0.025)
    fz = model.wrench(vx, vy, w, h, h).Fz
    # zero-slip state: round trip is exact (h_zero_slip = h)
    sol = model.sinkage_from_load(fz[1], vx[1], vy[1], w[1])
    assert float(sol.h) == pytest.approx(0.025, rel=1e-7)


def test_sinkage_reports_load_the_wheel_cannot_carry(model):
    vx, vy, w = state_from_slip(0.0, 0.0, V, model.wheel)
    sol = model.sinkage_from_load(np.array([20.0, 1e5]), vx, vy, w)
    assert not sol.ok
    assert list(sol.status) == ["ok", "load_exceeds_capacity"]
    assert np.isnan(sol.h[1]) and np.isfinite(sol.h[0])
    assert "maximum sinkage" in sol.reasons()[0]


def test_single_wheel_fast_sinkage_matches_robust_solve(model, rng):
    for _ in range(8):
        slip = rng.uniform(-1, 0.9)
        vx, vy, w = state_from_slip(slip, rng.uniform(-1.4, 1.4), V, model.wheel)
        load = rng.uniform(8.0, 25.0)
        fast = model.sinkage_from_load_single(load, vx, vy, w)
        robust = model.sinkage_from_load(load, vx, vy, w)
        assert fast.ok == robust.ok
        if robust.ok:
            np.testing.assert_allclose(fast.h, robust.h, rtol=1e-6)
            np.testing.assert_allclose(fast.h_zero_slip, robust.h_zero_slip, rtol=1e-6)


def test_single_wheel_sinkage_falls_back_and_reports_capacity(model):
    vx, vy, w = state_from_slip(0.0, 0.0, V, model.wheel)
    sol = model.sinkage_from_load_single(1e5, vx, vy, w)
    assert not sol.ok and sol.status[0] == "load_exceeds_capacity"
    with pytest.raises(ValueError, match="load must be > 0"):
        model.sinkage_from_load_single(-1.0, vx, vy, w)


# ---------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(h=float("nan")), "h must be finite"),
        (dict(vx=float("inf")), "vx must be finite"),
        (dict(h=-0.01), r"h must be in \(0"),
        (dict(h=20.0), "millimetres"),
        (dict(omega=-0.2), "opposes the travel direction"),
    ],
)
def test_bad_states_raise_clear_errors(model, kwargs, match):
    args = dict(vx=0.01, vy=0.0, omega=0.15, h=0.02)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        model.wrench(**args)


def test_degrees_where_radians_expected(model):
    with pytest.raises(ValueError, match="degrees"):
        state_from_slip(0.2, 45.0, V, model.wheel)


@pytest.mark.parametrize("load, match", [(0.0, "load must be > 0"), (float("nan"), "finite"), (-3.0, "load must be > 0")])
def test_bad_loads(model, load, match):
    with pytest.raises(ValueError, match=match):
        model.sinkage_from_load(load, 0.01, 0.0, 0.1)


@pytest.mark.parametrize(
    "kwargs, match",
    [(dict(radius=-0.05), "radius must be > 0"), (dict(width=0.0), "width must be > 0"), (dict(radius=58.0), "millimetres")],
)
def test_bad_wheel_geometry(kwargs, match):
    base = dict(radius=0.058, width=0.05, grouser_height=0.005, grouser_area_ratio=0.1, grouser_volume_fraction=0.2)
    base.update(kwargs)
    with pytest.raises(ParameterError, match=match):
        Wheel(**base)


def test_friction_angle_in_degrees_is_refused():
    with pytest.raises(ParameterError, match="degrees"):
        replace(SOIL_DISSERTATION_T53_GROUSERED, friction_angle=29.0)


def test_bad_options():
    with pytest.raises(ValueError, match="bulldozing"):
        ModelOptions(bulldozing="wong")
    with pytest.raises(ValueError, match="exit_angle"):
        ModelOptions(exit_angle="tuned")


def test_default_model_uses_linear_tuning(model):
    assert model.tuning == TUNING_T72_LINEAR
    assert model.wheel == WHEEL_GROUSERED_PUBLISHED_CODE


def test_second_derivatives_finite_at_the_zero_slip_switch():
    """At s = -1e-16 (skid by rounding) the skid front segments have zero length and their
    nodes sit on theta_f; the floors must keep IPOPT's Hessian finite there (a NaN Hessian
    stalled the driving-primitive solver with calibrated parameters)."""
    import casadi as ca

    from offline.physics.params import load_toml
    from importlib import resources

    ps = load_toml(resources.files("offline").joinpath("data", "calibrated_grousered.toml"))["parameter_set"]
    m = WheelModel.from_parameter_set(ps)
    x = ca.SX.sym("x", 2)
    sp = ca.SX.sym("sp")
    wr, d = m.expressions(sp * ca.cos(x[0]), -sp * ca.sin(x[0]), sp / m.wheel.shearing_radius, x[1], x[1])
    f = ca.Function("h", [x, sp], [ca.hessian(wr[2], x)[0], d["slip"]])
    H, s = f([-0.0141577541, 0.00745151614], 0.03)
    assert abs(float(s)) < 1e-12
    assert np.isfinite(np.array(H)).all()


@pytest.mark.parametrize("options", [ModelOptions(), ModelOptions(exit_angle="soil_flow"),
                                     ModelOptions(bulldozing="ishigami", nodes_per_segment=5)], ids=["classic", "soil_flow", "ishigami"])
def test_normal_force_is_the_wrench_normal_force_bit_for_bit(model, options):
    """:func:`rtctl.physics.terramechanics.normal_force` (the sinkage solve's F_z) is the F_z of
    :func:`wrench_core`, bit for bit, over slip, skid, a locked wheel and reverse travel."""
    from rtctl.physics.terramechanics import normal_force, wrench_core

    rng = np.random.default_rng(7)
    n = 64
    vx = rng.uniform(0.005, 0.05, (n, 1)) * np.where(np.arange(n)[:, None] % 4 == 3, -1.0, 1.0)
    vy = rng.uniform(-0.03, 0.03, (n, 1))
    om = vx / model.wheel.shearing_radius * rng.uniform(0.0, 2.0, (n, 1))
    om[::9] = 0.0
    h = rng.uniform(0.002, 0.03, (n, 1))
    h0 = h * rng.uniform(0.6, 1.4, (n, 1))
    (_, _, fz, _, _, _), _ = wrench_core(NUMPY, vx, vy, om, h, h0, model.params, options)
    assert normal_force(NUMPY, vx, vy, om, h, h0, model.params, options).tobytes() == fz.tobytes()
