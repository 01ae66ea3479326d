"""Tests of offline.fit.validation: reproduction of the dissertation's Table 5.5 (grousered wheel),
the shipped calibration against it, trial states, condition averaging and error bookkeeping."""

from __future__ import annotations

import dataclasses

import csv
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import RTOL_SINKAGE_LOAD
from offline.fit.dataset import AUTHORS_RIM_RADIUS, load_trials, load_tuned_params
from offline.physics.params import (
    SOIL_DISSERTATION_T53_GROUSERED,
    TUNING_T54_GROUSERED,
    WHEEL_GROUSERED_PUBLISHED_CODE,
    ContactTuning,
    load_toml,
)
from offline.physics.terramechanics import ModelOptions
from offline.fit.validation import (
    TABLE_5_5_GROUSERED,
    ErrorRow,
    Variant,
    average_conditions,
    beats_table_5_5,
    error_rows,
    errors_percent,
    format_table,
    predict,
    trial_states,
    tuning_for_angle,
    write_csv,
)

SHIPPED_PARAMS = Path(__file__).resolve().parents[1] / "offline" / "data" / "calibrated_grousered.toml"
SHIPPED_PARAMS_SOIL_FLOW = SHIPPED_PARAMS.with_name("calibrated_grousered_soil_flow.toml")
TABLE_ANGLES = (0.0, 15.0, 30.0, 45.0, 60.0)

# Table 5.5 reproduction, in percentage points (forces in % of load, sinkage in % of radius).
# An exact match is not expected: the authors' per-condition averaging (which trials, which
# load and speeds enter each condition's mean) and details of their code (quadrature, the
# binary search on sinkage, the omega conversion) are not fully known. Measured with the
# authors' per-angle a0..b1 (grouser_tuned_params.csv), classic exit angle:
#   F_x mean: largest deviation +3.14 (beta = 0), <= 1.4 elsewhere
#   F_y mean: <= 0.46;  sinkage mean: <= 0.31;  every sd: <= 1.09 (F_x sd at beta = 0)
TOL_FX_MEAN = 4.0
TOL_FY_MEAN = 1.0
TOL_H_MEAN = 1.0
TOL_SD = 1.5
# Soil-flow exit angle, measured: at 0 and 15 deg means within 2.61 (F_x), 0.42 (F_y), 0.26 (h)
# points; the sds within 1.91 points at every angle 0-60 deg. Means at 30-60 deg are NOT
# reproduced (see test_soil_flow_means_at_high_slip_angle_reproduce_table_5_5).
TOL_SD_SOIL_FLOW = 2.5


# ------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def trials():
    return load_trials()


@pytest.fixture(scope="module")
def avg(trials):
    return average_conditions(trials)


@pytest.fixture(scope="module")
def authors_tuning():
    return {b: ContactTuning(*v, name=f"authors_{b:g}", source="grouser_tuned_params.csv")
            for b, v in load_tuned_params().items()}


def _variant(name, tuning, options=None):
    return Variant(name, SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, tuning,
                   options or ModelOptions())


@pytest.fixture(scope="module")
def classic(avg, authors_tuning):
    v = _variant("dissertation: classic exit angle", authors_tuning)
    p = predict(avg, v)
    return v, p, {r.beta_deg: r for r in error_rows(avg, p, v.wheel.radius)}


@pytest.fixture(scope="module")
def soil_flow(avg, authors_tuning):
    v = _variant("dissertation: soil-flow exit angle", authors_tuning, ModelOptions(exit_angle="soil_flow"))
    p = predict(avg, v)
    return v, p, {r.beta_deg: r for r in error_rows(avg, p, v.wheel.radius)}


@pytest.fixture(scope="module")
def calibrated(avg):
    ps = load_toml(SHIPPED_PARAMS)["parameter_set"]
    v = Variant("calibrated: classic exit angle", ps.soil, ps.wheel, ps.tuning)
    p = predict(avg, v)
    return v, p, {r.beta_deg: r for r in error_rows(avg, p, v.wheel.radius)}


def _ours(row: ErrorRow) -> np.ndarray:
    return np.array([row.fx_mean, row.fx_sd, row.fy_mean, row.fy_sd, row.h_mean, row.h_sd])


