"""Profile of one whole drive diagnosis: where the re-simulations and the seconds go, by stage.

Records one case of ``bench_drive_time.py`` (an out-of-library case of
``bench_drive_empirical.py``, an in-library case or ``noiseN``), runs
:func:`offline.discrepancy.drive.diagnosis.diagnose_drives` on it with every re-simulation
(:meth:`DriveModel._run`) timed and attributed to the stage the diagnosis reported last
(its ``progress`` messages), and counts per stage: re-simulations, their seconds, those slower
than 0.4 s, re-simulations of a key already simulated before (what a cache could have served),
plant solves, Newton iterations of the solves that converged, solves that failed (no equilibrium:
:class:`offline.sim.plant.SimulationError`), and the plant evaluations spent in failed solves (and
how many of them were residual only: the line search's shortened steps, ``evaluate(jacobian=False)``).
Seconds depend on the shared machine's load (printed); counts do not.

Run (prints a markdown table; ``--out FILE`` also writes it)::

    nice python tests/bench/profile_drive_diagnosis.py current_limited --out tests/bench/results_profile_drive_diagnosis.md
"""

from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "bench"))


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("case")
    ap.add_argument("--out", type=Path)
    ap.add_argument("--halvings", type=int, help="DriveModel.halvings (default: the library's)")
    ap.add_argument("--log", action="store_true", help="print each progress message with the CPU seconds so far (stderr)")
    a = ap.parse_args(argv)
    import offline.discrepancy.drive.diagnosis as dd
    import offline.sim.plant as pl
    from bench_drive_actuators import _record as _record_actuators
    from bench_drive_time import _record
    from offline.discrepancy.drive.candidates import RoverExtension, rover_terms
    from offline.rover.scenario import load_scenario

    sc = load_scenario(ROOT / "offline/scenarios/nominal.toml")
    stage = ["start"]
    agg: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    secs: dict[str, float] = collections.defaultdict(float)
    seen: set[Any] = set()
    cur = collections.Counter[str]()
    o_ev, o_solve, o_run = pl.PlantModel._evaluate, pl.PlantModel.solve, dd.DriveModel._run

    def evaluate(self: Any, z: Any, ctx: Any, d: Any, jacobian: bool) -> Any:  # what solve calls
        cur["evals"] += 1
        cur["residual-only evals"] += not jacobian
        return o_ev(self, z, ctx, d, jacobian)

    def solve(self: Any, *x: Any, **k: Any) -> Any:
        e0, r0 = cur["evals"], cur["residual-only evals"]
        cur["solves"] += 1
        try:
            z, s = o_solve(self, *x, **k)
        except pl.SimulationError:
            cur["failed solves"] += 1
            cur["evaluations in failed solves"] += cur["evals"] - e0
            cur["residual-only in failed solves"] += cur["residual-only evals"] - r0
            raise
        cur["newton iterations (converged)"] += s.iterations
        return z, s

    def run(self: Any, d: Any, ext: Any, ho: float, extra: Any = None) -> Any:
        e = ext or RoverExtension()
        key = (id(d), ho, tuple(sorted(e.soil.items())), tuple(sorted(rover_terms(e).items())),
               extra.key() if extra is not None else None)
        cur.clear()
        t0 = time.perf_counter()
        out = o_run(self, d, ext, ho, extra)
        dt = time.perf_counter() - t0
        g = agg[stage[0]]
        g["re-simulations"] += 1
        g["slower than 0.4 s"] += dt > 0.4
        g["same key simulated before"] += key in seen
        g["lost (not ok)"] += not out[2]
        seen.add(key)
        g.update(cur)
        secs[stage[0]] += dt
        return out

    o_step = dd._step

    def step(sim: Any, dt: float, depth: int = 0, halvings: int = 0) -> None:
        """dd._step, counting the ticks whose full step fails and those its halving rescues."""
        if depth:
            return o_step(sim, dt, depth, halvings)
        keep = sim.act.steer.copy(), sim.act.omega_servo.copy(), sim.z.copy()
        sim.dt = dt
        try:
            sim.step()
            return None
        except pl.SimulationError:
            cur["ticks whose full step failed"] += 1
            if not halvings:
                cur["ticks lost"] += 1
                raise
        sim.act.steer, sim.act.omega_servo, sim.z = keep
        try:
            o_step(sim, dt / 2, 1, halvings)
            o_step(sim, dt / 2, 1, halvings)
        except pl.SimulationError:
            cur["ticks lost"] += 1
            raise
        cur["ticks rescued by halving"] += 1
        return None

    o_post = dd.DriveModel.__post_init__

    def post_init(self: Any) -> None:
        o_post(self)
        if a.halvings is not None:
            self.halvings = a.halvings

    pl.PlantModel._evaluate, pl.PlantModel.solve, dd.DriveModel._run = evaluate, solve, run  # type: ignore[method-assign]
    dd._step = step  # type: ignore[assignment]
    dd.DriveModel.__post_init__ = post_init  # type: ignore[method-assign]

    def progress(m: str) -> None:
        stage[0] = m.split(" of ")[0].split(" on top")[0].split(":")[0][:48]
        if a.log:
            print(f"[{time.process_time():8.1f} CPU-s] {m}", file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as tmpd:
        rec = _record_actuators if a.case in ("shortfall_RL", "current_limited_RL", "rate_limited_RL") else _record
        path, seed = rec(a.case, Path(tmpd))
        load0 = " ".join(f"{x:.1f}" for x in os.getloadavg())
        t0 = time.perf_counter()
        v = dd.diagnose_drives([path], sc, seed=seed, progress=progress)
        total = time.perf_counter() - t0
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    cols = ["ticks whose full step failed", "ticks rescued by halving", "ticks lost", "re-simulations", "same key simulated before", "slower than 0.4 s", "lost (not ok)", "solves",
            "newton iterations (converged)", "failed solves", "evaluations in failed solves", "residual-only in failed solves",
            "evals", "residual-only evals"]
    md = [f"# Profile of one drive diagnosis: `{a.case}`", "",
          f"`nice python tests/bench/profile_drive_diagnosis.py {a.case}` at commit `{commit}` (code: "
          f"`{Path(dd.__file__).resolve().parents[2]}`), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load "
          f"average {load0} before, {' '.join(f'{x:.1f}' for x in os.getloadavg())} after (shared 2-core machine). "
          f"Verdict `{v.status}` ({' + '.join(v.missing_physics) or '-'}), {v.model.simulations} re-simulations, "
          f"{total:.0f} s in all. 'evals': plant evaluations (one residual and, unless residual-only, its Jacobian "
          "each; the line search evaluates shortened steps residual only, about 2/3 of the cost).", "",
          "| stage | s | " + " | ".join(cols) + " |", "|---|---|" + "---|" * len(cols)]
    tot: collections.Counter[str] = collections.Counter()
    for k, g in agg.items():
        tot.update(g)
        md.append(f"| {k} | {secs[k]:.1f} | " + " | ".join(str(g[c]) for c in cols) + " |")
    md.append(f"| all | {sum(secs.values()):.1f} | " + " | ".join(str(tot[c]) for c in cols) + " |")
    md += ["", f"Scores (chi2 of the model as given {v.chi2_cv_base:.1f}; delta: held-out improvement, in: in-sample improvement of "
           "the full-data fit; refit: held-out refit per fold):", "",
           "| candidate | delta held-out | in-sample | refit | significant | p adjusted | values |", "|---|---|---|---|---|---|---|"]
    for s in v.scores:
        md.append(f"| {s.label} | {s.delta_cv:.1f} | {v.chi2_cv_base - s.chi2_in:.1f} | {s.refit} | {s.significant} | "
                  f"{s.p_adjusted:.3g} | {', '.join(f'{x:.4g}' for x in s.values)} |")
    md += ["", "Verdict summary:", "", "```", v.summary().rstrip(), "```"]
    text = "\n".join(md) + "\n"
    print(text)
    if a.out:
        from offline.files import write_text

        write_text(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
