"""Issue 25, safety: what one poisoned measurement costs the controller.

Drives the controller on the synthetic linear-rover tables (``tests/rtctl_synthetic.py``) with
300 valid measurements at 5 Hz and one poisoned measurement in the middle (tick 150), for each
poison of the issue (a time stamp of 1e300, one hour or 1e6 s ahead, a sequence number jumped
by 2**62 or 1e6, and values that are not finite real numbers: 10**400 as an int in each numeric
field, the string '1234' as a wheel speed). Reports, per poison, whether ``step`` raised, how
many of the ticks after the poisoned one were held (``mode == "hold"``), and whether the string
wheel speed was used. Writes ``tests/bench/results_rtctl_poison.md``::

    python tests/bench/bench_rtctl_poison.py [--out FILE]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from offline.files import write_text  # noqa: E402
from rtctl.config import ControllerConfig  # noqa: E402
from rtctl.controller import Controller  # noqa: E402
from rtctl.messages import FailureDeclaration, Measurements, Pose, Task  # noqa: E402
from rtctl_synthetic import RS, synthetic_tables  # noqa: E402

OM = 0.03 / (RS * 0.9)
N, K = 300, 150


def meas(k: int) -> Measurements:
    return Measurements(t=0.2 * k, seq=k, wheel_speed=(OM,) * 4, steer_angle=(0.0,) * 4, yaw_rate=0.0)


BIG = 10 ** 400
POISONS = {
    "t = 1e300": lambda m: replace(m, t=1e300),
    "t one hour ahead": lambda m: replace(m, t=m.t + 3600.0),
    "t 1e6 s ahead": lambda m: replace(m, t=m.t + 1e6),
    "seq + 2**62": lambda m: replace(m, seq=m.seq + 2 ** 62),
    "seq + 1e6": lambda m: replace(m, seq=m.seq + 10 ** 6),
    "t = 10**400 (int)": lambda m: replace(m, t=BIG),
    "yaw_rate = 10**400": lambda m: replace(m, yaw_rate=BIG),
    "roll = 10**400": lambda m: replace(m, roll=BIG),
    "wheel speed = 10**400": lambda m: replace(m, wheel_speed=(BIG, OM, OM, OM)),
    "pose.x = 10**400": lambda m: replace(m, pose=Pose(m.t, BIG, 0.0, 0.0)),
    "failure value = 10**400": lambda m: replace(m, failures=(FailureDeclaration("RR", "torque_limit", BIG),)),
    "task value = 10**400": lambda m: replace(m, task=Task("trench", "RR", BIG)),
    "wheel speed '1234' (str)": lambda m: replace(m, wheel_speed=("1234", OM, OM, OM)),
    "wheel speed str(OM) (a plausible value as str)": lambda m: replace(m, wheel_speed=(str(OM), OM, OM, OM)),
}


def run(tables: dict, poison) -> dict:
    c = Controller(tables, ControllerConfig())
    raised, held_after, str_used = "", 0, False
    for k in range(N):
        m = meas(k)
        if k == K:
            m = poison(m)
        try:
            _, d = c.step(m)
        except Exception as exc:  # noqa: BLE001 - what the bench measures
            raised = raised or f"{type(exc).__name__} at tick {k}"
            continue
        if k == K:
            str_used = isinstance(m.wheel_speed[0], str) and d.counter("rejected_wheel_FR") == 0 \
                and d.counter("rejected_wheel_vectors") == 0 and d.mode != "hold"
        if k > K and d.mode == "hold":
            held_after += 1
    return {"raised": raised or "no", "held_after": held_after, "str_used": str_used}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results_rtctl_poison.md"))
    a = ap.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=HERE).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        tables = synthetic_tables(Path(tmp))
        rows = [(name, run(tables, p)) for name, p in POISONS.items()]
    lines = [f"# One poisoned measurement among {N} valid ones (tick {K}), commit {commit}", "",
             "`python tests/bench/bench_rtctl_poison.py` (synthetic linear-rover tables)", "",
             f"| poison | step raised | ticks held after it (of {N - K - 1}) | string wheel speed used |",
             "|---|---|---|---|"]
    for name, r in rows:
        lines.append(f"| {name} | {r['raised']} | {r['held_after']} | {'yes' if r['str_used'] else 'no'} |")
    text = "\n".join(lines) + "\n"
    print(text)
    write_text(Path(a.out), text)


if __name__ == "__main__":
    main()
