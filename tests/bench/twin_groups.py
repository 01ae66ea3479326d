"""Speed-twin agreement of built tables (issue 22/23's twin defect), no solve.

Run from the repository root::

    python tests/bench/twin_groups.py TABLE.npz [TABLE.npz ...]

Points that differ only in speed pose one NLP up to the exact speed scaling (omega times the
speed ratio, everything else unchanged; ``offline.rover.table_builder.twin_resolve``), so a table
should hold one primitive per twin group. Per table: the groups whose members are all optimal and
whose primitives, scaled to the group's first speed, differ by more than 1e-6 variable scales
(the largest difference in scales, the objectives), and the groups with mixed statuses.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from rtctl.table import load_table  # noqa: E402

AGREE = 1e-6


def twin_groups(path: str | Path) -> dict:
    """Disagreeing speed-twin groups of the table at ``path``: ``{"groups", "apart": [(point,
    largest difference in scales, objectives)], "mixed": [(point, statuses)]}``."""
    t = load_table(path)
    if "speed" not in t.axis_order:
        return {"groups": 0, "apart": [], "mixed": []}
    a = t.axis_order.index("speed")
    v = np.asarray(t.axes["speed"], dtype=float)
    lay = t.layout
    om = [lay.var("omega", w) for w in lay.wheels]
    xsc = lay.variable_scale
    apart, mixed, n = [], [], 0
    for idx in np.ndindex(*[len(t.axes[k]) for k in t.axis_order]):
        if idx[a] != 0:
            continue
        n += 1
        members = [idx[:a] + (j,) + idx[a + 1:] for j in range(len(v))]
        st = [t.status_at(m) for m in members]
        point = {k: round(float(np.degrees(t.axes[k][i])) if k in ("slope", "cross_slope", "steer_stuck") else
                          float(t.axes[k][i]), 6) for k, i in zip(t.axis_order, idx) if k != "speed"}
        if len(set(st)) > 1:
            mixed.append((point, st))
            continue
        if st[0] != "optimal":
            continue
        x0 = np.asarray(t.arrays["x"][members[0]], dtype=float)
        worst = 0.0
        for j, m in enumerate(members[1:], start=1):
            x = np.array(t.arrays["x"][m], dtype=float)
            x[om] *= v[0] / v[j]
            worst = max(worst, float(np.max(np.abs(x - x0) / xsc)))
        if worst > AGREE:
            apart.append((point, worst, [float(t.arrays["objective"][m]) for m in members]))
    return {"groups": n, "apart": apart, "mixed": mixed}


def main(argv: list[str]) -> None:
    for p in argv:
        r = twin_groups(p)
        print(f"{p}: {r['groups']} twin groups, {len(r['apart'])} apart beyond {AGREE:g} scales, "
              f"{len(r['mixed'])} with mixed statuses")
        for point, worst, objs in r["apart"]:
            print(f"  apart {point}: {worst:.3g} scales, objectives {', '.join(f'{o:.10g}' for o in objs)}")
        for point, st in r["mixed"]:
            print(f"  mixed {point}: {st}")


if __name__ == "__main__":
    main(sys.argv[1:])
