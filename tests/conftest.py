"""Shared fixtures and the project's test tolerances, named per quantity (STYLE.md point 9)."""

from __future__ import annotations

import os
from pathlib import Path

# One BLAS thread per process: xdist already runs one worker per core, and OpenBLAS's own threads
# beside them oversubscribe the cores and spin (measured on the drive diagnoses' region tests, a
# 42000 x 40 x 1000 product: 2.58 CPU-s with two threads against 1.75 with one, the same result to
# the bit). Set before numpy loads OpenBLAS; the workers inherit it. A value set by the caller wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import pytest

from offline.physics.params import (
    SOIL_DISSERTATION_T53_GROUSERED,
    TUNING_T54_GROUSERED,
    TUNING_T72_LINEAR,
    WHEEL_GROUSERED_PUBLISHED_CODE,
)
from offline.physics.terramechanics import WheelModel

# Table builds in the suite run casadi's virtual machine: compiling an NLP's functions costs minutes
# of CPU once per NLP structure (offline.rover.compiled_nlp); tests/test_compiled_nlp.py tests that
# path. Set here, before any test module, so xdist workers and CLI subprocesses inherit it.
os.environ.setdefault("OFFNOMINAL_COMPILE", "off")

# --- tolerances (relative unless named _abs) -------------------------------------------
RTOL_BACKENDS = 1e-10  # numpy vs casadi evaluation of the same graph
RTOL_AD_FD = 1e-5  # exact derivative vs central finite difference
RTOL_REFACTOR = 1e-12  # a faster evaluation of the same physics vs values frozen from the code before it
RTOL_QUADRATURE = 2e-3  # default Gauss-Legendre nodes vs a 100-node reference
RTOL_SINKAGE_LOAD = 1e-6  # |F_z(h) - W| / W after the sinkage solve
RTOL_SWITCH = 5e-5  # value jump across the slip/skid switch, relative to |F| scale: the exact model is
# continuous; numerically the breakpoints move across the switch, so the jump is quadrature-level
# (measured 1.2e-5 at beta = 0, 8 nodes per segment)

RTOL_NLP_REFERENCE = 1e-9  # the mini rover's NLP re-solved after a refactor vs its stored solution (per variable
# scale; the refactor reproduced it bit for bit on the machine that made it)
RTOL_NLP_STRUCTURE = 1e-8  # the per-wheel NLP structure's solution vs the inlined one's (per variable scale): the same
# functions to rounding, but IPOPT's path may part at rounding level (fr_raised: 82 against 91 iterations, 8.7e-9
# scales apart, both within IPOPT's tol = 1e-9 of the scaled KKT conditions)

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "single_wheel"


@pytest.fixture(scope="session")
def model() -> WheelModel:
    """Published-code grousered wheel, Table 5.3 soil, continuous a(beta) of Table 7.2."""
    return WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR)


@pytest.fixture(scope="session")
def model_t54_45() -> WheelModel:
    """Table 5.4 tuning at beta = 45 deg."""
    return WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T54_GROUSERED[45.0])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261122)


@pytest.fixture(scope="session")
def calibrated_params():
    """The shipped calibrated grousered-wheel parameter set (``offline/data/calibrated_grousered.toml``)."""
    from importlib import resources

    from offline.physics.params import load_toml

    return load_toml(resources.files("offline").joinpath("data", "calibrated_grousered.toml"))["parameter_set"]


@pytest.fixture(scope="session")
def steady_recording():
    """The real single-wheel trials at the steady-state angles 0-60 deg (data README), one row per
    condition (:class:`~offline.discrepancy.wheel.recording.SingleWheelRecording`)."""
    from offline.discrepancy.wheel.recording import SingleWheelRecording
    from offline.fit.dataset import load_trials

    tr = load_trials()
    return SingleWheelRecording.from_trials(tr.subset(np.degrees(tr.beta_cmd) < 61))
