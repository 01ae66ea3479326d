"""The discrepancy tool on concealed effects (issue 10).

Every synthetic recording is the believed model's prediction at the 45 real testbed
conditions (0-60 deg, the shared single-wheel data) with an effect added by code written
HERE, from physics, not by calling the candidate that should name it (a different
functional form or mechanism), plus Gaussian noise at the real repeat-spread level, seeded.
The tool is told only the recording and the believed parameter file; it is never told
which effect is present, its form, or where it acts.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from offline.fit.dataset import load_trials
from offline.discrepancy.engine import DiscrepancyError, diagnose
from offline.discrepancy.report import write_report
from offline.discrepancy.wheel.candidates import predict_recording
from offline.discrepancy.wheel.recording import SingleWheelRecording
from offline.physics.params import load_toml
from offline.physics.terramechanics import ModelOptions

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def trials():
    tr = load_trials()
    return tr.subset(np.degrees(tr.beta_cmd) < 61)  # steady-state angles (data README)


@pytest.fixture(scope="module")
def params():
    from importlib import resources

    return load_toml(resources.files("offline").joinpath("data", "calibrated_grousered.toml"))["parameter_set"]


@pytest.fixture(scope="module")
def recording(trials):
    return SingleWheelRecording.from_trials(trials)


# ----------------------------------------------------------------- independent generators
def believed(recording, params, load=None):
    """The believed model's prediction (no extension) at the recording's conditions, optionally at another load."""
    rec = recording if load is None else replace(recording, load=load)
    pred, ok = predict_recording(params, ModelOptions(), rec)
    assert ok.all()
    return pred


def noisy(recording, truth, seed):
    rng = np.random.default_rng(seed)
    return recording.with_measured({ch: truth[ch] + rng.normal(0.0, recording.noise[ch]) for ch in truth})


def travel_unit_vector(recording):
    """Travel direction in the wheel frame from the wheel-frame velocity."""
    v = np.hypot(recording.vx, recording.vy)
    return recording.vx / v, recording.vy / v


def rut_edge_drag(recording, params, depth_start, coefficient, seed):
    """A rut edge / chassis part that scrapes soil once the wheel sinks past ``depth_start``:
    drag = coefficient * (h - depth_start)^1.5 (N, h from the believed model), against the
    travel direction. Functional form (power 1.5, no soil parameters) differs from the
    hub_drag candidate's passive-earth-pressure blade."""
    t = believed(recording, params)
    excess = np.maximum(t["sinkage"] - depth_start, 0.0)
    drag = coefficient * excess**1.5
    ux, uy = travel_unit_vector(recording)
    t["Fx"] = t["Fx"] - drag * ux
    t["Fy"] = t["Fy"] - drag * uy
    return noisy(recording, t, seed), int((excess > 0).sum())


def spring_tether(recording, params, t0, stiffness, azimuth_deg, elevation_deg, seed):
    """A cable to a fixed anchor behind/beside the bin: a spring whose tension grows with the
    distance travelled, T = t0 + stiffness * travel, pulling along a fixed testbed direction
    (azimuth from the travel direction, elevation above the horizontal). The vertical part
    unloads the wheel (the soil carries W - T sin(elevation)); the horizontal part is rotated
    into the wheel frame by the slip angle. The candidate assumes a constant horizontal pull."""
    T = t0 + stiffness * recording.travel
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    t = believed(recording, params, load=recording.load - T * math.sin(el))
    beta = np.arctan2(-recording.vy, recording.vx)
    # testbed frame (x = travel, y = left) -> wheel frame: rotate by -beta
    hx, hy = T * math.cos(el) * math.cos(az), T * math.cos(el) * math.sin(az)
    t["Fx"] = t["Fx"] + np.cos(beta) * hx + np.sin(beta) * hy
    t["Fy"] = t["Fy"] - np.sin(beta) * hx + np.cos(beta) * hy
    return noisy(recording, t, seed), float(np.mean(T * math.cos(el)))


def miscalibrated_sensor(recording, params, offset, crosstalk, seed):
    """A six-axis sensor read through a calibration matrix with small cross-talk (F_z leaks
    into F_x and F_y by ``crosstalk``) and a zero offset ``offset`` (N) in its own frame."""
    t = believed(recording, params)
    fz = recording.load
    t["Fx"] = t["Fx"] + crosstalk * fz + offset[0]
    t["Fy"] = t["Fy"] - crosstalk * fz + offset[1]
    return noisy(recording, t, seed)


