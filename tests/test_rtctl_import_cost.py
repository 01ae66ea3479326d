"""The controller's import cost (issue 25): filterpy's EKF without the filters rtctl does not use.

``from filterpy.kalman import ExtendedKalmanFilter`` imports every filter of the package and
scipy.stats; rtctl.estimator loads the class from its own module file instead
(:func:`rtctl.estimator._filterpy_ekf`). These tests check that the class is filterpy's, unchanged
in behaviour, that the stand-ins it used are gone, and that the rest of filterpy still imports
normally afterwards. (Import *times* are measured in ``tests/bench/bench_rtctl.py import``.)"""

from __future__ import annotations

import subprocess
import sys

import numpy as np


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_controller_import_skips_scipy_stats_and_the_other_filters():
    out = _run("import sys, rtctl.controller, rtctl.estimator as e; "
               "print(e.FILTERPY_EKF_SOURCE, 'scipy.stats' in sys.modules, 'filterpy.kalman' in sys.modules, "
               "'filterpy.stats' in sys.modules, 'filterpy.common' in sys.modules, "
               "e.ExtendedKalmanFilter.__module__)")
    assert out == "module file False False False False rtctl._filterpy_ekf"


def test_filterpy_still_imports_normally_afterwards():
    out = _run("import numpy as np, rtctl.estimator as e, filterpy.stats, filterpy.common, filterpy.kalman; "
               "print(hasattr(filterpy.stats, 'multivariate_normal'), hasattr(filterpy.common, 'Q_discrete_white_noise'), "
               "filterpy.kalman.ExtendedKalmanFilter is not e.ExtendedKalmanFilter); "
               "lazy = e.ExtendedKalmanFilter.__init__.__globals__['logpdf']; "
               "print(lazy is not filterpy.stats.logpdf, lazy(x=[0.1], cov=1.0) == filterpy.stats.logpdf(x=[0.1], cov=1.0))")
    # the EKF module's logpdf is the stand-in, which calls the real filterpy.stats.logpdf
    assert out.splitlines() == ["True True True", "True True"]


def test_same_bits_as_the_package_class():
    """The class from the module file and the package's compute the same bits (the same code)."""
    from filterpy.kalman import ExtendedKalmanFilter as Package

    from rtctl.estimator import ExtendedKalmanFilter as Light

    rng = np.random.default_rng(3)
    F = np.eye(3) + 0.1 * rng.normal(size=(3, 3))
    H = rng.normal(size=(2, 3))
    filters = []
    for cls in (Package, Light):
        f = cls(dim_x=3, dim_z=2)
        f.x = np.array([0.1, -0.2, 0.3])
        f.P = np.eye(3) * 0.5
        f.F, f.Q, f.R = F, np.eye(3) * 1e-3, np.eye(2) * 1e-2
        filters.append(f)
    for k in range(20):
        z = rng.normal(size=2)
        for f in filters:
            f.predict()
            f.update(z, lambda x: H, lambda x: H @ x)
    a, b = filters
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
