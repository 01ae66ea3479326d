"""Issue 25, allocation per tick: :meth:`rtctl.table.Table.at` gathers a cell's corner rows into a
buffer the table keeps, so a call allocates about one interpolated row (which the returned
:class:`rtctl.table.TablePoint` keeps), not ``2**d`` of them, and its answer is bit for bit the
plain formula's (``w @ flat[idx]`` on a freshly indexed copy), whatever the operating point
(inside, clamped, extrapolated over corners without a primitive, nearest feasible point)."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from rtctl.table import load_table

ROOT = Path(__file__).resolve().parents[1]
TABLES = [p for p in sorted((ROOT / "tables").glob("*.npz")) if load_table(p).feasible.any()]


def _reference_row(t, tp) -> np.ndarray:
    """The interpolated row the way ``at`` computed it before the buffer: a new fancy-indexed
    copy of the corner rows, the same weights (recomputed from the point actually used)."""
    import bisect

    base, ts = 0, []
    for i, k in enumerate(t.axis_order):
        ax = t._ax[i]
        if len(ax) == 1:
            continue
        v = tp.operating_point[k]
        j = min(max(bisect.bisect_right(ax, v) - 1, 0), len(ax) - 2)
        base += j * t._strides[i]
        ts.append((v - ax[j]) / (ax[j + 1] - ax[j]))
    w = np.array([1.0])
    for x in ts:
        w = np.array([a for b in w for a in (b * (1.0 - x), b * x)])
    idx = t._offsets + base
    feas = t._feas_flat[idx]
    if not feas.all():
        w = w * feas
        w = w / float(w.sum())
    return w @ t._flat[idx]


@pytest.mark.parametrize("path", TABLES, ids=[p.stem for p in TABLES])
def test_at_is_bit_for_bit_the_plain_gather(path):
    t = load_table(path)
    rng = np.random.default_rng(3)
    checked = 0
    for k in range(300):
        op = {}
        for a, v in t.axes.items():
            lo, hi = float(v[0]), float(v[-1])
            span = hi - lo if hi > lo else 1.0
            op[a] = float(rng.uniform(lo - 0.1 * span, hi + 0.1 * span)) if k % 5 else float(v[rng.integers(len(v))])
        tp = t.at(**op)
        if tp.status == "nearest feasible grid point":
            continue
        assert tp._row.tobytes() == _reference_row(t, tp).tobytes(), f"{t.name} at {op}"
        checked += 1
    assert checked > 100


def test_points_do_not_share_memory():
    """The buffer is only the gather: every TablePoint keeps its own row (a later call must not
    change an earlier point, which the controller keeps when a preparation fails)."""
    t = load_table(ROOT / "tables" / "nominal.npz")
    ax = {k: float(v[0]) for k, v in t.axes.items()}
    p1 = t.at(**ax)
    x1 = p1.x.copy()
    p2 = t.at(**{k: float(v[-1]) for k, v in t.axes.items()})
    assert not np.shares_memory(p1.x, p2.x)
    assert p1.x.tobytes() == x1.tobytes() and p2.x.tobytes() != x1.tobytes()


def test_at_allocates_about_one_row():
    """Transient peak of one call (tracemalloc) at most 1.5 rows plus 4 kB of small objects; the
    old gather allocated 2**d rows (16 on the shipped nominal table)."""
    t = load_table(ROOT / "tables" / "nominal.npz")
    assert len(t._offsets) >= 4
    row_bytes = t._flat.shape[1] * 8
    ops = [{k: float(v[0] + (v[-1] - v[0]) * f) for k, v in t.axes.items()} for f in (0.31, 0.52, 0.77)]
    t.at(**ops[0])  # warm (first-call caches)
    tracemalloc.start()
    try:
        peaks = []
        for op in ops:
            before = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            tp = t.at(**op)
            peaks.append(tracemalloc.get_traced_memory()[1] - before)
            del tp
    finally:
        tracemalloc.stop()
    assert max(peaks) <= 1.5 * row_bytes + 4096, (max(peaks), row_bytes, len(t._offsets))
