"""A rebuild against the table it replaces (issue 22/23's two builder defects,
``tests/bench/results_tables.md``): one primitive per speed-twin group, also among tied optima
and on refined grids; a search's verdict re-checked from the tables with the same failures at
the very point (the former build itself, a sibling soil); the former build's optimum offered to
the neighbour pass.

Small grids (1-6 points) on the real NLP; the tied optima are the nominal rover's two steering
branches at 20 deg slope, 0 cross slope (toe-in FR < 0 < FL, the shipped one, and toe-out: the
objective equal to 1e-10, the primitives about 3 scales apart).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from offline.rover import table_builder as TB
from offline.rover.table_builder import BuildOptions, build_table, table_spec
from rtctl.table import load_table

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "tables" / "scenarios"
FAST = BuildOptions(trust_steps=(0.0625, 0.125), trust_search=(0.0625, 0.25, 1.0))
GRID = "slope=20;cross_slope=0;speed=2,4"


def _index(folder: Path, names: list[str]) -> Path:
    """An index holding only the shipped tables ``names`` (the files linked, not copied)."""
    d = json.loads((ROOT / "tables" / "index.json").read_text())
    folder.mkdir(parents=True, exist_ok=True)
    d["tables"] = {k: v for k, v in d["tables"].items() if k in names}
    for v in d["tables"].values():
        (folder / v["file"]).symlink_to(ROOT / "tables" / v["file"])
    (folder / "index.json").write_text(json.dumps(d))
    return folder / "index.json"


def _shipped(spec, f):
    """The builder's record of the shipped nominal table's primitive at ``spec``'s point ``f``."""
    t = load_table(ROOT / "tables" / "nominal.npz")
    op = spec.grid.point(f)
    i = tuple(int(np.argmin(np.abs(np.asarray(t.axes[k]) - op[k]))) for k in t.axis_order)
    xsc, csc = t.layout.variable_scale, t.layout.constraint_scale
    d = {k: t.arrays[k][i] for k in ("x", "dx_dp", "objective")}
    return {"flat": f, "status": "optimal", "x_scaled": t.arrays["x"][i] / xsc, "lam_x": t.arrays["lam_x"][i] * xsc,
            "lam_g": t.arrays["lam_g"][i] * csc, "data": d}


def _toe_out(spec, f):
    """The other member of the tie at ``spec``'s point ``f``: IPOPT from the shipped primitive with the
    front steering angles swapped (verified by the independent check)."""
    from offline.rover.primitives import check_solution

    rec = _shipped(spec, f)
    sc = TB.scenario_at(spec.scenario, spec.family, spec.grid.point(f))
    pb = TB._problem(sc, spec.solver)
    ib = [pb.layout.var("beta", w) for w in pb.layout.wheels]
    x0 = np.array(rec["x_scaled"])
    x0[ib[:2]] = x0[ib[1::-1]]
    r = pb.solve(pb.bounds(sc), x0)
    assert r["success"] and check_solution(pb, sc, r["x"])[1]
    x = np.asarray(r["x"], dtype=float)
    return {"flat": f, "status": "optimal", "x_scaled": x, "lam_x": np.asarray(r["lam_x"]), "lam_g": np.asarray(r["lam_g"]),
            "data": {"x": x * pb.layout.variable_scale, "objective": float(r["f"])}}


@pytest.fixture(scope="module")
def tie():
    spec = table_spec(SCEN / "nominal.toml", grid=GRID, build=FAST)
    lay = TB._problem(spec.scenario, spec.solver).layout
    ib = [lay.var("beta", w) for w in lay.wheels]
    return spec, ib, {f: _shipped(spec, f) for f in (0, 1)}, {f: _toe_out(spec, f) for f in (0, 1)}