def constant_drawbar(recording, truth, pull):
    """A constant drawbar pull ``pull`` (N) resisting the travel, from a rig that holds the
    wheel back along its travel direction (not a candidate's formula: the travel direction
    from the wheel-frame velocity)."""
    ux, uy = travel_unit_vector(recording)
    return {**truth, "Fx": truth["Fx"] - pull * ux, "Fy": truth["Fy"] - pull * uy}


def recalibration_error(recording, candidate_params, truth):
    """rms over rows and channels of (prediction - noiseless truth) / noise."""
    pred, ok = predict_recording(candidate_params, ModelOptions(), recording)
    z = np.concatenate([(pred[ch] - truth[ch]) / recording.noise[ch] for ch in truth])
    return float(np.sqrt(np.mean(z**2))) if ok.all() else math.inf


def skid_drag(recording, params, per_unit_skid, seed):
    """Outside the library: an extra resistance only while skidding, proportional to the
    skid ratio (braking-wheel soil pile-up), drag = per_unit_skid * |s| for s < 0."""
    t = believed(recording, params)
    s = recording.features["slip"]
    t["Fx"] = t["Fx"] - per_unit_skid * np.where(s < 0, -s, 0.0)
    return noisy(recording, t, seed)


# ----------------------------------------------------------------- effect cases
# one noise seed here: "on every noise seed" is the benchmark's (tests/bench/bench_discrepancy.py,
# seeds 2000-2002, results_discrepancy.md). Seeds 31 and 32 were here too until the suite's budget cut
# (2026-11-27): with the fixed folds and the old screening (b341723, the parent of the screening fix)
# all three named hub_drag (clearance 46.6, 47.6, 47.6 mm), so there they caught nothing seed 21 did
# not; which seed the older folds failed on was not re-checked
@pytest.mark.parametrize("seed", [21])
def test_localised_deep_sinkage_drag_is_named_hub_drag(recording, params, seed):
    """Told: the recording (45 conditions) and the believed parameters. Not told: that a drag
    acts only where sinkage passes 45 mm (8 of 45 conditions, 6 above twice the noise), its 1.5-power form. Must
    name hub_drag with a clearance within 6 mm of 45 mm and explain > 60 % of the held-out
    excess chi2 (the power-1.5 form is not the candidate's) (issue 24: the old folds and screening
    named it on two seeds of three)."""
    data, n_rows = rut_edge_drag(recording, params, 0.045, 3.0e3, seed=seed)
    assert 3 <= n_rows <= 10
    v = diagnose(data, params)
    assert v.status == "explained", v.summary()
    assert v.missing_physics == ["hub_drag"], v.summary()
    clearance = v.chosen.values[v.chosen.names.index("clearance")]
    assert abs(clearance - 45.0) < 6.0, clearance
    assert v.explained_fraction > 0.6 and v.chosen.chi2_cv < 0.7 * v.chi2_cv_base


def test_deep_sinkage_drag_and_a_constant_drawbar_are_both_named(recording, params):
    """Told: recording and parameters. Not told: the deep-sinkage drag above (1.5 power beyond
    45 mm) AND a constant 1 N drawbar pull resisting the travel. Must name both, hub_drag and
    tether (issue 24: "grouser radius + tilt" or "grouser radius + hub", the drawbar missed),
    the clearance within 6 mm of 45 mm, the pull within 30 % of 1 N, along the travel (azimuth
    within 15 deg of 0), and the summary must say the explanation holds new terms."""
    t = believed(recording, params)
    t["Fx"] = t["Fx"] - 3.0e3 * np.maximum(t["sinkage"] - 0.045, 0.0) ** 1.5 * travel_unit_vector(recording)[0]
    t["Fy"] = t["Fy"] - 3.0e3 * np.maximum(t["sinkage"] - 0.045, 0.0) ** 1.5 * travel_unit_vector(recording)[1]
    v = diagnose(noisy(recording, constant_drawbar(recording, t, 1.0), seed=41), params)
    assert v.status in ("explained", "partly_explained"), v.summary()
    assert set(v.missing_physics) == {"hub_drag", "tether"}, v.summary()
    val = dict(zip(v.chosen.names, v.chosen.values))
    assert abs(val["clearance"] - 45.0) < 6.0, v.summary()
    assert -val["force"] == pytest.approx(1.0, rel=0.3) and abs(val["azimuth"]) < 15.0, v.summary()
    assert "holds the new term(s) hub_drag, tether" in v.summary()
    assert "parameters are off" not in v.summary()


