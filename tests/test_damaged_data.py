"""Damaged data must not give answers: one test per case of issue 9, each a clear error naming
file, row or key (pytest.raises(..., match=...)), or a documented fallback."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from cli_run import run
from offline.fit import calibration as C
from offline.fit.dataset import DatasetError, check_force_units, load_trials
from offline.physics import params as P
from offline.physics.terramechanics import ModelOptions, WheelModel, state_from_slip

SHIPPED = Path(__file__).resolve().parents[1] / "offline" / "data" / "grouser_trials.csv"
STATUSES = ("ok", "load_exceeds_capacity", "load_below_resolution", "load_at_discontinuity", "not_converged")


def damaged(tmp_path: Path, name: str = "damaged.csv", scale: dict[str, float] | None = None,
            drop_cols: tuple[str, ...] = (), rows: slice | list[int] | None = None) -> Path:
    """The shipped trials with columns scaled (a wrong unit), columns dropped or rows selected."""
    with SHIPPED.open() as fh:
        reader = csv.DictReader(fh)
        header = [c for c in reader.fieldnames if c not in drop_cols]
        body = list(reader)
    if rows is not None:
        body = body[rows] if isinstance(rows, slice) else [body[i] for i in rows]
    for r in body:
        for col, f in (scale or {}).items():
            r[col] = repr(float(r[col]) * f)
    p = tmp_path / name
    with p.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=header, extrasaction="ignore")
        w.writeheader()
        w.writerows(body)
    return p


# ------------------------------------------------------------------ forces in the wrong unit
def test_fx_in_millinewtons_is_refused_naming_the_unit(tmp_path):
    p = damaged(tmp_path, scale={"Fx_N": 1e3})
    with pytest.raises(DatasetError, match=r"damaged\.csv: data row \d+ \(trial_id .*column 'Fx_N'.*looks like mN"):
        load_trials(p)


def test_fy_in_kilonewtons_is_refused_naming_the_unit(tmp_path):
    p = damaged(tmp_path, scale={"Fy_N": 1e-3})
    with pytest.raises(DatasetError, match=r"column 'Fy_N'.*looks like kN \(multiply it by 1000\)"):
        load_trials(p)


def test_every_force_in_kilonewtons_is_refused(tmp_path):
    p = damaged(tmp_path, scale={"Fx_N": 1e-3, "Fy_N": 1e-3, "Fz_N": 1e-3})
    with pytest.raises(DatasetError, match=r"column 'Fz_N': the largest load is 0\.03\d* N.*looks like kN"):
        load_trials(p)


def test_every_force_in_millinewtons_is_refused_against_the_wheel(tmp_path):
    """Ratios between columns cannot see it; the load against the wheel's size can (physics:
    soft soil bears no 1 MPa), before validate or calibrate does any work."""
    p = damaged(tmp_path, scale={"Fx_N": 1e3, "Fy_N": 1e3, "Fz_N": 1e3})
    trials = load_trials(p)  # consistent ratios: loads alone
    with pytest.raises(DatasetError, match=r"column 'Fz_N'.*ground pressure of at least .* Pa.*look like mN"):
        check_force_units(trials, P.WHEEL_GROUSERED_PUBLISHED_CODE)
    out = tmp_path / "v"
    rc, stdout, stderr = run(["validate", "--data", str(p), "--out", str(out)])
    assert rc == 2 and "look like mN" in stderr and "Traceback" not in stderr
    assert not out.exists() and "nan" not in stdout
    rc, stdout, stderr = run(["calibrate", "--data", str(p), "--out", str(tmp_path / "c.toml"), "--quiet"])
    assert rc == 2 and "look like mN" in stderr and not (tmp_path / "c.toml").exists()


def test_shipped_forces_pass_the_unit_checks():
    trials = load_trials()
    for wheel in (P.WHEEL_GROUSERED_PUBLISHED_CODE, P.WHEEL_GROUSERED_T52, P.WHEEL_SMOOTH_T52):
        check_force_units(trials, wheel)


# ------------------------------------------------------------------------- duplicate rows
def test_duplicate_rows_without_trial_ids_are_refused(tmp_path):
    p = damaged(tmp_path, drop_cols=("trial_id",), rows=[0, 1, 2, 1])
    with pytest.raises(DatasetError, match=r"data row 4 is identical to data row 2 and the file has no 'trial_id'"):
        load_trials(p)


def test_distinct_rows_without_trial_ids_still_load(tmp_path):
    t = load_trials(damaged(tmp_path, drop_cols=("trial_id",), rows=[0, 40, 80, 120, 160, 180]))
    assert len(t) == 6 and "trial_id" in t.inferred


# ----------------------------------------------------------------------------- one trial
def test_a_single_trial_is_refused_before_the_fit(tmp_path, monkeypatch):
    p = damaged(tmp_path, rows=[40])
    trials = load_trials(p)
    with pytest.raises(C.CalibrationError, match=r"damaged\.csv: 1 trial\(s\): a calibration needs several trials"):
        C.check_fit_data(trials, C.JOINT_PARAMETERS)
    with pytest.raises(C.CalibrationError, match=r"1 trial"):
        C.fit_joint(trials, P.SOIL_DISSERTATION_T53_GROUSERED, P.WHEEL_GROUSERED_PUBLISHED_CODE, P.TUNING_T72_LINEAR)
    calls = []
    monkeypatch.setattr(C, "fit_joint", lambda *a, **k: calls.append(a))  # the CLI must not reach the fit
    rc, stdout, stderr = run(["calibrate", "--data", str(p), "--out", str(tmp_path / "c.toml"), "--quiet"])
    assert rc == 2 and "1 trial(s)" in stderr and "Traceback" not in stderr
    assert calls == [] and not (tmp_path / "c.toml").exists()


def test_too_few_trials_for_the_free_parameters_is_refused(tmp_path):
    trials = load_trials(damaged(tmp_path, rows=[40, 41, 42, 43]))
    with pytest.raises(C.CalibrationError, match=r"4 trials give 12 residuals .* for 13 free parameters; need at least 5"):
        C.check_fit_data(trials, C.JOINT_PARAMETERS)


# -------------------------------------------------------------------- contact-tuning slopes
def test_per_degree_slope_that_leaves_the_contact_patch_is_refused(tmp_path):
    p = tmp_path / "t.toml"
    # 0.5 per degree (a per-radian value written as per degree): theta_m = 45 theta_f at 90 deg
    p.write_text("[tuning]\na0 = 0.3\na1 = 0.6\nb0 = -0.5\nb1 = -0.2\na0_per_deg = 0.5\n")
    with pytest.raises(P.ParameterError, match=r"t\.toml: \[tuning\] .*theta_m / theta_f = .* at \|beta\| = 90 deg"
                                                r".*inside the contact patch"):
        P.load_toml(p)


def test_presets_and_shipped_tunings_stay_inside_the_contact_patch():
    lo, hi = P.CONTACT_RATIO_RANGE
    for t in (P.TUNING_T72_LINEAR, *P.TUNING_T54_GROUSERED.values(), *P.TUNING_T54_SMOOTH.values()):
        for beta in np.radians([0.0, 45.0, 90.0]):
            a0, a1, b0, b1 = t.at(beta)
            assert lo <= a0 <= hi and lo <= a0 + a1 <= hi and lo <= b0 + b1 <= hi


# --------------------------------------------------------------------- sinkage_from_load
def test_sinkage_from_load_on_an_empty_batch_returns_empty_arrays(model):
    sol = model.sinkage_from_load(np.array([]), np.array([]), np.array([]), np.array([]))
    assert sol.h.shape == sol.h_zero_slip.shape == sol.converged.shape == sol.status.shape == (0,)
    assert sol.ok and sol.reasons() == []


def test_status_strings_are_never_truncated(model, monkeypatch):
    """The zero-slip stage all 'ok' (2 characters) must not narrow the skid stage's statuses."""
    real = WheelModel._illinois
    stage = []

    def second_stage_fails(self, W, vx, vy, w, h0s, rtol, max_iter):
        h, ok, status, res, it = real(self, W, vx, vy, w, h0s, rtol, max_iter)
        stage.append(h0s is not None)
        if h0s is not None:  # the skid stage: report the longest status
            status = np.full(W.size, "load_exceeds_capacity")
            ok = np.zeros(W.size, dtype=bool)
        return h, ok, status, res, it

    monkeypatch.setattr(WheelModel, "_illinois", second_stage_fails)
    vx, vy, w = state_from_slip(np.array([0.3, -0.4]), 0.2, 0.01, model.wheel)  # one slipping, one skidding
    sol = model.sinkage_from_load(np.array([20.0, 20.0]), vx, vy, w)
    assert stage == [False, True]
    assert sol.status.tolist() == ["ok", "load_exceeds_capacity"]
    assert sol.status.dtype.itemsize >= 4 * max(len(s) for s in STATUSES)


