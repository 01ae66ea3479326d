"""A closed-loop rtctl drive in the simulated world, for the controller's tests (one place)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def drive_rtctl(tmp_path: Path, scenario_toml: str, distance: float, truth_toml: str | None = None,
                seed: int = 1) -> dict[str, Any]:
    """Drive the simulated mini rover with rtctl on the shipped tables; the drive's metrics.

    ``scenario_toml`` is a scenario file's text (its failures are what the rover declares);
    ``truth_toml`` the simulated world's truth file text (None: the scenario's own parameters).
    """
    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.rtctl_bridge import rtctl_factory
    from offline.sim.simulator import RoverSimulator
    from offline.sim.truth import Truth, load_truth

    f = tmp_path / "scenario.toml"
    f.write_text(scenario_toml)
    sc = load_scenario(f)
    if truth_toml is None:
        truth = Truth.nominal(sc.params, sc.rover)
    else:
        tr = tmp_path / "truth.toml"
        tr.write_text(truth_toml)
        truth = load_truth(tr, sc.rover)
    res = run_drive(RoverSimulator(sc, truth, seed=seed), rtctl_factory()(sc), distance=distance)
    return dict(res.metrics)
