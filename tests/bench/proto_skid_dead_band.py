"""Prototype, since applied: a dead band on rtctl's slip-correction speed shift for tables without lateral authority.

Applied in ``rtctl.controller.Controller.prepare`` on branch i23-skid (``_SLIP_DEAD_BAND``). Its numbers
with the allocator's unreachable-row fix are in ``results_any_rover_drives.md`` (i23-skid). On today's
rtctl this script's two rows are the same controller (the band is then added a second time, which
changes nothing); it is kept to reproduce the earlier comparison on an older tree.

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
copy. Prints the rows; writes nothing. ``--trace SEED`` drives one seed with the prototype and
prints where the slip estimate leaves the band (a diagnosis of seed 3, ``results_any_rover_drives.md``).
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
TRACE = NEW + ("            TRACE.append((float(x[3]), prev.primitive_slip, math.sqrt(P[3, 3]), factor))\n")
"""The prototype with a trace of each tick's slip estimate, primitive slip, its sigma and the factor
(``--trace SEED``: a diagnosis, module notes)."""

TRACE_DRIVE = '''
import sys, time
import numpy as np
sys.path.insert(0, str(ROOT / "tests" / "bench"))
import rtctl.controller as rc
rc.TRACE = []
from bench_any_rover_drives import CASES, ROVERS, _controller
from offline.rover.scenario import load_scenario
from offline.sim.experiments import run_drive
from offline.sim.simulator import RoverSimulator
case = [c for c in CASES if c.scenario == "skid_fr_unpowered" and c.controller == "rtctl" and not c.noise_free][0]
sc = load_scenario(ROVERS / f"{case.scenario}.toml").with_(speed=case.speed)
ctl, _ = _controller(case, sc)
res = run_drive(RoverSimulator(sc, seed=SEED), ctl, distance=5.0, max_time=15.0 / case.speed)
tr = np.array(rc.TRACE)  # s_hat, primitive slip, sigma, factor (the ticks where the shift was considered)
truth = res.truth
t = np.array([s.t for s in truth]); head = np.degrees([s.heading for s in truth])
slip_true = np.array([np.mean(s.slip) for s in truth])
rim = np.array([c.rim_speed for c in res.commands])
band = np.abs(tr[:, 0] - tr[:, 1]) < 2.0 * tr[:, 2]
n = len(tr)
print(f"seed {SEED}: {n} ticks with the shift considered; in the band {band.sum()} ({100 * band.mean():.1f} %)")
for lo, hi in ((0, n // 4), (n // 4, n // 2), (n // 2, 3 * n // 4), (3 * n // 4, n)):
    sl = slice(lo, hi)
    print(f"  ticks {lo}-{hi}: in band {100 * band[sl].mean():5.1f} %, sigma median {np.median(tr[sl, 2]):.4f}, "
          f"s_hat - s_prim median {np.median(tr[sl, 0] - tr[sl, 1]):+.4f} (abs p90 {np.quantile(np.abs(tr[sl, 0] - tr[sl, 1]), 0.9):.4f}), "
          f"s_prim range {tr[sl, 1].min():+.4f}..{tr[sl, 1].max():+.4f}, factor range {tr[sl, 3].min():.3f}..{tr[sl, 3].max():.3f}")
k = int(np.argmax(np.abs(head)))
print(f"  max |heading| {abs(head[k]):.3f} deg at t = {t[k]:.1f} s of {t[-1]:.1f} s; true mean slip median {np.median(slip_true):+.4f}")
d = np.abs(np.diff(rim, axis=0)).max(axis=1)
out = ~band
runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], out.astype(int), [0]]))))[::2] if out.any() else np.array([0])
print(f"  out-of-band runs: {len(runs)}, longest {runs.max()} ticks; per-wheel max rim change p90 in band "
      f"{1e3 * np.quantile(d[:n][band[:len(d)]], 0.9) if band.any() else float('nan'):.3f} mm/s, out of band "
      f"{1e3 * np.quantile(d[:n][out[:len(d)]], 0.9) if out.any() else float('nan'):.3f} mm/s")
'''

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
    if len(sys.argv) == 3 and sys.argv[1] == "--trace":
        with tempfile.TemporaryDirectory() as tmp:
            copy = Path(tmp) / "rtctl"
            shutil.copytree(ROOT / "rtctl", copy, ignore=shutil.ignore_patterns("__pycache__"))
            src = (copy / "controller.py").read_text()
            (copy / "controller.py").write_text(src.replace(OLD, TRACE).replace("\nimport math\n", "\nimport math\nTRACE: list = []\n", 1))
            _run(f"SEED = {int(sys.argv[2])}\n" + TRACE_DRIVE, Path(tmp), "trace")
        return 0
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
