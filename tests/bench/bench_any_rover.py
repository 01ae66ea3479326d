"""Steady-state primitives of rovers from files beside the mini rover's (issue 23).

Run on demand from the repository root::

    nice python tests/bench/bench_any_rover.py

Solves, from the automatic start of :func:`offline.rover.primitives.solve_primitive` with the
default :class:`~offline.rover.primitives.SolverOptions` (seed 0), the scenarios of
``offline/scenarios/rovers/`` (MER-class six-wheel rocker-bogie and four-wheel skid-steer, rover
files in ``rtctl/physics/rovers/``) and the mini rover's counterparts (its four-wheel path without
a rover file, and its rover file ``mini_rover_t72`` driving forward and backward with the
front-right wheel unpowered). Every optimal primitive is re-checked by the independent check
(:func:`offline.rover.primitives.check_solution`). Writes ``tests/bench/results_any_rover.md``:
status, check, objective (7.24) ``sum M_y^2 / (W r_s / N)^2``, drive power, slips, the dead
wheel's steering and load, IPOPT runs and iterations, wall time and the load average.

"Backward" is modelled as driving forward with the rover turned half round about the vertical
(:func:`rtctl.physics.rover_file.driving_backward`: every wheel centre, pivot and the centre of
mass ``(x, y) -> (-x, -y)``, wheel names and steering angles kept), so the dead right-front wheel
trails. The objective's scale ``W r_s / N`` is the same for both directions, so their objectives
compare directly.
"""

from __future__ import annotations

import math
import os
import platform
import subprocess
import sys
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

from offline.files import write_text
from offline.rover.primitives import PrimitiveResult, SolverOptions, _problem_for, check_solution, solve_primitive
from offline.rover.scenario import Scenario, WheelFailure, example_scenarios, load_scenario

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
ROVERS = ROOT / "offline" / "scenarios" / "rovers"
OUT = HERE / "results_any_rover.md"

CASES: tuple[tuple[str, str], ...] = (
    ("mer_nominal", "mer_nominal_backward"),
    ("mer_rf_unpowered", "mer_rf_unpowered_backward"),
    ("mer_rf_locked", "mer_rf_locked_backward"),
    ("mer_rf_locked_1cm", "mer_rf_locked_1cm_backward"),
    ("mer_rf_steer_stuck_7", ""),
    ("skid_nominal", ""),
    ("skid_fr_unpowered", ""),
)
"""(forward, backward) scenario files of ``offline/scenarios/rovers`` ("" : no backward case)."""


def _mini_cases(tmp: Path) -> list[tuple[str, Scenario]]:
    """The mini rover beside them: its four-wheel path (no rover key) nominal and with FR
    unpowered, and its rover file forward and backward with FR unpowered."""
    shipped = {p.stem: p for p in example_scenarios()}
    nominal = load_scenario(shipped["nominal"])
    out = [("mini nominal (no rover key)", nominal),
           ("mini fr_unpowered (no rover key)", replace(nominal, name="mini_fr_unpowered",
                                                        failures={"FR": WheelFailure(unpowered=True)}))]
    for direction in ("forward", "backward"):
        p = tmp / f"mini_file_fr_unpowered_{direction}.toml"
        p.write_text(f'[scenario]\nname = "mini_file_fr_unpowered_{direction}"\nrover = "mini_rover_t72"\n'
                     f'params = "dissertation-ch7"\nspeed_m_s = 0.03\ndrive_direction = "{direction}"\n'
                     '[wheels.FR]\nunpowered = true\n')
        out.append((f"mini rover file, FR unpowered, {direction}", load_scenario(p)))
    return out


def _fast_drive_case(tmp: Path) -> tuple[str, Scenario]:
    """MER-class, right-front locked, forward at 3 cm/s, with the drive speed limit raised from
    0.385 to 1.0 rad/s (a copy of the rover file): is the forward verdict the drive limit's?"""
    src = ROOT / "rtctl" / "physics" / "rovers"
    text = (src / "mer_class_rocker_bogie.toml").read_text()
    if "drive_speed_max_rad_s = 0.385" not in text:
        raise RuntimeError("mer_class_rocker_bogie.toml: drive_speed_max_rad_s is no longer 0.385; update the bench")
    (tmp / "mer_fast.toml").write_text(text.replace("drive_speed_max_rad_s = 0.385", "drive_speed_max_rad_s = 1.0"))
    (tmp / "mer_class_wheel.toml").write_text((src / "mer_class_wheel.toml").read_text())
    p = tmp / "mer_fast_rf_locked.toml"
    p.write_text('[scenario]\nname = "mer_fast_rf_locked"\nrover = "mer_fast.toml"\nspeed_m_s = 0.03\n[wheels.RF]\nlocked = true\n')
    return "mer_rf_locked, drive limit 1.0 rad/s (copy of the file)", load_scenario(p)