# ------------------------------------------------------------- Table 5.5 reproduction
@pytest.mark.parametrize("beta", TABLE_ANGLES)
def test_classic_exit_angle_reproduces_table_5_5(classic, beta):
    """Dissertation Table 5.5, grousered wheel, 'without soil flow model'."""
    _, _, rows = classic
    row = rows[beta]
    assert row.n == 9 and row.n_failed == 0  # nine slip ratios per angle, all solved
    ref = np.array(TABLE_5_5_GROUSERED["without soil flow"][beta])
    d = _ours(row) - ref
    assert abs(d[0]) <= TOL_FX_MEAN, (beta, d)
    assert abs(d[2]) <= TOL_FY_MEAN, (beta, d)
    assert abs(d[4]) <= TOL_H_MEAN, (beta, d)
    assert np.all(np.abs(d[[1, 3, 5]]) <= TOL_SD), (beta, d)


# Soil-flow variant: the exit angle averages the trench depth over the rear rim's footprint,
# centred where the rear rim leaves the surface (offline/soil_flow.py module notes). Measured
# ours - Table 5.5 'with soil flow' means (F_x, F_y, sinkage points) at 0/15/30/45/60 deg:
# F_x +2.4/+5.9/+6.7/+4.8/+2.1, F_y 0.0/+1.5/+2.7/+2.3/+0.1, sinkage +0.1/-1.3/-1.6/-1.6/-1.0.
# The classic rows already sit +0.9..+3.1 above the table in F_x (the reproduction floor); the
# authors' soil-flow code is not public, so the remaining few points are not resolved.
TOL_SF_FX, TOL_SF_FY, TOL_SF_H = 7.5, 3.0, 2.0


@pytest.mark.parametrize("beta", TABLE_ANGLES)
def test_soil_flow_exit_angle_reproduces_table_5_5(soil_flow, beta):
    _, _, rows = soil_flow
    d = _ours(rows[beta]) - np.array(TABLE_5_5_GROUSERED["with soil flow"][beta])
    assert abs(d[0]) <= TOL_SF_FX and abs(d[2]) <= TOL_SF_FY and abs(d[4]) <= TOL_SF_H, d


def test_soil_flow_shrinks_the_lateral_error_at_high_angle(classic, soil_flow):
    """The dissertation's qualitative finding (section 5.4.1): the soil-flow exit angle lowers
    the F_y error at high slip angles (at 60 deg: -19.7 -> 0.0 in Table 5.5)."""
    assert abs(soil_flow[2][60.0].fy_mean) < 0.5 * abs(classic[2][60.0].fy_mean)


@pytest.mark.parametrize("beta", TABLE_ANGLES)
def test_soil_flow_spread_matches_table_5_5(soil_flow, beta):
    _, _, rows = soil_flow
    d = _ours(rows[beta]) - np.array(TABLE_5_5_GROUSERED["with soil flow"][beta])
    assert np.all(np.abs(d[[1, 3, 5]]) <= TOL_SD_SOIL_FLOW), d


@pytest.mark.parametrize("which", ["classic", "soil_flow"])
def test_zero_slip_angle_lateral_row_is_the_data_offset(request, avg, which):
    """At beta = 0 the model gives F_y = 0 exactly, so the F_y error row is minus the data's
    own lateral offset: Table 5.5 prints -2.3 +/- 2.6 % for both variants."""
    _, pred, rows = request.getfixturevalue(which)
    at0 = avg.beta_cmd == 0.0
    assert np.all(pred.status[at0] == "ok")
    assert np.max(np.abs(pred.Fy[at0])) <= 1e-9 * np.max(avg.Fz[at0])
    row = rows[0.0]
    assert (round(row.fy_mean, 1), round(row.fy_sd, 1)) == (-2.3, 2.6)
    assert (round(row.fy_mean, 1), round(row.fy_sd, 1)) == TABLE_5_5_GROUSERED["without soil flow"][0.0][2:4]
    offset = 100.0 * avg.Fy[at0] / avg.Fz[at0]
    assert row.fy_mean == pytest.approx(-offset.mean(), rel=1e-9)
    assert row.fy_sd == pytest.approx(offset.std(ddof=0), rel=1e-9)


def test_predicted_sinkage_carries_the_measured_load(avg, classic, calibrated):
    """The defining equation of the validation (5.34): F_z(h) = W at every solved condition."""
    for _, pred, _ in (classic, calibrated):
        ok = pred.status == "ok"
        assert ok.sum() >= 55
        np.testing.assert_allclose(pred.Fz[ok], avg.Fz[ok], rtol=RTOL_SINKAGE_LOAD)
        assert np.all(np.isnan(pred.Fx[~ok])) and np.all(np.isnan(pred.sinkage[~ok]))


