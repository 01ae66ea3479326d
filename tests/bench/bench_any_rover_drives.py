"""Closed-loop drives of rovers from files beside the mini rover's (issue 23).

Run on demand from the repository root::

    nice python tests/bench/bench_any_rover_drives.py [--distance 5.0]

Each case drives the simulator (:class:`offline.sim.simulator.RoverSimulator`, the rover file's
own plant :class:`offline.sim.suspension_plant.SuspensionPlant`, default sensors, seed 1) the
given distance along world X, with

* ``rtctl``: rtctl's controller on the case's table of ``tests/data/tables/rovers/`` (README
  there), default :class:`rtctl.config.ControllerConfig` with the case's speed;
* ``uncompensated``: open loop, the rover's *nominal* primitive (the optimizer's, the failure
  not known) at the case's speed and direction, the failure acting in the actuators (a locked
  wheel held at rest, a stuck steering at its angle, an unpowered wheel free);
* ``table FF``: open loop, the failure table's own primitive at the case's operating point
  (the feedforward rtctl starts from);

and the mini rover's rtctl and uncompensated drives on its shipped tables beside them. Writes
``tests/bench/results_any_rover_drives.md``: the issue's targets (heading within 3 deg,
cross-track within 5 cm), the speed, and for the forward/backward comparison of the dead
right-front wheel the objective (7.24) ``sum T_i^2 / (W r_s / N)^2`` and the drive power
``sum T_i omega_i`` measured in the simulator (means over the second half of the drive)
beside the optimizer's objective of the same primitive.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from offline.files import write_text
from offline.rover.primitives import solve_primitive
from offline.rover.scenario import Scenario, load_scenario
from offline.sim.experiments import DriveResult, run_drive, scenario_by_name
from offline.sim.sensors import SensorConfig
from offline.sim.simulator import RoverSimulator
from rtctl.messages import Commands, Measurements

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
ROVERS = ROOT / "offline" / "scenarios" / "rovers"
TABLES = ROOT / "tests" / "data" / "tables" / "rovers"
OUT = HERE / "results_any_rover_drives.md"
HEADING_DEG, CROSSTRACK_CM = 3.0, 5.0


@dataclass(frozen=True)
class Case:
    """One drive: scenario file (``offline/scenarios/rovers``), controller, speed (m/s), table."""

    label: str
    scenario: str
    controller: str  # rtctl | uncompensated | table FF
    speed: float
    table: str = ""
    nominal: str = ""  # the nominal scenario of the uncompensated drive
    noise_free: bool = False  # sensors without noise (a diagnosis of the skid-steer's drive)


CASES: tuple[Case, ...] = (
    Case("MER, RF locked, backward (Spirit)", "mer_rf_locked_backward", "rtctl", 0.02, "mer_rf_locked_backward"),
    Case("MER, RF locked, backward (Spirit)", "mer_rf_locked_backward", "uncompensated", 0.02, nominal="mer_nominal_backward"),
    Case("MER, RF locked, forward", "mer_rf_locked", "uncompensated", 0.02, nominal="mer_nominal"),
    Case("MER, RF steering stuck 7 deg (Opportunity)", "mer_rf_steer_stuck_7", "rtctl", 0.03, "mer_rf_steer_stuck_7"),
    Case("MER, RF steering stuck 7 deg (Opportunity)", "mer_rf_steer_stuck_7", "uncompensated", 0.03, nominal="mer_nominal"),
    Case("MER, RF unpowered, forward", "mer_rf_unpowered", "rtctl", 0.03, "mer_rf_unpowered"),
    Case("MER, RF unpowered, forward", "mer_rf_unpowered", "uncompensated", 0.03, nominal="mer_nominal"),
    Case("MER, RF unpowered, backward", "mer_rf_unpowered_backward", "rtctl", 0.03, "mer_rf_unpowered_backward"),
    Case("MER, RF unpowered, backward", "mer_rf_unpowered_backward", "uncompensated", 0.03, nominal="mer_nominal_backward"),
    Case("skid-steer, FR unpowered", "skid_fr_unpowered", "rtctl", 0.03, "skid_fr_unpowered"),
    Case("skid-steer, FR unpowered, sensors without noise", "skid_fr_unpowered", "rtctl", 0.03, "skid_fr_unpowered",
         noise_free=True),
    Case("skid-steer, FR unpowered", "skid_fr_unpowered", "table FF", 0.03, "skid_fr_unpowered"),
    Case("skid-steer, FR unpowered", "skid_fr_unpowered", "uncompensated", 0.03, nominal="skid_nominal"),
)

MINI_CASES: tuple[tuple[str, str], ...] = (("rr_steer_stuck_50", "rtctl"), ("rr_steer_stuck_50", "none"),
                                           ("rr_speed_cap_half", "rtctl"), ("rr_speed_cap_half", "none"))
"""The mini rover's drives beside them: shipped scenarios and tables (``offnominal drive``'s)."""


class OpenLoop:
    """The same body-frame commands every tick (a primitive; for a backward drive in the body
    frame, rim speeds negated, as rtctl's controller outputs them)."""

    def __init__(self, rim: tuple[float, ...], steer: tuple[float, ...], name: str) -> None:
        self.rim, self.steer, self.name = rim, steer, name

    def step(self, m: Measurements) -> tuple[Commands, dict[str, Any]]:
        """The fixed commands."""
        return Commands(m.t, m.seq, self.rim, self.steer), {"controller": self.name}


def _sign(sc: Scenario) -> float:
    rf = sc.rover_file
    return -1.0 if rf is not None and rf.name.endswith(" (backward)") else 1.0


def _controller(case: Case, sc: Scenario) -> tuple[Any, float | None]:
    """The case's controller and the optimizer's objective of the primitive it starts from."""
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.table import load_table

    if case.controller == "uncompensated":
        nom = load_scenario(ROVERS / f"{case.nominal}.toml").with_(speed=case.speed)
        prim = solve_primitive(nom)
        if not prim.ok:
            raise RuntimeError(f"{case.nominal}: no nominal primitive ({prim.status})")
        rim = tuple(_sign(sc) * prim.wheels[k].rim_speed for k in sc.wheels)
        return OpenLoop(rim, tuple(prim.wheels[k].steer for k in sc.wheels), "uncompensated"), prim.objective
    t = load_table(TABLES / f"{case.table}.npz")
    tp = t.at(slope=sc.slope, cross_slope=0.0, speed=case.speed)
    if case.controller == "table FF":
        lay, rs = t.layout, sc.params.wheel.shearing_radius
        rim = tuple(_sign(sc) * float(tp.x[lay.var("omega", k)]) * rs for k in lay.wheels)
        return OpenLoop(rim, tuple(float(tp.x[lay.var("beta", k)]) for k in lay.wheels), "table FF"), tp.objective
    cfg = ControllerConfig()
    ctl = Controller({case.table: t}, replace(cfg, drive=replace(cfg.drive, speed=case.speed)))
    setattr(ctl, "name", "rtctl")
    return ctl, tp.objective


def _measured_objective(res: DriveResult, sim: RoverSimulator) -> tuple[float, float]:
    """Objective (7.24) ``sum T_i^2 / (W r_s / N)^2`` and power ``sum T_i omega_i`` (W) from the
    simulator's motor torques, means over the second half of the drive."""
    half = res.truth[len(res.truth) // 2:]
    n = len(half[0].omega)
    scale = sim.weight / n * sim.scenario.params.wheel.shearing_radius
    f = np.mean([sum(t * t for t in s.motor_torque) for s in half]) / scale ** 2
    p = np.mean([sum(t * w for t, w in zip(s.motor_torque, s.omega)) for s in half])
    return float(f), float(p)


def _verdict(m: dict[str, float], res: DriveResult, distance: float) -> str:
    on = m["max_abs_heading_deg"] <= HEADING_DEG and m["max_abs_cross_track_cm"] <= CROSSTRACK_CM
    if res.ended:
        return "ended early" + ("" if on else ", off the path")
    if not on:
        return "left the path" + ("" if m["distance_m"] >= distance - 1e-9 else f" (X {m['distance_m']:.2f} m at the time limit)")
    return "**on the path**" if m["distance_m"] >= distance - 1e-9 else "on the path, too slow (time limit)"


def _row(label: str, ctl: str, speed: float, res: DriveResult, distance: float, extra: str, cpu: float) -> str:
    m = res.metrics
    return (f"| {label} | {ctl} | {100 * speed:g} | {m['distance_m']:.2f} | {m['max_abs_heading_deg']:.2f} | "
            f"{m['final_heading_deg']:.2f} | {m['max_abs_cross_track_cm']:.2f} | {m['mean_speed_cm_s']:.2f} | "
            f"{_verdict(m, res, distance)} | {extra} | {cpu:.1f} |")


def main(argv: list[str] | None = None) -> int:
    """Run the drives and write the results file."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--distance", type=float, default=5.0, help="m along world X (default 5)")
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    load0, t_start = os.getloadavg(), time.process_time()
    rows, objectives = [], []
    for case in CASES:
        sc = load_scenario(ROVERS / f"{case.scenario}.toml").with_(speed=case.speed)
        c0 = time.process_time()
        ctl, f_opt = _controller(case, sc)
        sensors = None
        if case.noise_free:
            sensors = SensorConfig(wheel_speed_noise=0.0, steer_noise=0.0, gyro_bias=0.0, gyro_noise=0.0, tilt_noise=0.0,
                                   torque_noise=0.0, pose_noise_xy=0.0, pose_noise_heading=0.0, gyro_bias_walk=0.0)
        sim = RoverSimulator(sc, seed=1, sensors=sensors)
        res = run_drive(sim, ctl, distance=args.distance, max_time=3.0 * args.distance / case.speed)
        f_sim, power = _measured_objective(res, sim)
        cpu = time.process_time() - c0
        extra = f"{f_sim:.4f} / {'-' if f_opt is None else f'{f_opt:.4f}'} / {1e3 * power:.0f}"
        if res.ended:
            extra += f"; ended: {res.ended[:120]}"
        rows.append(_row(case.label, case.controller, case.speed, res, args.distance, extra, cpu))
        objectives.append((case, f_sim, f_opt, power, res))
        print(rows[-1], flush=True)
    mini_rows = []
    from offline.sim.experiments import build_controller
    from offline.sim.rtctl_bridge import rtctl_factory

    factory = rtctl_factory()
    for name, kind in MINI_CASES:
        sc = scenario_by_name(name)
        c0 = time.process_time()
        ctl = build_controller(kind, sc, rtctl_factory=factory)
        sim = RoverSimulator(sc, seed=1)
        res = run_drive(sim, ctl, distance=args.distance, max_time=3.0 * args.distance / sc.speed)
        f_sim, power = _measured_objective(res, sim)
        cpu = time.process_time() - c0
        label = {"none": "uncompensated"}.get(kind, kind)
        mini_rows.append(_row(f"mini rover, {name}", label, sc.speed, res, args.distance,
                              f"{f_sim:.4f} / - / {1e3 * power:.0f}", cpu))
        print(mini_rows[-1], flush=True)
    load1 = os.getloadavg()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    head = ("| case | controller | speed [cm/s] | distance [m] | max abs heading [deg] | final heading [deg] | "
            "max abs cross-track [cm] | mean speed [cm/s] | verdict (3 deg, 5 cm) | objective sim / optimizer, power [mW] | "
            "CPU [s] |\n|---|---|---|---|---|---|---|---|---|---|---|")
    by = {(c.scenario, c.controller): (f, fo, p) for c, f, fo, p, _ in objectives}
    fb = []
    for fwd, bwd in (("mer_rf_unpowered", "mer_rf_unpowered_backward"),):
        (f1, o1, p1), (f2, o2, p2) = by[(fwd, "rtctl")], by[(bwd, "rtctl")]
        fb.append(f"| RF unpowered, rtctl | forward {f1:.4f} (optimizer {o1:.4f}), {1e3 * p1:.0f} mW | backward {f2:.4f} "
                  f"(optimizer {o2:.4f}), {1e3 * p2:.0f} mW | backward / forward: simulator {f2 / f1:.4f}, optimizer "
                  f"{o2 / o1:.4f} |")
    (fl, _, pl), (fu, _, pu) = by[("mer_rf_locked_backward", "rtctl")], by[("mer_rf_locked", "uncompensated")]
    fb.append(f"| RF locked | forward: no primitive (the optimizer: infeasible, `results_any_rover.md`); uncompensated "
              f"forward drive {fu:.4f}, {1e3 * pu:.0f} mW (see its row) | backward, rtctl {fl:.4f}, {1e3 * pl:.0f} mW | "
              f"only backward has a primitive |")
    text = "\n".join([
        "# Closed-loop drives of rovers from files (issue 23)", "",
        f"Made by `nice python tests/bench/bench_any_rover_drives.py --distance {args.distance:g}` at commit {commit}, "
        f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, Python {platform.python_version()}, {platform.machine()}; "
        f"load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end (2 cores shared); "
        f"{time.process_time() - t_start:.0f} CPU-s in this process in all. One OpenBLAS thread.", "",
        "Simulator: `offline.sim.simulator.RoverSimulator`, the rover file's plant "
        "(`offline.sim.suspension_plant.SuspensionPlant`: the optimizer's wheel model and suspension rows), "
        "default sensors (noise, pose fixes) and servos from the rover file's `[actuators]`, seed 1, dt 0.1 s, "
        "5 Hz control. A backward drive: the plant in the travel frame, sensors and commands in the body frame "
        "(rtctl turns them). Tables: `tests/data/tables/rovers/` (README). Targets (issue 23): "
        f"heading within {HEADING_DEG:g} deg and cross-track within {CROSSTRACK_CM:g} cm over the whole drive.", "",
        "Controllers: **rtctl** on the failure's table; **uncompensated** = the rover's nominal primitive (the "
        "optimizer's, failure unknown) open loop with the failure acting in the actuators; **table FF** = the "
        "failure table's own primitive open loop. Objective (7.24) in the simulator: `sum T_i^2 / (W r_s / N)^2` "
        "from the motor torques, mean over the second half of the drive; optimizer: the objective of the primitive "
        "the controller starts from (rtctl, table FF: the table at the operating point; uncompensated: the nominal "
        "primitive). Power `sum T_i omega_i`.", "",
        "## Rovers from files", "", head, *rows, "",
        "## The mini rover beside them (shipped tables, `offnominal drive`'s scenarios)", "", head, *mini_rows, "",
        "## Forward against backward, the dead right-front wheel (Spirit's strategy)", "",
        "| case | forward | backward | comparison |", "|---|---|---|---|", *fb, "",
    ])
    write_text(Path(args.out), text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
