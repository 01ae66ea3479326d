"""Rover simulator: physics (steady state against the optimizer, force balance, symmetry,
failures), sensors and determinism. Short drives only (the full section 7.3 runs are in
tests/bench/bench_sim.py)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from offline.physics.terramechanics import WheelModel
from offline.rover.primitives import mirror_scenario, solve_primitive
from offline.rover.scenario import WheelFailure, example_scenarios, load_scenario
from offline.sim.plant import GRAVITY
from offline.sim.sensors import SensorConfig
from offline.sim.simulator import RoverSimulator, plant_for
from offline.sim.truth import Truth, TruthError, load_truth
from rtctl.messages import Commands

WHEELS = ("FR", "FL", "RR", "RL")
SCEN = {p.stem: p for p in example_scenarios()}

# The simulator derives its statics itself (offline.sim.plant); on flat ground with straight
# wheels they agree with the optimizer's (offline.rover.statics) to 1e-11 in slip and 1e-8 N in
# load (measured). With steered wheels the plan-view moment arms differ slightly (the simulator
# keeps the wheels at +-l_r/2, +-w_r/2 in the plan): 1.4e-4 in slip for the stuck primitive.
SLIP_TOL = 1e-8
SPEED_RTOL = 1e-9


@pytest.fixture(scope="module")
def nominal():
    sc = load_scenario(SCEN["nominal"])
    return sc, solve_primitive(sc)


def _cmd(prim, t=0.0, seq=0):
    return Commands(t, seq, tuple(prim.wheels[k].rim_speed for k in WHEELS), tuple(prim.wheels[k].steer for k in WHEELS))


def _drive(sim, cmd, seconds):
    sim.start(cmd)
    for _ in range(int(round(seconds / 0.2))):
        sim.measure()
        sim.apply(cmd)
        sim.advance(0.2)
    return sim.truth_state()


def test_nominal_drive_reaches_primitive_slip(nominal):
    sc, prim = nominal
    ts = _drive(RoverSimulator(sc, seed=3), _cmd(prim), 4.0)
    assert ts.u == pytest.approx(sc.speed, rel=SPEED_RTOL)
    assert abs(ts.v) < 1e-9 and abs(ts.yaw_rate) < 1e-9 and abs(ts.heading) < 1e-9
    for i, k in enumerate(WHEELS):
        assert ts.slip[i] == pytest.approx(prim.wheels[k].slip, abs=SLIP_TOL)
        assert ts.load[i] == pytest.approx(prim.wheels[k].load, rel=1e-7)
        assert ts.sinkage[i] == pytest.approx(prim.wheels[k].sinkage, rel=1e-7)


def test_stuck_primitive_drives_straight_and_uncompensated_drifts_right():
    sc = load_scenario(SCEN["rr_steer_stuck_50"])
    prim = solve_primitive(sc)
    ts = _drive(RoverSimulator(sc, seed=0), _cmd(prim), 6.0)
    assert ts.u == pytest.approx(sc.speed, rel=2e-3)
    assert ts.steer[2] == pytest.approx(math.radians(-50.0), abs=1e-12)
    nom = solve_primitive(replace(sc, failures={}))
    drift = _drive(RoverSimulator(sc, seed=0), _cmd(nom), 6.0)
    assert drift.y < -1e-3  # the outward-pointing right rear wheel pushes the rover right (section 7.3.3)
    # the primitive cancels the yaw of the stuck wheel to within the statics' differences (moment arms)
    assert abs(ts.yaw_rate) < 0.05 * abs(drift.yaw_rate) and abs(ts.y) < 0.05 * abs(drift.y)


def test_steady_state_force_balance_with_independent_numpy_model():
    """Slope, cross-slope and tether: the wheel forces from the numpy model (not the compiled
    path) balance gravity and the tether, and the loads carry the normal weight."""
    sc = load_scenario(SCEN["nominal"])
    prim = solve_primitive(sc)
    truth = Truth.nominal(sc.params, sc.rover, slope=math.radians(3.0), cross_slope=math.radians(2.0), tether_force=1.0)
    sim = RoverSimulator(sc, truth, seed=0)
    sim.start(_cmd(prim))
    z, sol = sim.z, sim.sol
    model = WheelModel(sc.params.soil, sc.params.wheel, sc.params.tuning, sim.plant.options)
    lr, wr = sc.rover.rocker_length, sc.rover.track_width
    xs, ys = np.array([lr, lr, -lr, -lr]) / 2, np.array([-wr, wr, -wr, wr]) / 2
    steer = sim.act.steer
    c, s = np.cos(steer), np.sin(steer)
    vxr, vyr = z[0] - z[2] * ys, z[1] + z[2] * xs
    w = model.wrench(c * vxr + s * vyr, -s * vxr + c * vyr, sol.omega, sol.sinkage, sol.sinkage_zero_slip).as_array()
    fx, fy = c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1]
    W = sim.weight
    gX, gY = -W * math.sin(truth.slope), -W * math.cos(truth.slope) * math.sin(truth.cross_slope)
    m, u, v, r = sim.mass, z[0], z[1], z[2]  # steady turning: the centripetal term remains
    assert abs(fx.sum() + gX - truth.tether_force + m * r * v) < 1e-6 * W
    assert abs(fy.sum() + gY - m * r * u) < 1e-6 * W
    assert abs(np.sum(w[:, 5] + xs * fy - ys * fx)) < 1e-6 * W * lr
    assert abs(w[:, 2].sum() - W * math.cos(truth.slope) * math.cos(truth.cross_slope)) < 1e-6 * W
    # the cross-slope pushes the rover's left (uphill) wheels' load onto the right ones
    assert sol.wrench[0, 2] + sol.wrench[2, 2] > sol.wrench[1, 2] + sol.wrench[3, 2]


def test_mirror_symmetry():
    sc = load_scenario(SCEN["rr_steer_stuck_50"])
    prim = solve_primitive(replace(sc, failures={}))  # uncompensated: the rover curves
    a = _drive(RoverSimulator(sc, seed=0), _cmd(prim), 3.0)
    b = _drive(RoverSimulator(mirror_scenario(sc), seed=0), _cmd(prim), 3.0)
    assert abs(a.y) > 1e-4
    assert b.y == pytest.approx(-a.y, rel=1e-6)
    assert b.heading == pytest.approx(-a.heading, rel=1e-6)
    assert b.x == pytest.approx(a.x, rel=1e-9)
    for i, j in ((0, 1), (2, 3)):
        assert b.slip[j] == pytest.approx(a.slip[i], abs=1e-8)
        assert b.load[j] == pytest.approx(a.load[i], rel=1e-7)


def test_failures_act_on_the_plant(nominal):
    sc, prim = nominal
    cap = replace(sc, failures={"RR": WheelFailure(rim_speed_max=0.015)})
    ts = _drive(RoverSimulator(cap, seed=0), _cmd(prim), 1.0)
    rs = sc.params.wheel.shearing_radius
    assert ts.omega[2] * rs == pytest.approx(0.015, rel=1e-9)
    assert ts.omega[0] * rs == pytest.approx(prim.wheels["FR"].rim_speed, rel=1e-9)
    locked = replace(sc, failures={"RL": WheelFailure(locked=True)})
    ts = _drive(RoverSimulator(locked, seed=0), _cmd(prim), 1.0)
    assert abs(ts.omega[3]) < 1e-15 and ts.slip[3] == pytest.approx(-1.0)
    free = replace(sc, failures={"RL": WheelFailure(unpowered=True)})
    ts = _drive(RoverSimulator(free, seed=0), _cmd(prim), 1.0)
    assert abs(ts.motor_torque[3]) < 1e-6 and 0 < ts.omega[3]  # an unpowered wheel turns freely under zero torque
    assert ts.slip[3] < 0.01  # dragged: it turns no faster than free rolling
    weak = replace(sc, failures={"FR": WheelFailure(torque_limit=0.03)})
    ts = _drive(RoverSimulator(weak, seed=0), _cmd(prim), 1.0)
    assert ts.motor_torque[0] == pytest.approx(0.03, rel=1e-6)
    assert ts.omega[0] * rs < prim.wheels["FR"].rim_speed


def test_truth_worn_wheel_turns_rover_and_slope_slows_it(nominal, tmp_path):
    sc, prim = nominal
    f = tmp_path / "truth.toml"
    f.write_text('[truth]\nslope_deg = 5.0\n\n[wheels.RR]\nradius_mm = 54.0\n')
    truth = load_truth(f, sc.rover)
    assert truth.wheel_radius[2] == pytest.approx(0.054) and truth.slope == pytest.approx(math.radians(5))
    worn = _drive(RoverSimulator(sc, Truth.nominal(sc.params, sc.rover, wheel_radius=(0.058, 0.058, 0.054, 0.058)),
                                 seed=0), _cmd(prim), 3.0)
    assert worn.heading < -1e-4  # the small right rear wheel is slower: the rover turns right
    up = _drive(RoverSimulator(sc, Truth.nominal(sc.params, sc.rover, slope=math.radians(5.0)), seed=0), _cmd(prim), 2.0)
    assert up.u < 0.97 * sc.speed and min(up.slip) > max(prim.wheels[k].slip for k in WHEELS)
    bad = tmp_path / "bad.toml"
    bad.write_text('[truth]\nslope_deg = 95.0\n')
    with pytest.raises(TruthError, match=r"bad.toml: \[truth\] slope_deg = 95.0 outside"):
        load_truth(bad, sc.rover)
    bad.write_text('[wheels.RR]\nradius_m = 0.05\n')
    with pytest.raises(TruthError, match=r"unknown key\(s\) \['radius_m'\]"):
        load_truth(bad, sc.rover)


def test_determinism_and_sensors(nominal):
    sc, prim = nominal
    cfg = SensorConfig(pose_period=1.0, pose_delay=0.4, pose_outage=(2.0, 3.5))

    def run(seed):
        sim = RoverSimulator(sc, sensors=cfg, seed=seed)
        sim.start(_cmd(prim))
        ms = []
        for _ in range(25):
            ms.append(sim.measure())
            sim.advance(0.2)
        return ms, sim.truth_state()

    a, ta = run(7)
    b, tb = run(7)
    c, tc = run(8)
    assert a == b and ta == tb  # bit for bit
    # the noise (and the gyro's bias walk) changes, the open-loop truth of the rover does not
    assert a != c and replace(ta, gyro_bias=0.0) == replace(tc, gyro_bias=0.0) and ta.gyro_bias != tc.gyro_bias
    poses = [(m.t, m.pose) for m in a if m.pose is not None]
    assert [round(p.t, 9) for _, p in poses] == [0.0, 1.0, 4.0]  # every 1 s, none taken in the outage
    assert all(t - p.t == pytest.approx(0.4) for t, p in poses)  # delivered 0.4 s after being taken
    gyro = np.mean([m.yaw_rate for m in a])
    assert gyro == pytest.approx(cfg.gyro_bias, abs=4 * cfg.gyro_noise / 5)


def test_plant_jacobian_matches_finite_differences(nominal):
    sc, prim = nominal
    sim = RoverSimulator(sc, seed=0)
    sim.start(_cmd(prim))
    rng = np.random.default_rng(0)
    z = sim.z + rng.normal(0, 1, 15) * np.r_[3e-3, 3e-3, 1e-2, 0.05 * np.ones(4), 0.05 * np.ones(8)]
    a = sim._inputs(10.0)
    a[12:16] = [0.2, -0.1, 0.3, 0.05]
    res, J, *_ = sim.plant.evaluate(z, a, sim.q)
    fd = np.zeros_like(J)
    for j in range(15):
        e = np.zeros(15)
        e[j] = 1e-7 * max(1e-2, abs(z[j]))
        fd[:, j] = (sim.plant.evaluate(z + e, a, sim.q)[0] - sim.plant.evaluate(z - e, a, sim.q)[0]) / (2 * e[j])
    # exact but for the rocker angle's dependence on sinkage (rows 4-6, log-sinkage columns)
    rows = [0, 1, 2, 3, 7, 8, 9, 10, 11, 12, 13, 14]
    assert np.abs(J[rows] - fd[rows]).max() < 1e-5 * np.abs(fd).max()
    assert np.abs(J - fd).max() < 2e-3 * np.abs(fd).max()


def test_plant_compiled_equals_interpreted(nominal):
    sc, prim = nominal
    comp = plant_for(sc.params, sc.rover, "classic", True)
    interp = plant_for(sc.params, sc.rover, "classic", False)
    sim = RoverSimulator(sc, seed=0)
    sim.start(_cmd(prim))
    a = sim._inputs(10.0)
    r1 = comp.evaluate(sim.z, a, sim.q)
    r2 = interp.evaluate(sim.z, a, sim.q)
    for x, y in zip(r1, r2):
        np.testing.assert_allclose(x, y, rtol=1e-9, atol=1e-12)
    assert sim.weight == pytest.approx(sc.rover.weight) and sim.mass == pytest.approx(sc.rover.weight / GRAVITY)


@pytest.mark.parametrize("name, wheels, kind", [
    ("mer_nominal", ("RF", "LF", "RM", "LM", "RR", "LR"), "SuspensionPlant"),
    ("skid_nominal", ("FR", "FL", "RR", "RL"), "SuspensionPlant"),
])
def test_a_rover_file_scenario_gets_its_own_wheels_and_plant(name, wheels, kind):
    """A rover-file scenario (six-wheel rocker-bogie, four-wheel skid-steer) is simulated on its
    own suspension's plant with the file's wheel set (issue 23; before, it was refused at
    construction, and before that it ran on the four-wheel rocker's plant and failed with "no
    equilibrium"); it takes a disturbance hook (refused before the rover-file plant had one;
    its physics: tests/test_sim_any_rover.py). The closed loops are in tests/test_sim_any_rover.py."""
    from pathlib import Path

    sc = load_scenario(Path(__file__).resolve().parents[1] / "offline" / "scenarios" / "rovers" / f"{name}.toml")
    sim = RoverSimulator(sc)
    assert sim.wheels == wheels and type(sim.plant).__name__ == kind and sim.z.shape == (3 + 3 * len(wheels),)
    assert sim.weight == pytest.approx(sc.rover_file.weight, rel=1e-12)
    hook = RoverSimulator(sc, disturbance=lambda t, s: None).disturbance  # a rover file's plant takes a hook (issue 23)
    assert hook is not None and hook(0.0, None) is None
