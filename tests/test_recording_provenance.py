"""Self-describing recordings (issue 25): provenance in the MCAP metadata, differences named, and
the replay's tolerance mode (first divergence beyond rtol/atol; bit for bit by default)."""

from __future__ import annotations

import copy
from dataclasses import replace

import pytest

from rtctl.config import ControllerConfig
from rtctl.controller import Controller
from rtctl.messages import Measurements
from rtctl.recording import Recorder, compare_provenance, provenance, read_recording
from rtctl.replay import ReplayError, replay
from rtctl_synthetic import RS, synthetic_tables

OM = 0.03 / (RS * 0.9)


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    return synthetic_tables(tmp_path_factory.mktemp("tables"))


@pytest.fixture(scope="module")
def recorded(tables, tmp_path_factory):
    """A 20-tick drive of the synthetic controller, recorded with its provenance."""
    ctl = Controller(tables, ControllerConfig())
    path = tmp_path_factory.mktemp("rec") / "drive.mcap"
    with Recorder(path, {"scenario": "synthetic"}, provenance=provenance(ctl)) as rec:
        for k in range(20):
            m = Measurements(0.2 * k, k, (OM * (1 + 0.01 * k),) * 4, (0.0,) * 4, 0.001 * k)
            c, _ = ctl.step(m)
            rec.measurements(m)
            rec.commands(c)
    return path


def test_provenance_names_tables_config_versions(tables):
    ctl = Controller(tables, ControllerConfig())
    p = provenance(ctl)
    assert set(p["tables"]) == set(tables) | set(ctl.mirrored)  # the mirrors rtctl adds are recorded too
    assert all(p["tables"][m]["file"].startswith("mirror of ") for m in ctl.mirrored)
    for name, t in tables.items():
        assert p["tables"][name] == {"file": t.source, "content_hash": t.header["content_hash"]}
    assert p["controller_config"]["qp"]["eps"] == ControllerConfig().qp.eps
    for key in ("library_version", "python", "numpy", "scipy", "osqp", "filterpy", "platform", "machine"):
        assert isinstance(p[key], str) and p[key], key
    assert "tables" not in provenance(object())  # anything else: versions and platform only


def test_provenance_round_trip_and_same_side_is_silent(tables, recorded):
    rec = read_recording(recorded)
    assert rec.metadata["scenario"] == "synthetic"
    assert compare_provenance(rec.provenance, provenance(Controller(tables, ControllerConfig()))) == ([], [])


def test_differences_are_named(tables, recorded):
    rec = read_recording(recorded)
    here = provenance(Controller(tables, ControllerConfig()))
    other = copy.deepcopy(here)
    name = sorted(other["tables"])[0]
    other["tables"][name]["content_hash"] = "0" * 64
    other["controller_config"]["qp"]["eps"] = 1e-5
    other["controller_config"]["tables_index"] = "/elsewhere/index.json"  # a path: not a difference
    other["numpy"] = "0.0.1"
    other["platform"] = "Other-1.0"
    refuse, warn = compare_provenance(rec.provenance, other)
    assert len(refuse) == 2
    assert refuse[0].startswith("tables.") or refuse[1].startswith("tables.")
    assert any(r.startswith(f"tables.{name}.content_hash: recorded '") and "now '0000" in r for r in refuse)
    assert "controller_config.qp.eps: recorded 1e-06, now 1e-05" in refuse
    assert any(w.startswith("numpy: recorded") and "now '0.0.1'" in w for w in warn)
    assert any(w.startswith("platform: recorded") for w in warn) and len(warn) == 2
    del other["tables"][name]
    refuse, _ = compare_provenance(rec.provenance, other)
    assert f"tables.{name}: recorded {rec.provenance['tables'][name]!r}, now '<absent>'" in refuse
    refuse, warn = compare_provenance({}, here)
    assert refuse == [] and "no provenance record" in warn[0]


def test_tolerance_mode_reports_first_divergence_beyond_it(tables, recorded):
    rec = read_recording(recorded)
    ctl = Controller(tables, ControllerConfig())
    assert replay(rec, ctl).identical  # bit for bit, the default
    # the recording as another machine might have written it: one steering angle 1e-9 rad off at
    # tick 7 and a rim speed 1e-7 m/s off at tick 12
    c7, c12 = rec.commands[7], rec.commands[12]
    rec.commands[7] = replace(c7, steer_angle=(c7.steer_angle[0] + 1e-9, *c7.steer_angle[1:]))
    rec.commands[12] = replace(c12, rim_speed=(*c12.rim_speed[:2], c12.rim_speed[2] + 1e-7, c12.rim_speed[3]))
    r = replay(rec, ctl)
    assert not r.identical and r.diverged_steps == 2 and r.first_divergence.index == 7
    assert r.first_divergence.field == "steer_angle" and r.first_divergence.wheel == "FR"
    assert r.largest_difference == pytest.approx(1e-7, rel=1e-3)
    r = replay(rec, ctl, atol=1e-8)
    assert not r.identical and r.diverged_steps == 1 and r.first_divergence.index == 12
    assert r.first_divergence.field == "rim_speed" and r.first_divergence.wheel == "RR"
    assert "differ beyond rtol 0, atol 1e-08" in r.summary()
    r = replay(rec, ctl, rtol=0.0, atol=1e-6)
    assert r.identical and r.bit_identical_steps == 18 and "within rtol 0, atol 1e-06" in r.summary()
    r = replay(rec, ctl, rtol=1e-3)  # relative to the recorded value (rim speed ~0.03 m/s)
    assert r.identical
    with pytest.raises(ReplayError, match="atol must be finite"):
        replay(rec, ctl, atol=float("nan"))
