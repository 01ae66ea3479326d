"""Reference outputs of the mini rover's NLP (7.25), made at the commit stored in the file (before issue 23 generalised the NLP to any rover file).

Run from the repository root: ``python tests/data/make_mini_rover_nlp_reference.py tests/data/mini_rover_nlp_reference.npz``.
tests/test_any_rover_nlp.py re-solves the same scenarios and compares (same variable order, same numbers to 1e-9).
"""
import subprocess, sys, time, json
import numpy as np
from offline.rover.scenario import load_scenario, example_scenarios
from offline.rover.primitives import solve_primitive
names = ["nominal", "rl_unpowered", "opportunity_steer_stuck_7", "rr_speed_cap_half", "fr_raised", "rr_steer_stuck_50", "hillside_traverse_10"]
paths = {p.stem: p for p in example_scenarios()}
out = {}
commit = subprocess.check_output(["git", "rev-parse", "HEAD"], text=True).strip()
for n in names:
    t = time.perf_counter()
    sc = load_scenario(paths[n])
    r = solve_primitive(sc)
    from offline.rover.primitives import _problem_for, SolverOptions
    pb = _problem_for(sc, SolverOptions())
    xp = r.x * pb.xscale
    out[f"{n}/x_physical"] = xp
    out[f"{n}/objective"] = np.array(r.objective)
    out[f"{n}/status"] = np.array(r.status)
    out[f"{n}/variable_names"] = np.array(pb.layout.variable_names)
    out[f"{n}/constraint_names"] = np.array(pb.layout.constraint_names)
    out[f"{n}/parameter_names"] = np.array(pb.layout.parameter_names)
    print(n, r.status, r.objective, r.stats["n_attempts"], round(time.perf_counter() - t, 1), flush=True)
out["commit"] = np.array(commit)
np.savez(sys.argv[1], **out)
