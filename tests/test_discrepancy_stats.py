"""The discrepancy engine's statistics and library terms, checked against closed forms (fast).

These tests know the answer analytically: a model linear in its parameters (where the
one-step held-out score and the tangent null are exact), the family-wise error of the min-P
adjustment under a simulated null, and the geometry of the new library terms.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from offline.discrepancy.wheel.candidates import Extension, SingleWheelModel, predict_recording
from offline.discrepancy.engine import DiscrepancyError, diagnose
from offline.discrepancy.significance import adjusted_p, fit, held_out, tangent_null, vuong
from offline.physics.terramechanics import ModelOptions


@pytest.fixture(scope="module")
def params(calibrated_params):
    return calibrated_params


@pytest.fixture(scope="module")
def recording(steady_recording):
    return steady_recording


def _linear_cv(D, e, folds, nc):
    """Exact K-fold held-out improvement of the linear model e ~ D b."""
    total = 0.0
    for f in np.unique(folds):
        tr = np.repeat(folds != f, nc)
        te = ~tr
        b = np.linalg.lstsq(D[tr], e[tr], rcond=None)[0]
        total += float((e[te] ** 2).sum() - ((e[te] - D[te] @ b) ** 2).sum())
    return total


def test_one_step_held_out_score_is_exact_for_a_linear_model():
    rng = np.random.default_rng(1)
    n, nc, k = 30, 2, 3
    D = rng.normal(size=(n * nc, k))
    y = rng.normal(size=n * nc) + D @ np.array([0.5, -1.0, 0.2])
    folds = np.arange(n) % 5
    lo, hi = np.full(k, -10.0), np.full(k, 10.0)
    res = fit(lambda x: y - D @ x, lo, hi, [np.zeros(k)], nc, max_nfev=50)
    rows = held_out(res, lambda x: (y - D @ x).reshape(-1, nc), folds, lo, hi, damping=0.0)
    exact = 0.0
    for f in range(5):
        tr = np.repeat(folds != f, nc)
        b = np.linalg.lstsq(D[tr], y[tr], rcond=None)[0]
        exact += float(((y[~tr] - D[~tr] @ b) ** 2).sum())
    assert rows.sum() == pytest.approx(exact, rel=1e-6)


def test_tangent_null_equals_the_exact_linear_held_out_improvement():
    rng = np.random.default_rng(2)
    n, nc, B = 20, 3, 50
    D = rng.normal(size=(n * nc, 2))
    folds = np.arange(n) % 4
    null = tangent_null([[D]], folds, nc, B, np.random.default_rng(7))
    E = np.random.default_rng(7).standard_normal((n * nc, B))
    direct = np.array([_linear_cv(D, E[:, b], folds, nc) for b in range(B)])
    assert null[0] == pytest.approx(direct, rel=1e-9, abs=1e-9)


def test_damped_null_does_not_overfit_barely_determined_directions():
    """Issue 24: the observed held-out score steps with damping 1e-3 in column-normalised
    coordinates; a null without it fits nearly collinear directions exactly and is far more
    negative, so noise beat it. The damped null of nearly collinear columns must be less
    negative than the undamped one, and for well-conditioned columns agree with it."""
    rng = np.random.default_rng(4)
    n, nc, B = 45, 3, 400
    base = rng.normal(size=(n * nc, 3))
    collinear = np.hstack([base, base + 1e-4 * rng.normal(size=base.shape)])
    folds = np.arange(n) % 5
    und = tangent_null([[collinear]], folds, nc, B, np.random.default_rng(9))
    damp = tangent_null([[collinear]], folds, nc, B, np.random.default_rng(9), damping=1e-3)
    assert damp.mean() > und.mean() + 3 * und.std() / math.sqrt(B)
    good_u = tangent_null([[base]], folds, nc, B, np.random.default_rng(9))
    good_d = tangent_null([[base]], folds, nc, B, np.random.default_rng(9), damping=1e-3)
    assert good_d[0] == pytest.approx(good_u[0], abs=0.02 * float(np.abs(good_u).mean()))


def test_min_p_adjustment_keeps_the_family_wise_error_rate():
    """Ten candidates, data drawn from the null 400 times: P(any p_adj < 0.05) must be ~0.05
    (binomial 3-sigma band), where unadjusted p would give ~40 %."""
    rng = np.random.default_rng(3)
    m, B, trials = 10, 2000, 400
    null = rng.standard_normal((m, B))
    obs = rng.standard_normal((trials, m))
    fwe = np.mean([adjusted_p(o, null)[1].min() < 0.05 for o in obs])
    raw = np.mean([adjusted_p(o, null)[0].min() < 0.05 for o in obs])
    assert abs(fwe - 0.05) < 3 * math.sqrt(0.05 * 0.95 / trials)
    assert raw > 0.3


def test_vuong_statistic():
    rng = np.random.default_rng(4)
    a = rng.chisquare(3, size=60)
    assert vuong(a, a) == 0.0
    assert vuong(a, a + 2.0 + rng.normal(0, 0.5, 60)) > 10  # b is clearly worse
    assert vuong(a + 2.0 + rng.normal(0, 0.5, 60), a) < -10
    # Schwarz's correction: a with p more parameters must beat b by more than p ln(rows) in chi-square
    d = 0.2 + rng.normal(0, 0.5, 60)
    plain, corrected = vuong(a, a + d), vuong(a, a + d, extra_parameters=4)
    assert corrected == pytest.approx((d.sum() - 4 * math.log(60)) / (math.sqrt(60) * d.std(ddof=1)))
    assert plain > 2.0 > corrected


def test_tether_along_the_travel_direction_pushes_along_the_velocity(recording, params):
    """A tether at azimuth 0 pulls along the travel direction (v_x, v_y)/|v| in the wheel frame;
    one at azimuth = beta pulls along the wheel's own x axis."""
    base, _ = predict_recording(params, ModelOptions(), recording)
    along, _ = predict_recording(params, ModelOptions(), recording, Extension(tether_force=2.0))
    v = np.hypot(recording.vx, recording.vy)
    assert along["Fx"] - base["Fx"] == pytest.approx(2.0 * recording.vx / v, abs=1e-9)
    assert along["Fy"] - base["Fy"] == pytest.approx(2.0 * recording.vy / v, abs=1e-9)
    rows = np.flatnonzero(np.isclose(recording.features["abs_beta_deg"], 30.0))
    sub = recording.subset(rows)
    b0, _ = predict_recording(params, ModelOptions(), sub)
    b = float(sub.beta[0])
    x, _ = predict_recording(params, ModelOptions(), sub, Extension(tether_force=2.0, tether_azimuth=b))
    assert x["Fx"] - b0["Fx"] == pytest.approx(np.full(rows.size, 2.0), abs=1e-9)
    assert x["Fy"] - b0["Fy"] == pytest.approx(np.zeros(rows.size), abs=1e-9)


