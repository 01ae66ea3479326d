"""Issue 25: cold import time and peak memory of the controller, interleaved between variants.

Each variant is a Python interpreter and an optional PYTHONPATH (e.g. an export of an older
rtctl); every round starts one fresh process per variant, in turn, so the machine's load hits
all variants alike. A process imports ``rtctl.controller`` (timed), then loads the shipped tables
and builds a Controller (timed), and reports its peak resident set (VmHWM)::

    python tests/bench/bench_rtctl_import_compare.py --rounds 10 \\
        --variant "this checkout=.venv/bin/python" \\
        --variant "rtctl of 40a08e8=.venv/bin/python:/tmp/old" \\
        --variant "rover install=/tmp/rover/bin/python" --out FILE
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(HERE))

CODE = ("import time, sys; t0 = time.perf_counter(); import rtctl.controller; t1 = time.perf_counter(); "
        "from rtctl.controller import Controller, load_tables; from rtctl.config import ControllerConfig; "
        f"c = Controller(load_tables({str(ROOT / 'tables' / 'index.json')!r}), ControllerConfig()); "
        "t2 = time.perf_counter(); "
        "hwm = [l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM')][0]; "
        "print(t1 - t0, t2 - t1, hwm, int('scipy.stats' in sys.modules), int('filterpy.kalman' in sys.modules))")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variant", action="append", required=True, help="LABEL=PYTHON[:PYTHONPATH]")
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    variants = []
    for v in a.variant:
        label, _, rest = v.partition("=")
        py, _, pp = rest.partition(":")
        variants.append((label, str(Path(py).absolute()), str(Path(pp).absolute()) if pp else ""))
    res: dict[str, list[tuple[float, float, int, int, int]]] = {label: [] for label, _, _ in variants}
    load0 = os.getloadavg()[0]
    for _ in range(a.rounds):
        for label, py, pp in variants:
            env = dict(os.environ)
            env.pop("PYTHONPATH", None)
            if pp:
                env["PYTHONPATH"] = pp
            o = subprocess.run([py, "-c", CODE], capture_output=True, text=True, check=True, env=env, cwd="/tmp")
            imp, load, hwm, stats, kalman = o.stdout.split()
            res[label].append((float(imp), float(load), int(hwm), int(stats), int(kalman)))
    import bench_rtctl as B

    B._COMMIT_AT_START = B._commit()
    lines = [B._header("rtctl cold import, interleaved variants", "shipped tables"),
             f"Command: `python tests/bench/bench_rtctl_import_compare.py --rounds {a.rounds} "
             + " ".join(f'--variant "{v}"' for v in a.variant) + f"`. Load average at the start {load0:.1f}, at the "
             f"end {os.getloadavg()[0]:.1f} (2 cores; wall-clock times, every variant under the same load).", "",
             "| variant | import rtctl.controller (s): min / median | tables + Controller (s): median | "
             "peak RSS (MB): median | scipy.stats imported | filterpy.kalman imported |", "|---|---|---|---|---|---|"]
    for label, rows in res.items():
        r = np.array(rows, dtype=float)
        lines.append(f"| {label} | {r[:, 0].min():.3f} / {np.median(r[:, 0]):.3f} | {np.median(r[:, 1]):.3f} | "
                     f"{np.median(r[:, 2]) / 1024:.1f} | {'yes' if r[0, 3] else 'no'} | {'yes' if r[0, 4] else 'no'} |")
    text = "\n".join(lines) + "\n"
    print(text)
    from offline.files import write_text

    write_text(Path(a.out), text)


if __name__ == "__main__":
    main()