def test_spring_tether_in_a_fixed_direction_is_named_tether(recording, params, tmp_path):
    """Told: recording and parameters. Not told: a cable whose tension grows with the travel
    (1.5 N + 2 N/m), 25 deg to the left of the travel direction, 10 deg upward (which also
    unloads the wheel). Must name tether (alone or first of an indistinguishable set), the
    horizontal pull within 20 % of the mean, the azimuth within 6 deg; report files written."""
    data, mean_pull = spring_tether(recording, params, 1.5, 2.0, 25.0, 10.0, seed=22)
    v = diagnose(data, params)
    assert v.status in ("explained", "partly_explained"), v.summary()
    assert v.chosen.keys[0] == "tether", v.summary()
    force = v.chosen.values[v.chosen.names.index("force")]
    azimuth = v.chosen.values[v.chosen.names.index("azimuth")]
    assert force == pytest.approx(mean_pull, rel=0.2)
    assert abs(azimuth - 25.0) < 6.0
    out = write_report(v, tmp_path / "report")
    verdict = json.loads((out / "verdict.json").read_text())
    assert verdict["chosen"]["terms"][0] == "tether"
    assert verdict["held_out_chi2_after"] < verdict["held_out_chi2_before"]
    assert {"report.md", "verdict.json", "residual_map.png", "measured_vs_predicted.png"} <= {p.name for p in out.iterdir()}
    assert not list(out.glob(".*part*"))  # atomic writes leave no temporary files


def test_sensor_offset_with_crosstalk_is_named_or_reported_with_its_look_alike(recording, params):
    """Told: recording and parameters. Not told: a force sensor with a (-1.2, +0.8) N zero
    offset and 1 % F_z cross-talk into F_x and F_y. Must put sensor_offset among the named
    (indistinguishable) explanations with Fx0, Fy0 within 0.4 N of the total bias at the mean
    load, and never name a wheel-physics term alone."""
    data = miscalibrated_sensor(recording, params, (-1.2, 0.8), 0.01, seed=23)
    v = diagnose(data, params)
    named = [v.chosen] + v.indistinguishable
    hit = [s for s in named if s.keys == ("sensor_offset",)]
    assert hit, v.summary()
    fz = float(np.mean(recording.load))
    assert hit[0].values[0] == pytest.approx(-1.2 + 0.01 * fz, abs=0.4)
    assert hit[0].values[1] == pytest.approx(0.8 - 0.01 * fz, abs=0.4)
    for s in v.indistinguishable:  # each look-alike comes with a separating experiment
        assert any(sep.b == s.label or sep.a == s.label for sep in v.separations)


# one noise seed here (seed 44 was the second; the benchmark runs seeds 2000-2002:
# tests/bench/bench_discrepancy.py, results_discrepancy.md). This case also carries the recalibrated
# file's checks: a second parameters-off truth (K x1.6 and friction angle +3 deg, seed 24) took the same
# path (recalibration wins, report writes recalibrated.toml) and is in the benchmark (suite time)
@pytest.mark.parametrize("seed", [24])
def test_no_cohesion_and_a_doubled_shear_modulus_is_parameters_off(recording, params, seed, tmp_path):
    """Told: recording and parameters. Not told: the truth is the same model with cohesion 0
    and the shear modulus K doubled (issue 24: "cohesion + a load offset" was answered). Must
    answer "parameters off" (recalibration wins whenever it explains as much), say that the
    explanation holds no new term, and the recalibrated cohesion and K be within 20 % of the
    truth (cohesion: within 20 % of the believed value of 0). The report writes recalibrated.toml
    that loads, and the recalibrated model reproduces the noiseless truth to within the noise
    (rms of (recalibrated - truth) / noise below 1) where the believed model is clearly off."""
    truth = replace(params, soil=replace(params.soil, cohesion=0.0, shear_modulus=2.0 * params.soil.shear_modulus))
    pred, ok = predict_recording(truth, ModelOptions(), recording)
    assert ok.all()
    v = diagnose(noisy(recording, pred, seed=seed), params)
    assert v.status == "parameters_off", v.summary()
    assert v.parameters_off and all(k == "parameters" for k in v.chosen.kinds), v.summary()
    assert "holds no new term" in v.summary()
    val = dict(zip(v.chosen.names, v.chosen.values))
    if "K" in val:
        assert val["K"] == pytest.approx(2e3 * params.soil.shear_modulus, rel=0.2), v.summary()
    if "c" in val:
        assert val["c"] < 0.2 * params.soil.cohesion / 1e3, v.summary()
    out = write_report(v, tmp_path / "report")
    loaded = load_toml(out / "recalibrated.toml")["parameter_set"]
    assert loaded.soil != params.soil or loaded.tuning != params.tuning
    assert recalibration_error(recording, loaded, pred) < 1.0
    assert recalibration_error(recording, params, pred) > 3.0  # the believed model was clearly off


