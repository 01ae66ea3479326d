"""Wheel spin inertia and the raised wheel in the simulator.

Inertia: a free (raised) wheel's servo step response is the analytic first-order lag while its
acceleration torque stays under the limit, and a ramp at ``T_limit / J`` joined to the lag when
not; an unpowered wheel knocked to half speed spins back up to its free-rolling speed without
overshoot (stable at dt 0.1 s), and the angular impulse of the soil and motor torques equals
the change of the wheel's angular momentum.

Raised wheel: zero load and no soil force on it, the other three loads carry the normal
weight, the roll and whole-rover pitch balances hold (checked with the independent free-body
balance of :mod:`offline.rover.statics`), and the loads agree with the optimizer's primitive.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from offline.rover.primitives import solve_primitive
from offline.rover.scenario import WheelFailure, example_scenarios, load_scenario
from offline.rover.statics import free_body_residuals
from offline.sim.actuators import ActuatorConfig, ActuatorError, Actuators
from offline.sim.plant import GRAVITY, default_wheel_inertia
from offline.sim.simulator import RoverSimulator
from offline.sim.truth import Truth
from rtctl.messages import Commands

WHEELS = ("FR", "FL", "RR", "RL")
SCEN = {p.stem: p for p in example_scenarios()}


def _cmd(prim):
    return Commands(0.0, 0, tuple(prim.wheels[k].rim_speed for k in WHEELS), tuple(prim.wheels[k].steer for k in WHEELS))


@pytest.fixture(scope="module")
def raised():
    sc = load_scenario(SCEN["fr_raised"])
    return sc, solve_primitive(sc)


@pytest.fixture(scope="module")
def unpowered():
    sc = load_scenario(SCEN["rl_unpowered"])
    return sc, solve_primitive(sc)


def _step_response(sc, prim, torque_limit, n, dt=0.01):
    """Step the raised FR wheel's rim-speed command from 0 to 0.3 m/s; wheel speeds and motor torques."""
    scn = replace(sc, failures={"FR": WheelFailure(raised=True, torque_limit=torque_limit)})
    sim = RoverSimulator(scn, seed=0, dt=dt)
    c0 = _cmd(prim)
    sim.start(c0)
    assert sim.sol.omega[0] == 0.0
    rim = (0.3,) + c0.rim_speed[1:]
    sim.apply(Commands(0.0, 1, rim, c0.steer_angle))
    om, tq = [0.0], [0.0]
    for _ in range(n):
        sim.step()
        om.append(float(sim.sol.omega[0]))
        tq.append(float(sim.motor[0]))
    return sim, np.array(om), np.array(tq), 0.3 / sc.params.wheel.shearing_radius


def test_free_wheel_servo_follows_the_first_order_lag(raised):
    sc, prim = raised
    sim, om, tq, target = _step_response(sc, prim, math.inf, 30)
    tau, dt, J = ActuatorConfig().wheel_lag, sim.dt, sim.truth.wheel_inertia
    t = dt * np.arange(len(om))
    assert om == pytest.approx(target * (1 - np.exp(-t / tau)), abs=1e-9 * target)
    # no soil on a raised wheel: the motor torque is the inertia's, J d(omega)/dt over each step
    assert tq[1:] == pytest.approx(J * np.diff(om) / dt, rel=1e-9, abs=1e-15)
    assert sim.truth_state().load[0] == 0.0


def test_free_wheel_at_its_torque_limit_ramps_then_follows_the_lag(raised):
    sc, prim = raised
    limit = 0.01  # N m, below the 0.03 N m the lag's first step would take
    sim, om, tq, target = _step_response(sc, prim, limit, 40)
    tau, dt, J = ActuatorConfig().wheel_lag, sim.dt, sim.truth.wheel_inertia
    decay = math.exp(-dt / tau)
    # analytic: a ramp at limit / J while the lag from the current speed needs more than the limit ...
    expect = [0.0]
    while J * (target - expect[-1]) * (1 - decay) / dt > limit:
        expect.append(expect[-1] + limit * dt / J)
    k = len(expect) - 1
    assert 3 <= k < 30  # the test covers both phases
    # ... then the first-order lag from the speed reached (the reference does not wind up)
    tail = target + (expect[-1] - target) * decay ** np.arange(1, len(om) - k)
    expect = np.r_[expect, tail]
    assert om == pytest.approx(expect, abs=1e-9 * target)
    assert np.all(np.abs(tq) <= limit * (1 + 1e-9))
    assert tq[1:k + 1] == pytest.approx(limit, rel=1e-9)


def test_unpowered_wheel_spins_up_to_free_rolling_without_overshoot(unpowered):
    sc, prim = unpowered
    first_gain = {}
    for dt, steps, tol in ((1e-3, 30, 0.01), (0.1, 3, 1e-4)):
        sim = RoverSimulator(sc, seed=0, dt=dt)
        sim.start(_cmd(prim))
        free = float(sim.sol.omega[3])
        sim.z[6] = 0.5 * free  # knock the unpowered rear-left wheel to half its free-rolling speed
        om, my, tq = [0.5 * free], [], []
        for _ in range(steps):
            sim.step()
            om.append(float(sim.sol.omega[3]))
            my.append(float(sim.sol.wrench[3, 4]))
            tq.append(sim.motor.copy())
        om_a = np.array(om)
        first_gain[dt] = om_a[1] - om_a[0]
        assert np.all(np.diff(om_a) > 0) and om_a.max() <= free * (1 + 1e-7)  # monotone, no overshoot
        assert om_a[-1] == pytest.approx(free, rel=tol)
        assert np.all(np.abs(np.array(tq)[:, 3]) < 1e-12)  # no motor torque on it
        # angular momentum: J (omega_N - omega_0) is the soil's angular impulse
        J = sim.truth.wheel_inertia
        assert J * (om_a[-1] - om_a[0]) == pytest.approx(dt * sum(my), rel=1e-6)
    # the soil torque is what spins it up: with 10x the inertia the first step gains less
    slow = RoverSimulator(sc, Truth.nominal(sc.params, sc.rover, wheel_inertia=10 * default_wheel_inertia(sc.params)),
                          seed=0, dt=1e-3)
    slow.start(_cmd(prim))
    slow.z[6] = 0.5 * free
    slow.step()
    assert 0.0 < slow.sol.omega[3] - 0.5 * free < 0.5 * first_gain[1e-3]


