"""The compiled wrench/Jacobian path (C code generation) against the casadi path it is built from."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from offline.physics.params import SOIL_DISSERTATION_T53_GROUSERED, TUNING_T72_LINEAR, WHEEL_GROUSERED_PUBLISHED_CODE
from offline.physics.terramechanics import WheelModel, state_from_slip

needs_cc = pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None,
                              reason="no C compiler: the compiled path falls back to casadi (tested elsewhere)")


@needs_cc
def test_compiled_wrench_and_jacobian_equal_the_casadi_path():
    model = WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR)
    rng = np.random.default_rng(3)
    vx, vy, w = state_from_slip(rng.uniform(-0.9, 0.9, 40), rng.uniform(-1.2, 1.2, 40), 0.03, model.wheel)
    h = rng.uniform(0.004, 0.04, 40)
    for i in range(40):
        x = np.array([vx[i], vy[i], w[i], h[i], 0.9 * h[i]])
        wc, Jc = model.wrench_and_jacobian(x, compiled=True)
        wi, Ji = model.wrench_and_jacobian(x, compiled=False)
        np.testing.assert_allclose(wc, wi, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(wi).max()))
        np.testing.assert_allclose(Jc, Ji, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(Ji).max()))
    assert model._direct  # the ctypes fast path was used, not a silent fallback


@needs_cc
def test_a_cold_build_says_what_it_builds(tmp_path, capsys, monkeypatch):
    import os

    import casadi as ca

    def no_chdir(path):  # the working folder is the process's: changing it raced with spawned workers
        raise AssertionError(f"os.chdir({path!r}) while generating C")

    monkeypatch.setattr(os, "chdir", no_chdir)

    model = WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR)
    x = ca.SX.sym("x", 2)
    f = ca.Function("tiny_test_fn", [x], [ca.sin(x[0]) * x[1]])
    g = model._compile(f, "tiny", cache_dir=tmp_path)
    err = capsys.readouterr().err
    assert "building the compiled tiny_test_fn" in err and str(tmp_path) in err and "built" in err
    assert float(g([0.5, 2.0])) == pytest.approx(np.sin(0.5) * 2.0, rel=1e-14)
    model._compile(f, "tiny", cache_dir=tmp_path)  # cache hit: silent
    assert "building" not in capsys.readouterr().err
