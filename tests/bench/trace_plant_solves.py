"""Why plant solves fail in a drive diagnosis, and whether a stagnation rule could stop them early.

Records one case of ``bench_drive_time.py``, runs the whole drive diagnosis with every plant
solve traced (:meth:`offline.sim.plant.PlantModel.solve` ``trace``: the max scaled residual,
accepted step and trial points of each Newton iteration, and the iterate) and reports:

* the failed solves (no equilibrium) by the state Newton stalls in (last iterate): *full slip*
  (every wheel on the ground at slip above 0.9: the rover cannot carry the load), *at the
  slip/skid switch* (a wheel at slip 0 within 1e-6, where the wheel model's wrench jumps:
  skid takes theta_m0 from the zero-slip sinkage h0, slip from h), *standstill* (|u| below
  1 mm/s and every wheel below 0.05 rad/s) and *other*; and how many of them reverse
  (every omega below 0), with their plant evaluations;
* the converged solves: iterations, trial points per iteration, and the longest stretch of
  iterations over which the residual fell by less than a factor (1 - eps), against the failed
  solves: for a rule "give up when the residual fell by less than eps over the last K
  iterations", on how many converged solves it would fire (changing their result) and how many
  evaluations of failed solves it would save.

Counts do not depend on the machine's load. Run::

    nice python tests/bench/trace_plant_solves.py current_limited --out tests/bench/results_plant_solves.md
"""

from __future__ import annotations

import argparse
import collections
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "bench"))


def classify(entry: dict[str, Any], contact: np.ndarray) -> str:
    """The state a failed solve stalled in (module docstring)."""
    slip, z = entry["slip"], entry["z"]
    on = contact > 0
    if np.all(slip[on] > 0.9):
        return "full slip"
    if np.nanmin(np.abs(slip[on])) < 1e-6:
        return "at the slip/skid switch"
    if abs(z[0]) < 1e-3 and np.all(np.abs(z[3:7]) < 0.05):
        return "standstill"
    return "other"


def longest_stall(norms: list[float], eps: float) -> int:
    """Longest run of iterations over which the residual fell by less than a factor (1 - eps)."""
    best = 0
    for i in range(len(norms)):
        j = i
        while j > 0 and norms[i] > (1 - eps) * norms[j - 1]:
            j -= 1
        best = max(best, i - j)
    return best


def fires_at(norms: list[float], eps: float, k: int) -> int | None:
    """First iteration at which the rule (residual fell by less than eps over k iterations) fires."""
    for i in range(k, len(norms)):
        if norms[i] > (1 - eps) * norms[i - k]:
            return i
    return None


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("--out", type=Path)
    a = ap.parse_args(argv)
    import offline.discrepancy.drive.diagnosis as dd
    import offline.sim.plant as pl
    from bench_drive_time import _record
    from offline.rover.scenario import load_scenario

    solves: list[tuple[bool, list[dict[str, Any]], np.ndarray]] = []
    o_solve = pl.PlantModel.solve

    def solve(self: Any, z0: Any, a_: Any, q: Any, d: Any = None, trace: Any = None) -> Any:
        tr: list[dict[str, Any]] = []
        contact = np.asarray(a_[25:29]) if len(a_) > 25 else np.ones(4)
        try:
            out = o_solve(self, z0, a_, q, d, trace=tr)
        except pl.SimulationError:
            solves.append((False, tr, contact))
            raise
        solves.append((True, tr, contact))
        return out

    pl.PlantModel.solve = solve  # type: ignore[method-assign]
    sc = load_scenario(ROOT / "offline/scenarios/nominal.toml")
    with tempfile.TemporaryDirectory() as tmpd:
        path, seed = _record(a.case, Path(tmpd))
        solves.clear()  # the recording's own solves are not the diagnosis'
        t0 = time.perf_counter()
        v = dd.diagnose_drives([path], sc, seed=seed)
        total = time.perf_counter() - t0

    def evals(tr: list[dict[str, Any]]) -> int:
        return 1 + sum(e["trials"] for e in tr[1:])

    ok = [s for s in solves if s[0]]
    bad = [s for s in solves if not s[0]]
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    md = [f"# Plant solves of one drive diagnosis: `{a.case}`", "",
          f"`nice python tests/bench/trace_plant_solves.py {a.case}` at commit `{commit}`, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; verdict `{v.status}`, {total:.0f} s. "
          f"{len(solves)} solves, {len(bad)} failed (no equilibrium). Evaluations: trial points (one residual each).", "",
          "## Failed solves by the state Newton stalls in (last iterate)", "",
          "| state | solves | of which reversing | evaluations | ended at 40 iterations | ended in a failed line search |",
          "|---|---|---|---|---|---|"]
    groups: dict[str, list[Any]] = collections.defaultdict(list)
    for s in bad:
        groups[classify(s[1][-1], s[2])].append(s)
    for name in ("full slip", "at the slip/skid switch", "standstill", "other"):
        g = groups.get(name, [])
        md.append(f"| {name} | {len(g)} | {sum(bool(np.all(s[1][-1]['z'][3:7] < 0)) for s in g)} | "
                  f"{sum(evals(s[1]) for s in g)} | {sum(len(s[1]) - 1 >= pl.PlantModel.MAX_NEWTON and s[1][-1]['step'] > 0 for s in g)} | "
                  f"{sum(s[1][-1]['step'] == 0.0 and s[1][-1]['trials'] == 30 for s in g)} |")
    its = np.array([len(s[1]) - 1 for s in ok])
    trials = max((e["trials"] for s in ok for e in s[1][1:]), default=0)
    md += ["", "## Converged solves against a stagnation rule", "",
           f"{len(ok)} converged solves: at most {its.max() if its.size else 0} iterations, at most {trials} trial points in one "
           f"iteration; {sum(evals(s[1]) for s in ok)} evaluations, failed solves {sum(evals(s[1]) for s in bad)}.", "",
           "Rule: give up when the residual fell by less than a factor (1 - eps) over the last K iterations. "
           "'converged longest' is the longest such stretch any converged solve went through before converging; "
           "a rule with K at or below it turns converged solves into failures (changes results).", "",
           "| eps | converged longest | K | converged solves it fires on | failed solves it stops | failed evaluations saved |",
           "|---|---|---|---|---|---|"]
    tot_bad = sum(evals(s[1]) for s in bad)
    for eps in (1e-2, 1e-4, 1e-6):
        worst = max((longest_stall([e["norm"] for e in s[1]], eps) for s in ok), default=0)
        for k in sorted({8, worst + 1, 2 * worst + 2}):
            fired = sum(fires_at([e["norm"] for e in s[1]], eps, k) is not None for s in ok)
            saved = stopped = 0
            for s in bad:
                i = fires_at([e["norm"] for e in s[1]], eps, k)
                if i is not None:
                    stopped += 1
                    saved += evals(s[1]) - evals(s[1][:i + 1])
            md.append(f"| {eps:.0e} | {worst} | {k} | {fired} | {stopped} of {len(bad)} | {saved} of {tot_bad} "
                      f"({100 * saved / max(tot_bad, 1):.0f} %) |")
    text = "\n".join(md) + "\n"
    print(text)
    if a.out:
        from offline.files import write_text

        write_text(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
