"""The simulator's disturbance hook (contract C5): ``None`` is bit for bit a zero disturbance (runs of the
same process), and the forces act as physics says (drawbar pull, yaw moment, hub drag on a servoed and an unpowered wheel)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from offline.rover.primitives import solve_primitive
from offline.rover.scenario import example_scenarios, load_scenario
from offline.sim import DisturbanceForces
from offline.sim.plant import DISTURBANCE_NAMES, GRAVITY
from offline.sim.sensors import SensorConfig
from offline.sim.simulator import DisturbanceError, RoverSimulator
from offline.sim.truth import Truth
from rtctl.messages import Commands

WHEELS = ("FR", "FL", "RR", "RL")
SCEN = {p.stem: p for p in example_scenarios()}

# The runs the hook must not change: 2 s of measurements and truth, seed 5, primitive commands,
# the later additions switched to their old behaviour (no gyro bias walk, no wheel spin inertia).
# They are compared with runs made in the same process (no hashes of floating-point runs from
# another machine: another CPU or compiler does not reproduce those bits).
LEGACY_SENSORS = SensorConfig(gyro_bias_walk=0.0)
RUNS = ("nominal", "rr_steer_stuck_50", "rl_unpowered", "rr_torque_limited")


def _cmd(prim):
    return Commands(0.0, 0, tuple(prim.wheels[k].rim_speed for k in WHEELS), tuple(prim.wheels[k].steer for k in WHEELS))


_PRIMS: dict[str, tuple] = {}


def _scenario(name):
    if name not in _PRIMS:
        sc = load_scenario(SCEN[name])
        _PRIMS[name] = (sc, solve_primitive(sc))
    return _PRIMS[name]


def _run(name, **kw) -> np.ndarray:
    """Measurements and truth of 2 s (10 ticks of 0.2 s), one row per tick."""
    sc, prim = _scenario(name)
    cmd = _cmd(prim)
    legacy = Truth.nominal(sc.params, sc.rover, wheel_inertia=0.0)
    sim = RoverSimulator(sc, legacy, seed=5, sensors=LEGACY_SENSORS, **kw)
    sim.start(cmd)
    rows = []
    for _ in range(10):
        m = sim.measure()
        sim.apply(cmd)
        sim.advance(0.2)
        ts = sim.truth_state()
        rows.append([m.t, *m.wheel_speed, *m.steer_angle, m.yaw_rate, m.roll, m.pitch, *(m.motor_torque or ()),
                     ts.x, ts.y, ts.heading, ts.u, ts.v, ts.yaw_rate, *ts.omega, *ts.sinkage, *ts.load, *ts.motor_torque])
    return np.asarray(rows, dtype=float)


@pytest.mark.parametrize("name", RUNS)
def test_no_disturbance_is_bit_for_bit_a_zero_disturbance(name):
    """``disturbance=None`` is the run without the hook, and a hook that returns zero forces adds
    exact zeros: the same bits, in the same process (any machine). A force of 1e-6 N changes the
    run, so the comparison can fail."""
    base = _run(name)
    assert np.array_equal(base, _run(name), equal_nan=True)  # deterministic
    assert np.array_equal(base, _run(name, disturbance=lambda t, s: DisturbanceForces()), equal_nan=True)
    nudged = _run(name, disturbance=lambda t, s: DisturbanceForces(body_force=(1e-6, 0.0)))
    assert not np.array_equal(base, nudged, equal_nan=True)


def _steady(name, truth=None, forces=None, seconds=2.0):
    sc, prim = _scenario(name)
    calls = []

    def hook(t, s):
        calls.append(t)
        return forces

    sim = RoverSimulator(sc, truth, seed=0, disturbance=None if forces is None else hook)
    sim.start(_cmd(prim))
    sim.advance(seconds)
    return sim, calls


def _body_forces(sim):
    """Wheel soil forces in the rover frame (4, 2) and yaw moments of each wheel about the CoM."""
    w = sim.sol.wrench
    st = np.asarray(sim.truth_state().steer)
    c, s = np.cos(st), np.sin(st)
    fx, fy = c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1]
    return fx, fy, w[:, 5]


def test_body_force_is_a_drawbar_pull_on_a_slope():
    truth = Truth.nominal(*(lambda sc: (sc.params, sc.rover))(_scenario("nominal")[0]), slope=math.radians(5.0))
    k = 1.0
    base, _ = _steady("nominal", truth)
    sim, calls = _steady("nominal", truth, DisturbanceForces(body_force=(-k, 0.0)))
    ts0, ts = base.truth_state(), sim.truth_state()
    # the hook runs at t = 0 (start) and at the start of every step, on the step's grid
    assert calls == pytest.approx([0.0] + [0.1 * i for i in range(20)], abs=1e-12)
    assert ts.disturbance == DisturbanceForces(body_force=(-k, 0.0))
    assert all(s1 > s0 + 1e-3 for s0, s1 in zip(ts0.slip, ts.slip))  # the wheels slip more to pull it
    assert ts.u < ts0.u
    fx, _, _ = _body_forces(sim)
    weight = sim.mass * GRAVITY
    assert fx.sum() + (-k) == pytest.approx(weight * math.sin(math.radians(5.0)), abs=1e-6 * weight)
    # the same as the truth's tether of k newtons
    teth, _ = _steady("nominal", replace(truth, tether_force=k))
    assert np.allclose(teth.truth_state().slip, ts.slip, rtol=0, atol=1e-8)  # Newton tolerance 1e-8
    assert np.allclose(teth.truth_state().load, ts.load, rtol=0, atol=1e-7 * weight)


def test_yaw_moment_turns_left_and_balances():
    base, _ = _steady("nominal")
    m = 0.05
    sim, _ = _steady("nominal", forces=DisturbanceForces(body_moment_z=m))
    ts = sim.truth_state()
    assert abs(base.truth_state().yaw_rate) < 1e-12
    assert ts.yaw_rate > 1e-4 and ts.heading > 0
    fx, fy, mz = _body_forces(sim)
    lr, wr = sim.scenario.rover.rocker_length, sim.scenario.rover.track_width
    xs, ys = np.array([lr, lr, -lr, -lr]) / 2, np.array([-wr, wr, -wr, wr]) / 2
    # steady turn: the wheels' yaw moment cancels the disturbance (implicit Euler, r settled)
    assert np.sum(mz + xs * fy - ys * fx) + m == pytest.approx(0.0, abs=1e-7 * sim.mass * GRAVITY * lr)


def test_wheel_force_on_the_right_wheel_turns_right():
    sim, _ = _steady("nominal", forces=DisturbanceForces(wheel_force=((-0.5, 0.0),) + ((0.0, 0.0),) * 3))
    ts = sim.truth_state()
    assert ts.yaw_rate < -1e-4
    fx, fy, mz = _body_forces(sim)
    weight = sim.mass * GRAVITY
    assert fx.sum() - 0.5 == pytest.approx(0.0, abs=1e-6 * weight)


def test_hub_drag_on_a_servoed_wheel_raises_its_motor_torque_only():
    base, _ = _steady("nominal")
    tau = 0.05
    sim, _ = _steady("nominal", forces=DisturbanceForces(wheel_torque=(tau, 0.0, 0.0, 0.0)))
    t0, t1 = base.truth_state(), sim.truth_state()
    assert t1.omega == pytest.approx(t0.omega, abs=1e-12)
    assert t1.motor_torque[0] - t0.motor_torque[0] == pytest.approx(tau, abs=1e-8)
    assert t1.motor_torque[1:] == pytest.approx(t0.motor_torque[1:], abs=1e-8)
    assert t1.slip == pytest.approx(t0.slip, abs=1e-10)


def test_hub_drag_slows_an_unpowered_wheel():
    base, _ = _steady("rl_unpowered")
    sim, _ = _steady("rl_unpowered", forces=DisturbanceForces(wheel_torque=(0.0, 0.0, 0.0, 0.02)))
    t0, t1 = base.truth_state(), sim.truth_state()
    assert t1.omega[3] < t0.omega[3] - 1e-3 * abs(t0.omega[3])
    assert t1.motor_torque[3] == pytest.approx(0.0, abs=1e-9)  # still no motor torque
    # the soil now drives the wheel against the drag: its axle moment equals the drag
    assert sim.sol.wrench[3, 4] == pytest.approx(0.02, abs=1e-8)


@pytest.mark.parametrize("kw", [dict(body_force=(math.nan, 0.0)), dict(body_force=(1.0,)),
                                dict(wheel_force=((0.0, 0.0, 0.0),) * 4), dict(wheel_force=()), dict(wheel_torque=()), dict(wheel_torque=(0.0, 0.0, "a", 0.0)),
                                dict(body_moment_z=math.inf)])
def test_bad_forces_are_clear_errors(kw):
    with pytest.raises(DisturbanceError, match="DisturbanceForces"):
        DisturbanceForces(**kw)


def test_per_wheel_forces_fit_the_wheel_count():
    """Per-wheel entries are one per wheel of the simulated rover (issue 23: a rover file's N); the
    default zeros fit any rover; the mini rover's vector is the 15 entries of DISTURBANCE_NAMES."""
    f = DisturbanceForces(body_force=(1.0, 2.0), wheel_force=((0.5, 0.0),) * 3)
    with pytest.raises(DisturbanceError, match="wheel_force has 3 entries; the simulated rover has 4 wheels"):
        f.vector()
    assert f.vector(3).tolist() == [1.0, 2.0, 0.0, 0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert DisturbanceForces(body_force=(1.0, 0.0)).vector(6).tolist() == [1.0] + [0.0] * 20
    assert len(DisturbanceForces().vector()) == len(DISTURBANCE_NAMES) == 15


def test_hook_must_return_forces():
    sc, prim = _scenario("nominal")
    sim = RoverSimulator(sc, disturbance=lambda t, s: (1.0, 0.0))
    with pytest.raises(DisturbanceError, match="expected DisturbanceForces"):
        sim.start(_cmd(prim))
    with pytest.raises(DisturbanceError, match="callable"):
        RoverSimulator(sc, disturbance=3.0)  # type: ignore[arg-type]


def test_truth_channel_serialises_the_forces():
    sim, _ = _steady("nominal", forces=DisturbanceForces(body_force=(-0.1, 0.02), wheel_torque=(0.01, 0, 0, 0)),
                     seconds=0.2)
    d = sim.truth_state().as_dict()
    assert d["disturbance"]["body_force"] == [-0.1, 0.02]
    assert d["disturbance"]["wheel_torque"] == [0.01, 0.0, 0.0, 0.0]
    assert sim.truth_state().v_x == sim.truth_state().u