def test_ok_only_when_the_load_residual_is_within_tolerance(model, monkeypatch):
    """F_z(h) with a jump across the load (as the soil-flow exit angle's regime switch makes):
    the bracket collapses onto the jump; that is not a sinkage that carries the load."""
    jump_at = 0.02

    def fz_with_jump(self, vx, vy, w, h, h0s):
        return np.where(h < jump_at, 10.0, 30.0) + 100.0 * h

    monkeypatch.setattr(WheelModel, "_fz", fz_with_jump)
    vx, vy, w = state_from_slip(np.array([0.3, 0.3]), 0.0, 0.01, model.wheel)
    sol = model.sinkage_from_load(np.array([20.0, 11.0]), vx, vy, w)
    assert sol.status.tolist() == ["load_at_discontinuity", "ok"]
    assert sol.converged.tolist() == [False, True] and math.isnan(sol.h[0])
    assert abs(sol.residual[0]) > 0.4 * 20.0  # the jump, reported
    assert abs(sol.residual[1]) <= 1e-9 * 11.0 and sol.h[1] == pytest.approx(0.01, rel=1e-6)
    assert "load_at_discontinuity" in sol.reasons()[0]


def test_soil_flow_ok_states_carry_the_load(model):
    m = WheelModel(model.soil, model.wheel, model.tuning, ModelOptions(exit_angle="soil_flow"))
    s = np.linspace(-0.6, 0.8, 15)
    vx, vy, w = state_from_slip(s, np.radians(40.0), 0.01, m.wheel)
    sol = m.sinkage_from_load(np.full(s.size, 20.0), vx, vy, w)
    assert set(sol.status.tolist()) <= set(STATUSES)
    ok = sol.status == "ok"
    assert ok.any() and np.all(np.abs(sol.residual[ok]) <= 1e-9 * 20.0 + 1e-12)


