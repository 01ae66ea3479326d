"""The discrepancy tool on data where the effect is concealed (issue: discrepancy tool).

Real single-wheel data against a model with one physics term removed; synthetic recordings
from the full model with a hidden effect and noise at the real repeat-spread level; and a
negative control. The tool is never told which effect is present.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from offline.fit.dataset import load_trials
from offline.fit.discrepancy import (
    CANDIDATES,
    Extension,
    SingleWheelRecording,
    _cv,
    _folds,
    diagnose,
    predict_recording,
)
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


def synthetic(recording, params, ext, seed):
    """Full-model predictions with a hidden effect, plus noise at the repeat-spread level."""
    rng = np.random.default_rng(seed)
    pred, ok = predict_recording(params, ModelOptions(), recording, ext)
    assert ok.all()
    return recording.with_measured({ch: pred[ch] + rng.normal(0.0, recording.noise[ch]) for ch in pred})


def full_model_cv(recording, params, options=None):
    return float(_cv([], params, options or ModelOptions(), recording, _folds(recording, 5), 10.0, None).sum())


def test_real_data_without_bulldozing_names_it_and_recovers_the_full_fit(trials, params, recording, tmp_path):
    v = diagnose(trials, params, ModelOptions(bulldozing="none"))
    assert v.missing_physics[0] == "sidewall_bulldozing"
    assert any(r.channel == "Fy" and r.mean > 0 for r in v.regions)  # F_y under-predicted somewhere
    scale = v.chosen.values[0]
    assert 0.75 < scale < 1.15  # 1 is the removed term
    full = full_model_cv(recording, params)
    assert v.chosen.chi2_cv < 1.1 * full < 0.5 * v.chi2_cv_base
    out = v.write(tmp_path / "report")
    verdict = json.loads((out / "verdict.json").read_text())
    assert verdict["missing_physics"][0] == "sidewall_bulldozing"
    assert verdict["held_out_chi2_after"] < verdict["held_out_chi2_before"]
    assert {"report.md", "residual_map.png", "measured_vs_predicted.png"} <= {p.name for p in out.iterdir()}
    assert "sidewall bulldozing" in (out / "report.md").read_text()


def test_real_data_without_skid_sinkage_names_it(trials, params, recording):
    crippled = replace(params, soil=replace(params.soil, n1=0.0, n2=0.0))
    v = diagnose(trials, crippled, ModelOptions())
    assert v.missing_physics[0] == "slip_skid_sinkage"
    n2 = v.chosen.values[v.chosen.names.index("n2")]
    assert n2 == pytest.approx(params.soil.n2, rel=0.1)
    assert any(r.channel == "sinkage" and r.mean > 0 and r.bounds.get("slip", (0, 0))[0] < 0 for r in v.regions)
    assert v.chosen.chi2_cv < 1.1 * full_model_cv(recording, params)


@pytest.mark.parametrize(
    "ext, key, check",
    [
        (Extension(hub_clearance=0.035, hub_width=0.04), "hub_drag",
         lambda x: abs(x[0] - 35.0) < 3.0 and abs(x[1] - 40.0) < 10.0),  # mm
        (Extension(force_along=-3.0), "external_force", lambda x: abs(x[0] + 3.0) < 0.3),  # N
        (Extension(force_along=2.0), "external_force", lambda x: abs(x[0] - 2.0) < 0.3),
    ],
    ids=["hub_drag", "tether_pull_back", "tether_pull_forward"],
)
def test_synthetic_hidden_effect_is_named_and_recovered(recording, params, ext, key, check):
    data = synthetic(recording, params, ext, seed=7)
    v = diagnose(data, params, ModelOptions())
    assert v.missing_physics == [key]
    assert check(v.chosen.values), v.chosen.values
    assert v.chosen.chi2_cv < 0.2 * v.chi2_cv_base


def test_synthetic_wheel_radius_change_is_recovered(recording, params):
    data = synthetic(recording, params, Extension(wheel={"radius": params.wheel.radius * 1.08}), seed=3)
    v = diagnose(data, params, ModelOptions())
    assert v.missing_physics[0] == "wheel_radius"
    assert v.chosen.values[0] == pytest.approx(8.0, abs=1.0)  # percent


@pytest.mark.parametrize("seed", [11, 12])
def test_negative_control_reports_nothing_missing(recording, params, seed):
    data = synthetic(recording, params, Extension(), seed=seed)
    v = diagnose(data, params, ModelOptions())
    assert v.missing_physics == []
    assert v.regions == []
    assert "no candidate physics passes" in v.summary()


def test_candidate_library_is_physical():
    keys = [c.key for c in CANDIDATES]
    assert len(keys) == len(set(keys))
    for c in CANDIDATES:
        assert c.physics and c.params
        for name, unit, lo, hi, start, to_si in c.params:
            assert lo < hi and lo <= start <= hi and to_si > 0


def test_full_real_data_flags_the_non_steady_high_angles(params):
    """On all 63 conditions the calibrated model (fitted at 0-60 deg) misses the 75 and 90 deg
    trials, which the data's authors say never reached steady state: the tool must locate a
    large F_y under-prediction there rather than declare agreement."""
    v = diagnose(load_trials(), params, ModelOptions())
    fy = [r for r in v.regions if r.channel == "Fy" and r.mean > 10.0]
    assert fy, v.summary()
    assert fy[0].bounds.get("abs_beta_deg", (0, 0))[0] >= 74.9 or fy[0].bounds.get("load_N", (99, 0))[1] < 20.0
    assert v.failed_before >= 1
