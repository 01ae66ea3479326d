"""The steady-state NLP's two casadi structures on README's worked example (issue 22).

``SolverOptions.nlp_structure``: ``inlined`` (one SX graph, every wheel's wrench inlined) against
``per_wheel`` (an MX graph calling one SX function per wheel model,
:func:`offline.rover.primitives.per_wheel_graph`). Run from the repository root, one command::

    nice python tests/bench/bench_nlp_structure.py [--compile] [--results tests/bench/results_nlp_structure_calls.md]

Writes (and prints), all in process CPU seconds, both structures measured in the same process:

1. build CPU of each problem, and the size of each IPOPT function: casadi instructions of the
   SX function, or for an MX function the instructions executed per call (every called SX
   function's instructions times its calls) and its distinct code (each called function once);
2. per-call CPU (best of 5 x 20 calls) of ``nlp_f``, ``nlp_g``, ``nlp_grad_f``, ``nlp_jac_g``,
   ``nlp_hess_l`` at the nominal start of the worked example (slope 0, stuck -30 deg), with the
   largest difference of their outputs relative to the output's largest entry;
3. IPOPT from the nominal start, and :func:`~offline.rover.primitives.solve_primitive` (the full
   automatic search and the independent check), at several grid points of the worked example:
   status, iterations, CPU, and the largest difference of the primitives in variable scales;
4. the least a per-wheel exact Hessian can cost: one wheel's 4x4 Hessian in its own variables
   (casadi SX, symmetric) and its Jacobian, instructions and per-call CPU;
5. with ``--compile``: the per-wheel structure's IPOPT functions compiled to C
   (:mod:`offline.rover.compiled_nlp`, cold cache in a temporary folder): compiler CPU, the
   generated C's size, per-call CPU compiled, and the same outputs.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

SCENARIO = """[scenario]
name = "fl_steer_stuck"
description = "Front-left steering actuator stuck at -30 deg"
params = "calibrated-sand"
rover = "mini-rover-t72"
speed_m_s = 0.03

