"""rtctl.table: file format, hash/schema/rover checks, determinism and interpolation (numpy only).

The tables here are written by :func:`rtctl.table.table_bytes` from fields that are exact
multilinear functions of the axes, so multilinear interpolation must reproduce them to
rounding; infeasible corners and clamping are checked against their documented rules. A
table built by the real NLP is tested in ``test_tables_build.py``.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from rtctl.layout import NlpLayout
from rtctl.table import (POINT_FIELDS, SCHEMA, SCHEMA_VERSION, STATUS_NAMES, TableError, field_shapes, load_index,
                         load_table, table_bytes)

SCALES = {"omega": 0.5, "beta": 0.3, "W": 8.0, "h": 0.015, "h0": 0.015}
CSCALES = {"force": 34.3, "moment": 11.0, "load": 8.6, "torque": 0.5}


def _table(tmp_path, infeasible=(), rover="mini_rover", name="t"):
    lay = NlpLayout.build(SCALES, CSCALES)
    axes = {"slope": np.radians([0.0, 10.0, 20.0]), "speed": np.array([0.02, 0.03]),
            "steer_stuck": np.radians([-60.0, 0.0, 30.0, 60.0])}
    G = tuple(len(v) for v in axes.values())
    S, V, B = np.meshgrid(*axes.values(), indexing="ij")
    shapes = field_shapes(lay.nx, lay.np_, lay.ng)
    rng = np.random.default_rng(0)
    arrays = {}
    for k, shp in shapes.items():  # each entry: c0 + c1 slope + c2 speed + c3 steer + c4 slope*speed
        c = rng.standard_normal((5,) + shp)
        arrays[k] = (c[0] + np.multiply.outer(S, c[1]) + np.multiply.outer(V, c[2]) + np.multiply.outer(B, c[3])
                     + np.multiply.outer(S * V, c[4]))
    status = np.zeros(G, dtype=np.int8)
    for idx in infeasible:
        status[idx] = STATUS_NAMES.index("infeasible")
        for k in shapes:
            arrays[k][idx] = np.nan
    arrays["status"] = status
    arrays["active_x"] = np.zeros(G + (lay.nx,), dtype=np.int8)
    arrays["active_g"] = np.zeros(G + (lay.ng,), dtype=np.int8)
    header = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "name": name,
              "rover": {"name": rover, "weight": 34.3, "rocker_length": 0.32, "pivot_height": 0.112, "track_width": 0.331},
              "axis_order": list(axes), "axes": {k: {"values": v.tolist(), "unit": "SI"} for k, v in axes.items()},
              "layout": json.loads(lay.to_json()), "trust_radius": {"speed": 0.005},
              "evidence": {str(np.ravel_multi_index(i, G)): {"closest": "test"} for i in infeasible}}
    p = tmp_path / f"{name}.npz"
    p.write_bytes(table_bytes(header, arrays))
    return p, axes, arrays, header


def test_interpolation_reproduces_multilinear_fields_exactly(tmp_path):
    p, axes, arrays, _ = _table(tmp_path)
    t = load_table(p, expect_rover="mini_rover")
    lay = t.layout
    rng = np.random.default_rng(1)
    shapes = field_shapes(lay.nx, lay.np_, lay.ng)
    for _ in range(20):
        op = {k: rng.uniform(v[0], v[-1]) for k, v in axes.items()}
        tp = t.at(**op)
        assert tp.feasible and not tp.clamped and not tp.extrapolated
        for k in ("x", "jac_g_x", "hess_lag", "hess_lag_xp", "dx_dp", "wrench_jac", "controllers"):
            got = getattr(tp, k) if k != "controllers" else np.stack(list(tp.controllers.values()))
            # the fields are multilinear in (slope, speed, steer): inside a cell they equal the
            # weighted sum of the corners, evaluated here independently of the table's code
            i = [min(np.searchsorted(v, op[a], side="right") - 1, len(v) - 2) for a, v in axes.items()]
            ts = [(op[a] - v[j]) / (v[j + 1] - v[j]) for (a, v), j in zip(axes.items(), i)]
            exp = 0.0
            for b in range(8):
                w, idx = 1.0, []
                for d in range(3):
                    bit = (b >> (2 - d)) & 1
                    w *= ts[d] if bit else 1 - ts[d]
                    idx.append(i[d] + bit)
                exp = exp + w * arrays[k][tuple(idx)]
            np.testing.assert_allclose(got, exp, rtol=1e-12, atol=1e-12)
            assert got.shape == shapes[k]


def test_exact_at_grid_points_and_fields_are_physical_arrays(tmp_path):
    p, axes, arrays, _ = _table(tmp_path)
    t = load_table(p)
    tp = t.at(slope=axes["slope"][1], speed=axes["speed"][0], steer_stuck=axes["steer_stuck"][2])
    np.testing.assert_array_equal(tp.x, arrays["x"][1, 0, 2])
    np.testing.assert_array_equal(tp.wrench, arrays["wrench"][1, 0, 2])
    np.testing.assert_array_equal(tp.trust_radius, arrays["trust_radius"][1, 0, 2])
    assert t.trust_radius[t.layout.index("speed")] == 0.005
    assert t.trust_radius[t.layout.index("slope")] == 0.0  # not verified: no step allowed
    assert set(tp.active) == {"x_lower", "x_upper", "g_lower", "g_upper"}


def test_clamped_outside_axes_and_never_nan(tmp_path):
    p, axes, arrays, _ = _table(tmp_path)
    t = load_table(p)
    tp = t.at(slope=math.radians(40.0), speed=0.01, steer_stuck=math.radians(80.0))
    assert tp.clamped and tp.feasible
    np.testing.assert_array_equal(tp.x, arrays["x"][-1, 0, -1])
    assert tp.operating_point["slope"] == axes["slope"][-1]


def test_infeasible_corners_get_zero_weight_and_nearest_fallback(tmp_path):
    bad = [(1, 0, 1), (1, 1, 1), (2, 0, 1), (2, 1, 1), (1, 0, 2), (1, 1, 2), (2, 0, 2), (2, 1, 2)]
    p, axes, arrays, _ = _table(tmp_path, infeasible=bad[:2])
    t = load_table(p)
    assert not t.feasible[1, 0, 1] and t.evidence
    tp = t.at(slope=axes["slope"][1] * 0.5, speed=0.025, steer_stuck=axes["steer_stuck"][1] * 0.5)
    assert tp.extrapolated and not tp.feasible
    for k in POINT_FIELDS:
        assert np.all(np.isfinite(getattr(tp, k) if k != "controllers" else tp._f(k)))
    # a cell with no feasible corner: nearest feasible grid point
    p2, *_ = _table(tmp_path, infeasible=bad, name="t2")
    t2 = load_table(p2)
    tp2 = t2.at(slope=math.radians(15.0), speed=0.025, steer_stuck=math.radians(15.0))
    assert tp2.status == "nearest feasible grid point" and tp2.clamped and not tp2.feasible
    assert np.all(np.isfinite(tp2.x))
    assert t2.feasible[tuple(int(np.searchsorted(axes[k], tp2.operating_point[k])) for k in axes)]


def test_bad_operating_points_are_refused(tmp_path):
    t = load_table(_table(tmp_path)[0])
    with pytest.raises(TableError, match="unknown axis"):
        t.at(slope=0.0, speed=0.03, steer_stuck=0.0, cross_slope=0.0)
    with pytest.raises(TableError, match="lacks axis 'steer_stuck'"):
        t.at(slope=0.0, speed=0.03)
    with pytest.raises(TableError, match="not finite"):
        t.at(slope=float("nan"), speed=0.03, steer_stuck=0.0)


def test_same_content_same_bytes(tmp_path):
    a = _table(tmp_path, name="a")[0].read_bytes()
    b = _table(tmp_path, name="a")[0].read_bytes()
    assert a == b
    with np.load(tmp_path / "a.npz", allow_pickle=False) as z:  # plain numpy can read it
        assert "header" in z.files and z["x"].shape[:3] == (3, 2, 4)


def test_corrupted_file_is_refused(tmp_path):
    p = _table(tmp_path)[0]
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0x01  # a flipped bit: the zip's CRC or the hash catches it
    bad = tmp_path / "bad.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(TableError, match="corrupted"):
        load_table(bad)
    with np.load(p, allow_pickle=False) as z:  # an edited value, re-zipped consistently
        members = {k: z[k] for k in z.files}
    members["x"] = members["x"].copy()
    members["x"][0, 0, 0, 0] += 1e-9
    edited = tmp_path / "edited.npz"
    np.savez(edited, **members)
    with pytest.raises(TableError, match="content hash mismatch"):
        load_table(edited)
    trunc = tmp_path / "trunc.npz"
    trunc.write_bytes(p.read_bytes()[:1000])
    with pytest.raises(TableError, match="not a readable table file|corrupted"):
        load_table(trunc)
    with pytest.raises(TableError, match="no such table file"):
        load_table(tmp_path / "missing.npz")


def test_other_rover_and_schema_are_refused(tmp_path):
    p = _table(tmp_path, rover="big_rover")[0]
    with pytest.raises(TableError, match="built for rover 'big_rover', not 'mini_rover'"):
        load_table(p, expect_rover="mini_rover")
    with pytest.raises(TableError, match="another rover.*weight"):
        load_table(p, expect_rover={"name": "big_rover", "weight": 100.0})
    _, axes, arrays, header = _table(tmp_path, name="s")
    header = dict(header, schema_version=SCHEMA_VERSION + 1)
    arrays = {k: v for k, v in arrays.items()}
    q = tmp_path / "future.npz"
    q.write_bytes(table_bytes(header, arrays))
    with pytest.raises(TableError, match=f"table schema {SCHEMA_VERSION + 1}, expected {SCHEMA_VERSION}"):
        load_table(q)


def test_schema_1_table_is_refused_with_the_rebuild_command(tmp_path):
    """A version-1 file (no hess_lag_xp, no trust_unverified) is refused before its arrays are
    read, and the message gives the exact build command from its header."""
    _, axes, arrays, header = _table(tmp_path, name="v1")
    header = dict(header, schema_version=1, sources={"scenario_file": {"name": "nominal.toml", "sha256": "0" * 64}})
    header["axes"]["slope"]["display_factor"] = math.pi / 180
    old = {k: v for k, v in arrays.items() if k not in ("hess_lag_xp", "trust_unverified")}
    q = tmp_path / "v1.npz"
    q.write_bytes(table_bytes(header, old))
    with pytest.raises(TableError, match="schema 1, expected 2: rebuild with `offnominal tables build nominal.toml "
                                         '--grid "slope=0,10,20;speed=0.02,0.03;steer_stuck=.*" --out DIR`'):
        load_table(q)


def test_trust_verified_flags_a_corner_with_the_fallback_radius(tmp_path):
    p, axes, arrays, header = _table(tmp_path, name="tv")
    arrays = dict(arrays)
    tu = np.zeros_like(arrays["trust_unverified"])
    tu[1, 0, 2, 1] = 1.0  # slope radius of one grid point is the fallback
    arrays["trust_unverified"] = tu
    q = tmp_path / "tv2.npz"
    q.write_bytes(table_bytes({k: v for k, v in header.items() if k != "content_hash"}, arrays))
    t = load_table(q)
    s = t.layout.index("slope")
    at = dict(slope=axes["slope"][1], speed=axes["speed"][0], steer_stuck=axes["steer_stuck"][2])
    assert not t.at(**at).trust_verified[s] and t.at(**at).trust_verified[t.layout.index("speed")]
    near = dict(at, slope=0.5 * (axes["slope"][1] + axes["slope"][2]))  # a cell with that corner
    assert not t.at(**near).trust_verified[s]
    far = dict(at, steer_stuck=axes["steer_stuck"][0])  # no contributing corner is flagged
    assert t.at(**far).trust_verified.all()


def test_index_round_trip_and_hash_check(tmp_path):
    p, *_ = _table(tmp_path)
    t = load_table(p)
    idx = {"schema": SCHEMA + " index", "schema_version": SCHEMA_VERSION, "tables": {"t": {
        "file": p.name, "content_hash": t.header["content_hash"], "sha256": "x", "axes": {}, "family": None,
        "feasible_fraction": 1.0, "feasible_ranges": {}}}}
    ip = tmp_path / "index.json"
    ip.write_text(json.dumps(idx))
    infos = load_index(ip)
    assert infos["t"].load().name == "t"
    idx["tables"]["t"]["content_hash"] = "0" * 64
    ip.write_text(json.dumps(idx))
    with pytest.raises(TableError, match="differs from the expected"):
        load_index(ip)["t"].load()
    ip.write_text("{")
    with pytest.raises(TableError, match="not valid JSON"):
        load_index(ip)


def test_rtctl_table_imports_numpy_only():
    code = ("import sys, rtctl.table; bad = [m for m in sys.modules if m.split('.')[0] in "
            "('casadi', 'offline', 'scipy', 'osqp')]; print(bad); sys.exit(1 if bad else 0)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
