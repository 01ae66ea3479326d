"""The drive discrepancy tool on six-wheel recordings (issue 23): concealed worn wheels and noise-only drives.

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_drive_discrepancy_any_rover.py [--duration 20]

Each case records a straight open-loop drive of the MER-class six-wheel rocker-bogie
(``offline/scenarios/rovers/mer_nominal.toml``, every wheel at 3 cm/s, no steering) on the rover
file's simulator plant with a world the tool is not told -- one wheel's rim radius smaller, set
in the simulator's truth here (``rover_file_truth`` with that wheel's radius changed), or the
believed world (noise only) -- and sensor noise (``REALISTIC_SENSORS`` with the torque noise
scaled by weight x wheel radius, as ``tests/test_drive_discrepancy_any_rover.py``), then
diagnoses it with :func:`offline.discrepancy.drive.diagnosis.diagnose_drives` on the believed
scenario with the default library made for the six wheels
(:func:`offline.discrepancy.drive.wheel_set.library_for`), the soil recalibration included, one
process. Writes ``tests/bench/results_drive_discrepancy_any_rover.md``: CPU seconds, verdict,
the named term and its fitted value against the truth, and the outcome (:func:`outcome`); exits 1
on a confident wrong name or a false alarm.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

from offline.discrepancy.drive.diagnosis import diagnose_drives  # noqa: E402
from offline.discrepancy.drive.synthetic import REALISTIC_SENSORS, DriveSegment, record_drive  # noqa: E402
from offline.files import write_text  # noqa: E402
from offline.rover.scenario import load_scenario  # noqa: E402
from offline.sim.simulator import rover_file_truth, suspension_plant_for  # noqa: E402

OUT = HERE / "results_drive_discrepancy_any_rover.md"
MER = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_nominal.toml")
MINI = load_scenario(ROOT / "offline" / "scenarios" / "nominal.toml")
SPEED = 0.03


@dataclass(frozen=True)
class Case:
    """A concealed worn wheel (``wheel``, relative ``change``) or none (noise only), the seed and the
    drive's length (None: ``--duration``)."""

    label: str
    wheel: str | None
    change: float
    seed: int
    duration: float | None = None


CASES = (Case("LM 5 % smaller", "LM", -0.05, 1), Case("RF 3 % smaller", "RF", -0.03, 4),
         Case("RF 3 % smaller", "RF", -0.03, 4, 60.0),
         Case("noise only", None, 0.0, 2), Case("noise only", None, 0.0, 3))


def outcome(v, case: Case) -> str:
    """What the verdict did with the case: for a worn wheel ``named within 20 %``, ``named, size off``,
    ``WRONG NAME`` (a confident wrong name: the failure the issue forbids), ``ambiguous`` (not
    determined; the advice says what to drive) or ``missed`` (agree); for noise only ``no false
    alarm`` or ``FALSE ALARM``."""
    named = v.chosen is not None and v.status not in ("agree", "unexplained", "ambiguous")
    if case.wheel is None:
        return "no false alarm" if v.status == "agree" and not v.regions else "FALSE ALARM"
    if v.status == "ambiguous":
        return "ambiguous"
    if not named:
        return "missed" if v.status == "agree" else v.status
    if v.chosen.keys != (f"wheel_radius_{case.wheel}",):
        return "WRONG NAME"
    return "named within 20 %" if abs(v.chosen.values[0] / 100 - case.change) <= 0.2 * abs(case.change) else "named, size off"



def sensors():
    """REALISTIC_SENSORS, torque noise scaled by the rovers' weight x wheel radius (the test's)."""
    scale = (MER.rover_file.weight * MER.params.wheel.radius) / (MINI.rover.weight * MINI.params.wheel.radius)
    return replace(REALISTIC_SENSORS, torque_noise=REALISTIC_SENSORS.torque_noise * scale)


