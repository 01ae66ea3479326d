"""The rover's exact linearisation, made cheaper, still computes the same numbers (issue 20).

``tests/data/online_step_reference.npz`` froze, with the code before the step-time work
(``tests/data/make_online_step_reference.py``, commit 98a77ab), the residual, objective,
objective gradient and row Jacobian of :meth:`SteadyStateResidual.evaluate` at seeded off-grid
points of every shipped table, and :func:`wrench_core` at seeded wheel states (slip, skid,
locked, reversed). A cheaper evaluation must agree to ``RTOL_REFACTOR`` of each quantity's
scale (the forward-difference gradient and Jacobian to that divided by their step); the Jacobian is also checked against central differences of the one-point residual
(an independent path: one wheel state per call, no structured columns).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import RTOL_AD_FD, RTOL_REFACTOR
from rtctl.physics.backend import NUMPY
from rtctl.physics.steady_state import SteadyStateModel, SteadyStateResidual
from rtctl.physics.terramechanics import wrench_core
from rtctl.table import load_index

ROOT = Path(__file__).resolve().parents[1]
REF = np.load(ROOT / "tests" / "data" / "online_step_reference.npz")
TABLES = {k: v for k, v in load_index(ROOT / "tables" / "index.json").items()}
NAMES = [str(n) for n in REF["tables"]]


def _residual(name):
    t = TABLES[name].load()
    return t, SteadyStateResidual(SteadyStateModel.from_table_header(t.header, t.layout.wheels), t.layout)


def _close(a, b, what, tol=RTOL_REFACTOR):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = max(float(np.max(np.abs(b))), 1e-300)
    err = float(np.max(np.abs(a - b))) / scale
    assert err <= tol, f"{what}: max difference {err:.3g} of its scale (tolerance {tol})"


# The objective gradient and the Jacobian are forward differences with a step of 1e-7 variable
# scales (SteadyStateResidual's fd_step): values that agree to RTOL_REFACTOR give differences
# that agree to RTOL_REFACTOR / 1e-7 of their scale, and no better (a restructured evaluation
# changes the rounding, which the difference divides by the step).
RTOL_FD_REFACTOR = RTOL_REFACTOR / 1e-7


def test_reference_covers_every_shipped_table_with_physics():
    assert len(NAMES) >= 5 and "rr_steer_stuck" in NAMES and "rr_trench_clean" in NAMES


@pytest.mark.parametrize("name", NAMES)
def test_linearisation_equals_the_frozen_values(name):
    _, res = _residual(name)
    for i, (x, p) in enumerate(zip(REF[f"{name}/x"], REF[f"{name}/p"])):
        g, f, grad, jac = res.evaluate(x, p, jacobian=True)
        _close(g, REF[f"{name}/g"][i], f"{name} point {i}: g")
        _close(f, REF[f"{name}/f"][i], f"{name} point {i}: f")
        _close(grad, REF[f"{name}/grad_f"][i], f"{name} point {i}: grad_f", RTOL_FD_REFACTOR)
        _close(jac, REF[f"{name}/jac_g_x"][i], f"{name} point {i}: jac_g_x", RTOL_FD_REFACTOR)
        g2, f2, grad2, none = res.evaluate(x, p, jacobian=False)  # the gradient-only columns: the same numbers
        assert none is None
        _close(g2, g, f"{name} point {i}: g without the Jacobian")
        _close(grad2, grad, f"{name} point {i}: grad_f without the Jacobian")


@pytest.mark.parametrize("name", NAMES)
def test_wheel_model_equals_the_frozen_values(name):
    _, res = _residual(name)
    S = REF[f"{name}/states"]
    w, _ = wrench_core(NUMPY, *(S[:, i:i + 1] for i in range(5)), res.model.phys[0], res.model.options)
    got = np.concatenate([np.asarray(q) for q in w], axis=1)
    ref = REF[f"{name}/wrench"]
    for c in range(6):  # each wrench component against its own scale
        _close(got[:, c], ref[:, c], f"{name}: wrench component {c}")


@pytest.mark.parametrize("name", ["rr_steer_stuck", "rr_trench_clean"])
def test_jacobian_against_central_differences_of_the_one_point_residual(name):
    t, res = _residual(name)
    sx = np.asarray(t.layout.variable_scale, dtype=float)
    x, p = REF[f"{name}/x"][0], REF[f"{name}/p"][0]
    g, _, _, jac = res.evaluate(x, p, jacobian=True)
    g1, _ = res.residual(x, p)
    _close(g1, g, f"{name}: one-point residual")
    fd = np.empty_like(jac)
    for j in range(x.size):
        d = 1e-6 * sx[j]
        e = np.zeros_like(x)
        e[j] = d
        fd[:, j] = (res.residual(x + e, p)[0] - res.residual(x - e, p)[0]) / (2 * d)
    scale = np.maximum(np.max(np.abs(fd), axis=1, keepdims=True), 1e-9)  # per row
    err = float(np.max(np.abs(jac - fd) / scale))
    assert err <= 100 * RTOL_AD_FD, f"{name}: forward-difference Jacobian vs central differences: {err:.3g} of the row scale"


def test_segment_nodes_sort_equals_the_fmin_fmax_network_bit_for_bit():
    """The numpy quadrature (one clamp and sort of the stacked breaks) gives exactly the nodes and
    weights of the fmin/fmax network the casadi graph uses (the same backend ops, network branch)."""
    from dataclasses import replace

    from rtctl.physics.backend import gauss_legendre

    network = replace(NUMPY, name="numpy, network")  # any other name takes the generic branch
    rng = np.random.default_rng(3)
    B = 64
    lo = rng.uniform(-0.6, 0.0, (B, 1))
    hi = rng.uniform(0.05, 0.8, (B, 1))
    breaks = [rng.uniform(-0.9, 1.0, (B, 1)) for _ in range(5)]
    breaks[1][:8] = breaks[0][:8]  # ties
    breaks[2][8:16] = hi[8:16] + 0.1  # beyond the ends: clamped
    x, w = gauss_legendre(8)
    th, wq = NUMPY.segment_nodes(lo, hi, breaks, x, w)
    th2, wq2 = network.segment_nodes(lo, hi, breaks, x, w)
    assert th.shape == wq.shape == (B, 48)
    assert np.array_equal(th, th2) and np.array_equal(wq, wq2)
    # states of mixed shapes broadcast as in the network
    th3, wq3 = NUMPY.segment_nodes(lo, hi, [breaks[0], np.full((1, 1), 0.01), *breaks[2:]], x, w)
    th4, wq4 = network.segment_nodes(lo, hi, [breaks[0], np.full((1, 1), 0.01), *breaks[2:]], x, w)
    assert np.array_equal(th3, th4) and np.array_equal(wq3, wq4)


VARIANTS = np.load(ROOT / "tests" / "data" / "wrench_core_variants_reference.npz")


@pytest.mark.parametrize("variant", [str(v) for v in VARIANTS["variants"]])
def test_wrench_core_variants_equal_the_frozen_values(variant):
    """Every model variant (bulldozing form, projection, scale, exit angle, node count) still
    gives the wrench frozen by ``tests/data/make_wrench_core_variants_reference.py`` (commit
    7e123c6, before the fused integrals): each component to ``RTOL_REFACTOR`` of the batch's
    force (|F|) or moment (|M|) scale."""
    from rtctl.physics.terramechanics import ModelOptions, PhysParams

    opts = ModelOptions(**eval(str(VARIANTS[f"{variant}/options"])))  # a dict literal written by the generator
    S = VARIANTS["states"]
    w, _ = wrench_core(NUMPY, *(S[:, i:i + 1] for i in range(5)), PhysParams(*VARIANTS["params"]), opts)
    got = np.concatenate([np.asarray(q) for q in w], axis=1)
    ref = VARIANTS[f"{variant}/wrench"]
    for cols, what in (((0, 1, 2), "force"), ((3, 4, 5), "moment")):
        scale = float(np.max(np.abs(ref[:, cols])))
        err = float(np.max(np.abs(got[:, cols] - ref[:, cols]))) / scale
        assert err <= RTOL_REFACTOR, f"{variant}: {what} differs by {err:.3g} of its scale (tolerance {RTOL_REFACTOR})"
