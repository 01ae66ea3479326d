"""Freeze :func:`rtctl.physics.terramechanics.wrench_core` for every model variant (issue 20).

One command (from the repository root)::

    python tests/data/make_wrench_core_variants_reference.py

``tests/data/online_step_reference.npz`` freezes the wheel physics with each shipped table's
options only (``pavlov`` bulldozing, ``printed`` projection, ``classic`` exit angle). This file
adds the other variants of :class:`~rtctl.physics.terramechanics.ModelOptions` (each bulldozing
form, the ``single`` projection, a scaled and an absent sidewall force, the soil-flow exit
angle, another node count) at 96 seeded wheel states over slip, skid, locked and reversed
travel, on the parameters of the shipped ``rr_steer_stuck`` table. It stores the six wrench
components with the commit that computed them in ``tests/data/wrench_core_variants_reference.npz``;
``tests/test_rtctl_linearisation_reference.py`` checks that a restructured evaluation still
gives these values (to 1e-12 of each component's scale). Written by the code before the fused
wheel physics of the step-time work (commit 7e123c6); regenerate only after a deliberate
change of the physics.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from rtctl.physics.backend import NUMPY  # noqa: E402
from rtctl.physics.steady_state import SteadyStateModel  # noqa: E402
from rtctl.physics.terramechanics import ModelOptions, wrench_core  # noqa: E402
from rtctl.table import load_index  # noqa: E402

OUT = ROOT / "tests" / "data" / "wrench_core_variants_reference.npz"
STATES = 96
VARIANTS = {
    "hegedus": ModelOptions(bulldozing="hegedus"),
    "ishigami": ModelOptions(bulldozing="ishigami"),
    "none": ModelOptions(bulldozing="none"),
    "single": ModelOptions(sidewall_projection="single"),
    "scaled": ModelOptions(bulldozing_scale=0.4),
    "soil_flow": ModelOptions(exit_angle="soil_flow"),
    "nodes5": ModelOptions(nodes_per_segment=5, shear_direction_smoothing=1e-3),
}


def wheel_states(r: float, rng: np.random.Generator) -> np.ndarray:
    """Seeded (vx, vy, omega, h, h0) over slip and skid, locked (4) and reversed (4) travel."""
    v = rng.uniform(0.005, 0.06, STATES)
    beta = rng.uniform(-1.2, 1.2, STATES)
    slip = rng.uniform(-0.8, 0.9, STATES)
    omega = v / r / (1.0 - slip)
    omega[:4] = 0.0
    vx = v * np.cos(beta)
    vx[4:8] *= -1.0
    vy = -v * np.sin(beta)
    vy[8:12] = 0.0  # straight driving: the zeros of v_jT are jumps of the integrand
    h = rng.uniform(0.002, 0.03, STATES)
    h0 = h * rng.uniform(0.6, 1.2, STATES)
    return np.stack([vx, vy, omega, h, h0], axis=1)


def main() -> None:
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    t = load_index(ROOT / "tables" / "index.json")["rr_steer_stuck"].load()
    model = SteadyStateModel.from_table_header(t.header, t.layout.wheels)
    phys = model.phys[0]
    S = wheel_states(float(model.shearing_radius[0]), np.random.default_rng(2026))
    data: dict[str, np.ndarray] = {"commit": np.array(rev), "states": S, "params": np.array([float(q) for q in phys]),
                                   "variants": np.array(list(VARIANTS))}
    for name, opt in VARIANTS.items():
        w, _ = wrench_core(NUMPY, *(S[:, i:i + 1] for i in range(5)), phys, opt)
        data[f"{name}/wrench"] = np.concatenate([np.asarray(q) for q in w], axis=1)
        data[f"{name}/options"] = np.array(repr(asdict(opt)))
    np.savez_compressed(OUT, **data)
    print(f"wrote {OUT.relative_to(ROOT)}: {', '.join(VARIANTS)} (commit {rev})")


if __name__ == "__main__":
    main()
