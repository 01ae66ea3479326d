"""The two physics paths the slow tests spend their time in, before and after (issue 20, suite CPU).

::

    python tests/bench/bench_suite_physics.py [--before b7649e8] [--repeats 5]

For the ``--before`` commit (checked out into a temporary worktree) and this tree, alternating, in
one run, each in its own process (thread CPU time, the best of ``--repeats``):

* ``sinkage``: :meth:`offline.physics.terramechanics.WheelModel.sinkage_from_load` on seeded batches
  of 1, 3 and 40 wheel states (loads 2-15 N, slip and skid, forward and reverse) for the classic,
  soil-flow and Ishigami variants: the single-wheel diagnoses' inner loop (tests/test_discrepancy.py);
* ``plant``: the 6 s drive of ``tests/test_plant_newton.py`` (nominal scenario, a steering step and a
  growing drawbar pull): every :meth:`offline.sim.plant.PlantModel._evaluate` call of it re-run on its
  recorded arguments (the drive diagnoses' inner loop, tests/test_drive_concealed.py), per call.

Each process also writes its outputs (sinkages, residuals, plant residuals, Jacobians, wrenches and the
drive's unknowns); the report says whether the two trees agree bit for bit. Results:
``tests/bench/results_suite_physics.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

_SCRIPT = r'''
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
repeats, out = int(sys.argv[2]), sys.argv[3]
import offline.physics.params as P
from offline.physics.terramechanics import ModelOptions, WheelModel
from offline.rover.primitives import solve_primitive
from offline.rover.scenario import example_scenarios, load_scenario
from offline.sim.plant import PlantModel
from offline.sim.simulator import DisturbanceForces, RoverSimulator
from rtctl.messages import Commands

models = [WheelModel(P.SOIL_DISSERTATION_T53_GROUSERED, P.WHEEL_GROUSERED_PUBLISHED_CODE, P.TUNING_T72_LINEAR, o)
          for o in (ModelOptions(), ModelOptions(exit_angle="soil_flow"), ModelOptions(bulldozing="ishigami"))]

def sinkage():
    rng = np.random.default_rng(5)
    res = []
    for m in models:
        for n in (1, 3, 40):
            for _ in range(6):
                W = rng.uniform(2, 15, n)
                vx = rng.uniform(0.005, 0.05, n) * rng.choice([-1, 1], n)
                vy = rng.uniform(-0.02, 0.02, n)
                om = np.sign(vx) * np.abs(vx) / 0.0635 * rng.uniform(0.3, 1.8, n)
                r = m.sinkage_from_load(W, vx, vy, om)
                res += [r.h, r.h_zero_slip, r.residual]
    return res

WHEELS = ("FR", "FL", "RR", "RL")
sc = load_scenario({p.stem: p for p in example_scenarios()}["nominal"])
prim = solve_primitive(sc)
rim = tuple(prim.wheels[k].rim_speed for k in WHEELS)
calls = []
original = PlantModel._evaluate
def recording(self, z, ctx, d, jacobian):
    calls.append((self, z.copy(), ctx, None if d is None else d.copy(), jacobian))
    return original(self, z, ctx, d, jacobian)
PlantModel._evaluate = recording
sim = RoverSimulator(sc, seed=0, disturbance=lambda t, _: DisturbanceForces(body_force=(-1.5 * t, 0.3)))
sim.start(Commands(0.0, 0, rim, (0.0,) * 4))
zs = []
for k in range(30):
    sim.apply(Commands(0.2 * k, k, rim, (0.35, 0.35, -0.35, -0.35) if k >= 5 else (0.0,) * 4))
    sim.advance(0.2)
    zs.append(sim.z.copy())
PlantModel._evaluate = original

def plant():
    return [o for c in calls for o in original(*c)]

best = {}
outputs = {}
sinkage()  # warm: compiled functions, caches
for _ in range(repeats):
    for name, f in (("sinkage", sinkage), ("plant", plant)):
        t0 = time.thread_time_ns()
        o = f()
        t = (time.thread_time_ns() - t0) / 1e6
        best[name] = min(best.get(name, 1e18), t)
        outputs[name] = o
arrays = {f"{k}_{i}": np.asarray(a, dtype=float) for k, v in outputs.items() for i, a in enumerate(v)}
arrays["drive"] = np.array(zs)
np.savez(out, **arrays)
print(json.dumps({"sinkage_ms": best["sinkage"], "plant_us_per_call": best["plant"] * 1e3 / len(calls),
                  "plant_calls": len(calls)}))
'''


def main() -> None:
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default="b7649e8")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    sys.path.insert(0, str(HERE))
    import bench_online_step as B

    runs: dict[str, list[dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        wt = Path(tmp) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt), a.before], check=True,
                       capture_output=True)
        try:
            for i, (label, tree) in enumerate([("before", wt), ("after", ROOT)] * 2):
                out = str(Path(tmp) / f"{label}{i}.npz")
                r = subprocess.run([sys.executable, "-c", _SCRIPT, str(tree), str(a.repeats), out], capture_output=True,
                                   text=True, env={**os.environ, "PYTHONPATH": str(tree)}, cwd=str(tree))
                if r.returncode:
                    raise SystemExit(f"{label}: {r.stderr[-3000:]}")
                runs.setdefault(label, []).append({**json.loads(r.stdout.strip().splitlines()[-1]), "out": out})
                print(label, runs[label][-1], flush=True)
            x, y = np.load(runs["before"][0]["out"]), np.load(runs["after"][0]["out"])
            same = x.files == y.files and all(np.array_equal(x[k], y[k], equal_nan=True) for k in x.files)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)], capture_output=True)

    def best(label: str, key: str) -> float:
        return min(r[key] for r in runs[label])

    meta = B._meta()
    lines = ["# The slow tests' physics paths, before and after (issue 20, suite CPU)", "",
             f"`python tests/bench/bench_suite_physics.py --before {a.before} --repeats {a.repeats}`; {meta['commit']}, "
             f"{meta['date']}, {meta['machine']}, {meta['cpus']} cpus (shared with other jobs: compare the columns).", "",
             "Thread CPU, the best of the repeats and of two alternating processes per tree (module docstring).", "",
             "| path | before | after | after / before |", "|---|---|---|---|"]
    for key, name in (("sinkage_ms", "sinkage solves (54 batches, 3 model variants) [ms]"),
                      ("plant_us_per_call", f"plant evaluate, per call ({runs['after'][0]['plant_calls']:.0f} calls) [us]")):
        b_, a_ = best("before", key), best("after", key)
        lines.append(f"| {name} | {b_:.1f} | {a_:.1f} | {a_ / b_:.2f} |")
    lines += ["", f"Outputs of the two trees (sinkages, residuals, plant residuals, Jacobians, wrenches, the drive): "
              f"{'identical bit for bit' if same else 'DIFFERENT'}.", ""]
    from offline.files import write_text

    write_text(HERE / "results_suite_physics.md", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
