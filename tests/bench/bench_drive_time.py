"""Benchmark: time of whole drive diagnoses, this tree against a baseline commit in the same run.

Each case records a 40 s calibration drive (as ``bench_drive_empirical.py``: the out-of-library
effects with seed 3, the in-library cases with their seeds, noise-only drives) once, then
diagnoses it with the whole drive tool (:func:`offline.discrepancy.drive.diagnosis.diagnose_drives`,
library and empirical stage, defaults) twice, each in its own process: once with the baseline's
code (``PYTHONPATH`` = a worktree of the baseline commit) and once with this tree's, the order
alternating from case to case so that a change of the shared machine's load falls on both. The
ratio of the two times is the result: wall seconds, and the processes' own CPU seconds, which an
overloaded shared machine changes far less (``--parallel`` runs both at the same time, so the same
load falls on both); seconds alone depend on the load (load averages in the results file). Each run also reports its re-simulations, and the two verdicts are compared
whole (``verdict.json`` without its seconds): a speed-up that changes nothing must give the same
verdict to the last digit.

Run (writes tests/bench/results_drive_time.md and .json; a row replaces an earlier row of the same
case, baseline and commit, rows of other commits are kept)::

    git worktree add --detach /tmp/base <commit>
    nice python tests/bench/bench_drive_time.py --baseline /tmp/base current_limited noise31 terrain_plane
    nice python tests/bench/bench_drive_time.py --baseline /tmp/base --parallel noise31

This tree's diagnosis runs on ``--workers`` processes (default: every core; a baseline whose
``diagnose_drives`` takes ``workers`` gets the same); the CPU seconds are the diagnosing process's
own plus its workers'.

Case names: a substring of an out-of-library case of ``bench_drive_empirical.py``, of an
in-library case of ``bench_drive_discrepancy.py``, or ``noiseN`` (noise-only drive, seed N).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "tests/bench/results_drive_time"
DURATION = 40.0


def _strip(x: Any) -> Any:
    """The verdict without what depends on the machine (seconds)."""
    if isinstance(x, dict):
        return {k: _strip(v) for k, v in x.items() if k not in ("seconds",)}
    if isinstance(x, list):
        return [_strip(v) for v in x]
    return x


def run_one(path: str, seed: int, workers: int = 1) -> None:
    """Child process: diagnose one recording with whatever ``offline`` is on the path; print JSON.
    ``workers`` > 1 is passed to a tree whose ``diagnose_drives`` takes it (one process otherwise);
    the CPU seconds are the process's own plus those of its worker processes."""
    import inspect
    import resource

    import offline.discrepancy.drive.diagnosis as dd
    from offline.rover.scenario import load_scenario

    import offline

    top = Path(offline.__file__).resolve().parent  # the drive tool moved (offline/fit -> offline/discrepancy/drive)
    sc = load_scenario(top / "scenarios/nominal.toml")
    kw = {"workers": workers} if "workers" in inspect.signature(dd.diagnose_drives).parameters else {}

    def children() -> float:
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
        return ru.ru_utime + ru.ru_stime

    t0, c0, k0 = time.perf_counter(), time.process_time(), children()
    v = dd.diagnose_drives([path], sc, seed=seed, **kw)
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0 + children() - k0
    print(json.dumps({"code": str(top.parent), "seconds": secs, "cpu_seconds": cpu,
                      "workers": kw.get("workers", 1),
                      "simulations": v.model.simulations, "status": v.status, "named": v.missing_physics,
                      "empirical": [t.law() for t in v.empirical.terms] if v.empirical is not None else None,
                      "verdict": _strip(json.loads(json.dumps(v.to_json(), default=float)))}, default=float))


def _record(name: str, tmp: Path) -> tuple[Path, int]:
    sys.path.insert(0, str(ROOT / "tests"))
    sys.path.insert(0, str(ROOT / "tests" / "bench"))
    from bench_drive_discrepancy import cases as library_cases
    from bench_drive_empirical import OUT_CASES, SEED
    from concealed_effects import Effect, record_concealed
    from offline.rover.scenario import load_scenario
    from offline.sim.truth import Truth

    sc = load_scenario(ROOT / "offline/scenarios/nominal.toml")
    f = tmp / f"{''.join(c if c.isalnum() else '_' for c in name)}.mcap"
    if name.startswith("noise") and name[5:].isdigit():
        seed = int(name[5:])
        return record_concealed(f, sc, Effect(), seed=seed, duration=DURATION), seed
    out = [c for c in OUT_CASES if name in c[0]]
    if out:
        return record_concealed(f, sc, out[0][1](), seed=SEED, duration=DURATION), SEED
    inl = [c for c in library_cases(Truth.nominal(sc.params, sc.rover))["effects"] if c[2] and name in c[0]]
    if not inl:
        raise SystemExit(f"no case matches {name!r}")
    _, make, _, seed = inl[0]
    return record_concealed(f, sc, make(), seed=seed, duration=DURATION), seed