# ----------------------------------------------------------- shipped calibration
@pytest.mark.parametrize("beta", TABLE_ANGLES)
def test_shipped_calibration_beats_table_5_5(calibrated, beta):
    _, _, rows = calibrated
    verdict = beats_table_5_5(rows[beta])
    assert verdict == {"Fx": True, "Fy": True, "sinkage": True}, (beta, rows[beta])


def test_shipped_calibration_metadata_agrees_with_a_fresh_score(calibrated):
    import json

    meta = load_toml(SHIPPED_PARAMS)["meta"]
    recorded = json.loads(meta["beats_table_5_5"])
    _, _, rows = calibrated
    assert {float(k): v for k, v in recorded.items()} == {b: beats_table_5_5(rows[b]) for b in TABLE_ANGLES}


def test_shipped_soil_flow_calibration_metadata_agrees_with_a_fresh_score(avg):
    """The soil-flow parameter file records how it compares with the 'with soil flow' rows;
    rescoring it must give the same verdicts. (Measured: F_x beats the table at every angle;
    sinkage at 0 deg and F_y at 60 deg do not.)"""
    import json

    loaded = load_toml(SHIPPED_PARAMS_SOIL_FLOW)
    meta, ps = loaded["meta"], loaded["parameter_set"]
    assert meta["exit_angle"] == "soil_flow"
    assert "zeta" in meta["free_parameters"].split(",") and "b0" not in meta["free_parameters"].split(",")
    v = Variant("calibrated: soil-flow exit angle", ps.soil, ps.wheel, ps.tuning, ModelOptions(exit_angle="soil_flow"))
    rows = {r.beta_deg: r for r in error_rows(avg, predict(avg, v), ps.wheel.radius)}
    fresh = {b: beats_table_5_5(rows[b], "with soil flow") for b in TABLE_ANGLES}
    assert {float(k): val for k, val in json.loads(meta["beats_table_5_5"]).items()} == fresh
    assert all(fresh[b]["Fx"] for b in TABLE_ANGLES)


# ----------------------------------------------------------------------- states
def test_trial_states_commanded_angle(trials):
    vx, vy, w = trial_states(trials)
    np.testing.assert_allclose(vx, trials.vx * np.cos(trials.beta_cmd), rtol=1e-15)
    np.testing.assert_allclose(vy, -trials.vx * np.sin(trials.beta_cmd), rtol=1e-15, atol=1e-18)
    np.testing.assert_allclose(np.hypot(vx, vy), trials.vx, rtol=1e-14)
    np.testing.assert_allclose(w, trials.rim_speed / 0.058, rtol=1e-15)
    assert AUTHORS_RIM_RADIUS == 0.058
    # beta > 0 is travel toward -y in the wheel frame (Fig. 5.1), so the lateral soil force is +y
    pos = trials.beta_cmd > 0
    assert np.all(vy[pos] < 0)


def test_trial_states_measured_angle_is_clipped_to_a_quarter_turn(trials):
    vx_c, _, w_c = trial_states(trials, "commanded")
    vx, vy, w = trial_states(trials, "measured")
    beta = np.clip(trials.beta, -math.pi / 2, math.pi / 2)
    np.testing.assert_allclose(vx, trials.vx * np.cos(beta), rtol=1e-15, atol=1e-18)
    np.testing.assert_allclose(vy, -trials.vx * np.sin(beta), rtol=1e-15)
    np.testing.assert_array_equal(w, w_c)
    assert np.max(np.degrees(trials.beta)) > 90.0  # the 90 deg setting overshoots in the log...
    assert np.all(vx >= 0.0)  # ...but the wheel is never read as travelling backwards
    # the testbed holds the commanded angle within 0.3 deg, so the two readings barely differ
    assert np.max(np.abs(vx - vx_c)) <= np.max(trials.vx) * math.radians(0.3)


def test_trial_states_rejects_unknown_angle(trials):
    with pytest.raises(ValueError, match="angle must be 'commanded' or 'measured', got 'mean'"):
        trial_states(trials, "mean")


