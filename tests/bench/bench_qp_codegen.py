"""Issue 25, a C path for the QP: OSQP's generated solver against OSQP-in-Python on every QP of
the committed recordings, answers and solve times.

For each table layout of ``tests/data/tables`` the allocator's QP is generated
(:func:`rtctl.codegen.generate`, OSQP embedded mode 2) and compiled with ``cc -O2`` (``--cflags``) into a shared
library; then every committed recording (``tests/data/rec_*.mcap``) is replayed through rtctl with
the generated solver shadowing the Python one (:func:`rtctl.codegen.shadow_osqp`): same setup,
same per-tick updates (vectors, matrix values), same warm starts, each keeping its own rho
adaptation. Per QP: the largest primal and dual difference, status and iteration count, and the
time of one tick's OSQP calls (update + warm start + solve) on each side, measured in the same
run on the same QPs: Python's with ``time.perf_counter`` around the ``osqp.OSQP`` calls, C's with
``clock_gettime`` inside the library (and around the ctypes calls). The replay is repeated
``--rounds`` times for the timings (the answers are checked on every round).

Writes ``tests/bench/results_qp_codegen.md``::

    nice python tests/bench/bench_qp_codegen.py [--rounds 20]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT))

import bench_rtctl as B  # noqa: E402
import rtctl.allocator as allocator_module  # noqa: E402
from offline.files import write_text  # noqa: E402
from offline.sim.experiments import scenario_by_name  # noqa: E402
from offline.sim.rtctl_bridge import rtctl_factory  # noqa: E402
from rtctl import codegen  # noqa: E402
from rtctl.recording import read_recording  # noqa: E402
from rtctl.replay import replay  # noqa: E402
from rtctl.table import load_table  # noqa: E402

DATA = ROOT / "tests" / "data"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=20, help="replays of every recording (timings over all of them)")
    ap.add_argument("--cflags", default="-O2", help="compiler flags of the generated solver (default -O2)")
    ap.add_argument("--out", default=str(HERE / "results_qp_codegen.md"))
    a = ap.parse_args()
    B._COMMIT_AT_START = B._commit()
    t_wall = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="qp_codegen_") as tmp:
        libs: dict[str, Path] = {}
        build_s: dict[str, float] = {}
        for f in sorted((DATA / "tables").glob("*.npz")):
            table = load_table(f)
            key = codegen.qp_pattern(table.layout).key
            if key not in libs:
                t0 = time.perf_counter()
                libs[key] = codegen.build_shared(codegen.generate(table, Path(tmp) / key), flags=a.cflags.split())
                build_s[f"{key} ({f.stem}: nx {table.layout.nx}, ng {table.layout.ng})"] = time.perf_counter() - t0
        rows = []
        all_log = codegen.ShadowLog.empty()
        original = allocator_module.osqp.OSQP
        for path in sorted(DATA.glob("rec_*.mcap")):
            rec = read_recording(path)
            sc = scenario_by_name(rec.metadata["scenario"])
            per = codegen.ShadowLog.empty()
            identical = True
            for _ in range(a.rounds):
                log = codegen.ShadowLog.empty()
                allocator_module.osqp.OSQP = codegen.shadow_osqp(libs, log)
                try:
                    rep = replay(rec, rtctl_factory(str(DATA / "tables"))(sc))
                finally:
                    allocator_module.osqp.OSQP = original
                identical &= rep.identical
                for name in vars(per):
                    getattr(per, name).extend(getattr(log, name))
            for name in vars(all_log):
                getattr(all_log, name).extend(getattr(per, name))
            rows.append((path.name, len(rec.measurements), len(per.max_abs_dx) // a.rounds, per, identical))
    wall = time.perf_counter() - t_wall

    def stats(log: codegen.ShadowLog) -> tuple[float, ...]:
        py, c, cw = (np.array(v) * 1e6 for v in (log.python_s, log.c_s, log.c_wall_s))
        return (float(np.median(py)), float(np.median(c)), float(np.median(cw)), float(np.median(c / py)),
                float(np.median(cw / py)), float(c.sum() / py.sum()))

    lines = [B._header("Generated C solver (OSQP codegen) against OSQP-in-Python on the recordings' QPs",
                       "tests/data/tables (the recordings' own)"),
             f"Command: `nice python tests/bench/bench_qp_codegen.py --rounds {a.rounds}"
             f"{'' if a.cflags == '-O2' else f' --cflags={a.cflags!r}'}` (wall {wall:.0f} s). "
             f"osqp {codegen.osqp.__version__}, generated in embedded mode 2, compiled with `cc {a.cflags}`.", "",
             "Generation + compilation per layout: " + "; ".join(f"{k}: {v:.1f} s" for k, v in build_s.items()) + ".", "",
             "## Answers (every QP of every round)", "",
             "| recording | ticks | QPs per replay | largest primal difference | largest dual difference | same status | "
             "same iterations | replay bit for bit |", "|---|---|---|---|---|---|---|---|"]
    for name, ticks, nqp, log, ident in rows:
        lines.append(f"| {name} | {ticks} | {nqp} | {max(log.max_abs_dx):.3g} | {max(log.max_abs_dy):.3g} | "
                     f"{sum(log.same_status)}/{len(log.same_status)} | {sum(log.same_iterations)}/{len(log.same_iterations)} | "
                     f"{ident} |")
    lines += ["", "Primal: the QP's scaled variables (step and slacks), the allocator's `last_solution`. Both solvers are "
              "warm-started alike (the allocator's warm start: last primal step, last duals) and each adapts rho every "
              "50 iterations from the same state, so the generated solver runs the same ADMM iterations (OSQP 1.1.3's "
              "algorithm, no polishing, QDLDL factorisation); a difference of 0 means bit for bit.", "",
              "## Time of one tick's OSQP calls (update + warm start + solve), us", "",
              "| recording | Python median | C median (in C) | C median (with ctypes) | median ratio C / Python | "
              "median ratio (ctypes) / Python | total C / total Python |", "|---|---|---|---|---|---|---|"]
    for name, _, _, log, _ in rows + [("all", 0, 0, all_log, True)]:
        s = stats(log)
        lines.append(f"| {name} | {s[0]:.0f} | {s[1]:.0f} | {s[2]:.0f} | {s[3]:.3f} | {s[4]:.3f} | {s[5]:.3f} |")
    lines += ["", "Same QPs, same run; each tick the Python solver runs first, then the generated one. Both are compiled "
              "C doing the same iterations, so the difference is the Python binding's overhead (argument conversion, "
              "the result's namespace and copies) on the few-iteration warm solves, and little on the long ones "
              "(the rim-speed-cap recording's QPs take hundreds of iterations). Thread CPU is shared with other jobs: "
              "only the ratios are meaningful.", ""]
    text = "\n".join(lines) + "\n"
    print(text)
    write_text(Path(a.out), text)


if __name__ == "__main__":
    main()
