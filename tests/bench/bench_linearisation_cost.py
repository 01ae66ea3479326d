"""What an exact Jacobian costs beyond the exact residual and gradient (issue 20, step time).

One command (from the repository root)::

    python tests/bench/bench_linearisation_cost.py [--calls 400]

On ``rr_steer_stuck`` at an off-grid point, the thread CPU time (median of ``--calls`` calls,
the three kinds interleaved) of :class:`rtctl.physics.steady_state.SteadyStateResidual`:
``residual`` (rows and objective: every wheel and its zero-slip state, 8 wheel states),
``evaluate(jacobian=False)`` (plus the exact objective gradient: the forward-difference wheel
states of every wheel variable kind, 32 states) and ``evaluate(jacobian=True)`` (plus the rows'
Jacobian from the same wheel states). It decides whether re-evaluating the exact Jacobian only
when the iterate moved (and otherwise reusing the last one) can pay: the difference between the
last two is all it can save, since the residual and gradient must stay exact every tick.
Results: ``tests/bench/results_online_step_linearisation_cost.md``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--calls", type=int, default=400)
    args = ap.parse_args()
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_index

    t = load_index(ROOT / "tables" / "index.json")["rr_steer_stuck"].load()
    lay = t.layout
    op = {"cross_slope": 0.0, "slope": 0.230157, "speed": 0.035129, "steer_stuck": 0.204401}
    tp = t.at(**op)
    rti = RealTimeIteration(t, QpSettings(), [lay.index(f"wheel torque {w}") for w in lay.wheels])
    assert rti.residual is not None
    x, p = np.array(tp.x), np.array(tp.p)
    kinds = {"residual (8 wheel states)": lambda: rti.residual.residual(x, p),
             "residual + gradient (32 states)": lambda: rti.residual.evaluate(x, p, jacobian=False),
             "residual + gradient + Jacobian (32 states)": lambda: rti.residual.evaluate(x, p, jacobian=True)}
    times: dict[str, list[int]] = {k: [] for k in kinds}
    for _ in range(args.calls):
        for k, f in kinds.items():
            t0 = time.thread_time_ns()
            f()
            times[k].append(time.thread_time_ns() - t0)
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    full = float(np.median(times["residual + gradient + Jacobian (32 states)"])) / 1e3
    lines = ["# Exact linearisation: what the Jacobian costs beyond the residual and gradient", "",
             f"`python tests/bench/bench_linearisation_cost.py --calls {args.calls}`; {rev}; thread CPU, median of "
             f"{args.calls} interleaved calls, rr_steer_stuck off-grid.", "",
             "| evaluation | median [us] | of the full linearisation |", "|---|---|---|"]
    for k, v in times.items():
        m = float(np.median(v)) / 1e3
        lines.append(f"| {k} | {m:.0f} | {m / full:.0%} |")
    lines += ["", "The cost is the number of numpy operations, not the number of wheel states: reusing the exact "
              "Jacobian between ticks (the residual and gradient exact every tick) saves at most the difference "
              "between the last two rows.", ""]
    (HERE / "results_online_step_linearisation_cost.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