# ---------------------------------------------------------------- averaging
def test_average_conditions_gives_63_repeat_means(trials, avg):
    assert len(trials) == 189 and len(avg) == 63  # 7 slip angles x 9 rim speeds, 3 repeats each
    assert np.all(avg.repeat == 3)
    conds = trials.conditions()
    for k, c in enumerate(conds):
        assert avg.beta_cmd[k] == c.beta_cmd and avg.rim_speed_cmd[k] == c.rim_speed_cmd
        for ch in ("Fx", "Fy", "Fz", "sinkage", "slip", "vx", "rim_speed"):
            assert getattr(avg, ch)[k] == pytest.approx(getattr(trials, ch)[c.indices].mean(), rel=1e-14, abs=1e-15)
        assert avg.Fx_std[k] == pytest.approx(np.std(trials.Fx[c.indices], ddof=1), rel=1e-12)
    # equal repeat counts: the mean of the means is the grand mean
    for ch in ("Fx", "Fy", "Fz", "sinkage"):
        assert getattr(avg, ch).mean() == pytest.approx(getattr(trials, ch).mean(), rel=1e-12)
    # each averaged row is its own condition
    assert len(avg.conditions()) == 63 and all(c.n == 1 for c in avg.conditions())
    assert np.all(np.isnan(avg.Fx_slope))


# ---------------------------------------------------------- error bookkeeping
def test_error_rows_match_an_independent_computation(avg, classic):
    v, pred, rows = classic
    for beta in (15.0, 90.0):
        sel = (np.degrees(avg.beta_cmd).round(3) == beta) & (pred.status == "ok")
        e_fx = 100.0 * (pred.Fx[sel] - avg.Fx[sel]) / avg.Fz[sel]
        e_h = 100.0 * (pred.sinkage[sel] - avg.sinkage[sel]) / v.wheel.radius
        r = rows[beta]
        assert r.n == 9 and r.n_failed == 9 - sel.sum()
        assert (r.fx_mean, r.fx_sd, r.fx_mae) == pytest.approx((e_fx.mean(), e_fx.std(), np.abs(e_fx).mean()), rel=1e-12)
        assert (r.h_mean, r.h_sd, r.h_mae) == pytest.approx((e_h.mean(), e_h.std(), np.abs(e_h).mean()), rel=1e-12)
    assert rows[90.0].n_failed > 0  # at 90 deg the Table 5.3 soil cannot carry several loads


def test_errors_percent_normalisation(avg, classic):
    _, pred, _ = classic
    e = errors_percent(avg, pred, radius=0.05)
    e2 = errors_percent(avg, pred, radius=0.10)
    np.testing.assert_allclose(e2["sinkage"], 0.5 * e["sinkage"], rtol=1e-15)
    np.testing.assert_array_equal(e2["Fx"], e["Fx"])


def test_mirrored_slip_angle_mirrors_the_errors(avg, authors_tuning, classic):
    """beta -> -beta with F_y -> -F_y: F_x and sinkage errors unchanged, F_y errors flip."""
    mirrored = replace(avg, beta=-avg.beta, beta_cmd=-avg.beta_cmd, Fy=-avg.Fy)
    sel = avg.beta_cmd <= math.radians(30.5)
    avg_s, mir_s = avg.subset(sel), mirrored.subset(sel)
    v = classic[0]
    a = {r.beta_deg: r for r in error_rows(avg_s, predict(avg_s, v), v.wheel.radius)}
    b = {-r.beta_deg: r for r in error_rows(mir_s, predict(mir_s, v), v.wheel.radius)}
    assert sorted(a) == sorted(b) == [0.0, 15.0, 30.0]
    for beta in a:
        ra, rb = a[beta], b[beta]
        assert (rb.fx_mean, rb.fx_sd, rb.h_mean, rb.h_sd) == pytest.approx((ra.fx_mean, ra.fx_sd, ra.h_mean, ra.h_sd),
                                                                           rel=1e-9, abs=1e-9)
        assert rb.fy_mean == pytest.approx(-ra.fy_mean, rel=1e-9, abs=1e-9)
        assert rb.fy_sd == pytest.approx(ra.fy_sd, rel=1e-9, abs=1e-9)


