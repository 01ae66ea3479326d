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
Also the wheel-state batch of ``evaluate`` alone (:func:`rtctl.physics.terramechanics.wrench_core`
on its first 8, 14 and all 32 states): an inexact Jacobian refreshed one wheel per tick
(round-robin; the residual exact every tick, the objective gradient ``2 M_y dM_y/dx`` from the
exact ``M_y`` and the last refreshed derivatives, so that both are exact at a fixed point) would
evaluate 14 states (the 8 of the residual and one wheel's 4 + 2 difference states) instead of 32,
which bounds what it could save (the row assembly costs the same at 6 as at 21 columns: its cost
is the operation count).
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
    import rtctl.physics.steady_state as S
    import rtctl.physics.terramechanics as T

    captured: dict[str, tuple] = {}

    def capture(*a: object) -> object:
        captured["a"] = a
        return T.wrench_core(*a)

    S.wrench_core = capture  # type: ignore[assignment]
    try:
        rti.residual.evaluate(x, p, jacobian=True)
    finally:
        S.wrench_core = T.wrench_core
    a = captured["a"]

    def batch(n: int) -> object:
        b = (a[0], *(q[:n] for q in a[1:6]), *a[6:])
        return lambda: T.wrench_core(*b)

    kinds = {"wheel-state batch alone, 8 states (the residual's)": batch(8),
             "wheel-state batch alone, 14 states (a round-robin Jacobian's)": batch(14),
             "wheel-state batch alone, 32 states (evaluate's)": batch(32),
             "residual (8 wheel states)": lambda: rti.residual.residual(x, p),
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
    b14 = float(np.median(times["wheel-state batch alone, 14 states (a round-robin Jacobian's)"])) / 1e3
    b32 = float(np.median(times["wheel-state batch alone, 32 states (evaluate's)"])) / 1e3
    lines += ["", "The cost is the number of numpy operations, not the number of wheel states: reusing the exact "
              "Jacobian between ticks (the residual and gradient exact every tick) saves at most the difference "
              "between the last two rows. A round-robin Jacobian (one wheel's block refreshed per tick, the residual "
              f"exact; the gradient as this script's docstring says) would evaluate 14 wheel states instead of 32: at most {b32 - b14:.0f} us "
              f"({(b32 - b14) / full:.0%} of the linearisation) saved per tick, so it was not built.", ""]
    from offline.files import write_text

    write_text(HERE / "results_online_step_linearisation_cost.md", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
