"""``build.seed_index = "run"``: a folder of scenarios rebuilt from scratch seeds its failure tables
from the failure-free tables the same call builds first (not from the files it replaces)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from offline.rover.table_builder import RUN_SEED_INDEX, BuildOptions, build_tables, seeds_others, table_spec
from rtctl.table import load_table

ROOT = Path(__file__).resolve().parents[1]
SCEN = ROOT / "tables" / "scenarios"
FAST = BuildOptions(trust_steps=(0.0625, 0.125), trust_search=(0.0625, 0.25, 1.0), seed_index="run")
GRID = "slope=5;cross_slope=0;speed=3"


def test_run_seeds_build_the_failure_free_table_first_and_seed_the_others_from_it(tmp_path):
    """The failure table comes first in the list yet is built second, seeded by the nominal table
    just built (name and content hash in its header), as it would be from a seed index holding
    that file; the temporary index is gone afterwards; a failure-free table is not seeded."""
    unpowered = table_spec(SCEN / "rr_unpowered.toml", grid=GRID, build=FAST)
    nominal = table_spec(SCEN / "nominal.toml", grid=GRID, build=FAST)
    assert seeds_others(nominal) and not seeds_others(unpowered)
    order: list[str] = []
    built = build_tables([unpowered, nominal], tmp_path, jobs=1, progress=False,
                         on_done=lambda p, s: order.append(p.stem))
    assert order == ["nominal", "rr_unpowered"] and [p.stem for p, _ in built] == order
    assert not (tmp_path / RUN_SEED_INDEX).exists()
    tn, tu = load_table(tmp_path / "nominal.npz"), load_table(tmp_path / "rr_unpowered.npz")
    seeds = tu.header["continuation"]["seed_tables"]
    assert [(s["name"], s["content_hash"]) for s in seeds] == [("nominal", tn.header["content_hash"])]
    assert any(v.startswith("seed table") for v in tu.header["continuation"]["started_from"].values())
    assert tn.header["continuation"]["seed_tables"] == []
    # the same as a build seeded by an index that holds the nominal file: the seeding is the only link
    from offline.rover.table_builder import build_table, write_index

    ix = write_index(tmp_path, [tmp_path / "nominal.npz"], index_name="seeds.json")
    other = tmp_path / "alone"
    build_table(replace(unpowered, build=replace(FAST, seed_index=str(ix))), other, progress=False)
    a, b = load_table(other / "rr_unpowered.npz"), tu
    assert a.header["continuation"] == b.header["continuation"]
    for k in ("x", "status", "objective"):
        assert (a.arrays[k].tobytes() == b.arrays[k].tobytes()), k


def test_build_tables_counts_the_points_of_every_table_on_an_nlp_structure(tmp_path, monkeypatch):
    """build_tables hands each table the points of all its tables on the same NLP structure, so a
    small table compiles with the large ones (compile_mode) instead of starting in the virtual
    machine while they compile; the trench table is a structure of its own."""
    import offline.rover.table_builder as TB

    got: dict[str, int | None] = {}

    def fake(spec, out_dir, **kw):
        got[spec.name] = kw.get("structure_points")
        return Path(out_dir) / f"{spec.name}.npz", {}

    monkeypatch.setattr(TB, "build_table", fake)
    opts = BuildOptions(compile="auto", seed_index="none")
    specs = [table_spec(SCEN / "rr_unpowered.toml", build=opts), table_spec(SCEN / "nominal.toml", build=opts),
             table_spec(SCEN / "rr_trench_clean.toml", grid="slope=0;cross_slope=0;speed=3", build=opts)]
    build_tables(specs, tmp_path, jobs=1, progress=False)
    n_unp, n_nom, n_tr = (s.grid.size for s in specs)
    assert got == {"rr_unpowered": n_unp + n_nom, "nominal": n_unp + n_nom, "rr_trench_clean": n_tr}
    assert TB.compile_mode(specs[0]) == "cached" and TB.compile_mode(specs[0], got["rr_unpowered"]) == "auto"


def test_one_scenario_file_takes_its_folders_grid(tmp_path, monkeypatch, capsys):
    """``offnominal tables build tables/scenarios/rr_trench_clean_mu01.toml`` builds the shipped
    3-point grid of ``grids.toml`` (the old command built the 144-point default grid for that file
    alone, a different table from the one it meant to rebuild); ``--grid`` overrides it."""
    from offline.cli import main
    from offline.rover import table_builder as TB

    got: list = []

    def fake(specs, out_dir, **kw):
        got.append([s.grid.size for s in specs])
        return []

    monkeypatch.setattr(TB, "build_tables", fake)
    f = str(SCEN / "rr_trench_clean_mu01.toml")
    assert main(["tables", "build", f, "--out", str(tmp_path), "--no-index", "--quiet"]) == 0
    assert "grid (--grid overrides) from" in capsys.readouterr().out
    assert main(["tables", "build", f, "--grid", "slope=0,5;cross_slope=0;speed=3;trench_depth=5",
                 "--out", str(tmp_path), "--no-index", "--quiet"]) == 0
    assert got == [[3], [2]]


def test_a_follower_starts_after_its_leader_on_shared_workers(tmp_path, monkeypatch):
    """With workers (tables built at once), a sibling's follower starts beside its leader and waits
    for the leader's file only for its re-check (a temporary index holding the leader), while an
    unrelated table builds beside them;
    the index is gone afterwards (the table builds are stand-ins: only the ordering is tested)."""
    import threading

    from offline.rover import table_builder as TB
    from rtctl.table import load_index

    none = replace(FAST, seed_index="none")
    mu01 = table_spec(SCEN / "rr_trench_clean_mu01.toml", grid="slope=0;cross_slope=0;speed=3;trench_depth=15", build=none)
    lead = table_spec(SCEN / "rr_trench_clean.toml", grid="slope=0;cross_slope=0;speed=3;trench_depth=10,15", build=none)
    other = table_spec(SCEN / "rr_unpowered.toml", grid=GRID, build=none)
    release, started, events = threading.Event(), threading.Event(), []

    def build(s, out_dir, **kw):
        if s.name == "rr_unpowered":  # still running when the follower has its leader's file
            assert release.wait(30)
        if s.name == "rr_trench_clean":  # the follower is under way before its leader ends
            assert started.wait(30)
        if s.name == "rr_trench_clean_mu01":
            events.append(("follower starts", s.name))
            started.set()
            ix = kw["recheck_index"]()  # waits for the leader
            events.append(("follower", sorted(load_index(ix))))
            release.set()
        else:
            assert kw["recheck_index"] is None
        dst = Path(out_dir) / f"{s.name}.npz"
        dst.parent.mkdir(parents=True, exist_ok=True)
        src = {"rr_trench_clean": "rr_trench_clean", "rr_unpowered": "rr_unpowered"}.get(s.name, "rr_trench_clean_mu01")
        dst.write_bytes((ROOT / "tables" / f"{src}.npz").read_bytes())
        events.append(("done", s.name))
        return dst, {"statuses": {}}

    monkeypatch.setattr(TB, "build_table", build)
    order: list[str] = []
    TB.build_tables([mu01, other, lead], tmp_path, jobs=2, progress=False, on_done=lambda p, s: order.append(p.stem))
    assert events.index(("follower starts", "rr_trench_clean_mu01")) < events.index(("done", "rr_trench_clean")) \
        < events.index(("follower", ["rr_trench_clean"]))
    assert events.index(("follower", ["rr_trench_clean"])) < events.index(("done", "rr_unpowered"))
    assert order == ["rr_unpowered", "rr_trench_clean", "rr_trench_clean_mu01"]
    assert not list(tmp_path.glob(".recheck-index-*"))
