"""Compare two builds of the same table (e.g. before and after a builder change).

Run from the repository root::

    nice python tests/bench/compare_builds.py BEFORE.npz AFTER.npz

Prints, per build, the statuses, ``not_found`` as a share of the grid and how many optimal
points pass the optimizer's independent numeric check again
(:func:`offline.rover.primitives.check_solution` on the stored primitive); then, at the points
optimal in both, how many hold the same primitive (within 1e-4 of the variable scales), the
largest difference, and where the objective is lower or higher in the second build. The two
files must share the grid (same axes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_new_failure import compare, recheck  # noqa: E402

from offline.rover.table_verify import spec_from_table  # noqa: E402
from rtctl.table import STATUS_NAMES, load_table  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    args = ap.parse_args()
    tables = [load_table(p) for p in (args.before, args.after)]
    if any(not np.array_equal(tables[0].axes[k], tables[1].axes[k]) for k in tables[0].axis_order) \
            or tables[0].axis_order != tables[1].axis_order:
        print("the two tables have different grids", file=sys.stderr)
        return 2
    for label, path, t in zip(("before", "after"), (args.before, args.after), tables):
        st = {s: int(np.sum(t.status == i)) for i, s in enumerate(STATUS_NAMES) if np.any(t.status == i)}
        n, ok = recheck(spec_from_table(t), path)
        nf = st.get("not_found", 0)
        print(f"{label}: {path}: {st}; not_found {nf}/{t.status.size} ({100 * nf / t.status.size:.1f} %); "
              f"independent check {ok}/{n} optimal points pass")
    c = compare(args.before, args.after)
    print(f"optimal in both: {c['both']}; same primitive (1e-4 scales): {c.get('same_x')}; largest difference "
          f"{c.get('max_dx', float('nan')):.3g} scales; objective lower in 'after' at {c.get('lower')}, higher at "
          f"{c.get('higher')} (largest relative increase {c.get('max_rel_higher', float('nan')):.3g})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
