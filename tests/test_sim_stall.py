"""A rover held by a locked wheel: the plant's static friction at rest and its exact Newton
fallback (issue 21: "locked wheels: the simulator finds no equilibrium at the start").

The wheel model's forces are rate-independent, so a wheel at rest has a set-valued force; the
plant regularises it with a stiction tolerance (:func:`offline.sim.plant._stiction`). These
tests check the physics of that (continuity through rest, a stall where the driven wheels
cannot drag the locked one, no change at all for wheels that move) and the rocker-angle terms
of the Jacobian against finite differences.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from offline.rover.scenario import load_scenario
from offline.scenarios import __path__ as _SCENARIOS
from offline.sim.plant import STICTION_SPEED, _stiction
from offline.sim.simulator import RoverSimulator
from rtctl.messages import Commands


def _sim(name: str = "fl_locked") -> RoverSimulator:
    return RoverSimulator(load_scenario(f"{_SCENARIOS[0]}/{name}.toml"), seed=1)


def _straight(sim: RoverSimulator) -> Commands:
    rim = sim.scenario.speed / 0.92  # the nominal primitive's slip, about 8 %
    return Commands(t=0.0, seq=0, rim_speed=(rim,) * 4, steer_angle=(0.0,) * 4)


def test_locked_front_wheel_stalls_the_rover() -> None:
    """Dissertation soil, FL locked, the other wheels driven straight at the nominal speed: the
    optimizer finds no primitive (the three wheels cannot drag it at 3 cm/s), and the plant
    finds the rover at rest (a creep below 1 mm/s) with the driven wheels spinning at slip
    near 1. Before the stiction tolerance the start raised "no equilibrium of the rover found"."""
    sim = _sim()
    sim.start(_straight(sim))
    sim.advance(2.0)
    sol = sim.sol
    assert sol is not None
    assert 0.0 < sol.u < 10 * STICTION_SPEED, sol.u
    assert abs(sol.omega[1]) < 1e-12
    driven = [0, 2, 3]
    assert np.all(sol.slip[driven] > 0.95), sol.slip
    # the locked wheel holds the rover: its force opposes the driven wheels' pull
    assert sol.wrench[1, 0] < -1.0 and np.sum(sol.wrench[driven, 0]) > 1.0


def test_resting_wheel_force_is_continuous_through_rest() -> None:
    """The locked wheel's soil force is continuous in the body speed through u = 0 and takes
    every value between its two sliding forces (without the regularisation it jumps between
    them, about 10 N, at u = 0). The driven wheels spinning on the resting rover are not
    continuous through u = 0 in the wheel model (its mirror image for v_x < 0 treats a wheel
    turning against its travel as a skid at slip -1): a stalled rover creeps forward, u > 0."""
    sim = _sim()
    sim.start(_straight(sim))
    z = sim.z.copy()
    a = sim._inputs(0.0)
    fx = {}
    for u in (-1e-3, -1e-7, 0.0, 1e-7, 1e-3):
        z[0], z[1], z[2] = u, 0.0, 0.0
        fx[u] = sim.plant.evaluate(z, a, sim.q)[2][1, 0]  # FL's F_x, wheel frame
        # the line search's residual-only evaluation scales the resting wheel the same, bit for bit
        assert np.array_equal(sim.plant.evaluate(z, a, sim.q, jacobian=False)[0], sim.plant.evaluate(z, a, sim.q)[0])
    assert fx[1e-3] < -5.0 and fx[-1e-3] > 5.0  # sliding: the full skid resistance, either way
    assert abs(fx[1e-7] - fx[-1e-7]) < 0.01 * abs(fx[1e-3])
    assert abs(fx[0.0]) < 1e-3 * abs(fx[1e-3])


def test_stiction_leaves_moving_wheels_bit_for_bit() -> None:
    """Above 20 stiction speeds (2 mm/s) nothing is changed: every drive whose wheels move is the
    unregularised plant bit for bit."""
    rng = np.random.default_rng(3)
    W = rng.normal(size=(6, 8))
    JW = rng.normal(size=(8, 6, 5))
    X = np.abs(rng.normal(size=(5, 8)))
    X[0, :4] = 20.5 * STICTION_SPEED  # travel just above the cut-off
    X[1, :4] = 0.0
    X[2, :4] = 0.0  # not even turning (a locked wheel dragged at 2 mm/s)
    W0, J0 = W.copy(), JW.copy()
    _stiction(W, JW, X, np.full(4, 0.068))
    assert np.array_equal(W, W0) and np.array_equal(JW, J0)
    # below the cut-off the resting wheel's shear is scaled, F_z is not
    X[0, 1] = STICTION_SPEED
    _stiction(W, JW, X, np.full(4, 0.068))
    f = math.tanh(1.0)
    assert np.allclose(W[[0, 1, 3, 4, 5], 1], f * W0[[0, 1, 3, 4, 5], 1], rtol=1e-5)
    assert W[2, 1] == W0[2, 1]
    assert np.array_equal(W[:, [0, 2, 3]], W0[:, [0, 2, 3]])


@pytest.mark.parametrize("raised", [False, True])
def test_rocker_jacobian_matches_finite_differences(raised: bool) -> None:
    """With ``rocker_jacobian`` on, the plant's Jacobian is exact (central differences, 1e-6);
    off, the documented approximation differs in the sinkage columns."""
    sim = _sim("rr_steer_stuck_50")
    plant = sim.plant
    rng = np.random.default_rng(0)
    z = plant.initial_guess(0.03, sim.q)
    z[7:11] += rng.normal(0.0, 0.3, 4)
    z[0:3] += [0.0, 0.002, 0.01]
    om = [0.6, 0.5, 0.55, 0.7]
    a = np.concatenate([om, np.ones(4), np.zeros(4), np.radians([10.0, 5.0, -8.0, 3.0]), [0.03, 0.0, 0.0, 0.1, 10.0],
                        om, [1.0, 0.0 if raised else 1.0, 1.0, 1.0]])

    def fd() -> np.ndarray:
        out = np.zeros((15, 15))
        for j in range(15):
            zp, zm = z.copy(), z.copy()
            zp[j] += 1e-7
            zm[j] -= 1e-7
            out[:, j] = (plant.evaluate(zp, a, sim.q)[0] - plant.evaluate(zm, a, sim.q)[0]) / 2e-7
        return out

    ref = fd()
    try:
        plant.rocker_jacobian = True
        exact = plant.evaluate(z, a, sim.q)[1]
    finally:
        plant.rocker_jacobian = False
    approx = plant.evaluate(z, a, sim.q)[1]
    assert np.max(np.abs(exact - ref)) < 1e-6
    assert np.max(np.abs(approx - ref)) > 1e-4


@pytest.mark.parametrize("tables,params,wheel", [("shipped", "dissertation-ch7", "FR"), ("test", "dissertation-ch7", "FR"),
                                                 ("shipped", "calibrated-sand", "FL")])
def test_rtctl_against_a_locked_wheel_stalls_and_may_dig_in(tmp_path, tables: str, params: str, wheel: str) -> None:
    """FR locked, no FR table (imposed on the nominal table, flagged), dissertation world: the
    optimizer has no primitive and the rover stalls against the locked wheel (before, the
    simulator raised "no equilibrium of the rover found" on the first stalled step). Here, with
    the shipped tables (another soil) rtctl steers the locked wheel, a step fails with a wheel
    below its shearing radius and the drive ends there with the reason in the result
    (``stuck``, ``stuck_at_s``); with the world's own test tables the rover creeps to the time
    limit. Every command is valid and the locked wheel is never driven. On the calibrated sand (the shipped
    tables' own soil) FL locked first failed at the start (a non-finite Jacobian raised
    LinAlgError); now the start's continuation falls back like a step and the drive digs in."""
    from pathlib import Path

    from drive_helpers import FlagRecorder
    from offline.sim.experiments import run_drive
    from offline.sim.rtctl_bridge import rtctl_factory
    from rtctl.config import ControllerConfig

    sc = tmp_path / "fr_locked.toml"
    sc.write_text(f'[scenario]\nname = "{wheel.lower()}_locked"\nparams = "{params}"\nspeed_m_s = 0.03\n\n'
                  f'[wheels.{wheel}]\nlocked = true\n')
    scenario = load_scenario(sc)
    index = None if tables == "shipped" else str(Path(__file__).parent / "data" / "tables" / "index.json")
    rec = FlagRecorder()
    res = run_drive(RoverSimulator(scenario, seed=1), rtctl_factory(index)(scenario), distance=0.3, recorder=rec)
    # stuck (a failed step with a wheel below its shearing radius) or crept to the time limit:
    # which one depends on whether Newton's method still finds the deep state's root, so on the
    # machine's arithmetic; this run's outcomes are in the docstring
    if res.stuck:
        assert "the rover is stuck, dug in" in res.stuck and "shearing radius" in res.stuck
        assert 0.0 < res.metrics["stuck_at_s"] < 30.0
    else:
        assert res.metrics["time_s"] >= 29.9
    assert res.metrics["distance_m"] < 0.05
    act = ControllerConfig().actuators
    assert all(c.is_valid(act.max_rim_speed, act.max_steer) for c in res.commands)
    flags = {f for tick in rec.flags for f in tick}
    assert any(f.startswith(f"no table for the declared failures {wheel} locked") for f in flags), flags
    i = ("FR", "FL", "RR", "RL").index(wheel)
    assert all(c.rim_speed[i] == 0.0 for c in res.commands[1:])  # the locked wheel is never driven