# ------------------------------------------------------------- Jacobian at zero travel speed
@pytest.mark.parametrize("omega", [0.5, 0.0], ids=["spinning_in_place", "at_rest"])
def test_wrench_jacobian_at_zero_travel_speed_is_a_clear_error(model, omega):
    x = np.array([0.0, 0.0, omega, 0.01, 0.01])
    with pytest.raises(ValueError, match=r"wrench Jacobian at v_x = v_y = 0 .* is undefined: the slip angle of eq\. "
                                         r"\(5\.1\) has no value"):
        model.wrench_and_jacobian(x, compiled=False)
    assert np.all(np.isfinite(model.wrench(*x).as_array()))  # the wrench itself is defined there
    w, J = model.wrench_and_jacobian(np.array([1e-6, 0.0, omega, 0.01, 0.01]), compiled=False)  # the advice works
    assert np.all(np.isfinite(J))


# ------------------------------------------------------------------ most conditions failed
def test_validate_where_most_conditions_fail_is_an_error(tmp_path):
    """A soil too soft to carry the loads: every prediction fails; never an answer."""
    params = P.save_toml(tmp_path / "weak.toml", soil=_weak_soil(), wheel=P.WHEEL_GROUSERED_T52, tuning=P.TUNING_T72_LINEAR)
    out = tmp_path / "v"
    rc, stdout, stderr = run(["validate", "--params", str(params), "--skip-dissertation", "--out", str(out)])
    assert rc == 2
    assert "most conditions failed for calibrated: classic exit angle: 63 of 63 (load_exceeds_capacity)" in stderr
    assert not (out / "table_5_5.csv").exists()


def test_calibration_where_most_loads_are_not_carried_is_an_error():
    trials = load_trials()
    trials = trials.subset(np.abs(trials.beta_cmd) <= math.radians(30.5))
    with pytest.raises(C.CalibrationError, match=r"carries the measured load on only 0 of 81 trials"):
        C.fit_joint(trials, _weak_soil(), P.WHEEL_GROUSERED_T52, P.TUNING_T72_LINEAR, ("a0",), max_nfev=2)


def _weak_soil() -> P.Soil:
    from dataclasses import replace

    return replace(P.SOIL_DISSERTATION_T53_GROUSERED, k=2.0e4, cohesion=0.0, name="too_soft")
