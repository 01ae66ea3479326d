"""The NLP's IPOPT functions compiled to C (offline.rover.compiled_nlp) against casadi's virtual machine.

The mini rover's NLP is 26 MB of generated C (minutes of compiler CPU), so the compiled path is
checked here on a small NLP through the same function (its six IPOPT functions, nlpsol's cache);
the same primitives on the real NLP, compiled against the virtual machine, over README's worked
example: tests/bench/results_worked_example_compiled.md (tests/bench/compare_builds.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from offline.rover import compiled_nlp as C

needs_cc = pytest.mark.skipif(C.find_compiler() is None, reason="no C compiler (the fallback is tested below)")
IPOPT = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": 1e-10, "calc_lam_p": False}


def _small_nlp():
    """A constrained Rosenbrock-type NLP with a parameter, bounds and a nonlinear row."""
    import casadi as ca

    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 2)
    f = (1 - x[0]) ** 2 + p[0] * (x[1] - x[0] ** 2) ** 2 + ca.exp(0.1 * x[2]) * x[2] ** 2
    g = ca.vertcat(x[0] + x[1] + x[2] - p[1], ca.sin(x[0]) * x[2] + ca.sqrt(1 + x[1] ** 2))
    return {"x": x, "p": p, "f": f, "g": g}


@needs_cc
def test_compiled_functions_give_the_virtual_machines_solution_and_are_cached(tmp_path, monkeypatch, capsys):
    import casadi as ca

    monkeypatch.setenv("OFFNOMINAL_CACHE", str(tmp_path))
    monkeypatch.setenv("OFFNOMINAL_NLP_CFLAGS", "-O0")  # a test checks values, not speed
    monkeypatch.setattr(C, "SPLIT_STATEMENTS", 5)  # cut the small functions into parts as the real ones are

    def no_chdir(path):  # the working folder is the process's: changing it raced with spawned workers
        raise AssertionError(f"os.chdir({path!r}) while generating C")

    monkeypatch.setattr(C.os, "chdir", no_chdir)
    nlp = _small_nlp()
    vm = ca.nlpsol("vm", "ipopt", nlp, IPOPT)
    fns = C.compiled_functions(vm, "on", "test NLP")
    assert fns is not None and set(fns) == set(C.NLP_FUNCTIONS)
    assert all(f.class_name() == "External" for f in fns.values())
    err = capsys.readouterr().err
    assert "compiling the test NLP functions" in err and str(tmp_path) in err
    libs = sorted(tmp_path.glob("nlp_fns_*.so"))
    assert len(libs) == 1 and not list(tmp_path.glob(".gen-*"))  # one library, no temporary left
    compiled = ca.nlpsol("compiled", "ipopt", nlp, {**IPOPT, "cache": fns})
    assert {compiled.get_function(n).class_name() for n in C.NLP_FUNCTIONS} == {"External"}
    assert vm.get_function("nlp_hess_l").class_name() == "SXFunction"
    for p, x0 in (([100.0, 1.0], [0.5, 0.5, 0.5]), ([10.0, 2.0], [-1.0, 2.0, 0.0])):
        args = {"x0": x0, "p": p, "lbx": [-2, -2, -2], "ubx": [2, 2, 2], "lbg": [0, -10], "ubg": [0, 1.5]}
        a, b = vm(**args), compiled(**args)
        assert vm.stats()["success"] and compiled.stats()["success"]
        assert vm.stats()["iter_count"] == compiled.stats()["iter_count"]
        for k in ("x", "lam_g", "lam_x", "f"):
            np.testing.assert_allclose(np.asarray(b[k]), np.asarray(a[k]), rtol=1e-9, atol=1e-12, err_msg=k)
    again = C.compiled_functions(ca.nlpsol("vm2", "ipopt", _small_nlp(), IPOPT), "auto")
    assert again is not None and "compiling" not in capsys.readouterr().err  # cache hit: no compiler run
    assert sorted(tmp_path.glob("nlp_fns_*.so")) == libs


def test_off_and_no_compiler_fall_back_to_the_virtual_machine(tmp_path, monkeypatch, capsys):
    import casadi as ca

    from offline.rover.primitives import SolverOptions, SteadyStateProblem
    from offline.rover.scenario import example_scenarios, load_scenario

    monkeypatch.setenv("OFFNOMINAL_CACHE", str(tmp_path))
    vm = ca.nlpsol("vm", "ipopt", _small_nlp(), IPOPT)
    assert C.compiled_functions(vm, "off") is None
    with pytest.raises(ValueError, match="expected one of"):
        C.compiled_functions(vm, "yes")
    monkeypatch.setenv("CC", "no-such-c-compiler")
    monkeypatch.setattr(C, "_said_no_compiler", False)
    with pytest.raises(C.CompileError, match="no C compiler"):
        C.compiled_functions(vm, "on")
    assert C.compiled_functions(vm, "auto") is None
    assert C.compiled_functions(vm, "auto") is None
    err = capsys.readouterr().err
    assert err.count("no C compiler found") == 1 and "virtual machine" in err  # one clear line per process
    assert not list(tmp_path.iterdir())
    # the real NLP with "auto" and no compiler: the interpreted solver, the same solve as "off"
    sc = load_scenario(next(p for p in example_scenarios() if p.stem == "nominal"))
    pa = SteadyStateProblem(sc.params, sc.rover, options=SolverOptions(compile="auto"))
    po = SteadyStateProblem(sc.params, sc.rover, options=SolverOptions(compile="off"))
    assert pa._compiled is None and pa.solver.get_function("nlp_hess_l").class_name() == "SXFunction"
    b = po.bounds(sc)
    ra, ro = pa.solve(b, pa.nominal_guess(sc)), po.solve(b, po.nominal_guess(sc))
    assert ro["success"] and ra["iterations"] == ro["iterations"]
    np.testing.assert_array_equal(ra["x"], ro["x"])


def test_compile_is_a_build_setting_that_changes_no_table_byte(monkeypatch):
    from offline.rover.primitives import SolverOptions
    from offline.rover.table_builder import BuildError, BuildOptions, encode

    monkeypatch.delenv("OFFNOMINAL_COMPILE", raising=False)
    assert BuildOptions().compile == "off"
    monkeypatch.setenv("OFFNOMINAL_COMPILE", "auto")
    assert BuildOptions().compile == "auto"
    with pytest.raises(BuildError, match="compile = 'fast'"):
        BuildOptions(compile="fast")
    assert encode(BuildOptions(compile="on")) == encode(BuildOptions(compile="off"))
    assert encode(SolverOptions(compile="on")) == encode(SolverOptions())


@needs_cc
def test_cached_mode_compiles_nothing_and_uses_a_library_already_built(tmp_path, monkeypatch, capsys):
    """``"cached"`` (a table below COMPILE_MIN_POINTS under ``auto``): the virtual machine and no
    compiler run while the cache lacks the library; once another build compiled it, the library."""
    import casadi as ca

    monkeypatch.setenv("OFFNOMINAL_CACHE", str(tmp_path))
    monkeypatch.setenv("OFFNOMINAL_NLP_CFLAGS", "-O0")

    def no_compiler(*a, **k):
        raise AssertionError("the compiler ran in 'cached' mode")

    with monkeypatch.context() as m:
        m.setattr(C, "_build", no_compiler)
        assert C.compiled_functions(ca.nlpsol("vm", "ipopt", _small_nlp(), IPOPT), "cached") is None
    assert not list(tmp_path.glob("nlp_fns_*.so")) and "compiling" not in capsys.readouterr().err
    assert C.compiled_functions(ca.nlpsol("vm", "ipopt", _small_nlp(), IPOPT), "on") is not None
    with monkeypatch.context() as m:
        m.setattr(C, "_build", no_compiler)
        fns = C.compiled_functions(ca.nlpsol("vm", "ipopt", _small_nlp(), IPOPT), "cached")
    assert fns is not None and all(f.class_name() == "External" for f in fns.values())


def test_a_small_table_under_auto_compiles_nothing():
    """build.compile = 'auto' becomes 'cached' below COMPILE_MIN_POINTS grid points (a compilation
    costs about as much as that many points run in the virtual machine), 'auto' from there on;
    'on' and 'off' are kept; the CLI's help states the same threshold."""
    from dataclasses import replace
    from pathlib import Path

    from offline.cli import build_parser
    from offline.rover import table_builder as TB

    toml = Path(__file__).resolve().parents[1] / "tables" / "scenarios" / "rr_unpowered.toml"
    spec = TB.table_spec(toml, grid="slope=0,5;cross_slope=0;speed=2,4", build=TB.BuildOptions(compile="auto"))
    assert spec.grid.size < TB.COMPILE_MIN_POINTS and TB.compile_mode(spec) == "cached"
    slopes = ",".join(str(0.25 * i) for i in range(TB.COMPILE_MIN_POINTS // 2))
    big = TB.table_spec(toml, grid=f"slope={slopes};cross_slope=0;speed=2,4", build=TB.BuildOptions(compile="auto"))
    assert big.grid.size == TB.COMPILE_MIN_POINTS and TB.compile_mode(big) == "auto"
    for mode in ("on", "off"):
        assert TB.compile_mode(replace(spec, build=TB.BuildOptions(compile=mode))) == mode
    # counted per NLP structure over a build of several tables: a small table compiles when the
    # tables sharing its structure are large together; another soil or a trench is another structure
    assert TB.compile_mode(spec, points=TB.COMPILE_MIN_POINTS) == "auto"
    scen = toml.parent
    keys = {n: TB.structure_key(TB.table_spec(scen / f"{n}.toml")) for n in
            ("nominal", "rr_unpowered", "rr_locked", "rr_trench_clean", "rr_trench_clean_mu01")}
    assert keys["nominal"] == keys["rr_unpowered"] == keys["rr_locked"]
    assert len({keys["nominal"], keys["rr_trench_clean"], keys["rr_trench_clean_mu01"]}) == 3
    sub = next(a for a in build_parser()._actions if a.dest == "command").choices["tables"]
    build = next(a for a in sub._actions if getattr(a, "choices", None) and "build" in a.choices).choices["build"]
    assert f"fewer than {TB.COMPILE_MIN_POINTS} grid points" in " ".join(build.format_help().split())