def test_predict_marks_angles_without_tuning(avg):
    partial = {b: t for b, t in TUNING_T54_GROUSERED.items() if b != 30.0}
    v = _variant("partial", partial)
    pred = predict(avg, v)
    at30 = np.abs(np.degrees(avg.beta_cmd) - 30.0) < 0.5
    assert np.all(pred.status[at30] == "no_tuning")
    assert np.all(np.isnan(pred.Fx[at30])) and np.all(np.isnan(pred.sinkage[at30]))
    assert np.all(pred.status[np.isin(np.degrees(avg.beta_cmd).round(), [0, 15, 45, 60])] == "ok")
    assert np.all(pred.status[np.degrees(avg.beta_cmd).round() >= 75] == "no_tuning")
    angles = [r.beta_deg for r in error_rows(avg, pred, v.wheel.radius)]
    assert angles == [0.0, 15.0, 45.0, 60.0]  # angles without a single prediction get no row


def test_an_angle_where_every_prediction_failed_is_still_reported(soil_flow, avg):
    v, pred, _ = soil_flow
    at90 = np.round(np.degrees(avg.beta_cmd)) == 90.0
    status = pred.status.copy()
    status[at90] = "load_exceeds_capacity"  # every prediction at 90 deg failed
    failed = dataclasses.replace(pred, status=status)
    rows = {r.beta_deg: r for r in error_rows(avg, failed, v.wheel.radius)}
    assert 90.0 in rows and rows[90.0].n_failed == 9 and np.isnan(rows[90.0].fx_mean)


def test_tuning_for_angle_lookup():
    t = TUNING_T54_GROUSERED
    assert tuning_for_angle(t, 30.4) is t[30.0]
    assert tuning_for_angle(t, -45.0) is t[45.0]  # |beta|: the model is mirror symmetric
    assert tuning_for_angle(t, 31.0) is None
    single = t[15.0]
    assert tuning_for_angle(single, 87.0) is single


# ----------------------------------------------------------- Table 5.5 comparison
def _row(fx=(7.1, 21.2), fy=(-2.3, 2.6), h=(5.5, 6.8), beta=0.0):
    return ErrorRow("x", beta, 9, 0, fx[0], fx[1], 0.0, fy[0], fy[1], 0.0, h[0], h[1], 0.0)


def test_beats_table_5_5_at_printed_precision():
    assert beats_table_5_5(_row()) == {"Fx": True, "Fy": True, "sinkage": True}  # equal is not worse
    assert beats_table_5_5(_row(fx=(7.14, 21.2)))["Fx"]  # prints as 7.1
    assert not beats_table_5_5(_row(fx=(7.16, 21.2)))["Fx"]  # prints as 7.2
    assert beats_table_5_5(_row(fx=(-7.1, 21.2)))["Fx"]  # |mean| is compared
    assert not beats_table_5_5(_row(fy=(-1.0, 2.7)))["Fy"]  # a smaller mean does not excuse a larger sd
    assert not beats_table_5_5(_row(h=(-5.6, 1.0)))["sinkage"]
    assert beats_table_5_5(_row(beta=75.0)) is None  # no published row
    soil_flow = beats_table_5_5(_row(fx=(15.6, 32.3), h=(1.6, 6.4)), reference="with soil flow")
    assert soil_flow == {"Fx": True, "Fy": True, "sinkage": True}


def test_format_table_pairs_each_variant_with_its_reference(classic, soil_flow):
    rows = list(classic[2].values()) + list(soil_flow[2].values())
    text = format_table(rows)
    assert "== dissertation: classic exit angle ==  (T5.5: Table 5.5 grousered, without soil flow model)" in text
    assert "== dissertation: soil-flow exit angle ==  (T5.5: Table 5.5 grousered, with soil flow model)" in text
    assert text.count("T5.5 ") == 10  # five published rows under each variant
    assert "(7 failed)" in text  # classic at 90 deg: 7 of 9 loads exceed what the wheel carries
    assert "T5.5" not in format_table(rows, reference=None)


def test_write_csv_round_trip(tmp_path, classic):
    rows = list(classic[2].values())
    path = write_csv(rows, tmp_path / "rows.csv")
    with path.open() as fh:
        read = list(csv.DictReader(fh))
    assert len(read) == len(rows) == 7
    for r, d in zip(rows, read):
        assert d["variant"] == r.variant
        assert float(d["beta_deg"]) == r.beta_deg
        assert int(d["n_failed"]) == r.n_failed
        assert float(d["fy_mean"]) == r.fy_mean  # repr precision: exact
