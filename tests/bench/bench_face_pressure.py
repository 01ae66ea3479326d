"""Does a face passive-pressure term with the recorded sinkage explain the 75-90 deg miss? (issue 14, part 2)

One command, writes tests/bench/results_face_pressure.md::

    nice python tests/bench/bench_face_pressure.py

Model under test: the shipped calibrated parameter set with the Pavlov sidewall term; data:
the shipped grousered trials (:func:`offline.discrepancy.wheel.face_pressure.held_out_angles`).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from offline.cli.common import DEFAULT_PARAMS, shipped
from offline.files import write_text
from offline.discrepancy.wheel.candidates import SingleWheelModel
from offline.fit.dataset import load_trials
from offline.discrepancy.wheel.face_pressure import held_out_angles
from offline.discrepancy.wheel.recording import SingleWheelRecording
from offline.physics.params import load_toml
from offline.physics.terramechanics import ModelOptions

ROOT = Path(__file__).resolve().parents[2]


def main() -> int:
    ps = load_toml(shipped(DEFAULT_PARAMS))["parameter_set"]
    rec = SingleWheelRecording.from_trials(load_trials(None))
    rows = held_out_angles(rec, SingleWheelModel(ps, ModelOptions(bulldozing="pavlov")))
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    md = ["# Face passive pressure with the recorded sinkage at 75-90 deg (held-out angles)", "",
          f"Commit `{commit}`; `nice python tests/bench/bench_face_pressure.py`; model `{DEFAULT_PARAMS}` with the Pavlov "
          "sidewall term; shipped grousered trials (condition means). For each angle the scales are fitted on every "
          "other condition (the other high angle included) and the angle's rows are scored; chi2 in units of repeat noise "
          "x the model's dispersion over Fx, Fy, sinkage (a row the model cannot predict counts 10 per channel).", "",
          "| held-out angle | rows | model fails | chi2 model | chi2 sidewall refit (scale) | chi2 face term (scale) | "
          "face term in-sample best (scale) | mean Fy residual model -> face [N] |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        md.append(f"| {r.angle_deg:.0f} deg | {r.rows} | {r.failed_rows} | {r.chi2_model:.0f} | {r.chi2_sidewall_refit:.0f} "
                  f"({r.sidewall_scale:.2f}) | {r.chi2_face:.0f} ({r.face_scale:.3g}) | {r.chi2_face_in_sample:.0f} "
                  f"({r.face_scale_in_sample:.3g}) | {r.fy_residual_model:.2f} -> {r.fy_residual_face:.2f} |")
    earns = all(r.chi2_face < min(r.chi2_model, r.chi2_sidewall_refit) for r in rows)
    md += ["", f"Verdict: the face term {'EARNS' if earns else 'does NOT earn'} its place on held-out angles."]
    write_text(ROOT / "tests/bench/results_face_pressure.md", "\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
