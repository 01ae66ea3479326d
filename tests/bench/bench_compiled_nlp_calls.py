"""Per-call CPU time of IPOPT's functions of README's worked example, casadi's virtual machine vs compiled.

Run in a folder holding README's ``fl_steer_stuck.toml`` (``--compile on`` compiles on a cold cache)::

    OFFNOMINAL_CACHE=DIR nice python tests/bench/bench_compiled_nlp_calls.py

Results: ``tests/bench/results_worked_example_compiled.md``.
"""
import time, numpy as np
from dataclasses import replace
from offline.rover.table_builder import table_spec, _problem
spec = table_spec("fl_steer_stuck.toml")
vm = _problem(spec.scenario, replace(spec.solver, compile="off"))
cp = _problem(spec.scenario, replace(spec.solver, compile="on"))
b = vm.bounds(spec.scenario)
x = vm.nominal_guess(spec.scenario); p = b["p"]; lg = np.random.default_rng(0).standard_normal(vm.layout.ng)
for n in ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l"):
    fv, fc = vm.solver.get_function(n), cp.solver.get_function(n)
    args = [x, p, 1.0, lg][:fv.n_in()]
    rv, rc = fv(*args), fc(*args)
    rv = rv if isinstance(rv, (list, tuple)) else [rv]; rc = rc if isinstance(rc, (list, tuple)) else [rc]
    err = max(float(np.max(np.abs(np.asarray(a) - np.asarray(c)))) / max(1.0, float(np.max(np.abs(np.asarray(a))))) for a, c in zip(rv, rc))
    ts = {}
    for tag, f in (("vm", fv), ("c", fc)):
        best = 1e9
        for rep in range(5):
            t0 = time.process_time()
            for _ in range(20): f(*args)
            best = min(best, (time.process_time() - t0) / 20)
        ts[tag] = best
    print(f"{n}: {fv.class_name()} {ts['vm']*1e3:.3f} ms CPU, {fc.class_name()} {ts['c']*1e3:.3f} ms CPU, ratio {ts['vm']/ts['c']:.1f}, max rel diff {err:.1e}")
r1 = vm.solve(b, x); r2 = cp.solve(b, x)
print("solve from the nominal guess:", r1["status"], r1["iterations"], r2["status"], r2["iterations"],
      float(np.max(np.abs(r1["x"] - r2["x"]))))
