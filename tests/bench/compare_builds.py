"""Compare two builds of the same table (e.g. before and after a builder change).

Run from the repository root::

    nice python tests/bench/compare_builds.py BEFORE.npz AFTER.npz

Prints, per build, the statuses, ``not_found`` as a share of the grid and how many optimal
points pass the optimizer's independent numeric check again
(:func:`offline.rover.primitives.check_solution` on the stored primitive); then, at the points
optimal in both, how many hold the same primitive (within 1e-4 of the variable scales), the
largest difference, and where the objective is lower or higher in the second build. The two
files must share the grid (same axes).

Array by array (no solve; also two folders of tables, compared by file name)::

    nice python tests/bench/compare_builds.py --arrays BEFORE AFTER

prints per table whether the files are byte-identical and the content hashes equal; per array
the largest absolute difference and that difference relative to the array's largest magnitude
in ``BEFORE`` (NaN at the same places counts as equal; a NaN on one side only is listed as a
count), arrays present on one side only; the points whose status differs (``before -> after``
with counts); and the header entries that differ (besides the content hash).
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
from rtctl.table import STATUS_NAMES, _read, load_table  # noqa: E402


def array_diffs(before: Path, after: Path) -> dict:
    """Array-by-array differences of two table files (no hash check, no solve).

    Returns
    -------
    dict
        ``same_bytes``; ``arrays``: name -> (max abs difference, relative to the largest
        magnitude in ``before``, NaN-pattern mismatches) for arrays of equal shape, or a note;
        ``only_before`` / ``only_after``; ``status``: {"before -> after": count} where they differ;
        ``header``: top-level header keys whose values differ.
    """
    hb, ab = _read(before)
    ha, aa = _read(after)
    out: dict = {"same_bytes": before.read_bytes() == after.read_bytes(), "arrays": {},
                 "only_before": sorted(set(ab) - set(aa)), "only_after": sorted(set(aa) - set(ab))}
    for k in sorted(set(ab) & set(aa)):
        a, b = np.asarray(ab[k]), np.asarray(aa[k])
        if a.shape != b.shape:
            out["arrays"][k] = f"shape {a.shape} vs {b.shape}"
            continue
        if a.dtype.kind not in "fiub":
            out["arrays"][k] = "equal" if np.array_equal(a, b) else "differs (non-numeric)"
            continue
        a64, b64 = a.astype(float), b.astype(float)
        na, nb = np.isnan(a64), np.isnan(b64)
        both = ~na & ~nb
        x, y = a64[both], b64[both]
        with np.errstate(invalid="ignore"):
            d = np.where(x == y, 0.0, np.abs(x - y))  # equal infinities: no difference
        mx = float(d.max()) if d.size else 0.0
        fin = np.abs(x[np.isfinite(x)])
        ref = float(fin.max()) if fin.size else 0.0
        out["arrays"][k] = (mx, mx / ref if ref > 0 else (0.0 if mx == 0 else float("inf")), int(np.sum(na != nb)))
    if "status" in ab and "status" in aa and ab["status"].shape == aa["status"].shape:
        trans: dict[str, int] = {}
        for s0, s1 in zip(ab["status"].ravel(), aa["status"].ravel()):
            if s0 != s1:
                key = f"{STATUS_NAMES[int(s0)]} -> {STATUS_NAMES[int(s1)]}"
                trans[key] = trans.get(key, 0) + 1
        out["status"] = trans
    out["header"] = sorted(k for k in set(hb) | set(ha) if k != "content_hash" and hb.get(k) != ha.get(k))
    return out


def print_array_diffs(before: Path, after: Path) -> float:
    """Print :func:`array_diffs` of one pair; the largest relative difference over its arrays."""
    r = array_diffs(before, after)
    worst = 0.0
    print(f"== {after.name}: byte-identical {r['same_bytes']}; status changes {r.get('status') or 'none'}; "
          f"header keys differing {r['header'] or 'none'}")
    if r["only_before"] or r["only_after"]:
        print(f"   arrays only before {r['only_before']}, only after {r['only_after']}")
    for k, v in r["arrays"].items():
        if isinstance(v, str):
            print(f"   {k}: {v}")
            continue
        mx, rel, nan = v
        worst = max(worst, rel)
        if mx > 0 or nan:
            print(f"   {k}: max abs {mx:.3g}, relative {rel:.3g}" + (f", NaN on one side at {nan}" if nan else ""))
    return worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--arrays", action="store_true", help="array-by-array differences only (files or folders)")
    args = ap.parse_args()
    if args.arrays:
        pairs = ([(args.before / p.name, p) for p in sorted(args.after.glob("*.npz")) if (args.before / p.name).is_file()]
                 if args.after.is_dir() else [(args.before, args.after)])
        if args.after.is_dir():
            lone = sorted({p.name for p in args.before.glob("*.npz")} ^ {p.name for p in args.after.glob("*.npz")})
            if lone:
                print(f"in one folder only: {lone}")
        worst = max((print_array_diffs(b, a) for b, a in pairs), default=0.0)
        print(f"largest relative difference over every array of {len(pairs)} table(s): {worst:.3g}")
        return 0
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
