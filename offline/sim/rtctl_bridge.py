"""The rtctl controller as a pluggable controller of the closed-loop harness.

Kept apart from :mod:`offline.sim.experiments` so the harness runs (with the optimizer's
controllers) where no tables have been built.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Callable

from ..rover.scenario import Scenario

__all__ = ["RtctlUnavailable", "rtctl_factory", "rtctl_controller", "shipped_tables"]


class RtctlUnavailable(RuntimeError):
    """rtctl's controller or its tables cannot be loaded; the message says what to build or pass."""


def shipped_tables() -> Path:
    """The shipped tables: the data package ``offnominal_tables`` (the repository's ``tables/``,
    installed with the package), else the ``tables/`` folder beside ``offline/`` in a checkout."""
    try:
        import offnominal_tables

        return offnominal_tables.folder()
    except ImportError:
        return Path(str(resources.files("offline"))).parent / "tables"


def rtctl_factory(tables: str | None = None, config: str | None = None) -> Callable[[Scenario], Any]:
    """A function ``scenario -> Controller`` on the given (default: shipped) tables and config.

    The controller chooses among the tables by the failures the rover declares, so one set of
    tables serves every scenario; the scenario's travel speed is the controller's target.

    Raises
    ------
    RtctlUnavailable
        No table index where expected, or rtctl's controller fails to load the tables.
    """
    base = _load(tables, config)
    return lambda sc: _at_speed(base, sc.speed)


def rtctl_controller(tables: str | None, config: str | None, speed: float) -> Any:
    """rtctl's Controller on the tables at a target ``speed`` (m/s); picklable through
    ``functools.partial`` as the factory of :func:`rtctl.hil.run_hil`'s controller process."""
    return _at_speed(_load(tables, config), speed)


def _load(tables: str | None, config: str | None) -> Any:
    try:
        from rtctl.hil import load_controller
    except ImportError as exc:
        raise RtctlUnavailable(f"rtctl's controller is not installed ({exc})") from None
    path = Path(tables) if tables else shipped_tables()
    index = path / "index.json" if path.is_dir() else path
    if not index.exists():
        raise RtctlUnavailable(f"{index}: no table index; build tables with 'offnominal tables build <scenario> --out "
                               f"{path}' or pass --tables")
    try:
        return load_controller(str(index), config)
    except Exception as exc:  # the table reader's and controller's own errors say what is wrong
        raise RtctlUnavailable(f"rtctl could not load {index}: {exc}") from None


def _at_speed(base: Any, speed: float) -> Any:
    from dataclasses import replace

    from rtctl.controller import Controller

    cfg = base.config
    if abs(cfg.drive.speed - speed) > 1e-12:
        cfg = replace(cfg, drive=replace(cfg.drive, speed=speed))
    ctl = Controller(base.tables, cfg, getattr(base, "unavailable", None))
    setattr(ctl, "name", "rtctl")  # the label experiments.drive reads with getattr(controller, "name", ...)
    return ctl
