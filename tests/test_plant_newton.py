"""The plant's Newton solve (:meth:`offline.sim.plant.PlantModel.solve`): its cheaper line search
changes no result, and a solve that finds no equilibrium gives up within its budgets.

The reference is the solve as it was before the line search evaluated shortened steps without the
wheel Jacobian (commit b65a2c7): every trial point evaluated with its Jacobian. Converged solves
must agree with it bit for bit (unknowns and iteration count), failed ones must fail as well.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import offline.sim.plant as plant_module
from offline.rover.primitives import solve_primitive
from offline.rover.scenario import example_scenarios, load_scenario
from offline.sim.plant import PlantModel, SimulationError
from offline.sim.simulator import RoverSimulator, plant_for
from rtctl.messages import Commands

WHEELS = ("FR", "FL", "RR", "RL")


def reference_solve(plant: PlantModel, z0: np.ndarray, a: np.ndarray, q: np.ndarray,
                    d: np.ndarray | None = None) -> tuple[np.ndarray, plant_module.PlantSolution]:
    """Newton with backtracking on the max-norm, every trial with its Jacobian (the previous solve)."""
    z = np.array(z0, dtype=float)
    res, J, w, sl, be = plant.evaluate(z, a, q, d)
    norm = float(np.max(np.abs(res)))
    it = 0
    while norm > plant.TOL and it < plant.MAX_NEWTON:
        it += 1
        try:
            dz = np.linalg.solve(J, -res)
        except np.linalg.LinAlgError:
            dz = np.linalg.lstsq(J, -res, rcond=None)[0]
        big = np.max(np.abs(dz[7:]))
        lam = 1.0 if big < 1.0 else 1.0 / big
        for _ in range(30):
            zt = z + lam * dz
            rt, Jt, wt, slt, bet = plant.evaluate(zt, a, q, d)
            nt = float(np.max(np.abs(rt)))
            if np.isfinite(nt) and (nt < (1 - 1e-4 * lam) * norm or nt <= plant.TOL):
                break
            lam *= 0.5
        else:
            break
        z, res, J, w, sl, be, norm = zt, rt, Jt, wt, slt, bet, nt
    if not (norm <= 1e-7 and np.all(np.isfinite(z))):
        raise SimulationError(f"reference: no equilibrium ({norm:.3g} after {it} iterations)")
    contact = np.asarray(a[25:29]) if len(a) > 25 else np.ones(4)
    return z, plant_module.PlantSolution(float(z[0]), float(z[1]), float(z[2]), z[3:7].copy(), np.exp(z[7:11]) * contact,
                                         np.exp(z[11:15]) * contact, w.reshape(4, 6), sl.ravel(), be.ravel(), it, norm)


class _Counter:
    """Counts plant evaluations, with and without the wheel Jacobian."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.full = self.residual_only = 0
        original = PlantModel._evaluate  # what the solve calls (evaluate with its per-solve context)

        def evaluate(plant: PlantModel, z: Any, ctx: Any, d: Any, jacobian: bool) -> Any:
            if jacobian:
                self.full += 1
            else:
                self.residual_only += 1
            return original(plant, z, ctx, d, jacobian)

        monkeypatch.setattr(PlantModel, "_evaluate", evaluate)

    def reset(self) -> None:
        self.full = self.residual_only = 0


@pytest.fixture(scope="module")
def driving() -> RoverSimulator:
    sc = load_scenario({p.stem: p for p in example_scenarios()}["nominal"])
    prim = solve_primitive(sc)
    sim = RoverSimulator(sc, seed=0)
    sim.start(Commands(0.0, 0, tuple(prim.wheels[k].rim_speed for k in WHEELS), tuple(prim.wheels[k].steer for k in WHEELS)))
    return sim


def test_residual_only_evaluation_is_bit_identical(driving: RoverSimulator) -> None:
    """``evaluate(jacobian=False)`` gives the same residual, wrench, slip and slip angle to the bit
    (steered, disturbed, quasi-static and dynamic, a wheel in torque mode, a raised wheel; the
    compiled and the interpreted plant), and a NaN Jacobian."""
    sim = driving
    interpreted = plant_for(sim.scenario.params, sim.scenario.rover, sim.scenario.exit_angle, compiled=False)
    rng = np.random.default_rng(1)
    for k in range(12):
        z = sim.z + rng.normal(0, 1, 15) * np.r_[1e-2, 1e-2, 3e-2, 0.1 * np.ones(4), 0.3 * np.ones(8)]
        a = sim._inputs([0.0, 5.0][k % 2])
        a[12:16] = rng.uniform(-0.5, 0.5, 4)
        if k % 3 == 1:
            a[4 + k % 4], a[8 + k % 4] = 0.0, 0.3  # a wheel held at a torque
        if k % 4 == 3:
            a[25 + k % 4] = 0.0  # a raised wheel
        d = rng.normal(0, 1.0, 15) if k % 2 else None
        for plant in (sim.plant, interpreted):
            full = plant.evaluate(z, a, sim.q, d)
            cheap = plant.evaluate(z, a, sim.q, d, jacobian=False)
            for i in (0, 2, 3, 4):
                assert np.array_equal(full[i], cheap[i], equal_nan=True), (k, i, plant is interpreted)
            assert np.all(np.isfinite(full[1])) and np.all(np.isnan(cheap[1]))


