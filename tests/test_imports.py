"""Front doors and the rtctl import contract (ARCHITECTURE.md: rtctl stays light)."""

from __future__ import annotations

import importlib
import importlib.util
import subprocess
import sys

import pytest

import offline


def test_rtctl_imports_no_heavy_or_offline_modules():
    """Every rtctl module loads without casadi or offline (scipy is allowed: filterpy imports
    it; qpsolvers is imported lazily, only for cross-checks)."""
    code = (
        "import sys, importlib, rtctl; "
        "[importlib.import_module('rtctl.' + m) for m in rtctl.__all__]; "
        "bad = [m for m in sys.modules if m == 'casadi' or m.startswith('casadi.') "
        "or m == 'offline' or m.startswith('offline.') or m == 'qpsolvers']; "
        "print(','.join(bad)); sys.exit(1 if bad else 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, f"rtctl pulled in: {out.stdout} {out.stderr}"


def test_import_check_can_fail():
    """The same check flags a module that imports offline (the test is not vacuous)."""
    code = ("import sys, rtctl, offline.files; "
            "bad = [m for m in sys.modules if m == 'offline' or m.startswith('offline.')]; sys.exit(1 if bad else 0)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 1


RTCTL_MODULES = [*(f"rtctl.{m}" for m in importlib.import_module("rtctl").__all__),
                 *(f"rtctl.physics.{m}" for m in importlib.import_module("rtctl.physics").__all__)]


@pytest.mark.parametrize("name", RTCTL_MODULES)
def test_rtctl_public_names_documented(name):
    import inspect

    mod = importlib.import_module(name)
    assert (mod.__doc__ or "").strip(), f"{name} has no module docstring"
    assert isinstance(mod.__all__, (list, tuple)) and mod.__all__
    missing = [item for item in mod.__all__ if (inspect.isfunction(getattr(mod, item)) or inspect.isclass(getattr(mod, item)))
               and not (inspect.getdoc(getattr(mod, item)) or "").strip()]
    assert not missing, f"{name}: undocumented public names {missing}"


def test_offline_numeric_path_does_not_import_casadi():
    code = (
        "import sys, numpy as np; from offline.physics.terramechanics import WheelModel; "
        "from offline.physics.params import *; "
        "m = WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR); "
        "m.wrench(0.01, 0.0, 0.1, 0.02); sys.exit(1 if 'casadi' in sys.modules else 0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr


def _modules() -> list[str]:
    """Every module of the offline front door: the subpackages and the modules they list."""
    names = []
    for pkg in offline.__all__:
        sub = importlib.import_module(f"offline.{pkg}")
        names.append(f"offline.{pkg}")
        if hasattr(sub, "__path__"):  # a subpackage: the modules its __all__ lists
            names += [f"offline.{pkg}.{m}" for m in sub.__all__ if importlib.util.find_spec(f"offline.{pkg}.{m}")]
    return names


MODULES = _modules()


@pytest.mark.parametrize("name", [m for m in MODULES if m != "offline.sim"])
def test_every_module_declares_all(name):
    mod = importlib.import_module(name)
    assert isinstance(mod.__all__, (list, tuple)) and mod.__all__
    for item in mod.__all__:
        is_submodule = hasattr(mod, "__path__") and importlib.util.find_spec(f"{name}.{item}") is not None
        assert is_submodule or hasattr(mod, item), f"{name}.__all__ lists missing name {item}"


def test_offline_front_door_lists_real_modules():
    for m in offline.__all__:
        importlib.import_module(f"offline.{m}")


@pytest.mark.parametrize("name", MODULES)
def test_every_public_name_is_documented(name):
    """Every name a module exports has a docstring (STYLE.md point 7); the module too."""
    import inspect

    mod = importlib.import_module(name)
    assert (mod.__doc__ or "").strip(), f"{name} has no module docstring"
    missing = []
    for item in mod.__all__:
        obj = getattr(mod, item)
        if inspect.isfunction(obj) or inspect.isclass(obj):
            if not (inspect.getdoc(obj) or "").strip():
                missing.append(item)
    assert not missing, f"{name}: undocumented public names {missing}"