def test_zero_slip_twin_of_a_reversing_wheel_is_at_zero_slip() -> None:
    """The plant's zero-slip twin rolls the way its wheel travels: at ``v_x < 0`` the wheel model
    (which mirrors travel toward -x) gives slip 0 for the twin's spin, as at ``v_x > 0`` (the
    twin spun forward on a reversing wheel was at slip -2)."""
    from offline.sim.plant import _twin_direction
    from rtctl.physics.backend import NUMPY
    from rtctl.physics.terramechanics import ModelOptions, PhysParams, wrench_core

    sim = _sim("rr_steer_stuck_50")
    ps = sim.truth.params
    p = PhysParams.from_sets(ps.soil, ps.wheel, ps.tuning)
    rs = ps.wheel.radius + ps.wheel.grouser_height
    for vx in (0.03, -0.03):
        vy = 0.004
        speed = math.hypot(vx, vy)
        om = float(_twin_direction(np.array([vx]))[0]) * speed / rs
        _, diag = wrench_core(NUMPY, np.array([vx]), np.array([vy]), np.array([om]), np.array([0.01]),
                              np.array([0.01]), p, ModelOptions())
        assert abs(float(np.ravel(diag["slip"])[0])) < 1e-12, (vx, diag["slip"])


def test_a_failed_step_below_the_shearing_radius_is_stuck_and_a_shallow_one_is_not() -> None:
    """``RoverStuck`` is raised for a failed step whose Newton iterate (or start) has a wheel on
    the ground deeper than its shearing radius; a shallow failure stays a SimulationError."""
    from offline.sim.plant import SimulationError
    from offline.sim.simulator import RoverStuck

    sim = _sim()
    sim.start(_straight(sim))
    z = sim.z.copy()
    err = SimulationError("no equilibrium")
    deep = z.copy()
    deep[7 + 2] = math.log(1.2 * float(sim.rs_true[2]))
    err.z = deep
    with pytest.raises(RoverStuck, match=r"dug in: RR \d+\.\d mm .* shearing radius"):
        sim._raise_if_dug_in(z, err)
    shallow = sim.plant.initial_guess(sim.scenario.speed, sim.q)  # straight driving's sinkages
    err.z = shallow
    assert float(np.max(np.exp(shallow[7:11]))) < float(np.min(sim.rs_true))
    sim._raise_if_dug_in(shallow, err)  # returns: the caller raises the SimulationError itself