def run_case(case: Case, duration: float, folder: Path) -> dict[str, object]:
    duration = case.duration or duration
    world = rover_file_truth(MER, suspension_plant_for(MER.params, MER.rover_file, MER.exit_angle))
    if case.wheel is not None:
        i = MER.wheels.index(case.wheel)
        world = replace(world, wheel_radius=tuple(r * (1 + case.change) if j == i else r
                                                  for j, r in enumerate(world.wheel_radius)))
    path = record_drive(folder / f"case_{case.seed}_{duration:g}.mcap", MER, world, seed=case.seed, duration=duration, sensors=sensors(),
                        segments=(DriveSegment(0.0, duration, (SPEED,) * 6, (0.0,) * 6, "straight"),))
    t0 = time.process_time()
    v = diagnose_drives([path], MER, segment=5, seed=case.seed)
    cpu = time.process_time() - t0
    named = v.chosen.label if v.chosen is not None and v.status not in ("agree", "unexplained", "ambiguous") else "-"
    fitted = v.chosen.parameters_text() if named != "-" else "-"
    expect = (f"wheel_radius_{case.wheel}: radius_change = {100 * case.change:+.1f} %" if case.wheel else "agree")
    return {"case": case.label, "seed": case.seed, "duration": duration, "outcome": outcome(v, case), "verdict": v.status, "named": named, "fitted": fitted, "truth": expect,
            "cpu": cpu, "sims": v.model.simulations, "rows": len(v.observations),
            "advice": v.observations.identification_advice() if v.status == "ambiguous" else ""}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="drive length, s (default %(default)s)")
    args = ap.parse_args()
    load0, t_all = os.getloadavg(), time.process_time()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in CASES:
            r = run_case(case, args.duration, Path(tmp))
            print(f"{r['case']} {r['duration']:g} s seed {r['seed']}: {r['verdict']} {r['named']} {r['fitted']} -> {r['outcome']} "
                  f"({r['cpu']:.1f} CPU-s)", flush=True)
            rows.append(r)
    load1 = os.getloadavg()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    lines = [
        "# Drive discrepancy on six-wheel recordings (issue 23)", "",
        f"Made by `OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_drive_discrepancy_any_rover.py --duration "
        f"{args.duration:g}` at commit {commit}, {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, Python "
        f"{platform.python_version()}, {platform.machine()}; load average {load0[0]:.1f} at the start, {load1[0]:.1f} at "
        f"the end (2 cores shared); {time.process_time() - t_all:.0f} CPU-s in this process in all. One process "
        "(`workers=1`), one OpenBLAS thread.", "",
        f"Drives: MER-class six-wheel rocker-bogie (`offline/scenarios/rovers/mer_nominal.toml`), straight, open loop, "
        f"every wheel at 3 cm/s, {args.duration:g} s at 5 Hz, on the rover file's plant (`SuspensionPlant`); the worn "
        "wheel concealed in the simulator's world (the rover file's truth with that wheel's rim radius changed), sensors "
        "`REALISTIC_SENSORS` with the torque noise scaled by weight x wheel radius (0.86 N m). Diagnosis: "
        "`diagnose_drives(..., segment=5)` on the believed `mer_nominal` scenario with the default library made for the "
        "six wheels (`wheel_set.library_for`: every wheel's radius, the four steerable wheels' steering offsets, slope, "
        "IMU tilt, drawbar pull, servo lag, torque saturation, gyro scale, soil stiffness, all radii; no hub contact or "
        "anchored tether: the rover-file plant takes no disturbance hook) and the soil recalibration, level 0.001.", "",
        "| case | drive [s] | seed | verdict | named | fitted | truth | outcome | CPU [s] | re-simulations | rows |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['case']} | {r['duration']:g} | {r['seed']} | {r['verdict']} | {r['named']} | {r['fitted']} | "
                     f"{r['truth']} | {r['outcome']} | {r['cpu']:.1f} | {r['sims']} | {r['rows']} |")
    for r in rows:
        if r["advice"]:
            lines += ["", f"- {r['case']} (seed {r['seed']}), ambiguous: {r['advice']}"]
    write_text(OUT, "\n".join(lines) + "\n")
    print(f"wrote {OUT}")
    return 1 if any(r["outcome"] in ("WRONG NAME", "FALSE ALARM") for r in rows) else 0


if __name__ == "__main__":
    raise SystemExit(main())
