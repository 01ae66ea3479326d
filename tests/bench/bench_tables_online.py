"""Every cell centre of a table: the raw interpolation against the online step (issue 22).

For each table file, at the centre of every cell whose corners are all feasible: the best verified
optimum there (``table_verify.check_interpolation``: every start and a continuation from each
corner), the raw interpolated primitive's distance to it (check 3, information since issue 22),
and ``tables verify``'s check 4 (``table_verify.check_online``: rtctl's real-time iteration from
the interpolated primitive, 5 ticks at the constant point, issue 20's targets). Prints one line per
centre and writes a markdown table.

    python tests/bench/bench_tables_online.py [TABLE.npz ...] [--out results.md] [--max-cells N]

Default: the shipped tables with a cell (``tables/index.json``). CPU seconds per table are
``time.process_time`` of this process (the checks run in it; no workers).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"


def _verdict(r: dict) -> str:
    """``ok``, ``ok, another optimum (objective +x %)`` (check 4's acceptance of a converged, balanced
    KKT point not notably worse than the reference: ``table_verify.ONLINE_OTHER_OPTIMUM``) or ``FAIL``."""
    if not r["passed"]:
        return "FAIL"
    if r.get("accepted") == "other optimum":
        return f"ok, another optimum (objective {100 * r['other']['objective_above_reference']:+.3f} %)"
    return "ok"


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from offline.files import write_text
    from offline.rover.table_verify import (ONLINE_OTHER_OPTIMUM, ONLINE_TARGETS, ONLINE_TICK1_TARGETS, ONLINE_TICKS, check_interpolation,
                                            check_online, feasible_cells, interpolation_tolerance, spec_from_table)
    from rtctl.table import load_table

    a = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a.add_argument("tables", nargs="*", help="table files (default: the shipped ones)")
    a.add_argument("--out", default=str(ROOT / "tests" / "bench" / "results_tables_online_i22.md"))
    a.add_argument("--max-cells", type=int, default=0, help="at most N cells per table, drawn with seed 0 (0: all)")
    args = a.parse_args()
    files = [Path(p) for p in args.tables] or [ROOT / "tables" / f"{n}.npz" for n in
                                               sorted(json.loads((ROOT / "tables" / "index.json").read_text())["tables"])]
    deg = 180.0 / np.pi
    lines = ["# Cell centres: raw interpolation against the online step (issue 22)", "",
             f"`python tests/bench/bench_tables_online.py {' '.join(args.tables)}`"
             + (f" `--max-cells {args.max_cells}`" if args.max_cells else "")
             + f"; commit {_commit()}, {time.strftime('%Y-%m-%d', time.gmtime())}.", "",
             f"Every cell whose corners are all feasible (unless `--max-cells`). Raw: the interpolated primitive's largest "
             f"error per variable scale against the best verified optimum at the centre (check 3; the former gate "
             f"was the table's interpolation tolerance, 0.5 unless refined). Online: check 4, rtctl's real-time "
             f"iteration from the interpolated primitive, {ONLINE_TICKS} ticks at the constant point; gates tick 1 "
             f"balance {ONLINE_TICK1_TARGETS}, tick {ONLINE_TICKS} {ONLINE_TARGETS}, or another local optimum "
             f"{ONLINE_OTHER_OPTIMUM} (converged, balanced, objective at most that much above).", ""]
    head = len(lines)
    summary = ["| table | cells | raw within its tolerance | online step passed | CPU s |", "|---|---|---|---|---|"]
    for path in files:
        t = load_table(path)
        cells = feasible_cells(t)
        if not cells:
            print(f"{t.name}: no cell with all corners feasible")
            continue
        if args.max_cells and len(cells) > args.max_cells:
            rng = np.random.default_rng(0)
            cells = [cells[int(i)] for i in sorted(rng.choice(len(cells), args.max_cells, replace=False))]
        spec = spec_from_table(t)
        tol = interpolation_tolerance(t)
        c0 = time.process_time()
        rows = [f"## {t.name} ({path.name}, grid {'x'.join(str(n) for n in t.shape)})", "",
                "| centre (deg, cm/s, fraction) | raw x error | optima found | tick-1 force / moment / load | x error "
                "by tick (scales) | tick-5 speeds / steering / objective | online |", "|---|---|---|---|---|---|---|"]
        n_raw = n_on = 0
        for c in cells:
            refs: list = []
            ri = check_interpolation(t, spec, [c], None, refs)
            if not refs:
                rows.append(f"| {c} | no primitive at the centre | | | | | FAIL |")
                print(t.name, c, "no primitive at the centre", flush=True)
                continue
            ro = check_online(t, spec, refs)
            m, r = ri["per_midpoint"][0], ro["per_centre"][0]
            op = {k: (v * deg if k in ("slope", "cross_slope", "steer_stuck") else v * 100 if k == "speed" else v)
                  for k, v in m["midpoint"].items()}
            raw_ok = m["x_error_per_scale"] <= tol
            n_raw += raw_ok
            n_on += bool(r["passed"])
            b = r.get("tick1_balance", {})
            last = r.get("last", {})
            errs = ", ".join(f"{e:.2g}" for e in r.get("x_error_per_scale_by_tick", []))
            rows.append(f"| {', '.join(f'{k} {v:.4g}' for k, v in op.items())} | {m['x_error_per_scale']:.2f} | "
                        f"{m['optima']} | "
                        + (f"{b['force_N']:.2g} / {b['moment_Nm']:.2g} / {b['load_N']:.2g}" if b else "-")
                        + f" | {errs} | "
                        + (f"{last['wheel_speed_rel']:.2%} / {last['steer_deg']:.3g} deg / {last['objective_rel']:.2%}"
                           if last else r.get("why", "-"))
                        + f" | {_verdict(r)} |")
            print(t.name, rows[-1], flush=True)
        cpu = time.process_time() - c0
        summary.append(f"| {t.name} | {len(cells)} | {n_raw} | {n_on} | {cpu:.0f} |")
        lines += rows + [""]
    out = Path(args.out)
    write_text(out, "\n".join(lines[:head] + summary + [""] + lines[head:]) + "\n")
    print("\n".join(summary))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
