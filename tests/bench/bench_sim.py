"""Speed benchmark of the rover simulator (issue 13: ">= 20 simulated seconds per wall second").

Run on demand, never in the test suite::

    nice python tests/bench/bench_sim.py [--quick]

Drives the section 7.3 scenarios 1.5 m at 3 cm/s (50 simulated seconds each) open loop
(feed-forward primitive: commands constant) and closed loop (feed-forward + PID: commands
change every 0.2 s, so the plant's Newton solve works every step), at the default step
(0.1 s) and at 0.05 s, with the simulator's defaults (wheel spin inertia, gyro bias walk);
then the closed loop at 0.1 s once more with a disturbance hook (contract C5: a drawbar pull
and hub drag varying with time, evaluated every step) to show the hook's cost. Primitives and steering controllers are solved before the clock
starts; the plant's C compile is cached on disk (first run only). Writes
``tests/bench/results_sim.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from offline.files import write_text
from offline.sim.experiments import build_controller, run_drive, scenario_by_name
from offline.sim.simulator import DisturbanceForces, RoverSimulator, TruthState

HERE = Path(__file__).resolve().parent
TARGET = 20.0


def _drag(t: float, s: TruthState) -> DisturbanceForces:
    """A time-varying drawbar pull (0.5-1 N) and a hub drag on the rear right wheel (0.02 N m)."""
    return DisturbanceForces(body_force=(-0.75 - 0.25 * np.sin(0.2 * t), 0.0),
                             wheel_torque=(0.0, 0.0, 0.02 * np.sign(s.omega[2]), 0.0))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, 0.5 m drives")
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    repeat = 1 if args.quick else 3
    distance = 0.5 if args.quick else 1.5
    rows = []
    load_start = os.getloadavg()[0]
    cases = [(name, kind, dt, None) for name in ("rr_steer_stuck_50", "rr_speed_cap_half", "rr_trench_clean")
             for kind in ("ff", "ff+optfb") for dt in (0.1, 0.05)]
    cases.append(("rr_steer_stuck_50", "ff+optfb", 0.1, _drag))
    controllers = {}
    for name, kind, dt, hook in cases:
        sc = scenario_by_name(name)
        if (name, kind) not in controllers:
            controllers[name, kind] = build_controller(kind, sc)
        ctl = controllers[name, kind]
        rates, cpu_rates, iters = [], [], []
        for _ in range(repeat):
            sim = RoverSimulator(sc, dt=dt, seed=0, disturbance=hook)
            t, c = time.perf_counter(), time.process_time()
            run_drive(sim, ctl, distance=distance)
            wall, cpu = time.perf_counter() - t, time.process_time() - c
            rates.append(sim.t / wall)
            cpu_rates.append(sim.t / cpu)
            iters.append(sim.newton_iterations / max(sim.steps, 1))
        rate = max(rates)
        label = kind + (" + disturbance hook" if hook is not None else "")
        rows.append((name, label, dt, rate, statistics.median(rates), max(cpu_rates), float(np.mean(iters))))
        print(f"{name:18s} {label:9s} dt={dt:<5} {rate:6.1f} sim-s/wall-s (median {statistics.median(rates):.1f}), "
              f"{max(cpu_rates):6.1f} sim-s/CPU-s, {np.mean(iters):.2f} Newton iterations per step", flush=True)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Simulator benchmark",
        "",
        f"Written by `nice python tests/bench/bench_sim.py{' --quick' if args.quick else ''}` on {stamp}; "
        f"{platform.machine()}, Python {platform.python_version()}, numpy {np.__version__}, pinned to one core "
        f"(machine shared with other jobs); best of {repeat}, {distance} m drives at 3 cm/s.",
        "",
        f"Target: >= {TARGET:.0f} simulated seconds per wall second. The wall rate depends on what else runs on the "
        f"machine (1-min load average {load_start:.1f} at the start and {os.getloadavg()[0]:.1f} at the end of this run "
        f"on {os.cpu_count()} cores); the rate per "
        "CPU second of this process does not.",
        "",
        "| scenario | controller | step [s] | sim-s per wall-s (best) | median | sim-s per CPU-s (best) | Newton it./step | |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, kind, dt, rate, med, cpu, it in rows:
        lines.append(f"| {name} | {kind} | {dt} | {rate:.1f} | {med:.1f} | {cpu:.1f} | {it:.2f} | "
                     f"{'PASS' if rate >= TARGET else 'below target'} |")
    lines.append("")
    write_text(HERE / "results_sim.md", "\n".join(lines))
    print(f"wrote {HERE / 'results_sim.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