def _apart(spec, recs):
    """Largest difference of the two speeds' primitives, scaled to the first speed (variable scales)."""
    x1 = TB.scaled_to_speed(spec, recs[1]["x_scaled"], 0.04, 0.02) if hasattr(TB, "scaled_to_speed") else None
    if x1 is None:  # the former code has no helper: the same exact scaling by hand
        lay = TB._problem(spec.scenario, spec.solver).layout
        x1 = np.array(recs[1]["x_scaled"])
        x1[[lay.var("omega", w) for w in lay.wheels]] *= 0.5
    return float(np.max(np.abs(x1 - np.asarray(recs[0]["x_scaled"]))))


def test_twin_pass_carries_the_tie_break_to_a_tied_member(tie, tmp_path):
    """Two speeds holding the two members of a tie (objective equal to 1e-10): the twin pass gives
    both the one the neighbour pass's tie-break prefers (lower steering angles: toe-in), whichever
    speed holds it. The former pass skipped tied members (and its tie-break was the lower speed)."""
    spec, ib, shipped, toe_out = tie
    assert abs(shipped[0]["data"]["objective"] - toe_out[0]["data"]["objective"]) < 1e-8
    twin_of = {f: TB.speed_twin(spec.grid, f) for f in range(2)}
    for n, recs in enumerate(({0: shipped[0], 1: toe_out[1]}, {0: toe_out[0], 1: shipped[1]})):
        recs = dict(recs)
        assert _apart(spec, recs) > 1.0
        assert TB._twin_pass(spec, recs, twin_of, TB._Checkpoint(tmp_path / f".t{n}", spec.key()), None, "twin") == 1
        assert _apart(spec, recs) < 1e-6
        assert recs[0]["x_scaled"][ib[0]] < 0 < recs[0]["x_scaled"][ib[1]]  # toe-in at both speeds
        assert recs[1 - n]["speed_twin_of"] == n


def test_neighbour_pass_takes_the_former_tables_optimum(tie, tmp_path):
    """A rebuild whose point holds the toe-out member of the tie, with no neighbour to start from:
    the former table of the same name (here the shipped nominal) offers its optimum at the point to
    the neighbour pass, which takes it by its order (equal objective, lower steering angles; a
    strictly lower objective likewise) after the independent check, and the twin pass carries it
    to the other speed."""
    from offline.rover import table_continuation as TC

    spec, ib, shipped, toe_out = tie
    spec = replace(spec, build=replace(spec.build, seed_index=str(_index(tmp_path / "idx", ["nominal"]))))
    former = TC.former_table(spec, spec.build.seed_index)
    assert former is not None and Path(former).name == "nominal.npz"
    recs = {0: dict(toe_out[0]), 1: dict(toe_out[1])}
    for f in recs:  # as the builder's records: with the sensitivity the carried start needs
        sc = TB.scenario_at(spec.scenario, spec.family, spec.grid.point(f))
        recs[f]["data"] = TB.point_data(spec, sc, recs[f]["x_scaled"], recs[f]["lam_x"], recs[f]["lam_g"])
    twin_of = {f: TB.speed_twin(spec.grid, f) for f in range(2)}
    bar = type("Bar", (), {"set_description": lambda self, s: None})()
    assert TB._polish(spec, recs, TB._Checkpoint(tmp_path / ".p", spec.key()), None, bar, twin_of, former) == 2
    assert recs[0]["continued_from"].startswith("former table nominal@") and "polished_from" not in recs[0]
    assert recs[1]["speed_twin_of"] == 0 and _apart(spec, recs) < 1e-6
    assert recs[0]["x_scaled"][ib[0]] < 0 < recs[0]["x_scaled"][ib[1]]
    # without the former table the point has no start: nothing changes
    recs2 = {0: dict(toe_out[0]), 1: dict(toe_out[1])}
    assert TB._polish(spec, recs2, TB._Checkpoint(tmp_path / ".q", spec.key()), None, bar, twin_of) == 0


