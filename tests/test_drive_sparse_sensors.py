"""Drives recorded with sparse sensors (issue 24): no motor torques and a pose fix only every 10 s.

Without enough pose fixes the tool takes the heading from the gyro and has no pose channels;
what it says a recording lacks (:meth:`offline.discrepancy.drive.diagnosis.DriveRecording.identification_advice`)
must then come from the rover's measured motion, not from the steering commands: on README's
main job (rr_steer_stuck_50, rtctl on the shipped tables) the declared stuck rear-right wheel sits
at -50 deg and rtctl steers the others to hold the line, so the commands spread by more than
50 deg while the rover drives straight. The diagnoses themselves are in
``tests/bench/bench_drive_discrepancy.py`` (groups ``sparse``, ``sparse_negatives``).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from offline.discrepancy.drive.diagnosis import DriveModel, DriveRecording, load_drives
from offline.discrepancy.drive.synthetic import REALISTIC_SENSORS, record_drive
from offline.rover.scenario import load_scenario
from offline.sim.sensors import SensorConfig
from offline.sim.truth import Truth

ROOT = Path(__file__).resolve().parents[1]
SPARSE = {"pose_period": 10.0, "torque_noise": math.nan}
"""A pose fix every 10 s, no motor torques (``Measurements.motor_torque`` None)."""


def _operational_drive(path: Path, sensors: SensorConfig) -> Path:
    """README's main job (``offnominal drive``): rr_steer_stuck_50, rtctl on the shipped tables, 1.5 m."""
    from rtctl.recording import Recorder

    from offline.sim.experiments import build_controller, run_drive, scenario_by_name
    from offline.sim.rtctl_bridge import rtctl_factory
    from offline.sim.simulator import RoverSimulator

    sc = scenario_by_name("rr_steer_stuck_50")
    ctl = build_controller("rtctl", sc, rtctl_factory=rtctl_factory(None, None))
    sim = RoverSimulator(sc, Truth.nominal(sc.params, sc.rover), sensors=sensors, dt=0.1, seed=3)
    with Recorder(path, {"scenario": sc.name, "seed": 3}, truth=True) as rec:
        r = run_drive(sim, ctl, distance=1.5, recorder=rec, name="rtctl")
    assert not r.stuck, r.stuck
    return path


def test_sparse_closed_loop_drive_is_straight_and_advice_asks_for_every_manoeuvre(tmp_path):
    from offline.sim.experiments import scenario_by_name

    sc = scenario_by_name("rr_steer_stuck_50")
    f = _operational_drive(tmp_path / "op.mcap", replace(SensorConfig(), **SPARSE))
    d = load_drives([f])[0]
    assert not any(k.startswith("torque_") for k in d.readings)  # absent, not zero
    assert d.heading_source.startswith("gyro integration")
    obs = DriveRecording.build([d], DriveModel(sc), 5)
    assert not any(c.startswith("torque_") or c in ("dx_body", "dy_body", "dheading") for c in obs.channels)
    have = obs.manoeuvres()
    duration = float(d.t[-1])
    # rtctl held the rover on its straight line: no turn, crab or reverse (the old command-based
    # count made the whole drive a turn: the stuck wheel's -50 deg against the others' +3 to +23 deg)
    assert have["turn"] == 0.0 and have["crab"] == 0.0 and have["reverse"] == 0.0, have
    assert have["straight"] >= 0.9 * duration, have
    advice = obs.identification_advice()
    for wanted in ("turn", "crabs", "reverse"):
        assert wanted in advice, advice


def test_sparse_calibration_drive_still_shows_its_manoeuvres(tmp_path):
    sc = load_scenario(ROOT / "offline/scenarios/nominal.toml")
    f = record_drive(tmp_path / "cal.mcap", sc, Truth.nominal(sc.params, sc.rover), seed=3, duration=40.0,
                     sensors=replace(REALISTIC_SENSORS, **SPARSE))
    d = load_drives([f])[0]
    assert d.heading_source.startswith("gyro integration")
    obs = DriveRecording.build([d], DriveModel(sc), 5)
    have = obs.manoeuvres()
    # 40 s compression of the 70 s script: Ackermann turns 12.6 s, crabs 11.4 s, reverse 4.6 s
    assert have["turn"] >= 8.0 and have["crab"] >= 8.0 and have["reverse"] >= 2.0, have
    assert "already has every calibration manoeuvre" in obs.identification_advice()
