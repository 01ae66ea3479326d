"""The drive discrepancy tool on six-wheel recordings (issue 23): concealed worn wheels and noise-only drives.

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_drive_discrepancy_any_rover.py [--duration 20] [--part open|closed|all]
        [--case LABEL_TEXT ...] [--out PATH]

Two parts, each its own section of the results file (a run of one part keeps the other's section):

``open`` (below); ``closed``: rtctl drives the MER-class rover with a declared failure (right-front
drive motor dead, ``mer_rf_unpowered``, its table ``tests/data/tables/rovers/mer_rf_unpowered.npz``,
default :class:`rtctl.config.ControllerConfig` at 3 cm/s) straight along world X in the simulator
(:func:`offline.sim.experiments.record_run`: the controller's commands, readings and truth written
as ``offnominal drive`` records them), in a world the tool is not told: a concealed worn wheel (the
truth's radius of that wheel), or one disturbance through the rover-file plant's hook (contract C5,
written here in code independent of the tool's candidates: an anchored tether's constant pull from
far behind, :class:`~offline.discrepancy.drive.candidates.AnchoredTether` through
:func:`offline.discrepancy.drive.wheel_set.truth_disturbance` of a ``[tether_anchor]`` truth; a
constant hub drag torque on one wheel, a brake the library has no term for), or the believed world
(noise only). The recording is diagnosed with the believed ``mer_rf_unpowered`` scenario (the
failure declared, as the rover's fault management does), the default library made for the six
wheels, the soil recalibration included.

The open part: each case records a straight open-loop drive of the MER-class six-wheel rocker-bogie
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

import math  # noqa: E402

from offline.discrepancy.drive.diagnosis import diagnose_drives  # noqa: E402
from offline.discrepancy.drive.synthetic import REALISTIC_SENSORS, DriveSegment, record_drive  # noqa: E402
from offline.discrepancy.drive.wheel_set import truth_disturbance  # noqa: E402
from offline.files import write_text  # noqa: E402
from offline.rover.scenario import load_scenario  # noqa: E402
from offline.sim.experiments import record_run  # noqa: E402
from offline.sim.simulator import DisturbanceForces, RoverSimulator, rover_file_truth, suspension_plant_for  # noqa: E402

OUT = HERE / "results_drive_discrepancy_any_rover.md"
MER = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_nominal.toml")
MINI = load_scenario(ROOT / "offline" / "scenarios" / "nominal.toml")
MER_RF_UNPOWERED = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_rf_unpowered.toml").with_(speed=0.03)
TABLE = ROOT / "tests" / "data" / "tables" / "rovers" / "mer_rf_unpowered.npz"
SPEED = 0.03
OPEN_MARK, CLOSED_MARK = "<!-- part: open -->", "<!-- part: closed -->"


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


@dataclass(frozen=True)
class ClosedCase:
    """A closed-loop drive's concealed world: a worn wheel (``wheel``, relative ``change``), a hook
    (``hook``: ``tether`` -- an anchored tether of ``size`` N from far behind; ``hub_<W>`` -- a hub
    drag torque of ``size`` N m on wheel W against its spin), or neither (noise only); ``expect``:
    the library term that names it (None: no term of the library is this physics)."""

    label: str
    seed: int
    wheel: str | None = None
    change: float = 0.0
    hook: str | None = None
    size: float = 0.0
    expect: str | None = None


CLOSED_CASES = (
    ClosedCase("LM 5 % smaller", 1, wheel="LM", change=-0.05, expect="wheel_radius_LM"),
    ClosedCase("noise only", 2),
    ClosedCase("anchored tether 20 N from far behind (hook)", 3, hook="tether", size=20.0, expect="tether"),
    ClosedCase("hub drag 3 N m on LM (hook)", 5, hook="hub_LM", size=3.0),
)


def closed_outcome(v, case: ClosedCase) -> str:
    """As :func:`outcome` for a closed-loop case: ``named`` (the expected term alone), ``WRONG NAME``
    (a confident verdict naming another term; for a disturbance the library has no term for, any
    confident name), ``ambiguous`` / ``not named (<verdict>)``, ``missed`` (agree); noise only: ``no
    false alarm`` or ``FALSE ALARM``."""
    named = v.chosen is not None and v.status not in ("agree", "unexplained", "ambiguous")
    if case.wheel is None and case.hook is None:
        return "no false alarm" if v.status == "agree" and not v.regions else "FALSE ALARM"
    if v.status == "ambiguous":
        return "ambiguous"
    if not named:
        return "missed" if v.status == "agree" else f"not named ({v.status})"
    if case.expect is None or v.chosen.keys != (case.expect,):
        return "WRONG NAME"
    return "named"


def _hub_drag(wheel: str, torque: float):
    """A constant hub drag torque on one wheel against its spin (smoothed through zero speed as the
    hub contact's, 0.01 rad/s), written here, not by the tool's candidates."""
    i = MER_RF_UNPOWERED.wheels.index(wheel)
    n = len(MER_RF_UNPOWERED.wheels)

    def hook(t: float, s) -> DisturbanceForces:
        om = s.omega[i]
        tq = [0.0] * n
        tq[i] = torque * om / math.sqrt(om * om + 1e-4)
        return DisturbanceForces(wheel_torque=tuple(tq))
    return hook


def run_closed_case(case: ClosedCase, duration: float, folder: Path) -> dict[str, object]:
    """Record rtctl's drive of the case's world and diagnose it (module notes)."""
    from dataclasses import replace as _replace

    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.table import load_table

    sc = MER_RF_UNPOWERED
    world = rover_file_truth(sc, suspension_plant_for(sc.params, sc.rover_file, sc.exit_angle))
    hook = None
    if case.wheel is not None:
        i = sc.wheels.index(case.wheel)
        world = _replace(world, wheel_radius=tuple(r * (1 + case.change) if j == i else r
                                                   for j, r in enumerate(world.wheel_radius)))
    if case.hook == "tether":
        hook = truth_disturbance(_replace(world, anchor={"tension": case.size, "bearing": math.pi}), sc)
    elif case.hook is not None:
        hook = _hub_drag(case.hook.partition("_")[2], case.size)
    cfg = ControllerConfig()
    ctl = Controller({sc.name: load_table(TABLE)}, _replace(cfg, drive=_replace(cfg.drive, speed=SPEED)))
    sim = RoverSimulator(sc, world, sensors=sensors(), seed=case.seed, disturbance=hook)
    t0 = time.process_time()
    res = record_run(folder / f"closed_{case.seed}.mcap", sim, ctl, distance=SPEED * duration, max_time=1.5 * duration,
                     metadata={"scenario": sc.name, "seed": case.seed, "controller": "rtctl"}, name="rtctl")
    cpu_drive = time.process_time() - t0
    t0 = time.process_time()
    v = diagnose_drives([folder / f"closed_{case.seed}.mcap"], sc, segment=5, seed=case.seed)
    cpu = time.process_time() - t0
    named = v.chosen.label if v.chosen is not None and v.status not in ("agree", "unexplained", "ambiguous") else "-"
    fitted = v.chosen.parameters_text() if named != "-" else "-"
    truth = (f"wheel_radius_{case.wheel}: {100 * case.change:+.1f} %" if case.wheel else
             f"tether {case.size:g} N" if case.hook == "tether" else
             f"hub drag {case.size:g} N m on {case.hook.partition('_')[2]} (no library term)" if case.hook else "agree")
    m = res.metrics
    return {"case": case.label, "seed": case.seed, "outcome": closed_outcome(v, case), "verdict": v.status, "named": named,
            "fitted": fitted, "truth": truth, "cpu": cpu, "cpu_drive": cpu_drive, "sims": v.model.simulations,
            "rows": len(v.observations), "heading": m["max_abs_heading_deg"], "cross": m["max_abs_cross_track_cm"],
            "distance": m["distance_m"], "ended": res.ended,
            "advice": v.observations.identification_advice() if v.status in ("ambiguous", "unexplained") else "",
            "summary": v.summary()}


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


def _open_section(rows: list[dict[str, object]], duration: float, commit: str, stamp: str) -> list[str]:
    lines = [
        OPEN_MARK, "",
        f"## Open loop (`--part open --duration {duration:g}`, commit {commit}, {stamp})", "",
        f"Drives: MER-class six-wheel rocker-bogie (`offline/scenarios/rovers/mer_nominal.toml`), straight, open loop, "
        f"every wheel at 3 cm/s, {duration:g} s at 5 Hz, on the rover file's plant (`SuspensionPlant`); the worn "
        "wheel concealed in the simulator's world (the rover file's truth with that wheel's rim radius changed), sensors "
        "`REALISTIC_SENSORS` with the torque noise scaled by weight x wheel radius (0.86 N m). Diagnosis: "
        "`diagnose_drives(..., segment=5)` on the believed `mer_nominal` scenario with the default library made for the "
        "six wheels (`wheel_set.library_for`: every wheel's radius, the four steerable wheels' steering offsets, slope, "
        "IMU tilt, drawbar pull, anchored tether, hub contact, servo lag, torque saturation, gyro scale, soil stiffness, "
        "all radii, the per-wheel actuator terms screened; force and torque bounds scaled to the rover's weight) and "
        "the soil recalibration, level 0.001.", "",
        "| case | drive [s] | seed | verdict | named | fitted | truth | outcome | CPU [s] | re-simulations | rows |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['case']} | {r['duration']:g} | {r['seed']} | {r['verdict']} | {r['named']} | {r['fitted']} | "
                     f"{r['truth']} | {r['outcome']} | {r['cpu']:.1f} | {r['sims']} | {r['rows']} |")
    for r in rows:
        if r["advice"]:
            lines += ["", f"- {r['case']} (seed {r['seed']}), ambiguous: {r['advice']}"]
    return lines + [""]


def _closed_section(rows: list[dict[str, object]], duration: float, commit: str, stamp: str) -> list[str]:
    lines = [
        CLOSED_MARK, "",
        f"## Closed loop: rtctl drives the rover with RF unpowered (`--part closed --duration {duration:g}`, commit "
        f"{commit}, {stamp})", "",
        f"Drives: rtctl on `tests/data/tables/rovers/mer_rf_unpowered.npz` (the failure declared by the simulator, "
        f"scenario `mer_rf_unpowered`), {duration:g} s ({100 * SPEED * duration:g} cm along world X at 3 cm/s), 5 Hz, "
        "recorded by `offline.sim.experiments.record_run`; sensors as the open part. The world concealed in the "
        "simulator (module notes). Diagnosis: `diagnose_drives(..., segment=5)` on the believed `mer_rf_unpowered` "
        "scenario, default library made for the six wheels, the soil recalibration, level 0.001. Drive CPU: the "
        "simulation with rtctl; diagnosis CPU: the tool.", "",
        "| case | seed | rtctl max heading [deg] / cross-track [cm] | verdict | named | fitted | truth | outcome | "
        "diagnosis CPU [s] | drive CPU [s] | re-simulations | rows |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['case']} | {r['seed']} | {r['heading']:.2f} / {r['cross']:.2f} | {r['verdict']} | {r['named']} | "
                     f"{r['fitted']} | {r['truth']} | {r['outcome']} | {r['cpu']:.1f} | {r['cpu_drive']:.1f} | {r['sims']} | "
                     f"{r['rows']} |")
    for r in rows:
        if r["advice"]:
            lines += ["", f"- {r['case']} (seed {r['seed']}), {r['verdict']}: {r['advice']}"]
    lines += ["", "<details><summary>Verdict summaries</summary>", ""]
    for r in rows:
        lines += [f"### {r['case']} (seed {r['seed']})", "", "```", str(r["summary"]), "```", ""]
    return lines + ["</details>", ""]


def _section(text: str, mark: str) -> list[str]:
    """The part of an earlier results file that starts at ``mark`` (up to the next part's mark)."""
    if mark not in text:
        return []
    body = text.split(mark, 1)[1]
    for other in (OPEN_MARK, CLOSED_MARK):
        if other != mark and other in body:
            body = body.split(other, 1)[0]
    return [mark, *body.rstrip("\n").split("\n"), ""]


def _run_part(cases, run, line) -> list[dict[str, object]]:
    """Each case's row (``run(case)``), printed as it comes (``line(row)``)."""
    rows = []
    for case in cases:
        rows.append(run(case))
        print(line(rows[-1]), flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=20.0, help="drive length, s (default %(default)s)")
    ap.add_argument("--part", choices=("open", "closed", "all"), default="all",
                    help="open-loop cases, closed-loop (rtctl) cases, or both (default %(default)s)")
    ap.add_argument("--case", action="append", default=None,  # e.g. --case tether --case "hub drag"
                    help="only the cases whose label contains this text (repeatable; default every case)")
    ap.add_argument("--out", default=str(OUT), help="results file (default %(default)s)")
    args = ap.parse_args()
    out = Path(args.out)

    def chosen(cases):
        return tuple(c for c in cases if args.case is None or any(k in c.label for k in args.case))
    load0, t_all = os.getloadavg(), time.process_time()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    stamp = f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC"
    old = out.read_text() if out.exists() else ""
    open_lines, closed_lines = _section(old, OPEN_MARK), _section(old, CLOSED_MARK)
    bad = False
    with tempfile.TemporaryDirectory() as tmp:
        if args.part in ("open", "all"):
            rows = _run_part(chosen(CASES), lambda c: run_case(c, args.duration, Path(tmp)),
                             lambda r: f"{r['case']} {r['duration']:g} s seed {r['seed']}: {r['verdict']} {r['named']} "
                                       f"{r['fitted']} -> {r['outcome']} ({r['cpu']:.1f} CPU-s)")
            open_lines = _open_section(rows, args.duration, commit, stamp)
            bad |= any(r["outcome"] in ("WRONG NAME", "FALSE ALARM") for r in rows)
        if args.part in ("closed", "all"):
            rows = _run_part(chosen(CLOSED_CASES), lambda c: run_closed_case(c, args.duration, Path(tmp)),
                             lambda r: f"closed {r['case']} seed {r['seed']}: rtctl {r['heading']:.2f} deg {r['cross']:.2f} "
                                       f"cm; {r['verdict']} {r['named']} {r['fitted']} -> {r['outcome']} ({r['cpu']:.1f} + "
                                       f"{r['cpu_drive']:.1f} CPU-s)")
            closed_lines = _closed_section(rows, args.duration, commit, stamp)
            bad |= any(r["outcome"] in ("WRONG NAME", "FALSE ALARM") for r in rows)
    load1 = os.getloadavg()
    reading = old.split("## Reading (written by hand", 1)
    lines = [
        "# Drive discrepancy on six-wheel recordings (issue 23)", "",
        f"Last run: `OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_drive_discrepancy_any_rover.py --part {args.part} "
        f"--duration {args.duration:g}{''.join(f' --case {k!r}' for k in args.case or ())}` at commit {commit}, {stamp}, Python {platform.python_version()}, "
        f"{platform.machine()}; load average {load0[0]:.1f} at the start, {load1[0]:.1f} at the end (2 cores shared); "
        f"{time.process_time() - t_all:.0f} CPU-s in this process in all. One process (`workers=1`), one OpenBLAS thread. "
        "Each part's section says when it was made.", "",
        *open_lines, *closed_lines,
    ]
    if len(reading) == 2:
        lines += ["## Reading (written by hand" + reading[1].rstrip("\n")]
    write_text(out, "\n".join(lines) + "\n")
    print(f"wrote {out}")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
