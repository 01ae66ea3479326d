"""The allocation QP is one exact SQP step of (7.25) in the parameters too (issue 11).

On a table built by the real NLP (``tests/data/rtctl_nominal_small.npz``, see
``tests/data/README_rtctl.md``), with tight OSQP settings, the change of the QP step with a
parameter (speed, slope, cross slope, the offsets of (7.26)-(7.27)) must equal the table's
parametric sensitivity ``dx*/dp`` (KKT system) times that change. The speed moves the wheel
velocities inside the wrench, so its response needs the cross derivative ``d^2 L / dx dp``
(``hess_lag_xp``) in the QP's linear term; without it the step is off by 11-28 % (measured,
and asserted below so that this test fails if the term is dropped).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtctl.allocator import QpAllocator
from rtctl.config import QpSettings
from rtctl.table import load_table

DATA = Path(__file__).resolve().parent / "data" / "rtctl_nominal_small.npz"
TIGHT = replace(QpSettings(), regularization=1e-9, command_weight=0.0, eps=1e-10, max_iter=200_000)
STEPS = {"speed": 0.001, "slope": 0.01, "cross_slope": 0.005, "mz_offset": 0.01, "fy_offset": 0.03}


class _WithoutCrossTerm:
    """A table point whose ``hess_lag_xp`` is withheld (the allocator then uses zeros)."""

    def __init__(self, tp):
        self._tp = tp

    def __getattr__(self, name):
        return None if name == "hess_lag_xp" else getattr(self._tp, name)


def _response_error(table, tp, name, cross_term=True):
    """max |QP step change - dx/dp dp| / scale, relative to max |dx/dp dp| / scale."""
    lay = table.layout
    j = lay.index(name)
    a = QpAllocator(lay, TIGHT)
    a.prepare(tp if cross_term else _WithoutCrossTerm(tp))
    base = a.solve(tp.p, (tp.lbx, tp.ubx))
    p = tp.p.copy()
    p[j] += STEPS[name]
    res = a.solve(p, (tp.lbx, tp.ubx))
    assert base.ok and res.ok and res.slack < 1e-6, res.status
    sx = lay.variable_scale
    pred = tp.dx_dp[:, j] * STEPS[name] / sx
    return float(np.max(np.abs((res.dx - base.dx) / sx - pred)) / np.max(np.abs(pred)))


@pytest.fixture(scope="module")
def table():
    return load_table(DATA, expect_rover="mini_rover")


@pytest.mark.parametrize("index", [(0, 0, 1), (1, 0, 0)])  # (slope 0, speed 3 cm/s), (slope 5 deg, 2 cm/s)
@pytest.mark.parametrize("name", list(STEPS))
def test_qp_response_to_every_parameter_is_the_tables_sensitivity(table, index, name):
    """Measured 2026-11-23: 1e-7..5e-6 relative for every parameter (the speed 2e-7)."""
    tp = table.at(**table.grid_point(index))
    assert np.any(tp.dx_dp[:, table.layout.index(name)] != 0)
    assert _response_error(table, tp, name) < 1e-4


@pytest.mark.parametrize("index", [(0, 0, 1), (1, 0, 0)])
def test_without_the_cross_term_the_speed_response_is_wrong(table, index):
    """The check above can fail: dropping d^2 L / dx dp gives 11 % (slope 0) and 28 %
    (slope 5 deg) error in the speed response (measured 2026-11-23)."""
    tp = table.at(**table.grid_point(index))
    assert np.abs(tp.hess_lag_xp[:, table.layout.index("speed")]).max() > 0
    assert _response_error(table, tp, "speed", cross_term=False) > 0.05