def test_a_failed_step_with_an_unloaded_wheel_is_a_lift_off_and_ends_the_drive(monkeypatch) -> None:
    """A failed step with a wheel in contact at its grouser height raises ``WheelLiftOff`` (the
    plant does not model a wheel leaving the ground; RR locked on the calibrated sand reached it at
    1.1 s), and :func:`run_drive` ends the drive there with the reason in ``ended`` and the
    metrics so far (before, the exception ended the whole run and the controller's flags with it)."""
    from offline.sim.experiments import run_drive
    from offline.sim.plant import SimulationError
    from offline.sim.simulator import RoverStuck, WheelLiftOff

    sim = _sim("nominal")
    sim.start(_straight(sim))
    err = SimulationError("no equilibrium")
    light = sim.z.copy()
    light[7 + 1] = math.log(0.9 * sim.truth.params.wheel.grouser_height)
    err.z = light
    with pytest.raises(WheelLiftOff, match=r"FL \d\.\d mm: sinkage at the 5 mm grouser height") as e:
        sim._raise_if_dug_in(sim.z, err)
    assert not isinstance(e.value, RoverStuck)

    sim = _sim("nominal")
    calls = {"n": 0}
    advance = sim.advance

    def lifts_at_the_third(period: float) -> None:
        calls["n"] += 1
        if calls["n"] == 3:
            raise WheelLiftOff("t=0.6 s: a wheel is unloading (FL 4.9 mm ...)")
        advance(period)

    monkeypatch.setattr(sim, "advance", lifts_at_the_third)
    from offline.sim.experiments import build_controller
    res = run_drive(sim, build_controller("none", sim.scenario), distance=0.3)
    assert res.ended.startswith("t=0.6 s: a wheel is unloading") and not res.stuck
    assert res.metrics["ended_at_s"] == pytest.approx(0.4) and len(res.commands) == 3
