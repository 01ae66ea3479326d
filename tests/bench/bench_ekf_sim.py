"""Benchmark: rtctl's EKF against the simulator's truth on closed-loop drives (issue 12/13).

Run from the repository root (one command; writes ``tests/bench/results_ekf_sim.md``)::

    python tests/bench/bench_ekf_sim.py [--seeds 1 2 3]

For each drive (main-job scenario, rear-right steering stuck at -50 deg, rtctl in the loop) it
reads the MCAP recording back and compares the EKF's estimate (``diagnostics.state`` with its
1-sigma ``state_sigma``) with the simulator's truth channel, after a 10 s settling time:
normalised squared errors per component (x, y, heading, slip, crab angle and, where the truth
records it, gyro bias; 1 for a consistent filter; diagonal only: the recording holds sigmas,
not the full covariance -- ``tests/test_rtctl_ekf_sim.py`` checks the full 5-dof NEES). The
rover-level slip is ``1 - V / V_odo`` with ``V_odo`` the least-squares speed of
``r_s omega_i = V cos(beta_i)`` over the four wheels, the estimator's odometry definition;
the truth's crab ``atan2(v, u)`` minus the crab the commands asked for over the tick
(``diagnostics.crab_commanded``, an input of the EKF's motion model since issue 13) is the
EKF's crab state.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1].parent
sys.path.insert(0, str(ROOT))

from offline.cli import main as drive  # noqa: E402
from offline.files import write_text  # noqa: E402
from offline.physics.params import load_toml  # noqa: E402
from rtctl.recording import read_recording  # noqa: E402

CASES = {"poses every 0.2 s": [], "poses every 10 s": ["--pose-period", "10"], "soil 30 % softer": ["--truth", "soil_soft_30"]}


def check(path: Path, rs: float, settle: float = 10.0) -> dict[str, float]:
    """Normalised squared errors and slip error of one recorded rtctl drive."""
    r = read_recording(path)
    truth = {round(t["t"], 6): t for t in r.truth}
    rows = []
    for d in r.diagnostics:
        t = truth.get(round(d["t"], 6))
        if t is None or d["mode"] != "qp" or d["t"] <= settle:
            continue
        x, y, h, s, a, b = d["state"]
        sx, sy, sh, ss, sa, sb = d["state_sigma"]
        om, st = np.array(t["omega"]), np.array(t["steer"])
        c = np.cos(st)
        v_odo = float(np.sum(c * rs * om) / np.sum(c * c))
        slip_true = 1.0 - math.hypot(t["u"], t["v"]) / v_odo
        crab_true = math.atan2(t["v"], t["u"]) - float(d.get("crab_commanded", 0.0))
        bias = (b - float(t["gyro_bias"])) / sb if "gyro_bias" in t else math.nan
        rows.append(((x - t["x"]) / sx, (y - t["y"]) / sy, math.remainder(h - t["heading"], 2 * math.pi) / sh,
                     (s - slip_true) / ss, (a - crab_true) / sa, bias, s - slip_true))
    z = np.array(rows)
    return {"ticks": len(z),
            **{f"nees_{n}": float(np.mean(z[:, i] ** 2)) for i, n in enumerate(("x", "y", "heading", "slip", "crab", "bias"))},
            "slip_err_mean_abs": float(np.mean(np.abs(z[:, 6])))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--out", default=str(ROOT / "tests" / "bench" / "results_ekf_sim.md"))
    args = ap.parse_args()
    rs = load_toml(ROOT / "offline" / "data" / "calibrated_grousered.toml")["parameter_set"].wheel.shearing_radius
    lines = ["# rtctl EKF against the simulator's truth", "",
             f"Written by `python tests/bench/bench_ekf_sim.py` on {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC. "
             "Main-job drive (RR steering stuck at -50 deg, 1.5 m at 3 cm/s, rtctl on the shipped tables); "
             "statistics after 10 s. Columns x ... bias: mean normalised squared error per component (1 for a "
             "consistent filter; diagonal only; crab: the disturbance crab, truth minus the commanded crab; bias: "
             "nan where the simulator's truth has no gyro bias). Slip error: mean |EKF slip - true rover-level slip|.",
             "", "| case | seed | ticks | x | y | heading | slip | crab | bias | slip error |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        for case, extra in CASES.items():
            for seed in args.seeds:
                out = Path(tmp) / f"{case.replace(' ', '_')}_{seed}"
                rc = drive(["drive", "--controllers", "rtctl", "--seed", str(seed), "--out", str(out), "--quiet", *extra])
                if rc != 0:
                    raise SystemExit(f"offnominal drive failed for {case}, seed {seed} (exit {rc})")
                res = check(next(out.glob("*rtctl*.mcap")), rs)
                lines.append(f"| {case} | {seed} | {res['ticks']} | {res['nees_x']:.2f} | {res['nees_y']:.2f} | "
                             f"{res['nees_heading']:.2f} | {res['nees_slip']:.2f} | {res['nees_crab']:.2f} | "
                             f"{res['nees_bias']:.2f} | {res['slip_err_mean_abs']:.3f} |")
                print(lines[-1], flush=True)
    write_text(args.out, "\n".join(lines) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