[wheels.FL]
steer_stuck_deg = -30.0
"""
FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")
# (slope deg, cross slope deg, speed cm/s, stuck deg): grid points of the worked example's default grid
POINTS = ((0, 0, 2, -30), (10, 0, 2, -30), (20, 0, 4, -30), (10, 10, 2, 60), (15, -10, 4, 90), (5, 0, 2, 0))


def sizes(f: Any) -> tuple[int, int]:
    """(instructions executed per call, distinct instructions) of a casadi function."""
    if f.is_a("SXFunction"):
        return f.n_instructions(), f.n_instructions()
    if not f.is_a("MXFunction"):
        return 0, 0
    run, seen = 0, {}
    for i in range(f.n_instructions()):
        o = f.instruction_MX(i)
        if o.is_call():
            g = o.which_function()
            r, d = sizes(g)
            run += r
            seen[g.name()] = d
    return run, sum(seen.values())


def per_call(fun: Any, args: list[Any]) -> float:
    best = math.inf
    for _ in range(5):
        t0 = time.process_time()
        for _ in range(20):
            fun(*args)
        best = min(best, (time.process_time() - t0) / 20)
    return best


def outputs(fun: Any, args: list[Any]) -> list[np.ndarray]:
    import casadi as ca

    r = fun(*args)
    r = r if isinstance(r, (list, tuple)) else [r]
    return [np.asarray(ca.densify(v), dtype=float) for v in r]


def rel_diff(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    return max(float(np.max(np.abs(u - v))) / max(1e-300, float(np.max(np.abs(u)))) for u, v in zip(a, b))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--compile", action="store_true", help="also compile the per-wheel structure (cold cache)")
    ap.add_argument("--results", default=str(ROOT / "tests" / "bench" / "results_nlp_structure_calls.md"))
    args = ap.parse_args()

    from offline.rover import primitives as P
    from offline.rover.table_builder import _problem, scenario_at, table_spec

    lines: list[str] = []

    def say(s: str = "") -> None:
        print(s, flush=True)
        lines.append(s)

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "fl_steer_stuck.toml"
        path.write_text(SCENARIO)
        spec = table_spec(str(path))
    say("# The NLP's two casadi structures on README's worked example (`tests/bench/bench_nlp_structure.py`)")
    say()
    say(f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; load average at start {os.getloadavg()[0]:.1f} "
        "(2 shared cores: CPU seconds, both structures measured in this one process)")
    say()
    pbs, build = {}, {}
    for s in P.NLP_STRUCTURES:
        t0 = time.process_time()
        P.get_problem.cache_clear()
        pbs[s] = _problem(spec.scenario, replace(spec.solver, nlp_structure=s, compile="off"))
        build[s] = time.process_time() - t0
    a, b = pbs["inlined"], pbs["per_wheel"]
    sc0 = spec.scenario
    bd = a.bounds(sc0)
    x0, p0 = a.nominal_guess(sc0), bd["p"]
    lam = np.random.default_rng(0).standard_normal(a.layout.ng)
    say("## 1-2. Size and per-call CPU of IPOPT's functions (nominal start, slope 0, stuck -30 deg)")
    say()
    say(f"Problem build (graph + IPOPT instance): inlined {build['inlined']:.2f} s, per_wheel {build['per_wheel']:.2f} s CPU.")
    say()
    say("| function | inlined: SX instructions | per_wheel: executed / distinct | inlined [ms] | per_wheel [ms] "
        "| per_wheel / inlined | largest output difference (relative) |")
    say("|---|---|---|---|---|---|---|")
    for n in FUNCTIONS:
        fa, fb = a.solver.get_function(n), b.solver.get_function(n)
        fargs = [x0, p0, 1.0, lam][:fa.n_in()]
        ta, tb = per_call(fa, fargs), per_call(fb, fargs)
        sa, sb = sizes(fa), sizes(fb)
        say(f"| `{n}` | {sa[0]} | {sb[0]} / {sb[1]} | {ta * 1e3:.3f} | {tb * 1e3:.3f} | {tb / ta:.2f} | "
            f"{rel_diff(outputs(fa, fargs), outputs(fb, fargs)):.1e} |")
    say()
    say("## 3. IPOPT at grid points of the worked example")
    say()
    say("| point (slope, cross slope, speed cm/s, stuck deg) | from the nominal start: inlined status / iter / CPU s "
        "| per_wheel | max dx [scales] | solve_primitive: inlined status / IPOPT iter / CPU s | per_wheel | "
        "max dx [scales] | objective inlined / per_wheel |")
    say("|---|---|---|---|---|---|---|---|")
    tot = {"inlined": [0.0, 0.0], "per_wheel": [0.0, 0.0]}
    for sl, cs, v, st in POINTS:
        sc = scenario_at(sc0, spec.family, {"slope": math.radians(sl), "cross_slope": math.radians(cs),
                                             "speed": v / 100.0, "steer_stuck": math.radians(st)})
        bb = a.bounds(sc)
        xs = a.nominal_guess(sc)
        cell: dict[str, Any] = {}
        for s, pb in pbs.items():
            t0 = time.process_time()
            r = pb.solve(bb, xs)
            t1 = time.process_time()
            rp = P.solve_primitive(sc, replace(spec.solver, nlp_structure=s, compile="off"))
            t2 = time.process_time()
            cell[s] = (r, t1 - t0, rp, t2 - t1)
            tot[s][0] += t1 - t0
            tot[s][1] += t2 - t1
        ra, rb = cell["inlined"], cell["per_wheel"]
        dx = float(np.max(np.abs(ra[0]["x"] - rb[0]["x"])))
        dxp = float(np.max(np.abs(ra[2].x - rb[2].x)))
        say(f"| {sl}, {cs}, {v}, {st} | {ra[0]['status']} / {ra[0]['iterations']} / {ra[1]:.3f} | "
            f"{rb[0]['status']} / {rb[0]['iterations']} / {rb[1]:.3f} | {dx:.1e} | "
            f"{ra[2].status} / {ra[2].stats['iterations']} / {ra[3]:.2f} | {rb[2].status} / {rb[2].stats['iterations']} / "
            f"{rb[3]:.2f} | {dxp:.1e} | {ra[2].objective:.6g} / {rb[2].objective:.6g} |")
    say()
    say(f"Totals: IPOPT from the nominal start inlined {tot['inlined'][0]:.2f} s, per_wheel {tot['per_wheel'][0]:.2f} s "
        f"(ratio {tot['per_wheel'][0] / tot['inlined'][0]:.2f}); solve_primitive inlined {tot['inlined'][1]:.2f} s, "
        f"per_wheel {tot['per_wheel'][1]:.2f} s (ratio {tot['per_wheel'][1] / tot['inlined'][1]:.2f}).")
    say()
    say("## 4. The least a per-wheel Hessian can cost (casadi SX, one wheel, its own variables)")
    say()
    import casadi as ca

    from offline.physics.backend import CASADI
    from rtctl.physics.terramechanics import wrench_core

    m = a.steady_state
    q, sp, mu = ca.SX.sym("q", 4), ca.SX.sym("speed"), ca.SX.sym("mu", 7)
    vx, vy = m.statics.wheel_velocity(CASADI, sp, q[0])
    w, _ = wrench_core(CASADI, vx, vy, q[1], q[2], q[3], m.phys[0], m.options)
    w0, _ = wrench_core(CASADI, vx, vy, sp / m.shearing_radius[0], q[3], q[3], m.phys[0], m.options)
    wv = ca.vertcat(*w, w0[2])
    hq, _ = ca.hessian(ca.dot(mu, wv), q)
    fh = ca.Function("wheel_hessian", [q, sp, mu], [ca.triu(hq)])
    fj = ca.Function("wheel_jacobian", [q, sp], [ca.jacobian(wv, q)])
    qa = [np.array([0.1, 1.7, 0.01, 0.01]), 0.03, np.ones(7)]
    th, tj = per_call(fh, qa), per_call(fj, qa[:2])
    say(f"q = (beta, omega, h, h0), the 7 outputs (wrench and zero-slip load) weighted by 7 multipliers: the 4x4 "
        f"Hessian (upper triangle) {fh.n_instructions()} instructions, {th * 1e3:.3f} ms; the 7x4 Jacobian (which the "
        f"Lagrangian Hessian's cross terms through the balance rows also need) {fj.n_instructions()} instructions, "
        f"{tj * 1e3:.3f} ms. Four wheels: {4 * fh.n_instructions()} + {4 * fj.n_instructions()} = "
        f"{4 * (fh.n_instructions() + fj.n_instructions())} instructions against the inlined Hessian's "
        f"{a.solver.get_function('nlp_hess_l').n_instructions()}.")
    if args.compile:
        from offline.rover import compiled_nlp as C

        say()
        say("## 5. The per-wheel structure compiled to C (cold cache)")
        say()
        with tempfile.TemporaryDirectory() as cache:
            os.environ["OFFNOMINAL_CACHE"] = cache
            c0, t0 = C._children_cpu(), time.process_time()
            comp = C.compiled_functions(b.solver, "on", "per-wheel NLP")
            c1, t1 = C._children_cpu(), time.process_time()
            assert comp is not None
            so = sorted(Path(cache).glob("*.so"))
            say(f"Compiler CPU {c1 - c0:.1f} s (children of this process), Python (code generation, cutting) "
                f"{t1 - t0:.1f} s; library {so[0].stat().st_size / 1e6:.1f} MB" if so else "no library found")
            say()
            say("| function | per_wheel VM [ms] | per_wheel compiled [ms] | inlined VM [ms] | compiled / inlined VM "
                "| largest output difference vs VM |")
            say("|---|---|---|---|---|---|")
            for n in FUNCTIONS:
                if n not in comp:
                    continue
                fa, fb, fc = a.solver.get_function(n), b.solver.get_function(n), comp[n]
                fargs = [x0, p0, 1.0, lam][:fa.n_in()]
                ta, tb, tc = per_call(fa, fargs), per_call(fb, fargs), per_call(fc, fargs)
                say(f"| `{n}` | {tb * 1e3:.3f} | {tc * 1e3:.3f} | {ta * 1e3:.3f} | {tc / ta:.2f} | "
                    f"{rel_diff(outputs(fb, fargs), outputs(fc, fargs)):.1e} |")
    Path(args.results).write_text("\n".join(lines) + "\n")
    print(f"written: {args.results}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
