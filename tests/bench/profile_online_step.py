"""Where the online step's time goes, function by function, before and after (issue 20).

::

    python tests/bench/profile_online_step.py [--before 98a77ab] [--steps 1000]

The closed loop of ``bench_online_step.py timing`` (same script, same seed) for the
``--before`` commit (checked out into a temporary worktree) and this tree, alternating, twice
each, in one run; every listed method wrapped with a thread-CPU clock (mean per step, ms;
nested: ``Controller.prepare`` holds ``QpAllocator.prepare`` and ``Controller._reachable``,
``RealTimeIteration.linearise`` holds ``SteadyStateResidual.evaluate``, which holds
``wrench_core`` and ``steady_state_rows``). The wrappers' own cost is in every number; compare
the columns, not with ``bench_online_step.py``. Also the isolated cost of one
``SteadyStateResidual.evaluate(jacobian=True)`` (median of 400 calls at the loop's last
iterate), which is what the numpy physics work changed. Results:
``tests/bench/results_online_step_profile.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

PARTS = [("rtctl.controller", "Controller", "prepare"), ("rtctl.allocator", "QpAllocator", "prepare"),
         ("rtctl.controller", "Controller", "_reachable"), ("rtctl.table", "Table", "at"),
         ("rtctl.controller", "Controller", "_crab_sensitivity"), ("rtctl.rti", "RealTimeIteration", "linearise"),
         ("rtctl.physics.steady_state", "SteadyStateResidual", "evaluate"),
         ("rtctl.physics.steady_state", None, "steady_state_rows"), ("rtctl.physics.terramechanics", None, "wrench_core"),
         ("rtctl.physics.statics", "FourWheelRocker", "balance"),
         ("rtctl.rti", "RealTimeIteration", "_structured_hessian"),
         ("rtctl.allocator", "QpAllocator", "solve_at"), ("rtctl.active_set", None, "solve_active_set"),
         ("rtctl.allocator", "QpAllocator", "_osqp"),
         ("rtctl.controller", "Controller", "_bounds"), ("rtctl.estimator", "SlipHeadingEKF", "predict"),
         ("rtctl.estimator", "SlipHeadingEKF", "update_pose"), ("rtctl.inputs", None, "read_measurements"),
         ("rtctl.controller", "Controller", "_diag"), ("rtctl.controller", "Controller", "_unreachable")]

_PRELUDE = r'''
import importlib, time as _time, numpy as _np
_shares = {}
def _wrap(modname, cls, name):
    mod = importlib.import_module(modname)
    owner = getattr(mod, cls) if cls else mod
    f = getattr(owner, name)
    key = (cls + "." if cls else "") + name
    def g(*a, **k):
        t0 = _time.thread_time_ns(); out = f(*a, **k); _shares[key] = _shares.get(key, 0) + _time.thread_time_ns() - t0
        return out
    setattr(owner, name, g)
    if not cls:  # functions imported by name elsewhere
        for m in ("rtctl.physics.steady_state", "rtctl.allocator", "rtctl.controller", "rtctl.rti"):
            mm = importlib.import_module(m)
            if getattr(mm, name, None) is f:
                setattr(mm, name, g)
for _m, _c, _n in PARTS:
    _wrap(_m, _c, _n)
'''

_POSTLUDE = r'''
import rtctl.physics.steady_state as _S
_loop = dict(_shares)  # the loop's shares, before the isolated calls below
_rti = ctl._prep.rti
_x, _p = _rti.iterate.copy(), _rti._last_p.copy()
_ts = []
for _ in range(400):
    t0 = _time.thread_time_ns(); _S.SteadyStateResidual.evaluate(_rti.residual, _x, _p, jacobian=True); _ts.append(_time.thread_time_ns() - t0)
_n = len(times) + 50
print(json.dumps({"parts": {k: v / 1e6 / _n for k, v in _loop.items()}, "step": float(_np.mean(times)),
                  "evaluate_us": float(_np.median(_ts)) / 1e3}))
'''


def main() -> None:
    import bench_online_step as B

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default="98a77ab")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--rounds", type=int, default=2, help="alternating runs of each tree (the best kept)")
    a = ap.parse_args()
    script = "PARTS = " + repr(PARTS) + "\n" + _PRELUDE + B._TIMING_SCRIPT.replace("print(json.dumps", "_ = (") + _POSTLUDE
    runs: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        wt = Path(tmp) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt), a.before], check=True, capture_output=True)
        try:
            for label, tree in [("before", wt), ("after", ROOT)] * a.rounds:
                env = {**os.environ, "PYTHONPATH": str(tree)}
                r = subprocess.run([sys.executable, "-c", script, str(tree), str(a.steps), str(ROOT / "tables" / "index.json"), "0"],
                                   capture_output=True, text=True, env=env, cwd=str(tree))
                if r.returncode:
                    raise SystemExit(f"{label}: {r.stderr[-3000:]}")
                runs.setdefault(label, []).append(json.loads(r.stdout.strip().splitlines()[-1]))
                print(label, "done", flush=True)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)], capture_output=True)

    def best(label: str, key: str) -> float:
        return min(r["parts"].get(key, float("nan")) for r in runs[label])

    meta = B._meta()
    lines = ["# The online step, function by function, before and after the step-time work (issue 20)", "",
             f"`python tests/bench/profile_online_step.py --before {a.before} --steps {a.steps} --rounds {a.rounds}`; {meta['commit']}, "
             f"{meta['date']}, {meta['machine']}, {meta['cpus']} cpus (shared with other jobs: compare the columns).", "",
             f"Thread CPU per step (mean, ms, the best of {a.rounds} alternating runs), every listed method wrapped; nested "
             "methods are inside their callers (module docstring).", "",
             "| method | before | after | after / before |", "|---|---|---|---|"]
    for m, c, n in PARTS:
        k = (c + "." if c else "") + n
        b_, a_ = best("before", k), best("after", k)
        lines.append(f"| {k} | {b_:.3f} | {a_:.3f} | {a_ / b_:.2f} |")
    sb, sa = min(r["step"] for r in runs["before"]), min(r["step"] for r in runs["after"])
    eb, ea = min(r["evaluate_us"] for r in runs["before"]), min(r["evaluate_us"] for r in runs["after"])
    lines += [f"| whole step (wrappers included) | {sb:.3f} | {sa:.3f} | {sa / sb:.2f} |", "",
              f"One `SteadyStateResidual.evaluate(jacobian=True)` alone (median of 400 calls): before {eb:.0f} us, after "
              f"{ea:.0f} us ({ea / eb:.2f}x)."]
    out = HERE / "results_online_step_profile.md"
    old = out.read_text() if out.exists() else ""
    if old:  # earlier runs are kept below the new one
        body = old.split("\n", 2)[2] if old.startswith("# ") else old
        lines += ["", "## Earlier runs (kept)", "", body.strip("\n")]
    from offline.files import write_text

    write_text(out, "\n".join(lines) + "\n")
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