def test_refined_grid_ends_with_one_primitive_per_twin_group(tmp_path, monkeypatch):
    """refine_grid solves each new point on its own; here (scripted) the new 4 cm/s point of the
    inserted slope 17.5 deg starts on the other steering branch and lands on the other member of
    the tie. The twin pass after the refinement gives the group one primitive again (the former
    build kept both: 1-3 scales apart)."""
    from offline.rover import table_refine as TR
    from offline.rover.table_refine import RefineOptions

    real = TR._point_task

    def flipped(spec, op, x0):
        if x0 is not None and abs(op["speed"] - 0.04) < 1e-12:
            lay = TB._problem(spec.scenario, spec.solver).layout
            ib = [lay.var("beta", w) for w in lay.wheels]
            x0 = np.array(x0)
            x0[ib[:2]] = x0[ib[1::-1]]
        return real(spec, op, x0)

    monkeypatch.setattr(TR, "_point_task", flipped)
    spec = table_spec(SCEN / "nominal.toml", grid="slope=15,20;cross_slope=0;speed=2,4",
                      build=replace(FAST, seed_index=str(_index(tmp_path / "idx", ["nominal"]))),
                      refine=RefineOptions(tol=1e-3, max_points=6, rounds=1))
    spec = replace(spec, name="nominal_twins")  # the shipped nominal seeds it (not its former build)
    path, summary = build_table(spec, tmp_path / "out", jobs=1, progress=False)
    t = load_table(path)
    assert [round(float(np.degrees(v)), 6) for v in t.axes["slope"]] == [15.0, 17.5, 20.0]
    assert summary["statuses"] == {"optimal": 6}
    lay = t.layout
    om = [lay.var("omega", w) for w in lay.wheels]
    for s in range(3):
        x0, x1 = np.array(t.arrays["x"][s, 0, 0]), np.array(t.arrays["x"][s, 0, 1])
        x1[om] *= 0.5
        assert float(np.max(np.abs(x1 - x0) / lay.variable_scale)) < 1e-6, s
    assert t.header["speed_twins"].get("3") == 2  # slope 17.5 deg, 4 cm/s: carried from 2 cm/s


def test_a_searchs_verdict_is_re_checked_from_the_former_build_at_the_point(tmp_path):
    """rr_steer_stuck at 0 deg slope, RR stuck at +45 deg: the search from the automatic start
    calls it infeasible (issue 22/23's from-scratch rebuild, both speeds), while the shipped table's
    primitive there is an optimum of today's NLP. With an index holding only that table (the
    former build of the same name; no seed table) the rebuild re-solves the verdict from it."""
    from offline.rover import table_continuation as TC

    idx = _index(tmp_path / "idx", ["rr_steer_stuck"])
    spec = table_spec(SCEN / "rr_steer_stuck.toml", grid="slope=0;cross_slope=0;speed=2;steer_stuck=45",
                      build=replace(FAST, seed_index=str(idx)))
    assert TC.seed_tables(spec, idx) == () and TC.family_seed_tables(spec, idx) == ()  # never its own former build
    path, summary = build_table(spec, tmp_path / "out", jobs=1, progress=False)
    t = load_table(path)
    assert summary["statuses"] == {"optimal": 1}
    assert t.header["continuation"]["started_from"]["0"].startswith("table rr_steer_stuck@")
    assert [d["name"] for d in t.header["continuation"]["recheck_tables"]] == ["rr_steer_stuck"]
    shipped = load_table(ROOT / "tables" / "rr_steer_stuck.npz")
    j = int(np.argmin(np.abs(np.degrees(shipped.axes["steer_stuck"]) - 45)))
    assert float(t.arrays["objective"].ravel()[0]) == pytest.approx(float(shipped.arrays["objective"][0, 0, 0, j]), rel=1e-6)


