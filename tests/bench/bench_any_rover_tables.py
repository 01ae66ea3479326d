"""Lookup tables of rovers from files: build time and ``tables verify`` (issue 23).

Run on demand from the repository root::

    nice python tests/bench/bench_any_rover_tables.py [--out DIR]

Builds, with ``offnominal tables build`` (one process, the default continuation schedule), small
tables of the MER-class six-wheel rover (nominal; right-front wheel locked, driving backward,
the direction the optimizer finds feasible) and of the four-wheel skid-steer rover (front-right
wheel unpowered; on flat ground and up to 5 deg at 2 and 4 cm/s, and on one branch of its
primitive: above the jump between 0 and 2.5 deg slope and below the rear-left wheel's motor speed
limit), then runs ``offnominal tables verify`` (its three checks, the informational
ladder included) on each. Replaces the section "Tables for rover files" at the end of
``tests/bench/results_any_rover.md`` (``bench_any_rover.py`` keeps it) with one row per table:
grid, statuses, build wall and CPU seconds, verify verdicts and time, size, the commands (a
"### Notes" subsection below the table, written by hand, is kept).
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from offline.files import write_text

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
OUT = HERE / "results_any_rover.md"
SECTION = "## Tables for rover files"
NOTES = "### Notes"

CASES: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("mer_nominal", "slope=0,5,10;cross_slope=0;speed=2,4", ()),
    ("mer_rf_locked_backward", "slope=0,2.5,5;cross_slope=0;speed=1,2", ()),
    ("skid_fr_unpowered", "slope=0,2.5,5;cross_slope=0;speed=2,4", ()),
    ("skid_fr_unpowered", "slope=2.5,3.75,5;cross_slope=0;speed=1.5,2", ()),
)
"""(scenario file stem in ``offline/scenarios/rovers``, ``--grid``, further build options)."""


def _cli() -> list[str]:
    return [sys.executable, "-c", "import sys; from offline.cli import main; sys.exit(main(sys.argv[1:]))"]


def _run(args: list[str]) -> tuple[subprocess.CompletedProcess[str], float, float]:
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([*_cli(), *args], cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return p, wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    except OSError:
        return "?"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="folder for the tables (default: a temporary folder)")
    args = ap.parse_args(argv)
    tmp = tempfile.TemporaryDirectory() if args.out is None else None
    out = Path(args.out) if args.out else Path(tmp.name)  # type: ignore[union-attr]
    load0 = os.getloadavg()
    rows = []
    for k, (stem, grid, extra) in enumerate(CASES):
        scen = f"offline/scenarios/rovers/{stem}.toml"
        dest = out / str(k)
        build = ["tables", "build", scen, "--grid", grid, *extra, "--out", str(dest), "--no-index", "--quiet"]
        p, wall_b, cpu_b = _run(build)
        print(p.stdout + p.stderr, end="")
        m = re.search(r"(\d+) points \(([^)]*)\), (.*?); feasible", p.stdout)
        statuses = m.group(3) if m else f"build failed (exit {p.returncode})"
        npz = dest / f"{stem}.npz"
        verdicts, wall_v, cpu_v = "-", 0.0, 0.0
        if p.returncode == 0 and npz.is_file():
            v, wall_v, cpu_v = _run(["tables", "verify", str(npz)])
            mv = re.search(r"verdicts: (.*)", v.stdout)
            verdicts = (mv.group(1) if mv else "?") + ("; PASSED" if v.returncode == 0 else "; FAILED")
            print(v.stdout.splitlines()[-2:] if v.stdout else v.stderr)
        size = f"{npz.stat().st_size / 1e6:.2f}" if npz.is_file() else "-"
        opts = " ".join(extra) or "-"
        rows.append(f"| {stem} | `{grid}` | {opts} | {statuses} | {wall_b:.0f} / {cpu_b:.0f} | {verdicts} | "
                    f"{wall_v:.0f} / {cpu_v:.0f} | {size} |")
    load1 = os.getloadavg()
    when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    section = "\n".join([
        SECTION,
        "",
        f"Made by `nice python tests/bench/bench_any_rover_tables.py` at commit {_commit()}, {when}, Python "
        f"{platform.python_version()}, {platform.machine()}; load average {load0[0]:.1f} at the start, {load1[0]:.1f} at "
        "the end (2 cores shared with other builds: wall time is not a speed measure here, CPU seconds are closer to one).",
        "",
        "Each table: `offnominal tables build offline/scenarios/rovers/<scenario>.toml --grid \"<grid>\" --out DIR "
        "--no-index` (one process, continuation schedule), then `offnominal tables verify DIR/<scenario>.npz` (three "
        "checks: Jacobians, linearisation at the stored trust radius, interpolation at cell midpoints; the ladder "
        "included). Grid values in display units (deg, deg, cm/s). The header of each table carries the wheel set "
        "(`wheel_set`: names, count, steerable, driven, the rover file's name and sha256) and the NLP layout.",
        "",
        "| scenario | grid | build options | statuses | build wall / CPU [s] | verify | verify wall / CPU [s] | size [MB] |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ])
    text = OUT.read_text() if OUT.is_file() else "# Primitives of rovers from files (issue 23)\n\n"
    head, _, old = text.partition(SECTION)
    notes = old.partition(NOTES)[1] + old.partition(NOTES)[2]  # hand-written notes below the table: kept
    write_text(OUT, head.rstrip("\n") + "\n\n" + section + ("\n" + notes if notes else ""))
    print(f"wrote {OUT}")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
