"""The C path of the allocation QP (:mod:`rtctl.codegen`): OSQP's generated code, built with the
system C compiler, answers every QP of the committed recordings as OSQP-in-Python does.

The generated solver shadows the Python one while the recordings replay: both get the same
setup data, the same sequence of updates (vectors, then the matrix values each tick: the
real-time iteration's refactorisation), the same warm starts (the allocator's own: last primal
step and duals), and both keep their own rho adaptation. Compiled once per module (one
library per table layout of ``tests/data/tables``).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import rtctl.allocator as allocator_module
from offline.sim.experiments import scenario_by_name
from rtctl import codegen
from rtctl.recording import read_recording
from rtctl.replay import replay
from rtctl.table import load_table

DATA = Path(__file__).parent / "data"
RECORDINGS = sorted(DATA.glob("rec_*.mcap"))
ATOL_PRIMAL = 1e-6
"""Largest difference allowed between the two primal solutions (the QP's scaled variables), issue 25."""

pytestmark = pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler 'cc' on PATH")


@pytest.fixture(scope="module")
def libraries(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One generated and compiled solver per table layout of the test tables."""
    root = tmp_path_factory.mktemp("qp_codegen")
    libs: dict[str, Path] = {}
    for f in sorted((DATA / "tables").glob("*.npz")):
        table = load_table(f)
        key = codegen.qp_pattern(table.layout).key
        if key not in libs:
            libs[key] = codegen.build_shared(codegen.generate(table, root / key))
    return libs


def _osqp_only(ctl):
    """The same controller with OSQP answering every tick (the exact active-set solve off): the
    flight build's path (rtctl.codegen)."""
    from dataclasses import replace

    from rtctl.controller import Controller

    cfg = replace(ctl.config, qp=replace(ctl.config.qp, active_set_iterations=0))
    return Controller(ctl.tables, cfg, getattr(ctl, "unavailable", None))


def _replay_shadowed(path: Path, libraries: dict[str, Path], monkeypatch: pytest.MonkeyPatch):
    """The recording's measurements through the OSQP-only controller twice: once with every OSQP
    call shadowed by the generated C solver, once plain; both runs' commands are compared."""
    from offline.sim.rtctl_bridge import rtctl_factory

    rec = read_recording(path)
    make = rtctl_factory(str(DATA / "tables"))
    plain = replay(rec, _osqp_only(make(scenario_by_name(rec.metadata["scenario"]))), rtol=1e30, atol=1e30)
    log = codegen.ShadowLog.empty()
    monkeypatch.setattr(allocator_module.osqp, "OSQP", codegen.shadow_osqp(libraries, log))
    ctl = _osqp_only(make(scenario_by_name(rec.metadata["scenario"])))
    rep = replay(rec, ctl, rtol=1e30, atol=1e30)
    monkeypatch.undo()
    return rec, (plain, rep), log


@pytest.mark.parametrize("path", RECORDINGS, ids=[p.stem for p in RECORDINGS])
def test_generated_solver_matches_python_on_every_qp_of_the_recording(path, libraries, monkeypatch):
    rec, (plain, rep), log = _replay_shadowed(path, libraries, monkeypatch)
    n = len(log.max_abs_dx)
    assert n >= len(rec.measurements) - 1, f"{n} QPs for {len(rec.measurements)} ticks: the shadow missed solves"
    dx = np.array(log.max_abs_dx)
    assert np.all(np.isfinite(dx)), "a QP without a finite solution"
    assert float(dx.max()) <= ATOL_PRIMAL, f"largest primal difference {dx.max():.3g} > {ATOL_PRIMAL}"
    assert all(log.same_status), "OSQP status differs on some QP"
    assert all(log.same_iterations), "ADMM iteration count differs on some QP"
    # the shadow must not have touched the Python path: the shadowed run equals the plain one bit for bit
    assert len(plain.commands) == len(rep.commands) == len(rec.measurements)
    assert all(a == b for a, b in zip(plain.commands, rep.commands))


def test_setup_reloads_a_new_table_like_a_fresh_osqp_setup(libraries):
    """One generated solver serves every table of its layout: loading another table's QP with
    ``rtctl_qp_setup`` (after a solve on the first table: rho adapted, iterates warm) answers as a
    fresh ``osqp.OSQP.setup`` does."""
    import osqp

    t1 = load_table(DATA / "tables" / "nominal.npz")
    t2 = load_table(DATA / "tables" / "rr_steer_stuck_50.npz")
    assert codegen.qp_pattern(t1.layout).key == codegen.qp_pattern(t2.layout).key
    lib = libraries[codegen.qp_pattern(t1.layout).key]
    c = codegen.GeneratedQp(lib)
    for k, t in enumerate((t1, t2, t1)):
        a = allocator_module.QpAllocator(t.layout, allocator_module.QpSettings())
        feas = np.argwhere(t.feasible)
        a.prepare(t.at(**t.grid_point(tuple(int(i) for i in feas[len(feas) // (k + 2)]))))
        q = np.concatenate([a._g, np.full(2 * a.ng, a.settings.slack_l1)])
        l = np.concatenate([a._lbg - a._g0, -np.ones(a.nx), np.zeros(2 * a.ng)])
        u = np.concatenate([a._ubg - a._g0, np.ones(a.nx), np.full(2 * a.ng, 1e30)])
        pr = a.problem((a._px_src, a._ax_src, q, l, u, None))  # the snapshot layout: the matrices' sources
        py = osqp.OSQP()
        s = a.settings
        py.setup(pr.P, pr.q, pr.A, pr.l, pr.u, verbose=False, eps_abs=s.eps, eps_rel=s.eps, max_iter=s.max_iter,
                 polishing=False, warm_starting=True)
        r = py.solve(raise_error=False)
        c.setup(pr.P.data, pr.A.data, pr.q, pr.l, pr.u)
        cs = c.solve()
        assert cs.status_val == int(r.info.status_val) and cs.iterations == int(r.info.iter)
        assert float(np.max(np.abs(cs.x - r.x))) <= ATOL_PRIMAL


def test_a_qp_of_another_layout_is_refused(monkeypatch):
    """A QP whose sparsity has no generated solver is refused by name, never solved by another."""
    monkeypatch.setattr(allocator_module.osqp, "OSQP", codegen.shadow_osqp({}, codegen.ShadowLog.empty()))
    t = load_table(DATA / "tables" / "nominal.npz")
    a = allocator_module.QpAllocator(t.layout, allocator_module.QpSettings())
    with pytest.raises(codegen.CodegenError, match="no generated solver for QP pattern"):
        a.prepare(t.at(**t.grid_point((0, 0, 0))))


def test_command_line_writes_the_folder(tmp_path):
    out = tmp_path / "qp"
    assert codegen.main([str(DATA / "tables" / "rr_trench_clean.npz"), "--out", str(out)]) == 0
    info = json.loads((out / codegen.LAYOUT_FILE).read_text())
    t = load_table(DATA / "tables" / "rr_trench_clean.npz")
    pat = codegen.qp_pattern(t.layout)
    assert (info["n"], info["m"], info["pattern_key"]) == (pat.n, pat.m, pat.key)
    assert info["settings"]["eps_abs"] == allocator_module.QpSettings().eps
    header = (out / "rtctl_qp.h").read_text()
    assert f"#define RTCTL_QP_N {pat.n}" in header and "rtctl_qp_solve" in header
    assert (out / f"{codegen.PREFIX}workspace.c").is_file() and (out / "src" / "osqp_api.c").is_file()
    assert codegen.main([str(DATA / "tables" / "rr_trench_clean.npz"), "--out", str(out)]) == 1  # exists: refused
