"""Steady-state driving primitives (chapter 7): balance, failure constraints, scenarios."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from offline.physics.backend import NUMPY
from offline.physics.params import ROVER_MINI_T72
from offline.rover.primitives import SolverOptions, check_solution, slope_sweep, solve_primitive, steering_controllers
from offline.rover.statics import WHEELS, FourWheelRocker
from offline.rover.scenario import ScenarioError, example_scenarios, load_scenario

SHIPPED = {p.stem: p for p in example_scenarios()}


@pytest.fixture(scope="module")
def nominal():
    return solve_primitive(load_scenario(SHIPPED["nominal"]))


def test_nominal_primitive_is_symmetric_and_balanced(nominal):
    assert nominal.ok and nominal.check_passed
    w = nominal.wheels
    assert w["FR"].rim_speed == pytest.approx(w["FL"].rim_speed, rel=1e-6)
    assert w["RR"].load == pytest.approx(w["RL"].load, rel=1e-6)
    assert abs(w["FR"].steer) < 1e-6 and abs(w["RL"].steer) < 1e-6
    assert sum(x.load for x in w.values()) == pytest.approx(ROVER_MINI_T72.weight, rel=1e-9)
    assert all(0.0 < x.slip < 0.3 for x in w.values())  # driving, not skidding
    assert nominal.power > 0


def test_independent_check_sees_a_perturbed_solution(nominal):
    sc = nominal.scenario
    from offline.rover.primitives import _problem

    pb = _problem(sc.params, sc.rover, sc.exit_angle, None, SolverOptions())
    res, ok = check_solution(pb, sc, nominal.x)
    assert ok and max(abs(v) for v in res.values()) < 1e-6
    x = nominal.x.copy()
    x[0] *= 1.05  # FR 5 % faster
    res, ok = check_solution(pb, sc, x)
    assert not ok and abs(res["balance Fx"]) > 1e-3


# fr_raised (8-10 CPU-s a solve) is checked on the primitive tests/test_failures.py solves once for
# its raised-wheel, mirror and load tests: the same assertions, the same solve
@pytest.mark.parametrize("name", ["rr_steer_stuck_50", "rr_speed_cap_half", "rl_unpowered", "rr_torque_limited",
                                  "opportunity_steer_stuck_7"])
def test_failure_scenarios_meet_their_constraints(name):
    sc = load_scenario(SHIPPED[name])
    r = solve_primitive(sc)
    assert r.ok, (r.status, r.evidence, r.stats["attempts"])
    assert r.check_passed
    for k, f in sc.failures.items():
        w = r.wheels[k]
        if f.steer_stuck is not None:
            assert w.steer == pytest.approx(f.steer_stuck, abs=1e-9)
        if math.isfinite(f.rim_speed_max):
            assert w.rim_speed <= f.rim_speed_max + 1e-9
        if f.unpowered:
            assert abs(w.torque) < 1e-6
            assert w.slip < 0  # a towed wheel skids
        if math.isfinite(f.torque_limit):
            assert abs(w.torque) <= f.torque_limit + 1e-7
        if f.raised:
            assert w.load == 0.0 and w.torque == 0.0


def test_clean_sided_trench_meets_depth_and_clean_side():
    sc = load_scenario(SHIPPED["rr_trench_clean"])
    r = solve_primitive(sc)
    assert r.ok and r.check_passed, (r.status, r.evidence)
    assert r.trench.d >= sc.trench.min_depth - 5e-4
    assert r.trench.h_R2 < 5e-4  # no pile on the rim side (7.28), to 0.5 mm
    assert r.wheels["RR"].steer <= 0.0  # turned outwards, as the scenario's steer range asks


def test_mirror_image_scenarios_get_mirror_image_primitives():
    from offline.rover.primitives import mirror_scenario

    sc = load_scenario(SHIPPED["opportunity_steer_stuck_7"])
    a, b = solve_primitive(sc), solve_primitive(mirror_scenario(sc))
    assert a.ok and b.ok
    mirror = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}
    for k, w in a.wheels.items():
        m = b.wheels[mirror[k]]
        assert m.rim_speed == pytest.approx(w.rim_speed, rel=1e-5, abs=1e-7)
        assert m.steer == pytest.approx(-w.steer, abs=1e-5)
        assert m.load == pytest.approx(w.load, rel=1e-5)


def test_speed_cap_forces_the_other_wheels_to_slip_more(nominal):
    r = solve_primitive(load_scenario(SHIPPED["rr_speed_cap_half"]))
    assert r.wheels["RR"].slip < 0  # the capped wheel skids
    assert r.mean_slip() > 2 * nominal.mean_slip()
    assert r.power > nominal.power


def test_locked_wheel_is_reported_infeasible_with_evidence():
    # smaller search budgets than the defaults (one restart, one continuation, one confirmation
    # start of one round, a main search of 12 attempts and 1500 iterations: 16 IPOPT runs, 2.0k
    # iterations instead of 63 and 6.8k; 9.9 against 17.1 CPU-s with the default main search, the
    # same verdict and closest point, 2.07 cm/s): the locked wheel has no primitive at any budget,
    # and the verdict still needs the whole path -- main search, continuation, confirmation, the
    # furthest point's independent check. Every wheel locked at the default budgets, with an audit
    # by a longer search: tests/bench/bench_primitives.py
    opts = SolverOptions(restarts=1, continuation=(4,), confirm_starts=1, confirm_rounds=1,
                         max_attempts=12, max_iterations=1500)
    r = solve_primitive(load_scenario(SHIPPED["fl_locked"]), opts)
    assert r.status == "infeasible"
    assert "most_violated_constraint" in r.evidence
    assert r.evidence["furthest_point_checked"]
    assert "lowest rim speed reached at a feasible point" in r.evidence["closest"]


def test_steering_controllers_steer_the_right_way(nominal):
    sc = nominal.scenario
    ctl = steering_controllers(sc, nominal, mz_offset=0.05, fy_offset=0.5)
    up = ctl["Mz+"]
    # a positive yaw-moment demand speeds up the right wheels relative to the left ones
    assert up["FR"][0] > up["FL"][0] and up["RR"][0] > up["RL"][0]
    # a lateral-force demand turns the wheels together
    fy = ctl["Fy+"]
    assert np.sign(fy["FR"][1]) == np.sign(fy["FL"][1]) == np.sign(fy["RR"][1]) == np.sign(fy["RL"][1])


def test_slope_raises_slip_and_power():
    sc = load_scenario(SHIPPED["nominal"])
    res = slope_sweep(sc, [0.0, 5.0, 10.0])
    assert all(r.ok for r in res)
    slips = [r.mean_slip() for r in res]
    powers = [r.power for r in res]
    assert slips[0] < slips[1] < slips[2]
    assert powers[0] < powers[1] < powers[2]
    # (7.32)-(7.33): total traction equals the weight component down the slope
    r = res[-1]
    fx = sum(w.wrench[0] * math.cos(w.steer) - w.wrench[1] * math.sin(w.steer) for w in r.wheels.values())
    assert fx == pytest.approx(ROVER_MINI_T72.weight * math.sin(math.radians(10.0)), rel=1e-6)


def test_rover_statics_mirror_symmetry():
    st = FourWheelRocker(ROVER_MINI_T72)
    rng = np.random.default_rng(1)
    wr = {k: tuple(rng.normal(size=6)) for k in WHEELS}
    beta = {k: rng.normal(0, 0.3) for k in WHEELS}
    h = {k: rng.uniform(0.005, 0.02) for k in WHEELS}
    load = {k: rng.uniform(5, 10) for k in WHEELS}
    a = st.balance(NUMPY, wr, beta, h, load, 0.0, 0.0, 0.0)
    mirror = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}
    # mirror y: Fy, Mx, Mz flip; beta flips; left and right swap
    flip = (1, -1, 1, -1, 1, -1)
    wr_m = {mirror[k]: tuple(s * v for s, v in zip(flip, wr[k])) for k in WHEELS}
    b = st.balance(NUMPY, wr_m, {mirror[k]: -beta[k] for k in WHEELS}, {mirror[k]: h[k] for k in WHEELS},
                   {mirror[k]: load[k] for k in WHEELS}, 0.0, 0.0, 0.0)
    assert b["Fx"] == pytest.approx(a["Fx"]) and b["Fy"] == pytest.approx(-a["Fy"])
    assert b["Mx"] == pytest.approx(-a["Mx"]) and b["Mz"] == pytest.approx(-a["Mz"])
    assert b["My_right"] == pytest.approx(a["My_left"]) and b["Fz"] == pytest.approx(a["Fz"])


# ------------------------------------------------------------------ scenario files
def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, match", [
    ("[scenario]\nspeed_m_s = 30\n", r"speed_m_s = 30.0 m/s outside \(0, 0.5\] m/s.*cm/s"),
    ("[scenario]\nspeed_m_s = 3.0\n", r"speed_m_s = 3.0 m/s outside .*write speed_m_s = 0.03"),
    ("[scenario]\ncross_slope_deg = 75\n", r"cross_slope_deg = 75.0 outside"),
    ("[scenario]\n[wheels.RR]\nsteer_stuck_deg = 400\n", r"bad\.toml: \[wheels\.RR\] steer_stuck_deg = 400.0 outside \[-90.0, 90.0\]"),
    ("[scenario]\n[wheels.XX]\nlocked = true\n", r"\[wheels\.XX\] unknown wheel"),
    ("[scenario]\n[wheels.FL]\nlocked = true\nunpowered = true\n", r"locked and unpowered contradict"),
    ("[scenario]\n[wheels.FL]\nraised = true\n[wheels.FR]\nraised = true\n", r"more than one raised wheel"),
    ("[scenario]\nslope_deg = 61\n", r"slope_deg = 61.0 outside"),
    ("[scenario]\nparams = \"nope.toml\"\n", r"params = 'nope\.toml'"),
    ("[scenario]\n[trench]\nwheel = \"RR\"\nmin_depth_m = 25\n", r"\[trench\] min_depth_m = 25.0 m outside"),
    ("[scenario]\n[wheels.RR]\nrim_speed = 0.01\n", r"\[wheels\.RR\] unknown key\(s\) \['rim_speed'\]"),
    ("[scenario]\nspeed_m_s = \"fast\"\n", r"speed_m_s must be a number"),
    ("[scenario\n", r"not valid TOML"),
])
def test_malformed_scenarios_name_key_and_reason(tmp_path, text, match):
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_write(tmp_path, text))


def test_every_shipped_scenario_loads():
    assert len(SHIPPED) >= 8
    for p in SHIPPED.values():
        sc = load_scenario(p)
        assert sc.description


def test_another_rover_of_this_layout_is_a_new_file(tmp_path):
    """Rover geometry comes from TOML: a heavier, longer rover is a file, not code."""
    from offline.physics.params import save_toml

    heavy = replace_rover(weight=50.0, rocker_length=0.40)
    save_toml(tmp_path / "big_rover.toml", rover=heavy)
    (tmp_path / "sc.toml").write_text('[scenario]\nname = "big"\nrover = "big_rover.toml"\nspeed_m_s = 0.03\n')
    sc = load_scenario(tmp_path / "sc.toml")
    assert sc.rover.weight == 50.0 and sc.rover.rocker_length == pytest.approx(0.40)
    r = solve_primitive(sc)
    assert r.ok and r.check_passed
    assert sum(w.load for w in r.wheels.values()) == pytest.approx(50.0, rel=1e-9)


def replace_rover(**kw):
    from dataclasses import replace as _replace

    return _replace(ROVER_MINI_T72, name="big_rover", source="test", **kw)


@pytest.mark.parametrize("key", ["nominal_flat_mean_slip", "stuck50_flat_mean_slip", "speedcap_flat_mean_slip",
                                 "speedcap_flat_max_slip", "trench_depth"])
def test_chapter7_reference_numbers(key):
    """The dissertation's chapter-7 numbers (one table, offline.rover.reference): ours within the
    stated tolerance, or inside the stated band with the reason it is not matched."""
    from offline.rover.reference import CHAPTER7, QUICK, compare, compute

    assert key in QUICK
    ref = next(r for r in CHAPTER7 if r.key == key)
    assert ref.matched or ref.why
    ok, why = compare(ref, compute(key))
    assert ok, why