def test_sensor_yaw_rotates_the_horizontal_force_and_keeps_its_magnitude(recording, params):
    base, _ = predict_recording(params, ModelOptions(), recording)
    rot, _ = predict_recording(params, ModelOptions(), recording, Extension(sensor_yaw=math.radians(7.0)))
    assert np.hypot(rot["Fx"], rot["Fy"]) == pytest.approx(np.hypot(base["Fx"], base["Fy"]), rel=1e-12)
    ang = np.arctan2(rot["Fy"], rot["Fx"]) - np.arctan2(base["Fy"], base["Fx"])
    assert np.mod(ang + math.pi, 2 * math.pi) - math.pi == pytest.approx(np.full(len(recording), math.radians(7.0)), abs=1e-9)


def test_cached_model_predicts_the_same_numbers(recording, params):
    m = SingleWheelModel(params, ModelOptions())
    for ext in (Extension(), Extension(hub_clearance=0.03, hub_width=0.05), Extension(soil={"cohesion": 1500.0}), Extension()):
        a, oka = m.predict(recording, ext)
        b, okb = predict_recording(params, ModelOptions(), recording, ext)
        assert (oka == okb).all()
        for ch in a:
            assert a[ch] == pytest.approx(b[ch], rel=1e-12, nan_ok=True)


def test_probes_change_what_they_say(recording):
    p = {pr.description: pr.observations for pr in recording.probes()}
    heavy = next(o for d, o in p.items() if "1.5 x the load" in d)
    assert heavy.load == pytest.approx(1.5 * recording.load)
    mirrored = next(o for d, o in p.items() if "mirror" in d)
    assert mirrored.vy == pytest.approx(-recording.vy, abs=1e-15)
    assert mirrored.vx == pytest.approx(recording.vx)


