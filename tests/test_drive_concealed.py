"""The drive discrepancy tool on concealed effects generated independently of its candidates (issue 14).

What the tool is told: the MCAP recording (commands, encoders, gyro, IMU tilt, motor torque,
pose fixes) and the believed scenario (nominal mini rover, flat, nominal soil). What it is NOT
told: which effect was concealed, its size, the noise levels, the ``/sim/truth`` channel.
The effects come from ``tests/concealed_effects.py``: forces through the simulator's
disturbance hook (contract C5), a misaligned steering encoder in the actuator and sensor
paths, IMU tilt computed from a terrain normal -- none of it goes through the plant inputs
(``Truth.cross_slope``, ``tether_force``, ``steer_offset``) that the candidates set, and each
has another functional form than the candidate that should name it (a plane given by its
normal; a cable to a fixed anchor whose pull turns with the heading; an encoder offset
passed through the servo's rate limits).

Budget: the tests run 24 s drives (32 s for the steering encoder: the crabs that separate the
front wheels need that long) against a library of eight candidates (the expected ones and
their confounders: IMU mounting tilt vs slope, a drawbar pull vs an anchored tether vs soil vs a
worn wheel, the other front wheel's steering), without the soil recalibration. The anchored
tether (five parameters: about 45 % of a diagnosis's re-simulations) is in the library where it
is a confounder -- the tether case -- and left out of the terrain plane, hub drag and
undulation cases (``LIBRARY_NO_ANCHOR``; the steering case has its own four, ``LIBRARY_STEER``): there the constant drawbar pull stays as the tether
look-alike, and with or without it these cases get the same verdict and the same values (checked
when the split was made; for the plane, 2026-11-27: held-out chi2 34477 believed, 210.6
terrain_slope, 34137 the anchored tether -- its pull of fixed world direction cannot tilt the
IMU -- the same slope and cross slope to the printed digits, 136 -> 82 re-simulations). The hub drag
and undulation cases also leave out the front steering offsets (``LIBRARY_NO_STEER``), and the
undulation drive is 16 s (2026-11-28, suite budget: both verdicts as before). The full
library, 40 s drives, every case, two effects at once and 20 negative seeds are in
``tests/bench/bench_drive_discrepancy.py``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from concealed_effects import (
    HubDrag,
    SteeringEncoderMisaligned,
    TerrainPlane,
    TetherToAnchor,
    Undulation,
    gravity_and_tilt,
    record_concealed,
)
from offline.discrepancy.drive.candidates import DRIVE_CANDIDATES
from offline.discrepancy.drive.diagnosis import diagnose_drives, held_out_drives
from offline.discrepancy.drive.report import write_drive_report
from offline.discrepancy.drive.synthetic import CALIBRATION_SPEED, DriveSegment, record_drive
from offline.rover.scenario import load_scenario
from offline.sim.sensors import SensorConfig
from offline.sim.simulator import DisturbanceForces
from offline.sim.truth import Truth, load_truth
from rtctl.recording import read_recording

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("terrain_slope", "imu_tilt", "tether", "tether_anchor", "soil_stiffness", "wheel_radius_RR", "steer_offset_FL", "steer_offset_FR")
LIBRARY_NO_ANCHOR = tuple(k for k in LIBRARY if k != "tether_anchor")  # module notes: budget
LIBRARY_NO_STEER = tuple(k for k in LIBRARY_NO_ANCHOR if not k.startswith("steer_offset"))
"""The hub drag and undulation cases' look-alikes: a worn wheel, a soil change, a drawbar pull, a slope and an
IMU tilt (each a torque or pitch signal like theirs); the front steering offsets, which turn the rover and
leave RR's spin torque and the pitch alone, are the plane's and the steering case's confounders (suite budget,
2026-11-28)."""
LIBRARY_STEER = ("terrain_slope", "wheel_radius_RR", "steer_offset_FL", "steer_offset_FR")
"""The steering case's look-alikes: the other front wheel, a worn wheel and a cross slope (all turn the
rover). Without the IMU tilt, the tether and the soil (which do not) it got the same verdict and the
same digits (steer_offset_FL 2.951 +- 0.2268 deg, held-out chi2 488.3 -> 327.5), 17.5 -> 12.1 CPU-s
(2026-11-27, suite budget)."""
QUIET = SensorConfig(wheel_speed_noise=0, steer_noise=0, gyro_noise=0, tilt_noise=0, torque_noise=0, pose_noise_xy=0,
                     pose_noise_heading=0, gyro_bias_walk=0)
DURATION = 24.0


SC = load_scenario(ROOT / "offline/scenarios/nominal.toml")
NOMINAL = Truth.nominal(SC.params, SC.rover)


@pytest.fixture(scope="module")
def sc():
    return SC


def _diagnose(path, sc, seed, library=LIBRARY):
    lib = [c for c in DRIVE_CANDIDATES if c.key in library]
    # the library's verdicts are what these cases guard; the empirical stage that follows an unexplained
    # verdict is tested on its own effects in tests/test_drive_empirical.py
    return diagnose_drives([path], sc, segment=6, candidates=lib, recalibrate=False, empirical=False, seed=seed)


def _readings(path):
    r = read_recording(path)
    return np.array([[*m.motor_torque, m.yaw_rate, m.roll, m.pitch] for m in r.measurements])


# --------------------------------------------------------------------------- the generators' physics
def test_terrain_normal_gravity_and_tilt_match_the_plants_slope_formula():
    """Independent code, same physics: for planes of 1-10 deg with fall lines along the axes,
    the in-plane gravity and IMU tilt from the normal equal the plant's slope / cross-slope
    formula (gX = -W sin a, gY = -W cos a sin b, pitch = slope, roll = cross slope at heading 0);
    at heading 90 deg a pure cross slope reads as pitch; a 3-4-5 rotation of the body leaves
    |F| = W sin(inclination)."""
    w = 34.3
    for a in np.radians([1.0, 3.5, 10.0]):
        n_cross = np.array([0.0, -math.sin(a), math.cos(a)])  # fall line to the right: left side up
        fx, fy, roll, pitch = gravity_and_tilt(n_cross, 0.0, w)
        assert (fx, fy) == pytest.approx((0.0, -w * math.sin(a)), abs=1e-12)
        assert (roll, pitch) == pytest.approx((a, 0.0), abs=1e-12)
        fx, fy, roll, pitch = gravity_and_tilt(n_cross, math.pi / 2, w)
        assert (fx, fy) == pytest.approx((-w * math.sin(a), 0.0), abs=1e-12)
        assert (roll, pitch) == pytest.approx((0.0, a), abs=1e-12)
        n_up = np.array([-math.sin(a), 0.0, math.cos(a)])  # rises ahead
        fx, fy, roll, pitch = gravity_and_tilt(n_up, 0.0, w)
        assert (fx, fy, roll, pitch) == pytest.approx((-w * math.sin(a), 0.0, 0.0, a), abs=1e-12)
        fx, fy, _, _ = gravity_and_tilt(n_up, math.atan2(3, 4), w)
        assert math.hypot(fx, fy) == pytest.approx(w * math.sin(a), rel=1e-12)


def test_terrain_plane_drive_equals_the_plants_cross_slope_drive(sc, tmp_path):
    """A noise-free drive on TerrainPlane(3.5 deg, fall line to the right) through the hook and
    the sensor path reproduces the plant's own 3.5 deg cross slope: torques within 1 mN m (the
    hook cannot lower the normal load by cos 3.5 deg: 0.19 %), yaw rate within 1e-4 rad/s, IMU
    within 1e-5 rad, pose within 0.1 mm. So the generator is the right physics, not a look-alike
    tuned to the candidate."""
    a = record_drive(tmp_path / "plant.mcap", sc, replace(NOMINAL, cross_slope=math.radians(3.5)), seed=0, duration=12.0,
                     sensors=QUIET)
    b = record_concealed(tmp_path / "plane.mcap", sc, TerrainPlane(math.radians(3.5), math.radians(-90.0)), seed=0,
                         duration=12.0, sensors=QUIET)
    d = np.abs(_readings(a) - _readings(b)).max(axis=0)
    assert np.all(d[:4] < 1e-3) and d[4] < 1e-4 and np.all(d[5:] < 1e-5), d
    pa = np.array([[t["x"], t["y"]] for t in read_recording(a).truth])
    pb = np.array([[t["x"], t["y"]] for t in read_recording(b).truth])
    assert np.abs(pa - pb).max() < 1e-4
    assert np.abs(_readings(b)[:, 5]).min() > math.radians(3.0)  # the IMU does see the plane


def test_tether_to_anchor_force_and_moment():
    """Anchor straight behind at heading 0: a pure backward pull of the reel tension, no moment.
    Heading 90 deg (turned left): in the body frame
    the pull points mostly to +y (the world's -X), with yaw moment attach_x * F_y. Tension grows
    with the paid-out length at the reel stiffness."""
    t = TetherToAnchor(anchor=(-3.0, 0.0), attach=(-0.2, 0.0), tension0=2.0, stiffness=0.5)

    class S:
        x = y = heading = 0.0

    f = t.forces(0.0, S)
    assert f.body_force == pytest.approx((-2.0, 0.0)) and f.body_moment_z == pytest.approx(0.0)
    S.heading = math.pi / 2  # attachment at world (0, -0.2): cable to the anchor along (-3, 0.2)
    f = t.forces(0.0, S)
    L = math.hypot(3.0, 0.2)
    ten = 2.0 + 0.5 * (L - 2.8)
    # body x = world Y, body y = -world X
    assert f.body_force == pytest.approx((ten * 0.2 / L, ten * 3.0 / L), rel=1e-9)
    assert f.body_moment_z == pytest.approx(-0.2 * f.body_force[1])
    S.heading, S.x = 0.0, 1.0
    assert -t.forces(0.0, S).body_force[0] == pytest.approx(2.0 + 0.5 * 1.0)


def test_hub_drag_reaches_the_recorded_motor_torque(sc, tmp_path):
    """The hook's hub drag shows in the RR motor torque, and only there, by exactly the torque the
    simulator records as applied; that torque opposes the spin (negative while reversing) and is
    coulomb + k h of the sinkage at the start of the step (median within 1 % of the tick's h)."""
    hd = HubDrag("RR", coulomb=0.005, per_sinkage=3.0)
    a = record_drive(tmp_path / "n.mcap", sc, NOMINAL, seed=0, duration=6.0, sensors=QUIET)
    b = record_concealed(tmp_path / "h.mcap", sc, hd, seed=0, duration=6.0, sensors=QUIET)
    d = _readings(b) - _readings(a)
    tr = read_recording(b).truth
    applied = np.array([t["disturbance"]["wheel_torque"][2] for t in tr[1:]])
    assert np.abs(d[:, [0, 1, 3, 4, 5, 6]]).max() < 1e-12
    assert d[1:, 2] == pytest.approx(applied, abs=1e-9)
    h = np.array([t["sinkage"][2] for t in tr[1:]])
    om = np.array([t["omega"][2] for t in tr[1:]])
    assert np.all(np.sign(applied) == np.sign(om)) and (om < 0).any()
    assert np.median(np.abs(np.abs(applied) / (0.005 + 3.0 * h) - 1)) < 0.01


# --------------------------------------------------------------------------- diagnoses: in the library
def test_terrain_plane_is_named_terrain_slope(sc, tmp_path):
    """A plane of 3.5 deg whose fall line points 80 deg right of the start heading: named
    terrain_slope (not the IMU mounting tilt, which fits the roll alone), the cross slope within
    20 % and the along slope within 0.5 deg of the plane's gravity components at heading 0.
    The explanation holds on a held-out drive on the same plane (another noise seed): chi-square
    below a fifth of the believed model's. The report folder has the plots, verdict.json and a
    truth file the simulator reads back with the fitted cross slope. (This case replaced the
    plant-input cross slope of tests/test_drive_discrepancy.py, whose effect lived in the
    candidate's own code.)"""
    eff = TerrainPlane(math.radians(3.5), math.radians(-80.0))
    f = record_concealed(tmp_path / "plane.mcap", sc, eff, seed=4, duration=DURATION)
    v = _diagnose(f, sc, 1, LIBRARY_NO_ANCHOR)
    assert v.missing_physics == ["terrain_slope"], v.summary()
    vals = dict(zip(v.chosen.names, v.chosen.values))
    want = eff.expect()["terrain_slope"]
    assert vals["cross_slope"] == pytest.approx(want["cross_slope"], rel=0.2)
    assert abs(vals["slope"] - want["slope"]) < 0.5
    f2 = record_concealed(tmp_path / "plane2.mcap", sc, TerrainPlane(math.radians(3.5), math.radians(-80.0)), seed=104,
                          duration=DURATION)
    ho = held_out_drives(v, [f2])
    assert ho["chi2_after"] < 0.2 * ho["chi2_before"], ho
    out = write_drive_report(v, tmp_path / "report")
    for name in ("report.md", "verdict.json", "trajectory.png", "residuals_over_time.png", "accepted_truth.toml"):
        assert (out / name).is_file(), name
    back = load_truth(out / "accepted_truth.toml", sc.rover)
    assert math.degrees(back.cross_slope) == pytest.approx(vals["cross_slope"], rel=1e-4)


@pytest.fixture(scope="module")
def tether_case(sc, tmp_path_factory):
    eff = TetherToAnchor()
    f = record_concealed(tmp_path_factory.mktemp("tether") / "tether.mcap", sc, eff, seed=4, duration=DURATION)
    return eff, _diagnose(f, sc, 1)


def test_tether_to_a_fixed_anchor_is_named_tether(tether_case):
    """A spring-reel cable to an anchor 3 m behind the start (2 N, +0.5 N/m paid out): its pull
    turns with the heading through the drive's turns. A tether is the first term named: the
    anchored tether with its tension at the start within 20 % of the reel's and the anchor's
    bearing within 15 deg of straight behind, or the constant drawbar pull with its force within
    20 % of the mean backward pull the rover felt (then, if a second term is added for the
    cable's lateral pull, outside that form, the verdict must not claim a full explanation)."""
    eff, v = tether_case
    assert v.missing_physics[:1] in (["tether"], ["tether_anchor"]), v.summary()
    vals = dict(zip(v.chosen.names, v.chosen.values))
    want = eff.expect()["tether|tether_anchor"]
    if v.missing_physics[0] == "tether_anchor":
        assert vals["tension"] == pytest.approx(want["tension"], rel=0.2)
        assert abs(vals["bearing"] - 180.0) < 15.0
    else:
        assert vals["force"] == pytest.approx(want["force"], rel=0.2)
        if len(v.missing_physics) > 1:
            assert v.status == "partly_explained", v.summary()


def test_tether_to_a_fixed_anchor_gets_no_spurious_second_term(tether_case):
    """Nothing but a tether is named (the anchored tether follows the cable's turning pull, which a
    constant drawbar pull left to a spurious second term)."""
    _, v = tether_case
    assert v.missing_physics in (["tether"], ["tether_anchor"]), v.summary()


@pytest.fixture(scope="module")
def steering_case(sc, tmp_path_factory):
    # 32 s: on the 24 s drive the crabs last 10 s and FL / FR still fit the held-out segments
    # equally ('ambiguous', FL best); from 32 s the crabs separate them
    f = record_concealed(tmp_path_factory.mktemp("steer") / "steer.mcap", sc,
                         SteeringEncoderMisaligned("FL", math.radians(3.0)), seed=4, duration=32.0)
    return _diagnose(f, sc, 1, LIBRARY_STEER)


def test_misaligned_steering_encoder_is_named_a_front_steering_offset(steering_case):
    """The FL steering servo turns to commanded + 3 deg while its encoder reads the commanded
    angle: a front-wheel steering offset is named alone -- or, when FL and FR fit the held-out
    segments equally, the verdict is 'ambiguous' (nothing named) with both listed -- its size
    within 20 %, and the true wheel is either the one chosen or reported with it."""
    v = steering_case
    best = v.missing_physics if v.status != "ambiguous" else list(v.chosen.keys)
    assert len(best) == 1 and best[0] in ("steer_offset_FL", "steer_offset_FR"), v.summary()
    assert v.chosen.values[0] == pytest.approx(3.0, rel=0.2)
    assert "steer_offset_FL" in [best[0], *(s.label for s in v.indistinguishable)], v.summary()


def test_misaligned_steering_encoder_is_named_on_its_wheel(steering_case):
    """The chosen wheel is the misaligned one (FL), alone: the calibration drive's crabs both ways
    at 57 deg give an FL offset a yaw moment an FR offset does not have (and the reverse)."""
    assert steering_case.missing_physics == ["steer_offset_FL"], steering_case.summary()


# --------------------------------------------------------------------------- diagnoses: outside the library
def test_hub_drag_is_not_given_a_confident_name(sc, tmp_path):
    """Hub drag on RR rising with sinkage (about 0.03 N m, 3-4 segment noise units): no candidate
    has a torque on one wheel's spin with no force on the rover, so an honest verdict is
    unexplained, partly explained or ambiguous (nothing named) -- never 'explained' by a worn
    wheel or a soil change."""
    f = record_concealed(tmp_path / "hub.mcap", sc, HubDrag("RR"), seed=4, duration=DURATION)
    v = _diagnose(f, sc, 1, LIBRARY_NO_STEER)
    assert v.status in ("unexplained", "partly_explained", "ambiguous"), v.summary()


def test_terrain_undulation_is_not_called_agreement(sc, tmp_path):
    """Terrain height 3 mm sin(2 pi X / 0.3 m): the IMU pitch swings by +-3.6 deg (about 20 times
    its noise) and gravity pushes and pulls the rover along the path (16 s of the drive: the swings are
    that large). No candidate has this form
    (the mean slope is near zero), so the honest verdict is unexplained or partly explained --
    and never 'agree'."""
    f = record_concealed(tmp_path / "und.mcap", sc, Undulation(), seed=4, duration=16.0)
    v = _diagnose(f, sc, 1, LIBRARY_NO_STEER)
    assert v.status in ("unexplained", "partly_explained"), v.summary()


def test_pull_on_a_straight_drive_is_not_given_to_the_soil_alone(sc, tmp_path):
    """Issue 24, "never a confident wrong name": on a straight drive a constant drawbar pull and a
    softer soil both raise every wheel's slip and torque. The pull is written here as 0.5 N backwards
    at each wheel's contact (the simulator's per-wheel disturbance forces; the library's tether is
    one force at the body). The soil recalibration (five parameters) fits the held-out segments a
    little better than the tether (one parameter) -- it also absorbs where the tether's form differs
    -- and today's engine listed the recalibration alone. Both must be listed as fitting equally
    ('ambiguous', nothing named), with the manoeuvres to add."""
    def pull(t, s):
        return DisturbanceForces(wheel_force=((-0.5, 0.0),) * 4)

    straight = (DriveSegment(0.0, 70.0, (CALIBRATION_SPEED,) * 4, (0.0,) * 4, "straight"),)
    f = record_drive(tmp_path / "pull.mcap", sc, seed=4, duration=DURATION, disturbance=pull, segments=straight)
    lib = [c for c in DRIVE_CANDIDATES if c.key in ("tether", "soil_stiffness", "wheel_radius_RR")]
    v = diagnose_drives([f], sc, segment=6, candidates=lib, recalibrate=True, empirical=False, seed=1)
    assert v.status == "ambiguous" and v.missing_physics == [] and not v.parameters_off, v.summary()
    listed = {k for s in v.explanations for k in s.keys}
    assert "tether" in listed and {"recalibration", "soil_stiffness"} & listed, v.summary()
    assert "turn" in v.ambiguity and "reverse" in v.ambiguity, v.ambiguity


def test_drags_at_the_wheels_on_a_straight_drive_are_not_named_a_tether(sc, tmp_path):
    """Issue 24, "never a confident wrong name": Rankine hub faces at all four wheels, written here
    (passive pressure on a 30 mm face below a 2 mm clearance, a drag against each wheel's travel and a
    torque F x 5 mm against its spin), on a straight 12 s drive. The library's hub_contact is left
    out; its tether (one pull at the body) fits the drive as well as the drags do, and the engine
    before the identifiability rule named it with confidence ('explained: tether'). On a straight
    drive a pull at the body and drags at the wheels give the same body wrench: the verdict is
    'ambiguous', the per-wheel drag probe listed beside the tether, with the reverse leg and the turn
    that would separate them."""
    soil = sc.params.soil
    kp = math.tan(math.pi / 4 + soil.friction_angle / 2) ** 2
    xy = [(0.5 * sc.rover.rocker_length * sx, 0.5 * sc.rover.track_width * sy) for sx, sy in ((1, -1), (1, 1), (-1, -1), (-1, 1))]

    def faces(t, s):
        wf, tq = [], []
        for i, (x, y) in enumerate(xy):
            e = max(s.sinkage[i] - 0.002, 0.0)
            f = 0.03 * (soil.unit_weight * kp * e * e / 2 + 2 * soil.cohesion * math.sqrt(kp) * e)
            vx, vy = s.u - s.yaw_rate * y, s.v + s.yaw_rate * x
            n = math.sqrt(vx * vx + vy * vy + 1e-6)
            wf.append((-f * vx / n, -f * vy / n))
            tq.append(f * 0.005 * s.omega[i] / math.sqrt(s.omega[i] ** 2 + 1e-4))
        return DisturbanceForces(wheel_force=tuple(wf), wheel_torque=tuple(tq))

    straight = (DriveSegment(0.0, 70.0, (CALIBRATION_SPEED,) * 4, (0.0,) * 4, "straight"),)
    f = record_drive(tmp_path / "faces.mcap", sc, seed=4, duration=12.0, disturbance=faces, segments=straight)
    lib = [c for c in DRIVE_CANDIDATES if c.key in ("tether", "terrain_slope", "wheel_radius_all")]
    v = diagnose_drives([f], sc, segment=6, candidates=lib, recalibrate=False, empirical=False, seed=1)
    assert v.status == "ambiguous" and v.missing_physics == [], v.summary()
    listed = {k for s in v.explanations for k in s.keys}
    assert {"tether", "wheel_drag"} <= listed, v.summary()
    assert "reverse" in v.ambiguity and "turn" in v.ambiguity, v.ambiguity