def _row(label: str, sc: Scenario, r: PrimitiveResult, seconds: float) -> str:
    ok = ""
    if r.ok:
        _, ok_b = check_solution(_problem_for(sc, SolverOptions()), sc, r.x)
        ok = "passed" if ok_b else "FAILED"
    dead = [k for k in sc.wheels if not sc.failure(k).nominal]
    d = r.wheels[dead[0]] if dead else None
    dead_txt = (f"{dead[0]}: steer {math.degrees(d.steer):.2f} deg, load {d.load:.2f} N, slip {d.slip:.3f}"
                if d is not None and r.ok else "")
    return (f"| {label} | {len(sc.wheels)} | {sc.speed * 100:.0f} | {r.status} | {ok or '-'} | "
            f"{r.objective:.6f} | {r.power * 1e3:.1f} | {r.mean_slip():.3f} | {r.max_slip():.3f} | {dead_txt} | "
            f"{r.stats['n_attempts']} | {r.stats['iterations']} | {seconds:.1f} |")


def main() -> int:
    import tempfile

    t_all = time.perf_counter()
    load0 = os.getloadavg()
    lines = []
    header = ("| scenario | wheels | speed [cm/s] | status | independent check | objective (7.24) | power [mW] | "
              "mean slip (working wheels) | max slip | dead wheel | IPOPT runs | iterations | wall [s] |")
    sep = "|" + "---|" * 13
    objective: dict[str, tuple[str, float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        runs: list[tuple[str, Scenario]] = []
        for fwd, back in CASES:
            for name in (fwd, back):
                if name:
                    runs.append((name, load_scenario(ROVERS / f"{name}.toml")))
        runs.append(_fast_drive_case(Path(tmp)))
        runs += _mini_cases(Path(tmp))
        for label, sc in runs:
            t = time.perf_counter()
            r = solve_primitive(sc)
            dt = time.perf_counter() - t
            objective[label] = (r.status, r.objective)
            lines.append(_row(label, sc, r, dt))
            print(lines[-1], flush=True)
    load1 = os.getloadavg()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    cmp_lines = []
    pairs = [(f, b) for f, b in CASES if b] + [("mini rover file, FR unpowered, forward", "mini rover file, FR unpowered, backward")]
    for f, b in pairs:
        sf, of = objective[f]
        sb, ob = objective[b]
        if sf == "optimal" and sb == "optimal":
            verdict = f"backward / forward = {ob / of:.4f}"
        else:
            verdict = "only " + ("backward" if sb == "optimal" else "forward" if sf == "optimal" else "neither") + " solves"
        cmp_lines.append(f"| {f} | {sf} {of:.6f} | {sb} {ob:.6f} | {verdict} |")
    text = "\n".join([
        "# Primitives of rovers from files (issue 23)",
        "",
        f"Made by `nice python tests/bench/bench_any_rover.py` at commit {commit}"
        + (" (with uncommitted changes)" if dirty else "") + f", {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, "
        f"Python {platform.python_version()}, {platform.machine()}; load average {load0[0]:.1f} at the start, "
        f"{load1[0]:.1f} at the end (2 cores shared); {time.perf_counter() - t_all:.0f} s in all. Default SolverOptions "
        "(seed 0). Wall times depend on the load; statuses, objectives and iteration counts do not (budgets count "
        "iterations).",
        "",
        "Objective (7.24): `sum_i M_y,i^2 / (W r_s / N)^2` (N wheels), the optimizer's own. Power: `sum T_i omega_i`. "
        "Rover files: `rtctl/physics/rovers/`; scenarios: `offline/scenarios/rovers/`. The MER-class rover's drive "
        "limit (0.385 rad/s, 5.0 cm/s rim speed) and torque limit (30 N m) are bounds of its NLP. For a status other "
        "than optimal the columns describe the furthest point the search reached, not a primitive; 'dead wheel' is "
        "shown for optimal rows only.",
        "",
        header, sep, *lines,
        "",
        "## Forward against backward (the dead right-front wheel trailing)",
        "",
        "Backward = the rover turned half round about the vertical (`rtctl.physics.rover_file.driving_backward`), "
        "driving forward; same objective scale, so the objectives compare directly.",
        "",
        "| case (forward) | forward: status, objective | backward: status, objective | comparison |",
        "|---|---|---|---|",
        *cmp_lines,
        "",
    ])
    tables = "## Tables for rover files"  # bench_any_rover_tables.py's section: kept
    if OUT.is_file() and tables in OUT.read_text():
        text = text.rstrip("\n") + "\n\n" + tables + OUT.read_text().split(tables, 1)[1]
    write_text(OUT, text)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