def test_folds_interleave_every_slip_level_at_every_angle(recording):
    """Issue 24: each fold must hold rows of every slip level (locked wheel, free rolling,
    driving...) and every commanded angle, in near-equal numbers. The old interleave shifted by
    round(deg(beta)) % 5, 0 for 0/15/30/45/60 deg: one fold held every locked-wheel row and
    another only zero-slip rows."""
    k = 5
    folds = recording.folds(k)
    slip = np.round(recording.features["slip"], 1)
    beta = np.round(np.degrees(recording.beta_cmd))
    assert sorted(np.bincount(folds, minlength=k)) == [len(recording) // k] * k
    for level in np.unique(slip):
        rows = slip == level
        if rows.sum() >= k:  # a level recorded at k or more angles is spread over every fold
            assert len(set(folds[rows].tolist())) == k, (level, folds[rows])
    for f in range(k):
        held = folds == f
        assert np.ptp(recording.features["slip"][held]) > 1.5  # spans skid to drive
        assert len(set(beta[held].tolist())) >= 4
    # a recording with fewer angles than folds: each slip level still spread over all its angles
    sub = recording.subset(np.flatnonzero(beta <= 30))
    fs = sub.folds(k)
    s_sub = np.round(sub.features["slip"], 1)
    for level in np.unique(s_sub):
        assert len(set(fs[s_sub == level].tolist())) == (s_sub == level).sum()


def test_too_few_rows_is_an_error(recording, params):
    with pytest.raises(DiscrepancyError, match="rows"):
        diagnose(recording.subset(np.arange(5)), params)


def test_cli_refuses_an_output_that_is_a_file_before_any_work(tmp_path, capsys):
    from offline.cli import main

    f = tmp_path / "report"
    f.write_text("not a folder")
    assert main(["discrepancy", "--out", str(f), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "not a folder" in err and "Traceback" not in err
    assert f.read_text() == "not a folder"


def test_region_test_with_the_series_correlation_keeps_its_level_on_correlated_noise():
    """Noise correlated from row to row (MA(1), lag-1 correlation 0.45) has no region. The
    region test with independent-row draws finds one far more often than its 1 % level;
    given the series' own correlated draws it stays near the level (the drive adapter's
    ``channel_null_draw``)."""
    from offline.discrepancy.significance import locate

    rho = 0.45
    theta = (1.0 - math.sqrt(1.0 - 4.0 * rho * rho)) / (2.0 * rho)

    def ma1(rng, n_draws, n_rows):
        w = rng.standard_normal((n_draws, n_rows + 1))
        return (w[:, 1:] + theta * w[:, :-1]) / math.sqrt(1.0 + theta * theta)

    n_rows, trials = 120, 200
    t = np.arange(n_rows, dtype=float)
    alarms = {"independent": 0, "correlated": 0}
    for seed in range(trials):
        z = ma1(np.random.default_rng(seed), 1, n_rows)[0]
        for kind in alarms:
            draw = None if kind == "independent" else (lambda rng, n: ma1(rng, n, n_rows))
            found = locate(z, z, {"time_s": t}, "x", "-", np.random.default_rng(1000 + seed), alpha=0.01,
                           n_perm=300, draw=draw)
            alarms[kind] += bool(found)
    # measured: 15 of 200 with independent draws (7.5 %), 0 of 200 with the correlated ones
    assert alarms["independent"] >= 8, alarms  # the check can fail: independent draws are too permissive here
    assert alarms["correlated"] <= 5, alarms  # 1 % of 200 is 2


class _OffModel:
    """A model ``off`` noise units above the data on every row and channel; with the extension's
    ``tether_force`` (used here as a bare parameter ``a``) above 0.5 its prediction is lost on every
    row (NaN), as a re-simulated drive the plant cannot carry is; below it, ``a`` only adds a
    little noise-free wobble the data do not hold."""

    def __init__(self, off: float) -> None:
        self.off = off

    def predict(self, obs, ext):
        a = 0.0 if ext is None else ext.tether_force
        pred = {ch: obs.measured[ch] + obs.noise[ch] * (self.off + 0.3 * a * np.cos(np.arange(len(obs))))
                for ch in obs.channels}
        if a > 0.5:
            pred = {ch: np.full(len(obs), np.nan) for ch in obs.channels}
        ok = np.isfinite(next(iter(pred.values())))
        return pred, ok


def test_a_lost_prediction_never_scores_better_than_the_model_as_given(recording):
    """Issue 24's engine flaw: a candidate whose re-simulation is lost (every row NaN) counted
    FAIL_Z = 10 per value and so beat a model as given that is 20 noise units off: its fit went to
    the parameters that lose everything and it came out significant, a held-out 'improvement' of
    300 per value. A lost row now counts the worst the model as given does (fail_floor): the
    candidate that can only lose rows is not significant and nothing is named."""
    from offline.discrepancy.significance import FAIL_Z, fail_floor, normalised
    from offline.discrepancy.wheel.candidates import Candidate

    lose = Candidate("lose_everything", "a parameter that loses the prediction above 0.5",
                     (("a", "-", 0.0, 1.0, 0.1, 1.0),), lambda x, p: Extension(tether_force=float(x[0])),
                     starts=((0.9,),), threshold=True)
    model = _OffModel(20.0)
    pred0, _ = model.predict(recording, None)
    scale = {ch: 1.0 for ch in recording.channels}
    lost = fail_floor(recording, pred0, scale)
    assert all(v == pytest.approx(20.0) for v in lost.values()) and FAIL_Z < 20.0
    nan = {ch: np.full(len(recording), np.nan) for ch in recording.channels}
    assert (normalised(recording, nan, scale, lost) ** 2).sum() >= (normalised(recording, pred0, scale, lost) ** 2).sum()
    v = diagnose(recording, model, candidates=[lose], recalibrate=False, n_boot=300, empirical=False, seed=0)
    s = v.scores[0]
    assert s.delta_cv <= 1e-6 * v.chi2_cv_base and not s.significant, v.summary()
    assert v.missing_physics == [] and v.status == "unexplained", v.summary()