def test_servo_motor_torque_is_consistent_with_the_wheel_inertia(raised):
    """A grounded, speed-servoed wheel through a command step: the reported motor torque, the
    soil's axle moment and J d(omega)/dt balance at every step."""
    sc, prim = raised
    sim = RoverSimulator(sc, seed=0, dt=0.02)
    c0 = _cmd(prim)
    sim.start(c0)
    rim = (c0.rim_speed[0], 1.3 * c0.rim_speed[1]) + c0.rim_speed[2:]
    sim.apply(Commands(0.0, 1, rim, c0.steer_angle))
    J = sim.truth.wheel_inertia
    prev = sim.sol.omega.copy()
    for _ in range(10):
        sim.step()
        om = sim.sol.omega
        assert sim.motor[1] == pytest.approx(J * (om[1] - prev[1]) / sim.dt - sim.sol.wrench[1, 4], rel=1e-12)
        prev = om.copy()
    assert om[1] == pytest.approx(1.3 * c0.rim_speed[1] / sc.params.wheel.shearing_radius, rel=0.01)


@pytest.mark.parametrize("slope_deg, cross_deg", [(0.0, 0.0), (5.0, 3.0)])
def test_raised_wheel_statics(raised, slope_deg, cross_deg):
    sc, prim = raised
    truth = Truth.nominal(sc.params, sc.rover, slope=math.radians(slope_deg), cross_slope=math.radians(cross_deg))
    sim = RoverSimulator(sc, truth, seed=0)
    sim.start(_cmd(prim))
    sim.advance(1.0)
    ts, s = sim.truth_state(), sim.sol
    W = sim.weight
    assert ts.load[0] == 0.0 and ts.sinkage[0] == 0.0 and np.all(s.wrench[0] == 0.0)
    assert math.isnan(ts.slip[0]) and math.isnan(ts.slip_angle[0])
    assert min(ts.load[1:]) > 0.0
    alpha, gamma = truth.slope, truth.cross_slope
    assert sum(ts.load) == pytest.approx(W * math.cos(alpha) * math.cos(gamma), rel=1e-7)
    # the independent free-body balance (3-D, rotation matrices), pivot locked, FR off the ground;
    # the heading is ~0 after 1 s, so the terrain and rover frames agree to that angle
    assert abs(ts.heading) < 1e-3
    wrench = {k: s.wrench[i] for i, k in enumerate(WHEELS)}
    beta = dict(zip(WHEELS, ts.steer))
    h = {k: max(ts.sinkage[i], 1e-3) for i, k in enumerate(WHEELS)}
    load = dict(zip(WHEELS, ts.load))
    res = free_body_residuals(sc.rover, wrench, beta, h, load, alpha, gamma, contact={"FR": 0.0, "FL": 1.0, "RR": 1.0, "RL": 1.0})
    M = W * sc.rover.rocker_length
    assert abs(res["Fz"]) < 1e-6 * W
    assert abs(res["Mx"]) < 1e-6 * M  # roll
    assert abs(res["My_right"] + res["My_left"]) < 1e-6 * M  # whole-rover pitch (the pivot is locked)
    if slope_deg == 0.0:
        # on flat ground the loads and sinkages are the optimizer's (same statics, raised wheel included)
        for i, k in enumerate(WHEELS[1:], start=1):
            assert ts.load[i] == pytest.approx(prim.wheels[k].load, abs=1e-6 * W)
        assert ts.u == pytest.approx(sc.speed, rel=1e-6) and abs(ts.yaw_rate) < 1e-5


def test_two_raised_wheels_are_refused():
    sc = load_scenario(SCEN["nominal"])
    with pytest.raises(ActuatorError, match="more than one raised wheel"):
        Actuators(ActuatorConfig(), {"FR": WheelFailure(raised=True), "RL": WheelFailure(raised=True)},
                  sc.params.wheel.shearing_radius)
    sim = RoverSimulator(sc)
    assert list(sim.contact) == [1.0, 1.0, 1.0, 1.0]
    assert GRAVITY * sim.mass == pytest.approx(sim.weight)


def test_truth_file_wheel_inertia(tmp_path):
    from offline.sim.truth import TruthError, load_truth

    sc = load_scenario(SCEN["nominal"])
    f = tmp_path / "t.toml"
    f.write_text("[truth]\nwheel_inertia_kg_m2 = 0.002\n")
    assert load_truth(f, sc.rover).wheel_inertia == 0.002
    f.write_text("[truth]\nslope_deg = 1.0\n")
    assert load_truth(f, sc.rover).wheel_inertia == pytest.approx(0.1 * sc.params.wheel.radius**2)
    f.write_text("[truth]\nwheel_inertia_kg_m2 = -1.0\n")
    with pytest.raises(TruthError, match="wheel_inertia_kg_m2 = -1.0 outside"):
        load_truth(f, sc.rover)
