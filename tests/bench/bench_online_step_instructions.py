"""Instructions per online step, this tree against baselines, independent of the machine's load (issue 20).

One command (from the repository root; needs ``valgrind``)::

    python tests/bench/bench_online_step_instructions.py [--baseline 40a08e8,7e123c6] [--steps 60,160] [--top 12]

On a shared machine the thread CPU time of a step moves by more than the changes being measured
(the p99 of ``bench_online_step.py timing`` moved by 10 % between two runs of the same tree at
load 12 on 2 cores). The number of instructions the step executes does not: each tree runs the
closed loop of ``bench_online_step.py timing`` (same script, same seed) under valgrind's callgrind
twice, for the two ``--steps`` counts, and the difference of the two totals divided by the
difference of the counts is the instructions per step (start-up, imports and table loading
cancel). Instructions are not time (cache misses and the instructions' own costs differ), but a
change that removes work shows here whatever the load. ``--top``: the C functions whose
per-step instructions changed most against the first baseline. Results:
``tests/bench/results_online_step_instructions.md`` (a dated section is added; older ones kept).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

from bench_online_step import _TIMING_SCRIPT, _meta  # noqa: E402
from bench_online_step_floor import append_section  # noqa: E402


def _callgrind(tree: Path, steps: int, out: Path) -> tuple[int, dict[str, int]]:
    """Total instructions of the timing loop of ``tree`` for ``steps`` steps, and per C function."""
    script = out.with_suffix(".py")
    script.write_text(_TIMING_SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1"}
    r = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable, str(script), str(tree),
                        str(steps), str(ROOT / "tables" / "index.json"), "0"], capture_output=True, text=True, env=env,
                       cwd=str(tree))
    m = re.search(r"Collected : (\d+)", r.stderr)
    if r.returncode != 0 or m is None:
        raise SystemExit(f"callgrind run of {tree} failed:\n{r.stderr[-3000:]}")
    ann = subprocess.run(["callgrind_annotate", "--threshold=100", str(out)], capture_output=True, text=True).stdout
    funcs: dict[str, int] = {}
    for ln in ann.splitlines():
        f = re.match(r"\s*([\d,]+) \([^)]*\)\s+(.*)", ln)
        if f and "PROGRAM TOTALS" not in ln:
            name = f.group(2).split(" [")[0].split(":")[-1]
            funcs[name] = funcs.get(name, 0) + int(f.group(1).replace(",", ""))
    return int(m.group(1)), funcs


def _per_step(tree: Path, steps: tuple[int, int], tmp: Path, tag: str) -> tuple[float, dict[str, float]]:
    (a, fa), (b, fb) = (_callgrind(tree, n, tmp / f"{tag}_{n}.cg") for n in steps)
    d = steps[1] - steps[0]
    return (b - a) / d, {k: (fb.get(k, 0) - fa.get(k, 0)) / d for k in set(fa) | set(fb)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default="40a08e8,7e123c6", help="comma list of commits")
    ap.add_argument("--steps", default="60,160", help="two step counts")
    ap.add_argument("--top", type=int, default=12)
    a = ap.parse_args()
    steps = tuple(int(v) for v in a.steps.split(","))
    if len(steps) != 2 or not 0 < steps[0] < steps[1]:
        raise SystemExit(f"--steps must be two increasing counts, got {a.steps!r}")
    meta = _meta()
    rows: dict[str, tuple[float, dict[str, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp_:
        tmp = Path(tmp_)
        for c in [b for b in a.baseline.split(",") if b]:
            wt = tmp / f"wt_{c}"
            subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt), c], check=True, capture_output=True)
            try:
                rows[c] = _per_step(wt, steps, tmp, c)
            finally:
                subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)], capture_output=True)
            print(c, f"{rows[c][0]:.0f} instructions per step", flush=True)
        rows["this tree"] = _per_step(ROOT, steps, tmp, "this")
        print("this tree", f"{rows['this tree'][0]:.0f} instructions per step", flush=True)
    new = rows["this tree"][0]
    lines = [f"## {meta['date'][:16].replace('T', ' ')} UTC, {meta['commit']}", "",
             f"`python tests/bench/bench_online_step_instructions.py --baseline {a.baseline} --steps {a.steps} "
             f"--top {a.top}`; valgrind callgrind, instructions per step of the timing loop (steps {steps[0] + 1} to "
             f"{steps[1]}), independent of the load.", "",
             "| tree | instructions per step | this tree / it |", "|---|---|---|"]
    for k, (v, _) in rows.items():
        lines.append(f"| {k} | {v / 1e6:.3f} M | {new / v:.3f} |")
    first = next(iter(rows))
    if first != "this tree" and a.top > 0:
        fb, fn = rows[first][1], rows["this tree"][1]
        keys = sorted(set(fb) | set(fn), key=lambda k: -abs(fn.get(k, 0.0) - fb.get(k, 0.0)))[:a.top]
        lines += ["", f"C functions whose instructions per step changed most against {first} (thousands):", "",
                  f"| function | {first} | this tree | change |", "|---|---|---|---|"]
        for k in keys:
            lines.append(f"| `{k}` | {fb.get(k, 0.0) / 1e3:.0f} | {fn.get(k, 0.0) / 1e3:.0f} | "
                         f"{(fn.get(k, 0.0) - fb.get(k, 0.0)) / 1e3:+.0f} |")
    md = "\n".join(lines)
    append_section("results_online_step_instructions",
                   "Instructions per online step (issue 20): a measure of the work that the machine's load does not move",
                   md, {"meta": meta, "steps": steps, "per_step": {k: v for k, (v, _) in rows.items()}})
    print(md)


if __name__ == "__main__":
    main()