def _start(code: Path, path: Path, seed: int, workers: int = 1) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(code))
    return subprocess.Popen([sys.executable, __file__, "--run-one", str(path), str(seed), str(workers)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tempfile.gettempdir())


def _result(code: Path, p: subprocess.Popen[str]) -> dict[str, Any]:
    out, err = p.communicate()
    if p.returncode:
        raise RuntimeError(f"{code}: {err[-2000:]}")
    return json.loads(out.strip().splitlines()[-1])


def _diff(a: Any, b: Any, where: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        return [d for k in sorted(set(a) | set(b)) for d in _diff(a.get(k), b.get(k), f"{where}.{k}")]
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _diff(x, y, f"{where}[{i}]")]
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return []  # NaN in both (e.g. the excess removed by no explanation)
    return [] if a == b else [where]


def _md(data: dict[str, Any]) -> str:
    md = ["# Whole drive diagnoses: time against a baseline commit, same run", "",
          "`nice python tests/bench/bench_drive_time.py --baseline WORKTREE CASE ...` (module docstring). Each case's "
          "40 s drive is diagnosed by the baseline's code and by this tree's code in separate processes, one after "
          "the other (order alternating), on the shared 2-core machine; the ratio is the result, seconds depend on "
          "the load. CPU seconds (the process's own, `time.process_time`) depend on it far less than wall seconds on "
          "an overloaded machine; `--parallel` runs both at the same time. Differences in verdict.json are listed by "
          "key (a count of re-simulations differs when the cache serves more).", ""]
    for r in data["rows"]:
        wk = (f" ({r['base'].get('workers', 1)} and {r['new'].get('workers', 1)} worker processes; CPU seconds include "
              "the workers')") if "workers" in r["new"] else ""
        same = "identical" if not r["differences"] else f"{len(r['differences'])} differences: {', '.join(r['differences'][:6])}"
        md.append(f"- `{r['case']}`: baseline `{r['baseline']}` {r['base']['seconds']:.0f} s, {r['base']['simulations']} "
                  f"simulations; this tree `{r['commit']}` {r['new']['seconds']:.0f} s, {r['new']['simulations']} simulations; "
                  f"time ratio new / baseline **{r['ratio']:.2f}**"
                  + (f", CPU seconds {r['base']['cpu_seconds']:.0f} -> {r['new']['cpu_seconds']:.0f}, CPU ratio "
                     f"**{r['cpu_ratio']:.2f}** ({'at the same time' if r.get('parallel') else 'one after the other'})"
                     if "cpu_ratio" in r else " (wall seconds only)")
                  + f"; verdict `{r['new']['status']}` "
                  f"({' + '.join(r['new']['named']) or '-'}); verdict.json without seconds: {same}; "
                  f"{r['when']}, load average {r['load_before']} before, {r['load_after']} after{wk}")
    md += ["", "| case | baseline -> this tree | baseline s | new s | ratio | CPU ratio | baseline sims | new sims | verdict | "
           "same verdict.json |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:
        cr = f"{r['cpu_ratio']:.2f}" if "cpu_ratio" in r else "-"
        md.append(f"| {r['case']} | `{r['baseline']}` -> `{r['commit']}` | {r['base']['seconds']:.0f} | {r['new']['seconds']:.0f} | "
                  f"{r['ratio']:.2f} | {cr} | "
                  f"{r['base']['simulations']} | {r['new']['simulations']} | {r['new']['status']} | "
                  f"{'yes' if not r['differences'] else 'NO'} |")
    return "\n".join(md) + "\n"


def main(argv: list[str]) -> int:
    if argv[:1] == ["--run-one"]:
        run_one(argv[1], int(argv[2]), int(argv[3]) if len(argv) > 3 else 1)
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, type=Path, help="a worktree of the baseline commit")
    ap.add_argument("--parallel", action="store_true",
                    help="run the baseline and this tree at the same time (on a loaded machine the same load falls on both)")
    ap.add_argument("--workers", type=int, default=None,
                    help="worker processes of this tree's diagnosis (default: every core; the baseline gets them too "
                         "if its diagnose_drives takes workers)")
    ap.add_argument("cases", nargs="+")
    a = ap.parse_args(argv)
    from offline.files import write_text

    def commit(p: Path) -> str:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=p, capture_output=True, text=True).stdout.strip()

    jpath = RESULTS.with_suffix(".json")
    data = json.loads(jpath.read_text()) if jpath.exists() else {"rows": []}
    with tempfile.TemporaryDirectory() as tmpd:
        for i, name in enumerate(a.cases):
            path, seed = _record(name, Path(tmpd))
            load0 = " ".join(f"{x:.1f}" for x in os.getloadavg())
            runs = {}
            code = {"base": a.baseline, "new": ROOT}
            workers = len(os.sched_getaffinity(0)) if a.workers is None else a.workers
            if a.parallel:  # both at once: the same load falls on both
                procs = {w: _start(code[w], path, seed, workers) for w in ("base", "new")}
                runs = {w: _result(code[w], p) for w, p in procs.items()}
            else:
                for which in (("base", "new") if i % 2 == 0 else ("new", "base")):
                    runs[which] = _result(code[which], _start(code[which], path, seed, workers))
            for which in ("base", "new"):
                print(name, which, runs[which]["seconds"], runs[which].get("cpu_seconds"), runs[which]["simulations"],
                      runs[which]["status"], flush=True)
            row = {"case": name, "baseline": commit(a.baseline), "commit": commit(ROOT),
                   "when": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "load_before": load0,
                   "load_after": " ".join(f"{x:.1f}" for x in os.getloadavg()),
                   "base": {k: v for k, v in runs["base"].items() if k != "verdict"},
                   "new": {k: v for k, v in runs["new"].items() if k != "verdict"},
                   "ratio": runs["new"]["seconds"] / runs["base"]["seconds"],
                   "cpu_ratio": runs["new"]["cpu_seconds"] / runs["base"]["cpu_seconds"], "parallel": a.parallel,
                   "differences": _diff(runs["base"]["verdict"], runs["new"]["verdict"])}
            # a run replaces the row of the same case, baseline and commit; rows of other commits are kept
            data["rows"] = [r for r in data["rows"]
                            if (r["case"], r["baseline"], r["commit"]) != (name, row["baseline"], row["commit"])] + [row]
            write_text(jpath, json.dumps(data, indent=1, default=float))
            write_text(RESULTS.with_suffix(".md"), _md(data))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
