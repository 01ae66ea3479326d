"""The steady-state NLP (7.25) of any rover from a file (issue 23), and the mini rover unchanged.

* The mini rover (no ``rover`` key): the NLP re-solved on seven shipped scenarios has the same
  variable, parameter and constraint order and the same solution and objective (to
  ``RTOL_NLP_REFERENCE`` of each variable's scale) as the code before the change
  (``tests/data/mini_rover_nlp_reference.npz``, made by ``tests/data/make_mini_rover_nlp_reference.py``
  at the commit stored in it).
* The mini rover through its rover file (``rover = "mini_rover_t72"``): the rover-file path
  (``SuspensionStatics`` rows, ``FreeBodyBalance`` check) solves the nominal scenario to the same
  primitive as the four-wheel path (the drive actuator limits of the file do not bind there).
* The independent free body (:class:`offline.rover.statics.FreeBodyBalance`: link angles by root
  finding, rotation matrices) equals the NLP's rows (:class:`rtctl.physics.suspension.SuspensionStatics`:
  closed-form angles) on random states of the three shipped rovers, as filed and turned half round
  (driving backward); for the rigid rover its plane row sees sinkages off one plane.
* Six-wheel MER-class rover: nominal and right-front unpowered, forward and backward (the rover
  turned half round); right-front steering stuck at 7 deg; right-front locked backward at 1 cm/s;
  a rim-speed cap on a bogie wheel: optimal and passing the independent check; the balance rows vanish at the solution by the
  independent free body; a non-steering wheel points straight; the failure holds.
* Skid-steer rover, one wheel unpowered: optimal, checked; the wheel centres on one plane.
* Scenario errors name the file and key (unknown wheel, steering stuck on a fixed wheel, raised
  wheel on a rocker-bogie, backward without a rover file).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import RTOL_NLP_REFERENCE

from offline.physics.backend import NUMPY
from offline.rover.primitives import SolverOptions, _problem_for, check_solution, mirror_wheels, solve_primitive
from offline.rover.scenario import ScenarioError, example_scenarios, load_scenario
from offline.rover.statics import FreeBodyBalance
from rtctl.physics.rover_file import driving_backward, shipped_rover
from rtctl.physics.suspension import SuspensionStatics

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "data" / "mini_rover_nlp_reference.npz"
ROVER_SCENARIOS = ROOT / "offline" / "scenarios" / "rovers"
MINI = ("nominal", "rl_unpowered", "opportunity_steer_stuck_7", "rr_speed_cap_half", "fr_raised", "rr_steer_stuck_50",
        "hillside_traverse_10")
TOL_FREE_BODY_ABS = 1e-9  # N, N m: NLP rows vs the independent free body (root finding to machine precision)


@pytest.fixture(scope="module")
def reference():
    return np.load(REFERENCE)


@pytest.mark.parametrize("name", MINI)
def test_mini_rover_nlp_is_unchanged(reference, name):
    sc = load_scenario({p.stem: p for p in example_scenarios()}[name])
    assert sc.rover_file is None and sc.wheels == ("FR", "FL", "RR", "RL")
    r = solve_primitive(sc)
    pb = _problem_for(sc, SolverOptions())
    L = pb.layout
    assert L.variable_names == list(reference[f"{name}/variable_names"])
    assert L.parameter_names == list(reference[f"{name}/parameter_names"])
    assert L.constraint_names == list(reference[f"{name}/constraint_names"])
    assert r.status == str(reference[f"{name}/status"]) == "optimal"
    x = r.x * pb.xscale
    np.testing.assert_allclose(x, reference[f"{name}/x_physical"], rtol=0, atol=RTOL_NLP_REFERENCE * L.variable_scale.max())
    assert np.all(np.abs(x - reference[f"{name}/x_physical"]) <= RTOL_NLP_REFERENCE * L.variable_scale)
    assert r.objective == pytest.approx(float(reference[f"{name}/objective"]), rel=RTOL_NLP_REFERENCE)


def _scenario(tmp_path: Path, name: str, body: str) -> Path:
    p = tmp_path / f"{name}.toml"
    p.write_text(body)
    return p


def test_mini_rover_through_its_rover_file_gives_the_same_primitive(tmp_path):
    four = load_scenario({p.stem: p for p in example_scenarios()}["nominal"])
    via = load_scenario(_scenario(tmp_path, "mini_file", '[scenario]\nrover = "mini_rover_t72"\nparams = "dissertation-ch7"\n'
                                  'speed_m_s = 0.03\n'))
    assert via.rover_file is not None and via.wheels == four.wheels
    r4, rf = solve_primitive(four), solve_primitive(via)
    assert r4.ok and rf.ok and rf.check_passed
    pf = _problem_for(via, SolverOptions())
    assert pf.layout.constraint_names == _problem_for(four, SolverOptions()).layout.constraint_names
    for k in four.wheels:
        a, b = r4.wheels[k], rf.wheels[k]
        assert b.omega == pytest.approx(a.omega, rel=1e-6) and b.load == pytest.approx(a.load, rel=1e-6)
        assert b.sinkage == pytest.approx(a.sinkage, rel=1e-6) and b.steer == pytest.approx(a.steer, abs=1e-7)
    assert rf.objective == pytest.approx(r4.objective, rel=1e-6)


@pytest.mark.parametrize("name", ["mini_rover_t72", "mer_class_rocker_bogie", "skid_steer_4w"])
@pytest.mark.parametrize("backward", [False, True])
def test_free_body_check_equals_the_nlp_rows(name, backward):
    rover = shipped_rover(name)
    rover = driving_backward(rover) if backward else rover
    st, fb = SuspensionStatics(rover), FreeBodyBalance(rover)
    rng = np.random.default_rng(23 + 2 * len(name) + backward)
    W = rover.weight / len(rover.wheels)
    for _ in range(3):
        wr = {k: tuple(rng.normal(size=6) * np.array([0.3, 0.3, 1.0, 0.05, 0.05, 0.05]) * W) for k in rover.wheel_names}
        beta = {k: rng.normal(0, 0.4) for k in rover.wheel_names}
        h = {k: rng.uniform(0.003, 0.04) for k in rover.wheel_names}
        load = {k: rng.uniform(0.5, 1.5) * W for k in rover.wheel_names}
        args = (rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.normal(), rng.normal())
        a = st.balance(NUMPY, wr, beta, h, load, args[0], args[2], args[3], args[1])
        b = fb.residuals(wr, beta, h, load, *args)
        for n in a:
            if n.startswith("height_compatibility"):
                continue
            assert a[n] == pytest.approx(b[n], abs=TOL_FREE_BODY_ABS), n
        if rover.suspension == "rigid":
            assert b["height_plane"] > 1e-4  # random sinkages are not on one plane: the row sees it


def test_driving_backward_turns_the_rover_half_round():
    mer = shipped_rover("mer_class_rocker_bogie")
    back = driving_backward(mer)
    assert back.wheel("RF").position == (-0.65, 0.6, -0.30)
    assert back.wheel("RF").steer_min == mer.wheel("RF").steer_min
    assert driving_backward(back).wheels == mer.wheels
    assert mirror_wheels(back) == {"RF": "LF", "LF": "RF", "RM": "LM", "LM": "RM", "RR": "LR", "LR": "RR"}


SOLVES = ["mer_nominal", "mer_nominal_backward", "mer_rf_unpowered", "mer_rf_unpowered_backward", "mer_rf_steer_stuck_7",
          "mer_rf_locked_1cm_backward", "skid_nominal", "skid_fr_unpowered"]


@pytest.fixture(scope="module")
def solved():
    cache: dict[str, object] = {}

    def get(name: str):
        if name not in cache:
            sc = load_scenario(ROVER_SCENARIOS / f"{name}.toml")
            cache[name] = (sc, solve_primitive(sc))
        return cache[name]

    return get


@pytest.mark.parametrize("name", SOLVES)
def test_rover_file_primitives_solve_and_pass_the_independent_check(solved, name):
    sc, r = solved(name)
    assert r.status == "optimal" and r.check_passed, (r.status, r.evidence)
    assert set(r.wheels) == set(sc.rover_file.wheel_names)
    pb = _problem_for(sc, SolverOptions())
    res, ok = check_solution(pb, sc, r.x)
    assert ok
    W = sc.rover_file.weight
    # the independent free body's rows vanish at the solution (forces to 1e-6 W, moments to 1e-6 W x wheelbase)
    bal = {k: v for k, v in res.items() if k.startswith("balance ")}
    assert {"balance Fx", "balance Fz", "balance My", "balance Mz"} <= set(bal)
    for k, v in bal.items():
        assert abs(v) <= 1e-6 * (pb.rs if "height" in k else W if k[8] == "F" else W * pb.length), k
    assert sum(w.load for w in r.wheels.values()) == pytest.approx(W * math.cos(sc.slope), rel=1e-6)
    for k, w in r.wheels.items():
        spec = sc.rover_file.wheel(k)
        if not spec.steerable:
            assert w.steer == 0.0
        assert w.omega <= sc.rover_file.actuators.drive_speed_max * (1 + 1e-6)
        assert abs(w.torque) <= sc.rover_file.actuators.drive_torque_max * (1 + 1e-6)
    f = sc.failure
    for k in sc.wheels:
        if f(k).unpowered:
            assert abs(r.wheels[k].torque) < 1e-6 * W * pb.rs
        if f(k).locked:
            assert r.wheels[k].omega == pytest.approx(0.0, abs=1e-9)
        if f(k).steer_stuck is not None:
            assert r.wheels[k].steer == pytest.approx(f(k).steer_stuck, abs=1e-9)
    if sc.rover_file.suspension == "rigid":
        assert res["balance height_plane"] < 1e-9


def test_six_wheel_rows_and_variables_follow_the_file():
    sc = load_scenario(ROVER_SCENARIOS / "mer_rf_steer_stuck_7.toml")
    L = _problem_for(sc, SolverOptions()).layout
    assert L.wheels == ("RF", "LF", "RM", "LM", "RR", "LR") and L.nx == 30
    assert [n for n in L.constraint_names if n.startswith("balance")] == [
        "balance Fx", "balance Fy", "balance Fz", "balance Mx", "balance My", "balance My_differential",
        "balance My_bogie_right", "balance My_bogie_left", "balance Mz"]
    assert sc.failure("RF").steer_stuck == pytest.approx(math.radians(7.0))


def test_nominal_six_wheel_primitive_is_left_right_symmetric(solved):
    _, r = solved("mer_nominal")
    for a, b in (("RF", "LF"), ("RM", "LM"), ("RR", "LR")):
        assert r.wheels[a].omega == pytest.approx(r.wheels[b].omega, rel=1e-6)
        assert r.wheels[a].load == pytest.approx(r.wheels[b].load, rel=1e-6)


def test_the_dead_wheel_costs_torque(solved):
    for dead in ("mer_rf_unpowered", "mer_rf_steer_stuck_7"):
        assert solved(dead)[1].objective > solved("mer_nominal")[1].objective
    assert solved("skid_fr_unpowered")[1].objective > solved("skid_nominal")[1].objective


@pytest.mark.parametrize("body,match", [
    ('rover = "mer_class_rocker_bogie"\n[wheels.FR]\nlocked = true\n', r"\[wheels.FR\] unknown wheel; use one of \['RF'"),
    ('rover = "mer_class_rocker_bogie"\n[wheels.RM]\nsteer_stuck_deg = 7.0\n', r"\[wheels.RM\] steer_stuck_deg: .*not steerable"),
    ('rover = "mer_class_rocker_bogie"\n[wheels.RM]\nraised = true\n', r"\[wheels.RM\] raised: .*'rocker' suspension only"),
    ('drive_direction = "backward"\n', r"drive_direction = 'backward' needs a rover file"),
    ('rover = "skid_steer_4w"\ndrive_direction = "sideways"\n', r"drive_direction = 'sideways'"),
])
def test_scenario_errors_name_the_key(tmp_path, body, match):
    head, _, wheels = body.partition("[wheels")
    text = "[scenario]\n" + head + ("[wheels" + wheels if wheels else "")
    with pytest.raises(ScenarioError, match=match):
        load_scenario(_scenario(tmp_path, "bad", text))


def test_rover_file_parameters_are_the_files_unless_the_scenario_names_them(tmp_path):
    sc = load_scenario(ROVER_SCENARIOS / "mer_nominal.toml")
    assert sc.params.wheel.radius == pytest.approx(0.13)  # mer_class_wheel.toml
    own = load_scenario(_scenario(tmp_path, "own", '[scenario]\nrover = "mer_class_rocker_bogie"\nparams = "dissertation-ch7"\n'))
    assert own.params.wheel.radius != pytest.approx(0.13)
    assert replace(sc, name="x").rover_file is sc.rover_file


def test_rim_speed_cap_on_a_six_wheel_bogie_wheel(tmp_path):
    p = _scenario(tmp_path, "mer_rr_cap", '[scenario]\nrover = "mer_class_rocker_bogie"\nspeed_m_s = 0.03\n'
                  '[wheels.RR]\nrim_speed_max_m_s = 0.02\n')
    sc = load_scenario(p)
    r = solve_primitive(sc)
    assert r.status == "optimal" and r.check_passed
    # IPOPT relaxes bounds by ~1e-8 relative; the failure kind's check allows check_rtol x travel speed
    assert r.wheels["RR"].rim_speed <= 0.02 + SolverOptions().check_rtol * sc.speed
    assert "rim speed RR" in r.residuals  # the failure kind's own check ran on the named wheel
