"""Speed benchmarks of the wheel-soil physics core (issue: physics core, "Speed").

Run on demand, never in the test suite::

    python tests/bench/bench_terramechanics.py [--quick]

Pins itself to one CPU core, measures, prints a table and writes ``tests/bench/results.md``.

Targets
-------
* full 6-component wrench, batched: >= 100,000 wheel states per second on one core, with the
  ratio to a per-state Python loop over the same code;
* one wrench plus its 6 x 5 Jacobian for a single state: <= 50 us;
* sinkage from load: <= 0.2 ms per wheel.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import statistics
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from offline.files import write_text
from offline.physics.params import SOIL_DISSERTATION_T53_GROUSERED, TUNING_T72_LINEAR, WHEEL_GROUSERED_PUBLISHED_CODE
from offline.physics.terramechanics import COMPILE_FLAGS, ModelOptions, WheelModel, state_from_slip

HERE = Path(__file__).resolve().parent


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times), statistics.median(times)


def random_states(model: WheelModel, n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    vx, vy, w = state_from_slip(rng.uniform(-1, 0.95, n), rng.uniform(-1.5, 1.5, n), 0.01, model.wheel)
    h = rng.uniform(0.005, 0.06, n)
    return vx, vy, w, h


def _cpu() -> float:
    """CPU seconds of this process and its finished children (the C compiler)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repeats (a smoke run)")
    ap.add_argument("--out", default=str(HERE / "results.md"), help="results file (default: %(default)s)")
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    rep = 3 if args.quick else 7
    rows: list[tuple[str, str, str, str]] = []

    for opt_name, opts in [("classic exit angle", ModelOptions()), ("soil-flow exit angle", ModelOptions(exit_angle="soil_flow"))]:
        try:
            model = WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR, opts)
            model.wrench(0.01, 0.0, 0.16, 0.02)
        except ImportError:
            continue
        n = 20_000 if args.quick else 100_000
        vx, vy, w, h = random_states(model, n)
        best, med = _best(lambda: model.wrench(vx, vy, w, h), rep)
        rate = n / best
        m = 300
        loop_best, _ = _best(lambda: [model.wrench(vx[i], vy[i], w[i], h[i]) for i in range(m)], max(2, rep // 2))
        loop_rate = m / loop_best
        rows.append((f"wrench, batched ({opt_name}), {n} states", f"{rate:,.0f} states/s (median {n / med:,.0f})",
                     ">= 100,000 states/s", "PASS" if rate >= 1e5 else "FAIL"))
        rows.append((f"wrench, per-state Python loop ({opt_name})", f"{loop_rate:,.0f} states/s; batched is {rate / loop_rate:,.0f}x faster",
                     "(ratio reported)", ""))

    # cold builds, honestly: an empty cache folder, wall and CPU time (the compiler is a child process)
    cold = tempfile.mkdtemp(prefix="offnominal-cold-")
    os.environ["XDG_CACHE_HOME"] = cold
    model = WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR)
    vx, vy, w, h = random_states(model, 200, seed=1)
    for what, build in (("wrench + Jacobian", lambda m: m.compiled_function(True)),
                        ("sinkage-from-load Newton", lambda m: m._single_sinkage_function())):
        c0, t = _cpu(), time.perf_counter()
        build(model)
        wall, cpu = time.perf_counter() - t, _cpu() - c0
        rows.append((f"cold build of the compiled {what} (empty cache, codegen + {' '.join(COMPILE_FLAGS)} compile)",
                     f"{wall:.1f} s wall, {cpu:.1f} s CPU", "(one-off per parameter set)", ""))
        again = WheelModel(SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR)
        t = time.perf_counter()
        build(again)
        rows.append((f"warm load of the compiled {what} (cache hit)", f"{time.perf_counter() - t:.2f} s", "", ""))
    shutil.rmtree(cold, ignore_errors=True)
    xs = [np.array([vx[i], vy[i], w[i], h[i], 0.9 * h[i]]) for i in range(200)]
    for compiled in (True, False):
        k = 2000 if compiled else 300
        best, med = _best(lambda: [model.wrench_and_jacobian(xs[i % 200], compiled=compiled) for i in range(k)], rep)
        us = best / k * 1e6
        label = "compiled C (casadi codegen)" if compiled else "casadi VM (no compiler)"
        rows.append((f"wrench + 6x5 Jacobian, one state, {label}", f"{us:.1f} us (median {med / k * 1e6:.1f})",
                     "<= 50 us" if compiled else "(reference)", ("PASS" if us <= 50 else "FAIL") if compiled else ""))

    rng = np.random.default_rng(2)
    k = 200
    s = rng.uniform(-1, 0.9, k)
    vx, vy, w = state_from_slip(s, rng.uniform(-1.3, 1.3, k), 0.01, model.wheel)
    load = rng.uniform(10, 30, k)
    model.sinkage_from_load_single(load[0], vx[0], vy[0], w[0])  # compile once
    best, med = _best(lambda: [model.sinkage_from_load_single(load[i], vx[i], vy[i], w[i]) for i in range(k)], rep)
    ms = best / k * 1e3
    rows.append((f"sinkage from load, one wheel at a time, compiled Newton (skid share {np.mean(s < 0):.0%})",
                 f"{ms:.3f} ms per wheel (median {med / k * 1e3:.3f})", "<= 0.2 ms per wheel", "PASS" if ms <= 0.2 else "FAIL"))
    for n in (100, 2000):
        s = rng.uniform(-1, 0.9, n)
        vx, vy, w = state_from_slip(s, rng.uniform(-1.3, 1.3, n), 0.01, model.wheel)
        load = rng.uniform(10, 30, n)
        best, med = _best(lambda: model.sinkage_from_load(load, vx, vy, w), rep)
        sol = model.sinkage_from_load(load, vx, vy, w)
        ms = best / n * 1e3
        rows.append((f"sinkage from load, batched numpy, {n} wheels (skid share {np.mean(s < 0):.0%}, {sol.converged.mean():.0%} converged)",
                     f"{ms:.3f} ms per wheel", "<= 0.2 ms per wheel", "PASS" if ms <= 0.2 else "FAIL"))

    head = (f"# Physics-core benchmarks\n\nWritten by `python tests/bench/bench_terramechanics.py` on "
            f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; {platform.machine()}, Python {platform.python_version()}, "
            f"numpy {np.__version__}, pinned to one core; best of {rep} runs; load average at the end "
            f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (speed rows are only comparable on a quiet machine; "
            f"the cold-build CPU seconds are not affected by load).\n\n")
    table = "| measurement | result | target | |\n|---|---|---|---|\n" + "\n".join(f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows)
    text = head + table + "\n"
    write_text(args.out, text)
    print(text)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
