"""Failure kinds as objects, deterministic verdicts, skid starts, statuses and evidence."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from offline.physics.params import load_toml
from offline.rover.failures import (
    KINDS,
    FailureKind,
    Locked,
    Raised,
    RimSpeedCap,
    SolutionView,
    SteerRange,
    StuckSteering,
    TorqueLimit,
    TrenchGoal,
    Unpowered,
    WheelBounds,
)
from offline.rover.primitives import _NOMINAL_CACHE, STATUSES, SolverOptions, get_problem, mirror_scenario, solve_primitive
from offline.rover.scenario import ScenarioError, WheelFailure, example_scenarios, load_scenario

SHIPPED = {p.stem: p for p in example_scenarios()}
CALIBRATED = Path(__file__).resolve().parents[1] / "offline" / "data" / "calibrated_grousered.toml"


def _bounds() -> WheelBounds:
    return WheelBounds(lo={"omega": 0.0, "beta": -1.5, "W": 0.0, "h": 0.002, "h0": 0.002},
                       hi={"omega": 5.0, "beta": 1.5, "W": 20.0, "h": 0.1, "h0": 0.1}, rim_radius=0.06, speed=0.03)


@pytest.mark.parametrize("kind, var, lo, hi, torque, contact", [
    (StuckSteering(0.3), "beta", 0.3, 0.3, (-math.inf, math.inf), 1.0),
    (SteerRange(-0.5, 0.0), "beta", -0.5, 0.0, (-math.inf, math.inf), 1.0),
    (RimSpeedCap(0.015), "omega", 0.0, 0.25, (-math.inf, math.inf), 1.0),
    (Locked(), "omega", 0.0, 0.0, (-math.inf, math.inf), 1.0),
    (Unpowered(), "omega", 0.0, 5.0, (0.0, 0.0), 1.0),
    (TorqueLimit(0.03), "omega", 0.0, 5.0, (-0.03, 0.03), 1.0),
    (Raised(), "W", 0.0, 0.0, (-math.inf, math.inf), 0.0),
])
def test_each_kind_sets_its_own_bounds(kind, var, lo, hi, torque, contact):
    b = _bounds()
    kind.apply(b)
    assert b.lo[var] == pytest.approx(lo) and b.hi[var] == pytest.approx(hi)
    assert b.torque == torque and b.contact == contact


def test_kinds_mirror_and_check():
    assert StuckSteering(0.3).mirror() == StuckSteering(-0.3)
    assert SteerRange(-0.5, 0.1).mirror() == SteerRange(-0.1, 0.5)
    assert RimSpeedCap(0.01).mirror() == RimSpeedCap(0.01)
    assert TrenchGoal("RR", True, 0.02).mirror().wheel == "RL"
    s = SolutionView(omega=0.5, beta=0.2, load=5.0, sinkage=0.01, torque=-0.05, rim_radius=0.06, speed=0.03)
    assert RimSpeedCap(0.02).check(s)["rim speed"][0] == pytest.approx(0.01)
    assert TorqueLimit(0.03).check(s)["torque"][0] == pytest.approx(0.02)
    assert "0.0500 N m" in TorqueLimit(0.03).evidence(s)  # the torque reached, not the bound
    assert StuckSteering(0.2).check(s)["steer"][0] == pytest.approx(0.0)
    wf = WheelFailure(steer_stuck=0.3, rim_speed_max=0.01)
    assert WheelFailure.from_kinds(wf.kinds()) == wf
    assert wf.mirror().steer_stuck == -0.3
    assert {type(k) for k in WheelFailure(locked=True, steer_min=-0.2).kinds()} == {Locked, SteerRange}
    assert all(k.TOML_KEYS for k in KINDS)


@dataclass(frozen=True)
class MinRimSpeed(FailureKind):
    """A kind written only here (the recipe): the wheel must turn at least this fast."""

    floor: float
    TOML_KEYS: ClassVar[tuple[str, ...]] = ("rim_speed_min_m_s",)

    def apply(self, b: WheelBounds) -> None:
        b.lo["omega"] = max(b.lo["omega"], self.floor / b.rim_radius)

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        return {"rim speed floor": (max(self.floor - s.rim_speed, 0.0), s.speed)}


def test_a_new_failure_kind_is_one_object():
    base = load_scenario(SHIPPED["nominal"])
    sc = replace(base, name="FR at least 1.5 v", failures={"FR": WheelFailure(extra=(MinRimSpeed(1.5 * base.speed),))})
    r = solve_primitive(sc)
    assert r.status == "optimal" and r.check_passed
    assert r.wheels["FR"].rim_speed >= 1.5 * base.speed - 1e-9
    assert "rim speed floor FR" in r.residuals
    assert r.wheels["FR"].slip > 0.3  # forced to spin


def _busy(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


@pytest.fixture(scope="module")
def fr_raised():
    """The shipped fr_raised scenario and its primitive, solved once for this module (8-10 CPU-s)."""
    sc = load_scenario(SHIPPED["fr_raised"])
    return sc, solve_primitive(sc)


def test_same_verdict_and_iterations_idle_and_under_cpu_load():
    """A solve whose search takes several IPOPT runs (calibrated sand, -10 deg: three attempts, a
    skid start among them) again with two busy-looping processes beside it: on 2 cores the solve
    then shares its core (with xdist's other worker, 4 runnable processes on 2 cores), and the
    verdict, iteration counts and solution are the same bit for bit. (The fr_raised search was the
    second case here; its loaded re-solve cost about 20 CPU-s while the busy loops took the other
    worker's core, and it exercises the same budget-in-iterations code path.)"""
    cal = load_toml(CALIBRATED)["parameter_set"]
    sc = replace(load_scenario(SHIPPED["nominal"]), params=cal, slope=math.radians(-10.0), name="calibrated -10 deg")
    idle = solve_primitive(sc)
    assert idle.stats["n_attempts"] > 1  # a search, not one IPOPT run
    # the nominal search is cached per problem and operating point (primitives._NOMINAL_CACHE): without
    # clearing it the loaded calibrated -10 deg solve, a nominal search, would be the idle one read back
    _NOMINAL_CACHE.clear()
    procs = _busy(2)
    try:
        loaded = solve_primitive(sc)
    finally:
        for p in procs:
            p.kill()
            p.wait()
    assert idle.status == loaded.status
    assert idle.stats["iterations"] == loaded.stats["iterations"] and idle.stats["n_attempts"] == loaded.stats["n_attempts"]
    np.testing.assert_array_equal(idle.x, loaded.x)


def test_calibrated_parameters_drive_down_a_10_degree_slope():
    """Downhill the wheels brake (skid); the automatic start covers skid."""
    cal = load_toml(CALIBRATED)["parameter_set"]
    sc = replace(load_scenario(SHIPPED["nominal"]), params=cal, slope=math.radians(-10.0))
    r = solve_primitive(sc)
    assert r.status == "optimal" and r.check_passed, (r.status, r.evidence, r.stats["attempts"])
    fx = sum(w.wrench[0] * math.cos(w.steer) - w.wrench[1] * math.sin(w.steer) for w in r.wheels.values())
    assert fx == pytest.approx(sc.rover.weight * math.sin(sc.slope), rel=1e-6)  # (7.32): net braking force


def test_40_degree_slope_is_infeasible_with_checked_evidence():
    sc = replace(load_scenario(SHIPPED["nominal"]), slope=math.radians(40.0))
    # a smaller budget than the default keeps the test short; the verdict may then be not_found. One
    # confirmation start of one round (as the locked wheel's test in tests/test_primitives.py): still
    # main search, confirmation and the furthest point's check, 23 IPOPT runs and 2248 iterations against
    # 27 and 2848 with two of two (10.2 against 12.6 CPU-s; the same verdict and closest slope, 24.38 deg)
    r = solve_primitive(sc, SolverOptions(max_attempts=40, max_iterations=1500, confirm_starts=1, confirm_rounds=1))
    assert r.status in ("infeasible", "not_found") and r.status in STATUSES
    assert "steepest slope reached" in r.evidence["closest"]
    if r.status == "infeasible":
        assert r.evidence["furthest_point_checked"]


def test_a_feasible_start_is_kept():
    """A cap equal to the travel speed, started from the half-speed primitive (which satisfies
    it): the verdict is never "infeasible"."""
    base = load_scenario(SHIPPED["rr_speed_cap_half"])
    half = solve_primitive(base)
    sc = replace(base, name="RR cap = v", failures={"RR": WheelFailure(rim_speed_max=base.speed)})
    r = solve_primitive(sc, SolverOptions(max_attempts=6, max_iterations=600, confirm=False), x0=half.x)
    assert r.status in ("optimal", "not_found")
    if r.status == "not_found":
        assert r.evidence.get("feasible_point_found") and r.check_passed  # the kept point passes the check


def test_raised_wheel_sinkage_is_zero_everywhere_and_mirror_is_exact(fr_raised):
    """The raised FR wheel carries nothing (no load, no sinkage, no torque), the primitive passes the
    independent check (the fr_raised case of tests/test_primitives.py's failure scenarios, checked
    here on the module's one solve), and the mirror scenario's primitive is its mirror image."""
    sc, a = fr_raised
    b = solve_primitive(mirror_scenario(sc))
    assert a.ok and b.ok and a.check_passed, (a.status, a.evidence, a.stats["attempts"])
    assert a.wheels["FR"].sinkage == 0.0 and a.wheels["FR"].load == 0.0 and a.wheels["FR"].torque == 0.0
    mirror = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}
    for k, w in a.wheels.items():
        m = b.wheels[mirror[k]]
        assert m.rim_speed == pytest.approx(w.rim_speed, rel=1e-6, abs=1e-9)
        assert m.steer == pytest.approx(-w.steer, abs=1e-6)


def test_cross_slope_pushes_the_wheels_uphill_and_mirrors():
    base = load_scenario(SHIPPED["nominal"])
    sc = replace(base, cross_slope=math.radians(10.0))
    r, m = solve_primitive(sc), solve_primitive(mirror_scenario(sc))
    assert r.ok and r.check_passed and m.ok
    fy = sum(w.wrench[0] * math.sin(w.steer) + w.wrench[1] * math.cos(w.steer) for w in r.wheels.values())
    W = sc.rover.weight
    assert fy == pytest.approx(W * math.sin(sc.cross_slope), rel=1e-6)  # lateral soil force holds the rover
    assert sum(w.load for w in r.wheels.values()) == pytest.approx(W * math.cos(sc.cross_slope), rel=1e-9)
    assert r.wheels["FR"].load > r.wheels["FL"].load  # the downhill (right) side carries more
    assert m.wheels["FL"].load == pytest.approx(r.wheels["FR"].load, rel=1e-6)


def test_layout_names_every_row_and_bounds_use_it():
    sc = load_scenario(SHIPPED["rr_torque_limited"])
    pb = get_problem(sc.params, sc.rover, sc.exit_angle, None)
    b = pb.bounds(sc)
    L = pb.layout
    j = L.index("wheel torque RR")
    assert b["ubg"][j] * L.constraint_scale[j] == pytest.approx(0.03)
    assert b["p"][L.index("cross_slope")] == 0.0
    assert pb.symbols["g"].shape[0] == L.ng and pb.symbols["x"].shape[0] == L.nx


def test_trench_given_as_a_number_is_a_clear_error(tmp_path):
    """``trench = 5`` (a number where the [trench] table belongs) names the key and the expected form."""
    f = tmp_path / "t5.toml"
    f.write_text('trench = 5\n[scenario]\nname = "t5"\nspeed_m_s = 0.03\n')
    with pytest.raises(ScenarioError, match=r"trench = 5: the trench goal is a table"):
        load_scenario(f)


def test_stuck_steering_is_held_at_the_declared_angle_up_to_90_deg():
    """The optimizer's +-89 deg limit bounds a free steering decision, not a stuck angle: the
    old clamp made the NLP solve 89 deg for a wheel declared stuck at 90 deg, and the
    independent check rejected the result (residual 1.75e-2 rad)."""
    from offline.rover.primitives import BETA_LIMIT

    b = _bounds()
    b.lo["beta"], b.hi["beta"] = -BETA_LIMIT, BETA_LIMIT
    StuckSteering(math.pi / 2).apply(b)
    assert b.lo["beta"] == b.hi["beta"] == pytest.approx(math.pi / 2, abs=1e-15)
    b = _bounds()
    b.lo["beta"], b.hi["beta"] = -BETA_LIMIT, BETA_LIMIT
    StuckSteering(-math.radians(95.0)).apply(b)  # beyond the model's domain (an offset can do this)
    assert b.lo["beta"] == b.hi["beta"] == pytest.approx(-math.pi / 2, abs=1e-15)


@pytest.mark.parametrize("angle", [90.0, -90.0])
def test_front_left_stuck_at_90_deg_passes_the_independent_check(angle):
    """README's worked example at its axis ends: optimal and the independent check passes
    (before the fix: 'IPOPT converged but the independent numeric check failed')."""
    cal = load_toml(CALIBRATED)["parameter_set"]
    sc = replace(load_scenario(SHIPPED["nominal"]), params=cal, speed=0.02, name=f"FL stuck {angle}",
                 failures={"FL": WheelFailure(steer_stuck=math.radians(angle))})
    r = solve_primitive(sc)
    assert r.status == "optimal" and r.check_passed, (r.status, r.evidence)
    assert r.wheels["FL"].steer == pytest.approx(math.radians(angle), abs=1e-9)
    assert abs(r.residuals["steer FL"]) <= 1e-9
