"""``offnominal tables verify`` and its gates, parameter presets by name, and an index in a fresh
``--out`` folder that keeps the shipped tables (issue 22).

The quick verify of every shipped table samples 2 points (and 2 cells) per table; the full
report is ``offnominal tables verify tables/<name>.npz``. Since issue 22 the gate between grid points
is check 4, the online step from the interpolated primitive (``table_verify.check_online``).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from offline.rover.scenario import PARAM_FILE_PRESETS, ScenarioError, load_scenario, param_preset_file
from offline.rover.table_builder import write_index
from offline.rover.table_verify import (FD_STEP, JACOBIAN_RTOL, STEEP_RTOL, _check_block, check_jacobians,
                                        feasible_cells, spec_from_table, verify_table)
from rtctl.table import load_index, load_table

ROOT = Path(__file__).resolve().parents[1]
TABLES = ROOT / "tables"
SHIPPED = sorted(json.loads((TABLES / "index.json").read_text())["tables"])


# ------------------------------------------------------------------------------ Jacobian check
def test_jacobian_check_accepts_an_exact_derivative_inside_a_boundary_layer():
    """A function differentiable only within 1e-12 of the point (sqrt with a 1e-24 floor, the
    trench flat fill's shape): the exact derivative passes, listed as a second-tier entry; a
    wrong one fails. The old check (one central step of 1e-6) rejected the exact one by 40x."""
    a = 1e-24

    def fun(z: np.ndarray) -> np.ndarray:
        return np.array([np.sqrt(max(z[0] ** 2 + a, a)) + 3.0 * z[1], 2.0 * z[1]])

    z = np.array([0.0, 0.5])
    exact = np.array([[0.0, 3.0], [0.0, 2.0]])  # d sqrt(z0^2 + a) / dz0 = z0 / sqrt(...) = 0 at z0 = 0
    step = FD_STEP * np.ones(2)
    entries: list = []
    assert _check_block(fun, z, step, exact, "b", {}, ["r0", "r1"], ["c0", "c1"], entries) <= JACOBIAN_RTOL
    assert entries == []  # symmetric: the central quotient is exact here
    # shifted off the symmetric point by 1e-13: the slope there is ~0.1, the 1e-6 step sees ~1e-7
    z = np.array([1e-13 / math.sqrt(99.0), 0.5])
    d0 = z[0] / math.sqrt(z[0] ** 2 + a)
    exact = np.array([[d0, 3.0], [0.0, 2.0]])
    entries = []
    err = _check_block(fun, z, step, exact, "b", {}, ["r0", "r1"], ["c0", "c1"], entries)
    assert len(entries) == 1 and entries[0]["row"] == "r0" and entries[0]["column"] == "c0"
    assert err <= STEEP_RTOL, entries
    wrong = exact.copy()
    wrong[0, 0] = 0.5 * d0
    err = _check_block(fun, z, step, wrong, "b", {}, ["r0", "r1"], ["c0", "c1"], [])
    assert err > STEEP_RTOL


def test_jacobian_check_takes_a_one_sided_derivative_at_a_cusp_and_rejects_a_wrong_one():
    """g = z + sqrt(max(z, 0)) (the clean-side pile height at A_R2 = 0): the backward derivative
    is 1, the forward one infinite. The stored 1 passes as 'backward'; 1.5 fails."""
    def fun(z: np.ndarray) -> np.ndarray:
        return np.array([z[0] + math.sqrt(max(z[0], 0.0))])

    z = np.array([0.0])
    entries: list = []
    err = _check_block(fun, z, FD_STEP * np.ones(1), np.array([[1.0]]), "b", {}, ["r"], ["c"], entries)
    assert err <= STEEP_RTOL and entries[0]["side"] == "backward"
    assert _check_block(fun, z, FD_STEP * np.ones(1), np.array([[1.5]]), "b", {}, ["r"], ["c"], []) > STEEP_RTOL


def test_jacobian_check_takes_the_inside_side_at_the_models_domain_edge():
    """A function defined only for z0 >= 0 (NaN beyond: the numpy wheel model refuses v_x < 0 with
    omega > 0, and a wheel stuck at 90 deg has v_x = 0 at its optimum): at z0 = 0 the stored
    derivative is checked against the forward quotient and passes; a wrong one fails. The old
    check took the central quotient there (NaN; the wheel model's ValueError crashed
    ``offnominal tables verify`` on the rebuilt rr_steer_stuck)."""
    def fun(z: np.ndarray) -> np.ndarray:
        if z[0] < 0.0:
            return np.full(2, np.nan)
        return np.array([np.sqrt(z[0] + 1.0) + z[1], z[0] * z[1]])

    z = np.array([0.0, 2.0])
    exact = np.array([[0.5, 1.0], [2.0, 0.0]])
    step = FD_STEP * np.ones(2)
    assert _check_block(fun, z, step, exact, "b", {}, ["r0", "r1"], ["c0", "c1"], []) <= JACOBIAN_RTOL
    wrong = exact.copy()
    wrong[1, 0] = 2.1
    assert _check_block(fun, z, step, wrong, "b", {}, ["r0", "r1"], ["c0", "c1"], []) > STEEP_RTOL


def test_stuck_at_90_deg_points_have_checkable_jacobians():
    """The shipped rr_steer_stuck at -90 deg (v_x = 0 on the stuck wheel): every block passes. (+90 deg,
    the same edge of the wheel model's domain from the other side, was checked here too until 2026-11-28;
    dropped for the suite's time, 1.3 s, to pay for check 4's other-optimum test below.)"""
    t = load_table(TABLES / "rr_steer_stuck.npz")
    spec = spec_from_table(t)
    edge = [int(f) for f in np.flatnonzero(t.feasible.ravel())
            if abs(abs(spec.grid.point(int(f))["steer_stuck"]) - math.pi / 2) < 1e-9]
    assert edge, "no feasible +-90 deg point in the shipped rr_steer_stuck"
    errs = check_jacobians(t, spec, [edge[0]], [])
    assert errs["wrench_jac"] <= JACOBIAN_RTOL and errs["grad_f"] <= JACOBIAN_RTOL, errs
    assert errs["jac_g_x"] <= STEEP_RTOL and errs["jac_g_p"] <= STEEP_RTOL, errs


def test_trench_table_jacobians_pass_and_name_the_flat_width_row():
    """rr_trench_clean_mu01 (issue 22: jac_g_x 27x and jac_g_p 41x off under the old check): the
    stored Jacobians are the limits of the difference quotients; the entries that needed the
    smaller steps are the trench flat-width row."""
    t = load_table(TABLES / "rr_trench_clean_mu01.npz")
    flats = [int(i) for i in np.flatnonzero(t.feasible.ravel())]
    entries: list = []
    errs = check_jacobians(t, spec_from_table(t), flats, entries)
    assert errs["jac_g_x"] <= STEEP_RTOL and errs["jac_g_p"] <= STEEP_RTOL, errs
    assert errs["wrench_jac"] <= JACOBIAN_RTOL and errs["grad_f"] <= JACOBIAN_RTOL, errs
    assert entries and {e["row"] for e in entries} == {"trench flat width RR"}, entries


# ------------------------------------------------------------------------------ interpolation reference
def test_interpolation_reference_is_the_best_optimum_not_the_first_start(monkeypatch):
    """Check 3's direct solve: of the optima its starts reach at a midpoint, the best by the builder's
    order (lowest objective), not the first that converged. Scripted solver (cheap): the
    interpolated start converges to a worse optimum (objective 2), the corners' continuation to a
    better one (objective 1). The former check took the first one; issue 22: at rr_unpowered's
    (7.5, 5) deg midpoint the first start reached an optimum of objective 1.062 (4.09 scales from
    the interpolation) where the corners' branch, reached by a continuation, has 0.909 (2.0)."""
    import offline.rover.table_verify as tv

    t = load_table(ROOT / "tests" / "data" / "tables" / "nominal.npz")
    spec = spec_from_table(t)
    cell = feasible_cells(t)[0]
    xsc = t.layout.variable_scale
    mid_op = {k: float(0.5 * (t.axes[k][i] + t.axes[k][i + 1])) for k, i in zip(t.axis_order, cell)}
    tp = t.at(**mid_op)
    x_good = tp.x / xsc
    x_bad = x_good + 0.3  # 0.3 scales off in every variable

    class Scripted:
        layout = t.layout

        def __init__(self) -> None:
            self.calls = 0

        def bounds(self, sc):
            return {}

        def solve(self, b, x0, *a, **k):
            self.calls += 1
            return {"success": True, "x": x_bad if self.calls == 1 else x_good, "f": 2.0 if self.calls == 1 else 1.0,
                    "lam_x": np.zeros(t.layout.nx), "lam_g": np.zeros(t.layout.ng)}

    pb = Scripted()
    monkeypatch.setattr(tv, "_problem", lambda sc, solver=None: pb)
    monkeypatch.setattr("offline.rover.primitives.check_solution", lambda pb, sc, x: (None, True))
    monkeypatch.setattr(tv, "_direct_data", lambda spec, sc, x: {"x": x * xsc, "jac_g_x": tp.jac_g_x,
                                                                  "wrench_jac": tp.wrench_jac})
    res = tv.check_interpolation(t, spec, [cell])
    assert res["x_error_per_scale"] < 0.01, res  # the former check: 0.3 (the first start's optimum)
    mid = res["per_midpoint"][0]
    assert mid["objective"] == 1.0 and mid["first_start_other_optimum"] and mid["optima"] == [1.0, 2.0], mid


# ------------------------------------------------------------------------------ online-step check (check 4)
def _bad_copy(src, tmp_path, name, change):
    """A copy of ``src`` with ``change(arrays)`` applied (a new file, the original untouched)."""
    from rtctl.table import table_bytes

    arrays = {k: np.array(v) for k, v in src.arrays.items()}
    change(arrays)
    path = tmp_path / f"{name}.npz"
    path.write_bytes(table_bytes({k: v for k, v in src.header.items() if k != "content_hash"}, arrays))
    return load_table(path)


def test_online_check_passes_a_good_table_and_fails_bad_ones(tmp_path):
    """Check 4 runs rtctl's own online step from the interpolated primitive at a cell centre: on the
    test nominal table it reaches the NLP optimum (issue 20's targets); the same table with every
    grid point's primitive corrupted (wheel speeds 3 variable scales up) or with wrong bounds (the
    wheel-speed bound below the optimum) FAILS, though the iteration runs on the exact residual.
    Measured: the corrupted tables end 1.1-1.9 scales from the optimum after 5 ticks, the good one
    0.005 (about 1.2 CPU s)."""
    from offline.rover.primitives import check_solution
    from offline.rover.table_builder import _problem, scenario_at
    from offline.rover.table_verify import ONLINE_TARGETS, check_online

    src = load_table(ROOT / "tests" / "data" / "tables" / "nominal.npz")
    spec = spec_from_table(src)
    lay = src.layout
    xsc = lay.variable_scale
    cell = feasible_cells(src)[0]
    op = {k: float(0.5 * (src.axes[k][i] + src.axes[k][i + 1])) for k, i in zip(src.axis_order, cell)}
    sc = scenario_at(spec.scenario, spec.family, op)
    pb = _problem(sc, spec.solver)
    r = pb.solve(pb.bounds(sc), src.at(**op).x / xsc)
    assert r["success"] and check_solution(pb, sc, r["x"])[1]
    ref = [(op, np.asarray(r["x"]) * xsc)]
    good = check_online(src, spec, ref)
    assert good["failed"] == 0 and good["per_centre"][0]["passed"], good
    om = [lay.var("omega", w) for w in lay.wheels]

    def shift(key, cols, by):
        def change(a):
            a[key][..., cols] = a[key][..., cols] + by
        return change

    def low_bound(a):
        a["ubx"][..., om] = 0.8 * a["x"][..., om]

    for name, change in (("speeds", shift("x", om, 3.0 * xsc[om])), ("bounds", low_bound)):
        res = check_online(_bad_copy(src, tmp_path, name, change), spec, ref)
        row = res["per_centre"][0]
        assert res["failed"] == 1 and not row["passed"], (name, row)
        assert any(row["last"][k] > v for k, v in ONLINE_TARGETS.items()), (name, row)
    # (steering 0.5 rad off at every grid point: since issue 22's restart by continuation the online
    # step recovers the optimum, measured 0.003 scales after 5 ticks, 1.1-1.9 before; such a table
    # fails verify on check 1, its stored Jacobians being another point's. That case was run here
    # until 2026-11-28, dropped for the suite's time to pay for check 4's other-optimum test.)


def test_verify_prints_passed_only_when_every_gated_check_passed(monkeypatch):
    """The online step's failure alone makes the verdict FAILED (the other checks passing), and the
    raw interpolation distance is printed either way (information, with the former gate). The
    checks themselves are stand-ins here (their real runs on every shipped table are the quick
    verify's below; this test had run them again on the test nominal table, 3-4 CPU s): what is
    tested is how ``verify_table`` turns their results into verdicts and text."""
    import offline.rover.table_verify as tv

    def interpolation(t, spec, cells, tol, refs):
        refs.append(({"slope": 0.1}, np.zeros(t.layout.nx)))
        return {"midpoints": 1, "no_direct_solution": 0, "x_error_per_scale": 0.7, "jac_g_x_rel_error": 0.0,
                "wrench_jac_rel_error": 0.0, "worst_midpoint": {"slope": 0.1}, "midpoints_without_primitive": [],
                "per_midpoint": [{"midpoint": {"slope": 0.1}, "x_error_per_scale": 0.7, "reference": "stand-in",
                                  "objective": 1.0, "optima": [1.0]}]}

    def online(t, spec, refs, *a, **k):
        return {"ticks": 5, "centres": 1, "failed": 1, "worst": {}, "tick1_targets": {}, "targets": {},
                "per_centre": [{"midpoint": {"slope": 0.1}, "x_error_per_scale_by_tick": [0.5] * 5, "passed": False}]}

    monkeypatch.setattr(tv, "check_jacobians", lambda t, spec, flats, entries: {"jac_g_x": 0.0})
    monkeypatch.setattr(tv, "check_trust_radius", lambda t, spec, flats: (
        [{"point": {}, "parameter": "slope", "step": 0.01, "error": 0.0, "tolerance": 0.1}], []))
    monkeypatch.setattr(tv, "check_interpolation", interpolation)
    monkeypatch.setattr(tv, "check_online", online)
    rep = tv.verify_table(ROOT / "tests" / "data" / "tables" / "nominal.npz", points=1, seed=0, ladder=False)
    assert rep.verdicts == {"jacobians": True, "linearisation": True, "interpolation": True, "online step": False}
    assert not rep.passed
    text = rep.text()
    assert text.splitlines()[-1] == "FAILED" and "PASSED" not in text
    assert "information, the raw interpolated primitive" in text and "4. Online step (gated)" in text
    monkeypatch.setattr(tv, "check_online", lambda t, spec, refs, *a, **k: {**online(t, spec, refs), "failed": 0})
    assert tv.verify_table(ROOT / "tests" / "data" / "tables" / "nominal.npz", points=1, seed=0, ladder=False).passed


# ------------------------------------------------------------------------------ every shipped table
ONLINE_FAILS: dict[str, str] = {}
"""Shipped tables whose quick verify fails, on check 4 (the online step) alone, and why: measured at every
cell centre by ``python tests/bench/bench_tables_online.py`` (``tests/bench/results_tables_online_i22.md``).
Such a failure is one of what rtctl commands between grid points, not of the check's reference (the best
verified optimum found by every start and a continuation from each corner). Empty since 2026-11-28: the
last one, rr_unpowered at (12.5, -5 deg), converges to the cell corners' branch, a balanced KKT point 0.22 %
above a second optimum that is the best only in a patch about 0.5 x 0.8 deg around that centre; check 4
accepts such a point within ``ONLINE_OTHER_OPTIMUM`` (``offline/rover/table_verify.py``, check 4, why;
:func:`test_check_4_takes_another_optimum_only_converged_balanced_and_not_notably_worse`). Before, since the
restart by parameter continuation (issue 22), rr_rim_speed_cap (4 of 4 cells, 2 before: a period-2 cycle and
a slow start) and rr_steer_stuck (27 of 27, 26 before: a start 2.8 scales off near 90 deg) passed."""


@pytest.fixture(scope="module")
def quick_reports():
    """The quick verify of every shipped table: 2 sampled points and cells, no ladder."""
    return {name: verify_table(TABLES / f"{name}.npz", points=2, seed=0, ladder=False) for name in SHIPPED}


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_table_passes_the_jacobian_and_linearisation_gates(quick_reports, name):
    rep = quick_reports[name]
    if not np.any(load_table(TABLES / f"{name}.npz").feasible):
        assert rep.passed and not rep.verdicts  # nothing to check beyond the file
        return
    assert rep.verdicts["jacobians"], rep.text()
    assert rep.verdicts["linearisation"] and rep.trust, rep.text()


@pytest.mark.parametrize("name", [n for n in SHIPPED if n not in ONLINE_FAILS])
def test_shipped_tables_pass_the_whole_verify(quick_reports, name):
    rep = quick_reports[name]
    assert rep.passed, rep.text()


@pytest.mark.parametrize("name", sorted(ONLINE_FAILS))
def test_known_failures_fail_on_the_online_step_alone(quick_reports, name):
    """These fail honestly (ONLINE_FAILS): the verdict is FAILED, decided by check 4 alone, with a
    primitive found at every centre (the grid and the online step, not a hole); the raw interpolation
    distance is reported."""
    rep = quick_reports[name]
    assert not rep.passed and rep.verdicts == {"jacobians": True, "linearisation": True, "interpolation": True,
                                               "online step": False}, rep.text()
    assert rep.interpolation["no_direct_solution"] == 0 and rep.online["failed"] >= 1
    assert "x_error_per_scale" in rep.interpolation and not rep.interpolation["raw_within_tolerance"]


def test_check_4_takes_another_optimum_only_converged_balanced_and_not_notably_worse(quick_reports):
    """rr_unpowered's quick sample draws the centre (12.5, -5 deg, 3 cm/s), where the best optimum is a
    branch held by none of the cell's corners and the best only in a patch about 0.5 x 0.8 deg wide
    (0.22 % better at the centre); the online step converges, balanced, to the corners' branch, steering
    7.4 deg away. Check 4 accepts it as another local optimum (it FAILED before 2026-11-28: the table was
    in ONLINE_FAILS); the same run FAILS when the objective tolerance is below its 0.22 % (a notably
    worse optimum), and after one tick, whose command is still 1.35 scales from the table's start (not
    shown converged)."""
    from offline.rover.table_verify import ONLINE_OTHER_OPTIMUM, check_online

    rep = quick_reports["rr_unpowered"]
    rows = [r for r in rep.online["per_centre"] if r.get("accepted") == "other optimum"]
    assert rep.passed and len(rows) == 1, rep.text()
    row, other = rows[0], rows[0]["other"]
    assert row["last"]["steer_deg"] > 5.0 and 0.001 < other["objective_above_reference"] <= 0.005, row
    assert other["last_step_per_scale"] <= ONLINE_OTHER_OPTIMUM["step_per_scale"], row
    ref = [(op, x) for op, x in rep.references if {k: round(v, 6) for k, v in op.items()} == row["midpoint"]]
    t = load_table(TABLES / "rr_unpowered.npz")
    spec = spec_from_table(t)
    worse = check_online(t, spec, ref, other_optimum={**ONLINE_OTHER_OPTIMUM, "objective_rel": 0.001})
    assert worse["failed"] == 1 and "not an accepted other optimum" in worse["per_centre"][0]["why"], worse
    moving = check_online(t, spec, ref, ticks=1)
    assert moving["failed"] == 1 and moving["per_centre"][0]["other"]["last_step_per_scale"] > 1.0, moving


def test_verify_fails_when_the_linearisation_is_off(tmp_path, monkeypatch):
    """A table whose dx/dp is wrong passes the Jacobian check but fails the linearisation gate:
    the verdict is not decided by the Jacobians alone, nor by checks 3 and 4 (told to pass here:
    this test is about check 2's gate; their real runs on this table cost 3 of its 4 CPU s and
    are the quick verify's)."""
    import offline.rover.table_verify as tv
    from rtctl.table import table_bytes

    src = load_table(TABLES / "nominal.npz")
    arrays = {k: np.array(v) for k, v in src.arrays.items()}
    arrays["dx_dp"] = 3.0 * arrays["dx_dp"]
    bad = tmp_path / "nominal.npz"
    bad.write_bytes(table_bytes({k: v for k, v in src.header.items() if k != "content_hash"}, arrays))
    monkeypatch.setattr(tv, "check_interpolation", lambda t, spec, cells, tol, refs: (
        refs.append(({}, np.zeros(1))),
        {"no_direct_solution": 0, "x_error_per_scale": 0.0, "jac_g_x_rel_error": 0.0, "wrench_jac_rel_error": 0.0})[1])
    monkeypatch.setattr(tv, "check_online", lambda t, spec, refs: {"failed": 0, "centres": len(refs)})
    rep = verify_table(bad, points=1, seed=0, ladder=False)
    assert rep.verdicts == {"jacobians": True, "linearisation": False, "interpolation": True, "online step": True}
    assert not rep.passed


# ------------------------------------------------------------------------------ presets
def test_a_scenario_names_the_calibrated_sand_from_any_folder(tmp_path):
    body = '[scenario]\nname = "x"\nparams = "{}"\nrover = "mini-rover-t72"\n[wheels.FL]\nsteer_stuck_deg = -30.0\n'
    by_name = tmp_path / "a" / "by_name.toml"
    by_name.parent.mkdir()
    by_name.write_text(body.format("calibrated-sand"))
    by_path = tmp_path / "by_path.toml"
    by_path.write_text(body.format(str(ROOT / "offline" / "data" / "calibrated_grousered.toml")))
    assert load_scenario(by_name).params == load_scenario(by_path).params
    for name, file in PARAM_FILE_PRESETS.items():
        assert param_preset_file(name) is not None and param_preset_file(name).name == file
        assert param_preset_file(name).is_file()
    bad = tmp_path / "bad.toml"
    bad.write_text(body.format("calibrated-snd"))
    with pytest.raises(ScenarioError, match="neither a preset.*calibrated-sand"):
        load_scenario(bad)


# ------------------------------------------------------------------------------ index in a fresh folder
def test_index_in_a_fresh_folder_keeps_the_shipped_tables(tmp_path):
    """A table written to a fresh folder: its index lists it and every shipped table, each
    loadable (hash-checked) from where it is; a name built here replaces the shipped entry."""
    fresh = tmp_path / "fresh"
    fresh.mkdir()
    new = fresh / "rr_locked.npz"
    shutil.copy(TABLES / "rr_locked.npz", new)
    ip = write_index(fresh, [new], base_index=TABLES / "index.json")
    infos = load_index(ip)
    assert sorted(infos) == SHIPPED
    assert infos["rr_locked"].path.resolve() == new.resolve()
    assert infos["nominal"].path.resolve() == (TABLES / "nominal.npz").resolve()
    assert infos["nominal"].load().name == "nominal"
    # a second build into the same folder updates its own index (no base any more)
    ip2 = write_index(fresh, [new], base_index=None)
    assert sorted(load_index(ip2)) == SHIPPED


def test_build_into_a_fresh_folder_from_a_scenario_anywhere(tmp_path, capsys):
    """End to end, as a new user: a scenario outside the repository names the calibrated sand;
    ``tables build --out fresh/`` writes an index holding the new table and the shipped ones,
    and the controller's loader reads all of them (each checked against its hash)."""
    from offline.cli import main
    from rtctl.controller import load_tables

    sc = tmp_path / "elsewhere" / "my_nominal.toml"
    sc.parent.mkdir()
    sc.write_text('[scenario]\nname = "my_nominal"\nparams = "calibrated-sand"\nrover = "mini-rover-t72"\n')
    out = tmp_path / "fresh"
    assert main(["tables", "build", str(sc), "--grid", "slope=0;cross_slope=0;speed=3", "--out", str(out),
                 "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert f"({len(SHIPPED) + 1} tables, with the tables of" in printed and f"--tables {out / 'index.json'}" in printed
    tables = load_tables(out / "index.json")
    assert sorted(tables) == sorted([*SHIPPED, "my_nominal"])
    assert load_table(out / "my_nominal.npz").header["sources"]["params_preset"] == "calibrated-sand"
    # which index a fresh folder starts from: none when asked, or when the folder has its own
    from offline.cli.tables import _base_index

    assert _base_index("none", tmp_path / "alone") is None
    assert _base_index("shipped", out) is None  # out has an index now: it is updated, not rebased
    assert _base_index("shipped", tmp_path / "alone") == TABLES / "index.json"
    assert _base_index("shipped", TABLES) is None  # building the shipped tables themselves
    assert _base_index(str(out), tmp_path / "alone") == out / "index.json"


# ------------------------------------------------------------------------------ relaxation evidence
def test_relaxation_is_the_scenario_without_failures_when_that_is_a_relaxation():
    from dataclasses import replace

    from offline.rover.scenario import WheelFailure
    from offline.rover.table_builder import relaxation_of

    base = load_scenario(TABLES / "scenarios" / "rr_steer_stuck.toml")
    rel = relaxation_of(base)
    assert rel is not None and rel.failures == {} and rel.trench is None
    assert (rel.params, rel.rover, rel.speed, rel.slope) == (base.params, base.rover, base.speed, base.slope)
    assert relaxation_of(replace(base, failures={})) is None  # nothing to relax
    # a stuck angle beyond the optimizer's +-89 deg lies outside the nominal bounds
    assert relaxation_of(replace(base, failures={"RR": WheelFailure(steer_stuck=math.radians(90.0))})) is None
    # a raised wheel changes the equations
    assert relaxation_of(replace(base, failures={"RR": WheelFailure(raised=True)})) is None
    trench = load_scenario(TABLES / "scenarios" / "rr_trench_clean.toml")
    assert relaxation_of(trench).params == trench.params  # the trench's zeta = 1 stays
