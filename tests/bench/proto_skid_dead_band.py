"""Prototype (not applied): a dead band on rtctl's slip-correction speed shift for tables without lateral authority.

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/proto_skid_dead_band.py

The skid-steer's chatter (``results_any_rover_drives.md``): rtctl's slip correction (a) moves the
table speed by ``(1 - s_primitive) / (1 - s_hat)`` every tick, 1-5 % from EKF slip noise, and
carries the skid-steer's free-rolling FR wheel across the wheel model's zero-slip kink. The change
tried here, on a copy of ``rtctl/`` in a temporary folder (rtctl is not edited by this script):
in :meth:`rtctl.controller.Controller.prepare`, after the factor is computed,

    if not prev.lateral and abs(s_hat - prev.primitive_slip) < 2.0 * math.sqrt(P[3, 3]):
        factor = 1.0

-- no speed shift while the estimated slip is within two of its standard deviations of the
primitive's, on a table whose free variables cannot move the F_y row (``lateral_authority``
False: only the skid-steer's among the shipped and test tables; every optimal grid point of every
mini rover table has lateral authority), so the mini rover's commands cannot change. The script
drives the skid-steer 5 m (``bench_any_rover_drives.py``'s case, seeds 1-3) with rtctl as it is and
with the copy, and replays the committed mini rover recordings (``tests/data/rec_*.mcap``) with the
copy. Prints the rows; writes nothing.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1].parent
OLD = "            factor = min(max((1.0 - prev.primitive_slip) / (1.0 - s_hat), _SPEED_SHIFT[0]), _SPEED_SHIFT[1])\n"
NEW = OLD + ("            if not prev.lateral and abs(s_hat - prev.primitive_slip) < 2.0 * math.sqrt(P[3, 3]):\n"
             "                factor = 1.0  # prototype: dead band on a table without lateral authority\n")

DRIVES = '''
import sys, time
import numpy as np
sys.path.insert(0, str(ROOT / "tests" / "bench"))
import rtctl.controller as rc
from bench_any_rover_drives import CASES, ROVERS, _controller
from offline.rover.scenario import load_scenario
from offline.sim.experiments import run_drive
from offline.sim.simulator import RoverSimulator
case = [c for c in CASES if c.scenario == "skid_fr_unpowered" and c.controller == "rtctl" and not c.noise_free][0]
for seed in (1, 2, 3):
    sc = load_scenario(ROVERS / f"{case.scenario}.toml").with_(speed=case.speed)
    c0 = time.process_time()
    ctl, _ = _controller(case, sc)
    res = run_drive(RoverSimulator(sc, seed=seed), ctl, distance=5.0, max_time=15.0 / case.speed)
    m, rim = res.metrics, np.array([c.rim_speed for c in res.commands])
    d = np.abs(np.diff(rim, axis=0))
    print(f"| {LABEL} | {seed} | {m['max_abs_heading_deg']:.3f} | {m['max_abs_cross_track_cm']:.3f} | "
          f"{m['mean_speed_cm_s']:.3f} | {1e3 * np.median(d):.4f} / {1e3 * np.quantile(d, 0.9):.4f} | "
          f"{time.process_time() - c0:.1f} |", flush=True)
'''

REPLAY = '''
from offline.sim.experiments import build_controller, scenario_by_name
from offline.sim.rtctl_bridge import rtctl_factory
from rtctl.recording import read_recording
from rtctl.replay import replay
DATA = ROOT / "tests" / "data"
for path in sorted(DATA.glob("rec_*.mcap")):
    rec = read_recording(path)
    kind = rec.metadata["controller"]
    sc = scenario_by_name(rec.metadata["scenario"])
    ctl = rtctl_factory(str(DATA / "tables"))(sc) if kind == "rtctl" else build_controller(kind, sc)
    rep = replay(rec, ctl)
    print(f"- replay of {path.name} with the prototype: " + ("bit for bit" if rep.identical else rep.summary()), flush=True)
'''


def _run(code: str, first: Path | None, label: str) -> None:
    path = [str(first)] if first is not None else []
    head = (f"import sys; from pathlib import Path; sys.path[:0] = {path + [str(ROOT)]!r}; ROOT = Path({str(ROOT)!r}); "
            f"LABEL = {label!r}\nimport rtctl\nassert Path(rtctl.__file__).parent.parent == Path(sys.path[0]), rtctl.__file__\n")
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "PYTHONPATH": ""}
    subprocess.run([sys.executable, "-c", head + code], check=True, env=env)


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "rtctl"
        shutil.copytree(ROOT / "rtctl", copy, ignore=shutil.ignore_patterns("__pycache__"))
        src = (copy / "controller.py").read_text()
        if src.count(OLD) != 1:
            print("the slip correction's factor line is not where this prototype expects it (rtctl changed)")
            return 1
        (copy / "controller.py").write_text(src.replace(OLD, NEW))
        print("| rtctl | seed | max heading [deg] | max cross-track [cm] | speed [cm/s] | tick-to-tick rim-speed change "
              "median / p90 [mm/s] | CPU [s] |\n|---|---|---|---|---|---|---|", flush=True)
        _run(DRIVES, None, "as it is")
        _run(DRIVES, Path(tmp), "dead band (prototype)")
        _run(REPLAY, Path(tmp), "")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
