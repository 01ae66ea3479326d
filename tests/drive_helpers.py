"""A closed-loop rtctl drive in the simulated world, for the controller's tests (one place)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


class FlagRecorder:
    """The least of a recorder: keeps every tick's diagnostics flags."""

    def __init__(self) -> None:
        self.flags: list[tuple[str, ...]] = []
        self._channels: dict[str, Any] = {}

    def measurements(self, m: Any) -> None:
        pass

    def commands(self, c: Any) -> None:
        pass

    def diagnostics(self, t: float, d: Any) -> None:
        self.flags.append(tuple(getattr(d, "flags", ())))

    def timing(self, *args: Any) -> None:
        pass


def ticks(ctl: Any, failures: tuple[Any, ...], n: int = 3, steer: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)) -> Any:
    """``n`` controller steps standing still on flat ground with these declared failures; the last
    ``(Commands, Diagnostics)``."""
    from rtctl.messages import Measurements

    out = None
    for k in range(n):
        m = Measurements(t=0.2 * (k + 1), seq=k, wheel_speed=(0.48,) * 4, steer_angle=steer, yaw_rate=0.0, pitch=0.0,
                         roll=0.0, pose=None, failures=failures)
        out = ctl.step(m)
    return out


def drive_rtctl(tmp_path: Path, scenario_toml: str, distance: float, truth_toml: str | None = None,
                seed: int = 1, flags: list[tuple[str, ...]] | None = None) -> dict[str, Any]:
    """Drive the simulated mini rover with rtctl on the shipped tables; the drive's metrics.

    ``scenario_toml`` is a scenario file's text (its failures are what the rover declares);
    ``truth_toml`` the simulated world's truth file text (None: the scenario's own parameters);
    ``flags``, if given, receives every tick's diagnostics flags.
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
    rec = FlagRecorder()
    res = run_drive(RoverSimulator(sc, truth, seed=seed), rtctl_factory()(sc), distance=distance, recorder=rec)
    if flags is not None:
        flags.extend(rec.flags)
    return dict(res.metrics)