def test_effect_outside_the_library_is_never_explained_with_confidence(recording, params):
    """Told: recording and parameters. Not told: an extra resistance only while skidding,
    proportional to the skid ratio (2.5 N at full skid), a mechanism no candidate has. The
    verdict must be "unexplained" or "partly explained" (never "explained" or "parameters
    off"), the region located in the skid range, and what a partial explanation leaves shown
    (a region after it in the skid range, or an F_x misfit in noise units)."""
    data = skid_drag(recording, params, 2.5, seed=25)
    v = diagnose(data, params)
    assert v.status in ("unexplained", "partly_explained"), v.summary()
    # one set of units: a residual misfit significant in noise units is never printed beside
    # "100 % of the excess removed" (issue 24); the share is in the misfit test's units
    # (the library's lines: the empirical term's own share and misfit follow "empirical:", tested in
    # tests/test_wheel_empirical.py)
    library_lines = v.summary().split("\nempirical:")[0]
    if v.misfit_after:
        assert v.excess_removed < 1.0, v.summary()
        assert "100 % of the excess" not in library_lines and "a misfit above noise remains" in library_lines
    def skid(regions):
        return any(r.channel == "Fx" and r.bounds.get("slip", (-1, 1))[0] < 0 for r in regions)

    # located in the skid range, and what the partial explanation leaves is shown: a region after
    # it in the skid range, or (the rest too spread for the region test) the F_x misfit after it
    assert skid(v.regions), v.summary()
    if v.status == "partly_explained":
        assert skid(v.regions_after) or any(ch == "Fx" for ch, *_ in v.misfit_after), v.summary()
    # and what the library lacks is modelled: an empirical term in the skid range (issue 24; slip and
    # rim speed locate the same rows on this rig, the tool names both when they fit equally)
    em = v.empirical
    assert em is not None and em.terms, v.summary()
    assert any(t.feature in ("slip", "rim_speed_mm_s") and t.shape in ("below", "hinge_below")
               for t in [em.terms[0], *em.lookalikes[0]]), v.summary()


@pytest.mark.parametrize("seed", [101])
def test_negative_control_agrees(recording, params, seed):
    """Told: recording and parameters. The data ARE the believed model plus noise at the stated
    level. Must answer "agree" with nothing named (false-alarm rate over 20 seeds is measured in
    tests/bench/bench_discrepancy.py, seeds 1000-1019; one seed here: a second one, 102 until
    the suite's budget cut, only sampled that rate again)."""
    truth = believed(recording, params)
    v = diagnose(noisy(recording, truth, seed), params)
    assert v.status == "agree", v.summary()
    assert v.missing_physics == [] and v.regions == []


def test_real_data_without_bulldozing_names_it_and_recovers_the_full_fit(trials, params):
    """Real testbed data (0-60 deg); the model under test has its sidewall term removed (told
    only: the data and the handicapped model). Must name sidewall_bulldozing with a scale near
    1 (the removed term is scale 1)."""
    v = diagnose(trials, params, ModelOptions(bulldozing="none"))
    assert v.chosen is not None and v.chosen.keys[0] == "sidewall_bulldozing", v.summary()
    assert v.status in ("explained", "partly_explained")
    assert 0.75 < v.chosen.values[0] < 1.25
    assert any(r.channel == "Fy" and r.mean > 0 for r in v.regions)


def test_forces_in_millinewton_are_an_error_not_agreement(recording, params):
    """Issue 9: forces (the load included) in mN: the model cannot carry a 1000x load in any
    condition. This must be a DiscrepancyError naming the likely unit, never "agree"."""
    m = recording.measured
    scaled = replace(recording, load=recording.load * 1e3).with_measured(
        {"Fx": m["Fx"] * 1e3, "Fy": m["Fy"] * 1e3, "sinkage": m["sinkage"]})
    with pytest.raises(DiscrepancyError, match="units of the force columns"):
        diagnose(scaled, params)
