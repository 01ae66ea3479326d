"""The steady-state NLP built per wheel (an MX graph calling one SX wheel function) is the inlined NLP.

``SolverOptions.nlp_structure = "per_wheel"`` (:func:`offline.rover.primitives.per_wheel_graph`)
builds the same rows and objective from the same source as the default inlined SX graph:

* every function IPOPT evaluates (``f``, ``g``, their derivatives and the Lagrangian Hessian)
  equals the inlined one's to rounding, at the nominal start and at a perturbed point, on the
  mini rover, with a trench wheel, per-wheel rim radii with hub contact, and a rover file;
* its derivatives equal central finite differences of its own ``g`` and Lagrangian gradient;
* IPOPT from the same start reaches the same point in the same iterations, and the mini rover's
  seven reference scenarios (``tests/data/mini_rover_nlp_reference.npz``) solve to the stored
  primitive (to ``RTOL_NLP_STRUCTURE`` of each variable's scale: the search's IPOPT path may part
  at rounding level, e.g. ``fr_raised``);
* ``auto`` builds the inlined graph in casadi's virtual machine (``compile = "off"``);
* an unknown structure is an error naming the option.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import RTOL_AD_FD, RTOL_BACKENDS, RTOL_NLP_REFERENCE, RTOL_NLP_STRUCTURE

from offline.rover.primitives import SolverOptions, _problem_for, solve_primitive
from offline.rover.scenario import example_scenarios, load_scenario
from rtctl.physics.hub_drag import HubFace

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = ROOT / "tests" / "data" / "mini_rover_nlp_reference.npz"
FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")
EXAMPLES = {p.stem: p for p in example_scenarios()}


def _pair(sc):
    return (_problem_for(sc, SolverOptions(nlp_structure="inlined")), _problem_for(sc, SolverOptions(nlp_structure="per_wheel")))


def _dense(v) -> np.ndarray:
    import casadi as ca

    return np.asarray(ca.densify(v), dtype=float)


def _scenarios() -> dict[str, object]:
    """Mini rover nominal and stuck steering, a trench wheel, per-wheel radii with hub contact, a rover file."""
    nominal = load_scenario(EXAMPLES["nominal"])
    return {"nominal": nominal, "rr_steer_stuck_50": load_scenario(EXAMPLES["rr_steer_stuck_50"]),
            "rr_trench_clean": load_scenario(EXAMPLES["rr_trench_clean"]),
            "radii_hub": replace(nominal, wheel_radius=(0.049, 0.05, 0.051, 0.05),
                                 hub_contact=HubFace(clearance=0.01, face_width=0.03, arm=0.02)),
            "mer_rf_unpowered": load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_rf_unpowered.toml")}


def test_every_ipopt_function_equals_the_inlined_one():
    rng = np.random.default_rng(0)
    for name, sc in _scenarios().items():
        a, b = _pair(sc)
        assert a.layout.constraint_names == b.layout.constraint_names
        bd = a.bounds(sc)
        x0 = a.nominal_guess(sc)
        for x in (x0, x0 * (1 + 0.05 * rng.standard_normal(x0.size))):
            lam = rng.standard_normal(a.layout.ng)
            for n in FUNCTIONS:
                fa, fb = a.solver.get_function(n), b.solver.get_function(n)
                args = [x, bd["p"], 0.7, lam][:fa.n_in()]
                ra, rb = fa(*args), fb(*args)
                ra, rb = (r if isinstance(r, (list, tuple)) else [r] for r in (ra, rb))
                for u, v in zip(ra, rb):
                    u, v = _dense(u), _dense(v)
                    assert u.shape == v.shape
                    assert np.max(np.abs(u - v)) <= RTOL_BACKENDS * max(1.0, float(np.max(np.abs(u)))), (name, n)


def test_per_wheel_derivatives_match_finite_differences():
    import casadi as ca

    sc = load_scenario(EXAMPLES["rr_steer_stuck_50"])
    _, b = _pair(sc)
    s = b.symbols
    bd = b.bounds(sc)
    rng = np.random.default_rng(1)
    x = b.nominal_guess(sc) * (1 + 0.05 * rng.standard_normal(b.layout.nx))
    for i, k in enumerate(b.wheels):  # steered away from beta = 0 (the shear-direction smoothing's narrow curvature)
        x[b.layout.var("beta", k)] = (0.05 + 0.02 * i) / b.xscale[b.layout.var("beta", k)]
    lam = rng.standard_normal(b.layout.ng)
    g = ca.Function("g", [s["x"], s["p"]], [s["g"]])
    grad_lag = ca.Function("gl", [s["x"], s["p"]], [ca.gradient(s["f"] + ca.dot(ca.DM(lam), s["g"]), s["x"])])
    jac = _dense(b.solver.get_function("nlp_jac_g")(x, bd["p"])[1])
    hess = _dense(b.solver.get_function("nlp_hess_l")(x, bd["p"], 1.0, lam))
    hess = np.triu(hess) + np.triu(hess, 1).T  # IPOPT gets the upper triangle
    d = 1e-6
    for j in range(x.size):
        e = np.zeros(x.size)
        e[j] = d
        fd_j = (_dense(g(x + e, bd["p"])) - _dense(g(x - e, bd["p"]))).ravel() / (2 * d)
        fd_h = (_dense(grad_lag(x + e, bd["p"])) - _dense(grad_lag(x - e, bd["p"]))).ravel() / (2 * d)
        np.testing.assert_allclose(jac[:, j], fd_j, rtol=0, atol=RTOL_AD_FD * max(1.0, float(np.max(np.abs(jac)))))
        np.testing.assert_allclose(hess[:, j], fd_h, rtol=0, atol=RTOL_AD_FD * max(1.0, float(np.max(np.abs(hess)))))


def test_ipopt_from_the_same_start_reaches_the_same_point():
    sc = load_scenario(EXAMPLES["rr_steer_stuck_50"])
    a, b = _pair(sc)
    for slope in (0.0, math.radians(10.0)):
        s = replace(sc, slope=slope)
        bd = a.bounds(s)
        x0 = a.nominal_guess(s)
        ra, rb = a.solve(bd, x0), b.solve(bd, x0)
        assert ra["success"] and rb["success"]
        assert ra["iterations"] == rb["iterations"]
        assert np.max(np.abs(ra["x"] - rb["x"])) <= RTOL_NLP_REFERENCE


@pytest.mark.parametrize("name", ("nominal", "rl_unpowered", "opportunity_steer_stuck_7", "rr_speed_cap_half", "fr_raised",
                                  "rr_steer_stuck_50", "hillside_traverse_10"))
def test_reference_scenarios_solve_to_the_stored_primitive(name):
    ref = np.load(REFERENCE)
    sc = load_scenario(EXAMPLES[name])
    opt = SolverOptions(nlp_structure="per_wheel")
    r = solve_primitive(sc, opt)
    pb = _problem_for(sc, opt)
    assert r.status == "optimal"
    assert np.all(np.abs(r.x * pb.xscale - ref[f"{name}/x_physical"]) <= RTOL_NLP_STRUCTURE * pb.layout.variable_scale)
    assert r.objective == pytest.approx(float(ref[f"{name}/objective"]), rel=RTOL_NLP_STRUCTURE)


def test_auto_builds_inlined_in_the_virtual_machine(monkeypatch):
    monkeypatch.delenv("OFFNOMINAL_NLP_STRUCTURE", raising=False)
    assert SolverOptions().nlp_structure == "auto"  # the default: per wheel only when compiled
    sc = load_scenario(EXAMPLES["nominal"])
    assert _problem_for(sc, SolverOptions(compile="off")).nlp_structure == "inlined"
    assert _problem_for(sc, SolverOptions(nlp_structure="auto", compile="off")).nlp_structure == "inlined"
    assert _problem_for(sc, SolverOptions(nlp_structure="per_wheel", compile="off")).nlp_structure == "per_wheel"


def test_unknown_structure_is_an_error_naming_the_option():
    with pytest.raises(ValueError, match="nlp_structure = 'mx'"):
        SolverOptions(nlp_structure="mx")
