"""The drive discrepancy tool's hook candidates and empirical terms on a rover file (issue 23).

Before this file's change the library's hub contact and anchored tether were left out of a rover
file's library (their re-simulation built the mini rover's four-wheel hook), the empirical search
was switched off on a rover file's recording, a truth file's per-wheel ``[[empirical_force]]`` was
refused there, the force bounds were the mini rover's (a drawbar pull of at most 10 N on a
646 N rover) and the accepted truth file named ``params = "dissertation-ch7"`` whatever the
believed rover's wheels were.

The effects are concealed HERE, by this module's own code (not the library's formulas): a hub face
bulldozing soil at each of the MER-class rover's six wheels (Rankine passive pressure written out
below), a cable to an anchor fixed in the terrain (a constant tension toward a world point), and a
3 N m drag resisting the left-middle wheel's spin. What the tool is told: the recording and the
believed scenario.

Budget: three short straight drives of the six-wheel rover, one of them backward (10 s, the fewest
rows the held-out test takes; the open-loop stride skips steady ticks), the re-simulations at the
concealed values, and one diagnosis with a one-term library and the empirical search (the report's
plots skipped): about 7 CPU-s in all, one process.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from offline.discrepancy.drive.candidates import (
    DRIVE_CANDIDATES,
    AnchoredTether,
    Hooks,
    HubContact,
    RoverExtension,
    disturbance_from_terms,
    wheel_plan_positions,
)
from offline.discrepancy.drive.diagnosis import DriveModel, DriveRecording, diagnose_drives, load_drives
from offline.discrepancy.drive.synthetic import REALISTIC_SENSORS, DriveSegment, record_drive
from offline.discrepancy.drive.wheel_set import library_for, truth_disturbance
from offline.rover.scenario import load_scenario
from offline.sim.simulator import DisturbanceForces, TruthState
from offline.sim.truth import load_truth

ROOT = Path(__file__).resolve().parents[1]
ROVERS = ROOT / "offline" / "scenarios" / "rovers"
MER = load_scenario(ROVERS / "mer_nominal.toml")
MER_BACK = load_scenario(ROVERS / "mer_nominal_backward.toml")
MINI = load_scenario(ROOT / "offline" / "scenarios" / "nominal.toml")
SPEED = 0.03  # m/s
DURATION = 10.0  # s: 10 rows of 5 ticks
HUB = (0.005, 0.10, 0.05)  # clearance, face width, arm (m): the MER wheels sink about 14 mm
TENSION, ANCHOR = 30.0, 20.0  # N; the anchor 20 m behind the start
LM_DRAG = 3.0  # N m resisting the left-middle wheel's spin


def _sensors():
    """REALISTIC_SENSORS with the torque noise scaled by weight x wheel radius (as
    ``tests/test_drive_discrepancy_any_rover.py``)."""
    scale = (MER.rover_file.weight * MER.params.wheel.radius) / (MINI.rover.weight * MINI.params.wheel.radius)
    return replace(REALISTIC_SENSORS, torque_noise=REALISTIC_SENSORS.torque_noise * scale)


def _rankine(sinkage: float, clearance: float, width: float) -> float:
    """Passive earth pressure on a vertical face of ``width`` submerged ``sinkage - clearance``:
    ``b (gamma K_p e^2 / 2 + 2 c sqrt(K_p) e)``, ``K_p = tan^2(45 deg + phi / 2)`` (this module's own)."""
    soil = MER.params.soil
    kp = math.tan(math.pi / 4 + soil.friction_angle / 2) ** 2
    e = max(sinkage - clearance, 0.0)
    return width * (soil.unit_weight * kp * e * e / 2 + 2 * soil.cohesion * math.sqrt(kp) * e)


def _concealed_world(t: float, s: TruthState) -> DisturbanceForces:
    """Hub faces at the six wheels (drag against each contact's travel, torque F arm against its
    spin) and a cable pulling toward a point ``ANCHOR`` m behind the start (world frame, turned into
    the body frame)."""
    clearance, width, arm = HUB
    wf, tq = [], []
    for i, w in enumerate(MER.rover_file.wheels):
        f = _rankine(s.sinkage[i], clearance, width)
        vx, vy = s.u - s.yaw_rate * w.position[1], s.v + s.yaw_rate * w.position[0]
        n = math.hypot(vx, vy)
        wf.append((-f * vx / n, -f * vy / n))
        tq.append(f * arm * math.copysign(1.0, s.omega[i]))
    dx, dy = -ANCHOR - s.x, -s.y  # toward the anchor
    d = math.hypot(dx, dy)
    c, sn = math.cos(s.heading), math.sin(s.heading)
    fx, fy = TENSION * (c * dx + sn * dy) / d, TENSION * (-sn * dx + c * dy) / d
    return DisturbanceForces(body_force=(fx, fy), wheel_force=tuple(wf), wheel_torque=tuple(tq))


def _lm_drag(t: float, s: TruthState) -> DisturbanceForces:
    i = MER.wheels.index("LM")
    return DisturbanceForces(wheel_force=((0.0, 0.0),) * 6,
                             wheel_torque=tuple(LM_DRAG * math.copysign(1.0, s.omega[i]) if j == i else 0.0 for j in range(6)))


def _straight(tmp_path: Path, name: str, hook, seed: int) -> Path:
    return record_drive(tmp_path / f"{name}.mcap", MER, seed=seed, duration=DURATION, sensors=_sensors(), disturbance=hook,
                        segments=(DriveSegment(0.0, DURATION, (SPEED,) * 6, (0.0,) * 6, "straight"),))


def _state(**kw) -> TruthState:
    z = (0.0,) * 6
    base = dict(t=0.0, x=0.0, y=0.0, heading=0.0, u=SPEED, v=0.0, yaw_rate=0.0, omega=(0.2,) * 6, steer=z,
                sinkage=(0.014,) * 6, load=z, slip=z, slip_angle=z, motor_torque=z, travelled=0.0)
    return TruthState(**{**base, **kw})


def test_the_hooks_act_at_a_rover_files_wheels():
    """The hub contact at the MER-class file's six wheels is this module's Rankine drag, against each
    contact's travel (a yaw rate turns it), with the torque ``F arm`` against the spin; two hooks add on
    six wheels; a backward drive's anchored tether pulls the same way in the world (its plant frame is
    turned by pi). The library keeps both hook candidates on the file's channels, with the force bounds
    scaled by the weight ratio (the mini rover's +-10 N drawbar pull is +-188 N on the 646 N rover)."""
    sinkage = (0.014, 0.015, 0.013, 0.016, 0.012, 0.0)
    s = _state(sinkage=sinkage, yaw_rate=0.01, omega=(0.2, 0.2, 0.2, 0.2, 0.2, -0.2))
    hub = HubContact(*HUB, MER.params.soil, MER.rover_file)(0.0, s)
    xy = wheel_plan_positions(MER.rover_file)
    assert xy.shape == (6, 2) and xy[MER.wheels.index("LM"), 1] > 0.0  # left is +y
    for i, w in enumerate(MER.rover_file.wheels):
        f = _rankine(sinkage[i], HUB[0], HUB[1])
        vx, vy = s.u - s.yaw_rate * w.position[1], s.v + s.yaw_rate * w.position[0]
        assert hub.wheel_force[i] == pytest.approx((-f * vx / math.hypot(vx, vy), -f * vy / math.hypot(vx, vy)), rel=2e-3, abs=1e-9)
        assert hub.wheel_torque[i] == pytest.approx(f * HUB[2] * math.copysign(1.0, s.omega[i]), rel=2e-3, abs=1e-9)
    assert hub.wheel_force[5] == (0.0, 0.0) and hub.wheel_force[0][0] < -1.0
    ext = RoverExtension(terms={"hub_clearance": HUB[0], "hub_face_width": HUB[1], "hub_arm": HUB[2],
                                "anchor_tension": TENSION, "anchor_bearing": math.pi, "anchor_inverse_distance": 0.0,
                                "anchor_attach_x": -0.3})
    both = disturbance_from_terms(ext, MER.params, MER.rover_file)
    assert isinstance(both, Hooks) and both.wheels == 6
    f = both(0.0, s)
    assert f.wheel_torque == pytest.approx(hub.wheel_torque, rel=1e-12)
    assert f.body_force == pytest.approx((-TENSION, 0.0), abs=1e-9)
    # backward: the plant's heading is the recorded body heading + pi; the pull is the same world vector
    forward = disturbance_from_terms(ext, MER.params, MER.rover_file, lambda t: (0.0, 0.0, 0.3))(0.0, s)
    back = disturbance_from_terms(ext, MER.params, MER_BACK.rover_file, lambda t: (0.0, 0.0, 0.3))(0.0, s)
    assert back.body_force == pytest.approx((-forward.body_force[0], -forward.body_force[1]), rel=1e-12)
    assert back.body_moment_z == pytest.approx(forward.body_moment_z, rel=1e-12)
    assert isinstance(disturbance_from_terms(RoverExtension(terms={"anchor_tension": 1.0}), MER.params, MER.rover_file),
                      AnchoredTether)
    lib = {c.key: c for c in library_for(DRIVE_CANDIDATES, MER)}
    mini = {c.key: c for c in DRIVE_CANDIDATES}
    assert "torque_LR" in lib["hub_contact"].channels and "torque_FR" not in lib["hub_contact"].channels
    ratio = MER.rover.weight / MINI.rover.weight
    assert lib["tether"].params[0][2:4] == pytest.approx((-10.0 * ratio, 10.0 * ratio), rel=1e-12)
    assert lib["tether_anchor"].params[0][3] == pytest.approx(10.0 * ratio, rel=1e-12)
    assert lib["hub_contact"].params[0] == mini["hub_contact"].params[0]  # the clearance: a depth, not scaled
    assert lib["terrain_slope"].params == mini["terrain_slope"].params
    assert library_for(tuple(lib.values()), MER) == tuple(lib.values())  # idempotent: not scaled twice
    assert library_for(DRIVE_CANDIDATES, MINI) == DRIVE_CANDIDATES


def test_the_hook_candidates_re_simulate_a_six_wheel_world(tmp_path):
    """A straight drive of the MER-class rover in this module's world (hub faces at the six wheels and
    an anchored cable): the hub-contact and anchored-tether terms at the concealed values re-simulate it
    to the noise (residual chi-square within 25 % of its 180 values), while the believed model misses it
    by far and neither term alone reaches it."""
    path = _straight(tmp_path, "hub_and_cable", _concealed_world, seed=4)
    model = DriveModel(MER)
    obs = DriveRecording.build(load_drives([path], model.sensors.gyro_bias), model, 5)
    hub = {"hub_clearance": HUB[0], "hub_face_width": HUB[1], "hub_arm": HUB[2]}
    cable = {"anchor_tension": TENSION, "anchor_bearing": math.pi, "anchor_inverse_distance": 1.0 / ANCHOR}

    def chi2(terms):
        pred, ok = model.predict(obs, RoverExtension(terms=terms) if terms else None)
        assert ok.all()
        return float(sum(np.sum(((obs.measured[c] - pred[c]) / obs.noise[c]) ** 2) for c in obs.channels))

    n = len(obs) * len(obs.channels)
    both = chi2({**hub, **cable})
    assert abs(both / n - 1.0) < 0.25, (both, n)
    assert chi2({}) > 3.0 * n and chi2(hub) > 1.5 * both and chi2(cable) > 1.5 * both


def _cable_behind_the_travel(t: float, s: TruthState) -> DisturbanceForces:
    """A cable to a point ``ANCHOR`` m behind the start in the plant's frame (a backward drive's travel
    frame: behind the travel is ahead of the body), turned into the plant's body frame."""
    dx, dy = -ANCHOR - s.x, -s.y
    d = math.hypot(dx, dy)
    c, sn = math.cos(s.heading), math.sin(s.heading)
    return DisturbanceForces(body_force=(TENSION * (c * dx + sn * dy) / d, TENSION * (-sn * dx + c * dy) / d))


def test_the_anchored_tether_re_simulates_a_backward_six_wheel_drive(tmp_path):
    """Driving backward (the plant in the travel frame, the recording in the body frame): a cable to an
    anchor behind the travel -- ahead of the body, bearing 0 from the recorded start heading -- is
    re-simulated by the anchored-tether term to the noise; the same term at bearing 180 deg (the
    body's behind, which a plant-frame hook without the half turn would pull toward) misses by far."""
    path = record_drive(tmp_path / "back.mcap", MER_BACK, seed=6, duration=DURATION, sensors=_sensors(),
                        disturbance=_cable_behind_the_travel,
                        segments=(DriveSegment(0.0, DURATION, (-SPEED,) * 6, (0.0,) * 6, "straight backward"),))
    model = DriveModel(MER_BACK)
    obs = DriveRecording.build(load_drives([path], model.sensors.gyro_bias), model, 5)
    n = len(obs) * len(obs.channels)

    def chi2(bearing):
        ext = RoverExtension(terms={"anchor_tension": TENSION, "anchor_bearing": bearing,
                                    "anchor_inverse_distance": 1.0 / ANCHOR})
        pred, ok = model.predict(obs, ext)
        assert ok.all()
        return float(sum(np.sum(((obs.measured[c] - pred[c]) / obs.noise[c]) ** 2) for c in obs.channels))

    right = chi2(0.0)
    assert abs(right / n - 1.0) < 0.25, (right, n)
    assert chi2(math.pi) > 3.0 * n


def test_an_empirical_term_names_a_six_wheel_rovers_hub_drag(tmp_path, monkeypatch):
    """A 3 N m drag on the left-middle wheel's spin (no library term; the one-term library explains
    nothing): the empirical search, run on the rover file's wheels, names ``torque.LM`` throughout the
    drive within 10 % of 3 N m. The report's accepted truth names the rover file's own wheel parameter
    file (``mer_class_wheel.toml``, relative to the report folder) and carries the term on ``LM``;
    ``load_truth`` reads it back with the believed parameter set, and its hook drags that wheel.
    (The report's plots are skipped: two thirds of this test's CPU time, and not what it checks.)"""
    import offline.discrepancy.drive.report as drive_report
    import offline.discrepancy.report as report

    monkeypatch.setattr(report, "residual_plots", lambda v, out: [])
    monkeypatch.setattr(drive_report, "_drive_plots", lambda v, out, ext: [])

    path = _straight(tmp_path, "lm_drag", _lm_drag, seed=4)
    lib = [c for c in library_for(DRIVE_CANDIDATES, MER) if c.key == "wheel_radius_all"]
    v = diagnose_drives([path], MER, segment=5, candidates=lib, recalibrate=False, seed=4)
    assert v.status == "unexplained" and v.empirical is not None, v.summary()
    (term,) = v.empirical.terms
    assert (term.direction, term.where) == ("torque.LM", "everywhere"), v.empirical.summary_lines()
    assert term.magnitude == pytest.approx(LM_DRAG, rel=0.10)
    out = drive_report.write_drive_report(v, tmp_path / "report")
    text = (out / "accepted_truth.toml").read_text()
    data = tomllib.loads(text)
    ref = data["truth"]["params"]
    assert Path(ref).name == "mer_class_wheel.toml" and not Path(ref).is_absolute(), text
    assert (out / ref).resolve() == (ROOT / "rtctl" / "physics" / "rovers" / "mer_class_wheel.toml").resolve()
    assert data["empirical_force"][0]["direction"] == "torque.LM"
    back = load_truth(out / "accepted_truth.toml", MER.rover_file)
    assert back.params == MER.params
    hook = truth_disturbance(back, MER)
    f = hook(0.0, _state())
    i = MER.wheels.index("LM")
    assert f.wheel_torque[i] == pytest.approx(term.magnitude, rel=2e-3)  # the hook's sign is smoothed over 0.01 rad/s
    assert sum(abs(x) for j, x in enumerate(f.wheel_torque) if j != i) == 0.0


def test_the_accepted_truth_names_the_believed_parameter_set(tmp_path):
    """``params_reference`` names the set the diagnosis believed, so ``load_truth`` reads it back: a
    preset by name (the mini rover's ``dissertation-ch7``, a shipped file's ``calibrated-sand``), a
    rover file's wheel parameter file by its path from the report folder, and a set no file holds (a
    scenario's grouser override) as a copy beside the truth file; a parameter file the command line
    gave by its path. (Before: ``dissertation-ch7`` whatever the believed set; the command line's
    file by its bare name.)"""
    from types import SimpleNamespace

    from offline.discrepancy.drive.report import BELIEVED_PARAMS, params_reference

    out = tmp_path / "report"
    out.mkdir()
    sand = tmp_path / "sand.toml"
    sand.write_text('[scenario]\nname = "sand"\nparams = "calibrated-sand"\nspeed_m_s = 0.03\n')
    zeta = tmp_path / "zeta.toml"
    zeta.write_text('[scenario]\nname = "zeta"\nparams = "dissertation-ch7"\nspeed_m_s = 0.03\ngrouser_volume_fraction = 0.3\n')
    for sc, expected in ((MINI, "dissertation-ch7"), (load_scenario(sand), "calibrated-sand"),
                         (MER, None), (load_scenario(zeta), BELIEVED_PARAMS)):
        ref = params_reference(SimpleNamespace(params=sc.params, scenario=sc), out)
        if expected is None:
            assert Path(ref).name == "mer_class_wheel.toml" and not Path(ref).is_absolute()
        else:
            assert ref == expected
        truth = out / "accepted_truth.toml"
        truth.write_text(f'[truth]\nparams = "{ref}"\n')
        back = load_truth(truth, sc.rover_file or sc.rover).params
        if ref == BELIEVED_PARAMS:  # written in the file format's units: equal to its rounding
            assert back.wheel.grouser_volume_fraction == pytest.approx(0.3, rel=1e-12)
            assert back.soil.k == pytest.approx(sc.params.soil.k, rel=1e-9)
        else:
            assert back == sc.params
    # a parameter file given on the command line (offnominal discrepancy --params FILE): named by its path from the report
    from offline.physics.params import load_toml

    given = tmp_path / "my_wheel.toml"
    given.write_text((ROOT / "rtctl" / "physics" / "rovers" / "mer_class_wheel.toml").read_text())
    told = load_toml(given)["parameter_set"]
    ref = params_reference(SimpleNamespace(params=told, scenario=MINI), out, str(given))
    assert ref == "../my_wheel.toml"