def test_converged_solves_unchanged_and_line_search_residual_only(driving: RoverSimulator,
                                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """From perturbed starts (steered, under a drawbar pull): every solve equals the reference bit
    for bit or fails with it; shortened steps are evaluated without the Jacobian."""
    sim = driving
    rng = np.random.default_rng(0)
    cases = []
    for k in range(30):
        z = sim.z + rng.normal(0, 1, 15) * np.r_[1e-2, 1e-2, 3e-2, 0.1 * np.ones(4), 0.5 * np.ones(8)]
        a = sim._inputs([0.0, 5.0][k % 2])
        a[12:16] = rng.uniform(-0.4, 0.4, 4)
        d = np.zeros(15)
        d[0] = -rng.uniform(0.0, 12.0)
        cases.append((z, a, d))
    expected = []
    for z, a, d in cases:
        try:
            expected.append(reference_solve(sim.plant, z, a, sim.q, d))
        except SimulationError:
            expected.append(None)
    count = _Counter(monkeypatch)
    shortened = 0
    for (z, a, d), exp in zip(cases, expected):
        count.reset()
        if exp is None:
            with pytest.raises(SimulationError):
                sim.plant.solve(z, a, sim.q, d)
            continue
        trace: list[dict[str, Any]] = []
        zz, sol = sim.plant.solve(z, a, sim.q, d, trace=trace)
        assert np.array_equal(zz, exp[0]) and sol.iterations == exp[1].iterations
        assert np.array_equal(sol.wrench, exp[1].wrench) and np.array_equal(sol.slip, exp[1].slip)
        assert len(trace) == 1 + sol.iterations and np.array_equal(trace[-1]["z"], zz)
        assert trace[-1]["norm"] == sol.residual
        assert count.full <= 1 + sol.iterations + count.residual_only
        shortened += count.residual_only > 0
    assert sum(e is not None for e in expected) >= 25
    assert shortened >= 5  # the residual-only path was exercised by converged solves


def test_failed_solve_gives_up_within_budget(driving: RoverSimulator, monkeypatch: pytest.MonkeyPatch) -> None:
    """A drawbar pull of 20 N on the 34 N rover: no equilibrium (the wheels go to full slip). The
    solve raises within its budgets: at most ``MAX_NEWTON`` iterations of at most 30 trial points,
    at most two Jacobian evaluations per iteration, and most trial points without the Jacobian."""
    sim = driving
    assert sim.weight < 35.0
    d = np.zeros(15)
    d[0] = -20.0
    count = _Counter(monkeypatch)
    for inv_dt in (0.0, 5.0):
        count.reset()
        a = sim._inputs(inv_dt)
        with pytest.raises(SimulationError, match="no equilibrium"):
            sim.plant.solve(sim.z, a, sim.q, d)
        n = PlantModel.MAX_NEWTON
        assert count.full <= 1 + 2 * n
        assert count.full + count.residual_only <= 1 + 31 * n
        assert count.residual_only > 2 * count.full  # the failing line searches cost residuals only
        with pytest.raises(SimulationError):
            reference_solve(sim.plant, sim.z, a, sim.q, d)


def test_short_drive_bit_identical_to_reference(monkeypatch: pytest.MonkeyPatch) -> None:
    """A 6 s drive with a steering step and a growing drawbar pull: every tick's truth equals the
    drive simulated with the reference solve, bit for bit."""
    from offline.sim.simulator import DisturbanceForces

    sc = load_scenario({p.stem: p for p in example_scenarios()}["nominal"])
    prim = solve_primitive(sc)
    rim = tuple(prim.wheels[k].rim_speed for k in WHEELS)

    def pull(t: float, _: Any) -> DisturbanceForces:
        return DisturbanceForces(body_force=(-1.5 * t, 0.3))

    def drive() -> list[np.ndarray]:
        sim = RoverSimulator(sc, seed=0, disturbance=pull)
        sim.start(Commands(0.0, 0, rim, (0.0,) * 4))
        out = []
        for k in range(30):
            steer = (0.35, 0.35, -0.35, -0.35) if k >= 5 else (0.0,) * 4
            sim.apply(Commands(0.2 * k, k, rim, steer))
            sim.advance(0.2)
            out.append(sim.z.copy())
        return out

    count = _Counter(monkeypatch)
    new = drive()
    assert count.residual_only > 0  # shortened steps were taken (and evaluated without the Jacobian)
    monkeypatch.undo()

    monkeypatch.setattr(PlantModel, "solve", reference_solve)
    old = drive()
    assert len(new) == len(old) == 30
    for k, (x, y) in enumerate(zip(new, old)):
        assert np.array_equal(x, y), k