def test_a_sibling_soils_table_re_checks_the_verdict_and_tables_are_chosen_by_failure(tmp_path, monkeypatch):
    """rr_trench_clean_mu01 (grouser area ratio 0.1) at a 15 mm trench: the search calls it
    infeasible; rr_trench_clean (the same failure on mu = 0.5) has a primitive at the point, and
    one IPOPT run from it finds mu01's optimum. A folder build from scratch (``seed_index =
    "none"``) that holds both builds mu01 after its sibling, listed first, and re-checks it from
    the sibling's file as soon as it is written (here the shipped file stands in for the sibling's build, so that only
    mu01 is solved); the old builder built both at once from scratch and called the point
    infeasible. Tables of the same failures only: the former build first, the sibling soil next;
    another failure, or none, is no such table."""
    import shutil

    from offline.rover import table_continuation as TC

    none = replace(FAST, seed_index="none")
    spec = table_spec(SCEN / "rr_trench_clean_mu01.toml", grid="slope=0;cross_slope=0;speed=3;trench_depth=15",
                      build=none)
    lead = table_spec(SCEN / "rr_trench_clean.toml", grid="slope=0;cross_slope=0;speed=3;trench_depth=10,15",
                      build=none)
    assert TB.sibling_leaders([spec, lead]) == {"rr_trench_clean_mu01": "rr_trench_clean"}
    real = TB.build_table

    def build(s, out_dir, **kw):
        if s.name != "rr_trench_clean":
            return real(s, out_dir, **kw)
        assert kw.get("recheck_index") is None
        dst = Path(out_dir) / "rr_trench_clean.npz"
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / "tables" / "rr_trench_clean.npz", dst)
        return dst, {"statuses": {}}

    monkeypatch.setattr(TB, "build_table", build)
    order: list[str] = []
    TB.build_tables([spec, lead], tmp_path / "out", jobs=1, progress=False, on_done=lambda p, s: order.append(p.stem))
    assert order == ["rr_trench_clean", "rr_trench_clean_mu01"]
    assert not list((tmp_path / "out").glob(".recheck-index-*")) and TB.RUN_RECHECK_INDEX.startswith(".recheck-index-")
    t = load_table(tmp_path / "out" / "rr_trench_clean_mu01.npz")
    assert t.status.ravel().tolist() == [0]
    assert t.header["continuation"]["started_from"]["0"].startswith("table rr_trench_clean@")
    assert [r["name"] for r in t.header["continuation"]["recheck_tables"]] == ["rr_trench_clean"]
    assert t.header["continuation"]["seed_tables"] == []
    mu01 = load_table(ROOT / "tables" / "rr_trench_clean_mu01.npz")
    assert float(t.arrays["objective"].ravel()[0]) == pytest.approx(float(mu01.arrays["objective"].ravel()[2]), rel=1e-6)
    shipped = TB._seed_index("shipped")
    assert [Path(p).stem for p in TC.failure_tables(spec, shipped)] == ["rr_trench_clean_mu01", "rr_trench_clean"]
    nominal = table_spec(SCEN / "nominal.toml", grid="slope=0;cross_slope=0;speed=2")
    assert [Path(p).stem for p in TC.failure_tables(nominal, shipped)] == ["nominal"]
    assert TB.sibling_leaders([spec, lead, nominal]) == {"rr_trench_clean_mu01": "rr_trench_clean"}


def test_a_described_shipped_family_table_seeds_its_mirror_image(tmp_path):
    """``offnominal tables describe`` adds ``declares`` to a shipped table's family record; the family
    seed tables are matched without it, so the shipped rr_steer_stuck (mirrored) seeds a rear-left
    stuck-steering build (the former comparison of the whole record found none)."""
    from offline.rover import table_continuation as TC

    src = (SCEN / "rr_steer_stuck.toml").read_text()
    toml = tmp_path / "rl_steer_stuck.toml"
    toml.write_text(src.replace("rr_steer_stuck", "rl_steer_stuck").replace("[wheels.RR]", "[wheels.RL]")
                    .replace("../../offline", str(ROOT / "offline")))
    spec = table_spec(toml)
    assert spec.family["wheel"] == "RL"
    got = TC.family_seed_tables(spec, TB._seed_index("shipped"))
    assert [(Path(p).name, m) for p, m in got] == [("rr_steer_stuck.npz", True)]
