"""``offnominal tables verify`` and its gates, parameter presets by name, and an index in a fresh
``--out`` folder that keeps the shipped tables (issue 22).

The quick verify of every shipped table samples 2 points (and 2 cells) per table; the full
report is ``offnominal tables verify tables/<name>.npz``.
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
                                        spec_from_table, verify_table)
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


# ------------------------------------------------------------------------------ every shipped table
@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_table_passes_a_quick_verify(name):
    """All three gates on 2 sampled points and cells per table (no informational ladder)."""
    rep = verify_table(TABLES / f"{name}.npz", points=2, seed=0, ladder=False)
    assert rep.passed, rep.text()
    if np.any(load_table(TABLES / f"{name}.npz").feasible):
        assert rep.verdicts["jacobians"] and rep.verdicts["linearisation"], rep.verdicts
        assert rep.trust, "no trust-radius check ran"


def test_verify_fails_when_the_linearisation_is_off(tmp_path):
    """A table whose dx/dp is wrong passes the Jacobian check but fails the linearisation gate:
    the verdict is not decided by the Jacobians alone."""
    from rtctl.table import table_bytes

    src = load_table(TABLES / "nominal.npz")
    arrays = {k: np.array(v) for k, v in src.arrays.items()}
    arrays["dx_dp"] = 3.0 * arrays["dx_dp"]
    bad = tmp_path / "nominal.npz"
    bad.write_bytes(table_bytes({k: v for k, v in src.header.items() if k != "content_hash"}, arrays))
    rep = verify_table(bad, points=1, seed=0, ladder=False)
    assert rep.verdicts["jacobians"] and not rep.verdicts["linearisation"] and not rep.passed


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
