"""Helpers shared by the command modules: shipped files, error printing, loaders that report instead of raising."""

from __future__ import annotations

import sys
from importlib import resources
from pathlib import Path
from typing import Any

__all__ = ["DEFAULT_PARAMS", "DEFAULT_PARAMS_SF", "WHEELS", "TUNED_SETS", "shipped", "fail", "trials_or_fail",
           "parameter_set_or_fail", "soil_flow_available", "load_scenario_or_fail", "provenance", "file_sha256"]

DEFAULT_PARAMS = "calibrated_grousered.toml"
"""Parameter file shipped in ``offline/data`` (written by ``offnominal calibrate``)."""
DEFAULT_PARAMS_SF = "calibrated_grousered_soil_flow.toml"
"""Soil-flow variant (``offnominal calibrate --exit-angle soil_flow``)."""

WHEELS = {
    "published-code": "WHEEL_GROUSERED_PUBLISHED_CODE",
    "table-5.2": "WHEEL_GROUSERED_T52",
}


TUNED_SETS = {
    "authors-grousered": "grouser_tuned_params.csv",
    "table-5.4-grousered": "dissertation_grousered_t54.toml",
    "table-5.4-smooth": "dissertation_smooth_t54.toml",
}
"""Built-in per-angle tuned sets for ``validate --tuned``: the data authors' a0..b1 for the
grousered wheel (published code's wheel, Table 5.3 soil), and Table 5.4's grousered and
smooth rows with the Table 5.2 wheel and Table 5.3 soil of each."""


def shipped(name: str) -> Path:
    """Path of a file shipped in ``offline/data``."""
    return Path(str(resources.files("offline").joinpath("data", name)))


def file_sha256(path: str | Path) -> str:
    """Hex sha256 of a file's bytes."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def provenance(path: str | Path) -> dict[str, str]:
    """A file's name and content hash (never a machine path), for shipped metadata."""
    p = Path(path)
    return {"name": p.name, "sha256": file_sha256(p)}


def fail(msg: str) -> int:
    """Print ``offnominal: error: msg`` to stderr and return exit status 2."""
    print(f"offnominal: error: {msg}", file=sys.stderr)
    return 2


def trials_or_fail(path: str | None) -> Any:
    """Load trials, or print the loader's message and return None."""
    from ..fit.dataset import DatasetError, load_trials

    try:
        return load_trials(path)
    except (DatasetError, FileNotFoundError) as exc:
        fail(str(exc))
        return None


def parameter_set_or_fail(path: str | None) -> tuple[Any, Path]:
    """Load a parameter set (default: the shipped calibrated file), or print why not."""
    from ..physics import params as P

    params_path = Path(path) if path else shipped(DEFAULT_PARAMS)
    try:
        loaded = P.load_toml(params_path)
    except P.ParameterError as exc:
        fail(str(exc))
        return None, params_path
    if "parameter_set" not in loaded:
        fail(f"{params_path}: needs [soil], [wheel] and [tuning] sections")
        return None, params_path
    return loaded["parameter_set"], params_path


def soil_flow_available() -> bool:
    """True when the soil-flow model (chapter 4) can be imported."""
    try:
        from rtctl.physics import soil_flow  # noqa: F401
    except ImportError:
        return False
    return True


def load_scenario_or_fail(path: str) -> Any:
    """Load a scenario file (or a shipped example by name), or print why not and return None."""
    from ..rover.scenario import ScenarioError, example_scenarios, load_scenario

    p = Path(path)
    if not p.exists():
        shipped = {q.stem: q for q in example_scenarios()}
        if path in shipped:
            p = shipped[path]
    try:
        return load_scenario(p)
    except ScenarioError as exc:
        print(f"offnominal: error: {exc}", file=sys.stderr)
        return None
