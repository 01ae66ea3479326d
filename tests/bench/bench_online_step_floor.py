"""The floor of the online step's time: its irreducible parts alone, at this problem size (issue 20).

One command (from the repository root)::

    python tests/bench/bench_online_step_floor.py [--baseline 40a08e8] [--calls 2000] [--warmup 300]

The closed loop of ``bench_online_step.py timing`` (same script, same seed, rr_steer_stuck with
RR stuck at -50 deg and 3 deg of roll) runs ``--warmup`` steps on this tree; at its last tick the
inputs of the parts that any exact real-time iteration must pay every tick are captured, and each
part is then timed alone, ``--calls`` times (thread CPU, p50 / p99 / mean):

* **residual + Jacobian**: one :meth:`rtctl.physics.steady_state.SteadyStateResidual.evaluate`
  with ``jacobian=True`` at the tick's iterate and parameters (exact residual, objective gradient,
  the rows' Jacobian); inside it, the batched wheel physics
  (:func:`rtctl.physics.terramechanics.wrench_core`) alone;
* **QP**: the tick's QP (Hessian, exact Jacobian, bounds) solved by the step's own solver,
  :func:`rtctl.active_set.solve_active_set` warm-started at the tick's active set; and by OSQP
  set up once on the same QP (:meth:`rtctl.allocator.QpAllocator.problem`, the allocator's
  settings): warm-started at its last answer with only ``q, l, u`` updated, and with the
  Jacobian's values updated as well (``Ax``: one refactorisation, what an exact Jacobian costs
  OSQP every tick); and with OSQP's termination checked every 5 iterations instead of its
  default 25 (the same tolerances: a warm start at the optimum then stops at the first check);
* **EKF**: one :meth:`rtctl.estimator.SlipHeadingEKF.predict` and one ``update_pose`` (the
  controller's estimator, on a copy), and filterpy's ``ExtendedKalmanFilter.predict`` +
  ``update`` alone on the same six states and three measurements (the library's own floor);
* **one numpy operation** on arrays of this size: ``a + b`` on 32 wheel states ``(32, 1)`` and on
  their quadrature nodes ``(32, 48)``, the unit cost that the numpy physics pays per operation.

The floor is the sum (each part's p99, and the p99 of the per-call sum of one residual +
Jacobian, one active-set QP and one EKF predict + update run back to back); the target (half of
the ``--baseline`` step's p99) is measured in the same invocation with ``bench_online_step.py``'s
own timing loop (``--steps 2000``, twice, the better kept). Results:
``tests/bench/results_online_step_floor.md`` (a dated section is added; older ones are kept).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

from bench_online_step import _TIMING_SCRIPT, _meta  # noqa: E402


def _stats(ns: list[int]) -> dict[str, float]:
    a = np.asarray(ns, dtype=float) / 1e3  # us
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "mean": float(a.mean())}


def _time(f: Callable[[], Any], calls: int) -> list[int]:
    out = []
    for _ in range(calls):
        t0 = time.thread_time_ns()
        f()
        out.append(time.thread_time_ns() - t0)
    return out


def _closed_loop(steps: int) -> Any:
    """The timing loop's controller after ``steps`` steps, and the inputs of the last tick's QP."""
    import rtctl.active_set as AS
    import rtctl.allocator as A
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.messages import FailureDeclaration, Measurements, Pose
    from rtctl.table import load_index

    captured: dict[str, Any] = {}
    inner = AS.solve_active_set

    def capture(*a: Any) -> Any:
        captured.setdefault("calls", []).append(a)
        return inner(*a)

    A.solve_active_set = capture  # type: ignore[assignment]
    try:
        tables = {k: v.load() for k, v in load_index(ROOT / "tables" / "index.json").items()}
        ctl = Controller(tables, ControllerConfig())
        fail = (FailureDeclaration("RR", "steer_stuck", math.radians(-50.0)),)
        rng = np.random.default_rng(0)  # as bench_online_step.py's timing loop
        beta = [0.0, 0.0, math.radians(-50.0), 0.0]
        om = [0.03 / 0.063 * 1.1] * 4
        t = x = y = 0.0
        for k in range(steps):
            captured["calls"] = []
            t += 0.2
            x += 0.2 * 0.03
            pose = Pose(t - 0.4, x + rng.normal(0, 0.003), y + rng.normal(0, 0.003), rng.normal(0, 0.01)) if k % 5 == 0 else None
            m = Measurements(t=t, seq=k, wheel_speed=tuple(w + rng.normal(0, 0.01) for w in om), steer_angle=tuple(beta),
                             yaw_rate=rng.normal(0, 0.002), pitch=0.0, roll=math.radians(3.0), pose=pose, failures=fail)
            cmd, _ = ctl.step(m)
            om = [c / 0.063 for c in cmd.rim_speed]
            beta = list(cmd.steer_angle)
    finally:
        A.solve_active_set = inner  # type: ignore[assignment]
    return ctl, captured["calls"], t


def _parts(ctl: Any, qp_calls: list[tuple[Any, ...]], t_end: float, calls: int) -> dict[str, dict[str, float]]:
    import osqp
    from filterpy.kalman import ExtendedKalmanFilter

    import rtctl.physics.steady_state as S
    import rtctl.physics.terramechanics as T
    from rtctl.active_set import solve_active_set
    from rtctl.estimator import Odometry
    from rtctl.messages import Pose

    prep = ctl._prep
    rti = prep.rti
    x, p = rti.iterate.copy(), rti._last_p.copy()
    res = rti.residual
    cap: dict[str, Any] = {}
    inner_wc = S.wrench_core

    def grab(*a: Any) -> Any:
        cap["a"] = a
        return inner_wc(*a)

    S.wrench_core = grab  # type: ignore[assignment]
    try:
        res.evaluate(x, p, jacobian=True)
    finally:
        S.wrench_core = inner_wc  # type: ignore[assignment]
    wa = cap["a"]
    out: dict[str, list[int]] = {}
    out["residual + Jacobian (SteadyStateResidual.evaluate)"] = _time(lambda: res.evaluate(x, p, jacobian=True), calls)
    out["  of which the wheel physics (wrench_core, %d states)" % wa[1].shape[0]] = _time(lambda: T.wrench_core(*wa), calls)
    # the step's QP: the last active-set call of the last tick, warm-started at its guess
    qa = qp_calls[-1]
    out["QP, active set (solve_active_set, warm)"] = _time(lambda: solve_active_set(*qa), calls)
    # OSQP on the same QP, set up once with the allocator's settings, then warm-started each call
    alloc = prep.allocator
    qp = alloc.problem()
    s = alloc.settings
    solver = osqp.OSQP()
    solver.setup(qp.P, qp.q, qp.A, qp.l, qp.u, verbose=False, eps_abs=s.eps, eps_rel=s.eps, max_iter=s.max_iter,
                 polishing=False, warm_starting=True)
    r0 = solver.solve(raise_error=False)
    if r0.info.status_val != osqp.SolverStatus.OSQP_SOLVED:
        raise SystemExit(f"OSQP does not solve the tick's QP: {r0.info.status}")
    xw, yw = np.array(r0.x), np.array(r0.y)
    Ax = qp.A.data.copy()
    iters: list[int] = []

    def osqp_vectors() -> None:
        solver.update(q=qp.q, l=qp.l, u=qp.u)
        solver.warm_start(x=xw, y=yw)
        iters.append(int(solver.solve(raise_error=False).info.iter))

    def osqp_matrix() -> None:
        solver.update(q=qp.q, l=qp.l, u=qp.u, Ax=Ax)
        solver.warm_start(x=xw, y=yw)
        iters.append(int(solver.solve(raise_error=False).info.iter))

    out["QP, OSQP warm (q, l, u updated)"] = _time(osqp_vectors, calls)
    it_vec = float(np.mean(iters))
    iters.clear()
    out["QP, OSQP warm (q, l, u and the Jacobian's values: refactorisation)"] = _time(osqp_matrix, calls)
    it_mat = float(np.mean(iters))
    # OSQP checks termination every 25 iterations by default: a warm start at the optimum costs
    # 25 iterations; checked every 5 (the same tolerances), the same warm start stops after 5
    solver5 = osqp.OSQP()
    solver5.setup(qp.P, qp.q, qp.A, qp.l, qp.u, verbose=False, eps_abs=s.eps, eps_rel=s.eps, max_iter=s.max_iter,
                  polishing=False, warm_starting=True, check_termination=5)
    r5 = solver5.solve(raise_error=False)
    x5, y5 = np.array(r5.x), np.array(r5.y)
    iters.clear()

    def osqp_check5() -> None:
        solver5.update(q=qp.q, l=qp.l, u=qp.u)
        solver5.warm_start(x=x5, y=y5)
        iters.append(int(solver5.solve(raise_error=False).info.iter))

    out["QP, OSQP warm, check_termination = 5 (q, l, u updated)"] = _time(osqp_check5, calls)
    it_5 = float(np.mean(iters))
    # the controller's EKF on a copy: predict by one period, then a pose fix at the predicted pose
    ekf = copy.deepcopy(ctl.ekf)
    clock = [t_end]

    def ekf_step() -> None:
        clock[0] += 0.2
        ekf.predict(clock[0], Odometry(0.03, 1e-6, 0.0, 0.0))
        xs = ekf.x
        ekf.update_pose(Pose(clock[0], float(xs[0]), float(xs[1]), float(xs[2])))

    out["EKF predict + update_pose (the controller's)"] = _time(ekf_step, calls)
    # filterpy alone on the same dimensions
    nx_ekf = len(ctl.ekf.x)
    f = ExtendedKalmanFilter(dim_x=nx_ekf, dim_z=3)
    f.x = np.array(ctl.ekf.x, dtype=float)
    f.P = np.array(ctl.ekf.P, dtype=float)
    f.F = np.eye(nx_ekf)
    f.Q = np.eye(nx_ekf) * 1e-6
    f.R = np.eye(3) * 1e-4
    H = np.zeros((3, nx_ekf))
    H[0, 0] = H[1, 1] = H[2, 2] = 1.0

    def raw_ekf() -> None:
        f.predict()
        f.update(f.x[:3].copy(), lambda _x: H, lambda xx: H @ xx)

    out[f"EKF, filterpy predict + update alone ({nx_ekf} states, 3 measurements)"] = _time(raw_ekf, calls)
    # back to back: the three parts every exact tick pays
    ekf2 = copy.deepcopy(ekf)
    clock2 = [clock[0]]

    def together() -> None:
        res.evaluate(x, p, jacobian=True)
        solve_active_set(*qa)
        clock2[0] += 0.2
        ekf2.predict(clock2[0], Odometry(0.03, 1e-6, 0.0, 0.0))
        xs = ekf2.x
        ekf2.update_pose(Pose(clock2[0], float(xs[0]), float(xs[1]), float(xs[2])))

    out["sum, back to back: residual + Jacobian, active-set QP, EKF"] = _time(together, calls)
    a1, b1 = np.random.default_rng(0).random((32, 1)), np.random.default_rng(1).random((32, 1))
    a2, b2 = np.random.default_rng(0).random((32, 48)), np.random.default_rng(1).random((32, 48))
    out["one numpy operation, a + b on (32, 1)"] = _time(lambda: a1 + b1, calls)
    out["one numpy operation, a + b on (32, 48)"] = _time(lambda: a2 + b2, calls)
    out["one numpy operation, cos on (32, 48)"] = _time(lambda: np.cos(a2), calls)
    out["empty call (the clock's own cost)"] = _time(lambda: None, calls)
    stats = {k: _stats(v) for k, v in out.items()}
    stats["QP, OSQP warm (q, l, u updated)"]["iterations"] = it_vec
    stats["QP, OSQP warm (q, l, u and the Jacobian's values: refactorisation)"]["iterations"] = it_mat
    stats["QP, OSQP warm, check_termination = 5 (q, l, u updated)"]["iterations"] = it_5
    stats["_sizes"] = {"nx": float(alloc.nx), "ng": float(alloc.ng), "osqp_n": float(alloc.n), "osqp_m": float(alloc.m)}
    return stats


def _baseline(baseline: str, steps: int) -> dict[str, Any]:
    index = str(ROOT / "tables" / "index.json")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        wt = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt), baseline], check=True,
                       capture_output=True)
        try:
            for _ in range(2):
                env = {**os.environ, "PYTHONPATH": str(wt)}
                r = subprocess.run([sys.executable, "-c", _TIMING_SCRIPT, str(wt), str(steps), index, "0"],
                                   capture_output=True, text=True, env=env, cwd=str(wt))
                if r.returncode != 0:
                    raise SystemExit(f"baseline run failed:\n{r.stderr[-3000:]}")
                runs.append(json.loads(r.stdout.strip().splitlines()[-1]))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)], capture_output=True)
    return min(runs, key=lambda r: r["p99"])


def append_section(name: str, title: str, md: str, data: dict[str, Any]) -> None:
    """Add ``md`` as a new section of ``tests/bench/<name>.md`` (titled ``title`` when new; the
    sections of earlier runs are kept) and write ``data`` to ``<name>.json`` (this run's)."""
    from offline.files import write_text

    path = HERE / f"{name}.md"
    before = path.read_text().rstrip("\n") + "\n\n" if path.exists() else f"# {title}\n\n"
    write_text(path, before + md + "\n")
    write_text(HERE / f"{name}.json", json.dumps(data, indent=1, sort_keys=True) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default="40a08e8")
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--warmup", type=int, default=300)
    args = ap.parse_args()
    meta = _meta()
    base = _baseline(args.baseline, 2000)
    ctl, qp_calls, t_end = _closed_loop(args.warmup)
    stats = _parts(ctl, qp_calls, t_end, args.calls)
    sizes = stats.pop("_sizes")
    target = 0.5 * base["p99"] * 1e3  # us
    floor = stats["sum, back to back: residual + Jacobian, active-set QP, EKF"]
    lines = [f"## {meta['date'][:16].replace('T', ' ')} UTC, {meta['commit']}", "",
             f"`python tests/bench/bench_online_step_floor.py --baseline {args.baseline} --calls {args.calls} "
             f"--warmup {args.warmup}`; {meta['machine']}, {meta['cpus']} cpus; thread CPU per call, us (ratios "
             "between rows of one run are what carry over to another machine).", "",
             f"Problem size: nx = {sizes['nx']:.0f} variables, ng = {sizes['ng']:.0f} rows (OSQP's soft form: "
             f"{sizes['osqp_n']:.0f} variables, {sizes['osqp_m']:.0f} constraints).", "",
             f"Baseline {args.baseline}, its whole step in the timing loop (2000 steps, better of two): p99 "
             f"{base['p99'] * 1e3:.0f} us, p50 {base['p50'] * 1e3:.0f} us; the target (half its p99): "
             f"**{target:.0f} us**.", "",
             "| part | p50 | p99 | mean | p99 / target |", "|---|---|---|---|---|"]
    for k, v in stats.items():
        extra = f" ({v['iterations']:.1f} iterations)" if "iterations" in v else ""
        lines.append(f"| {k}{extra} | {v['p50']:.1f} | {v['p99']:.1f} | {v['mean']:.1f} | {v['p99'] / target:.2f} |")
    lines += ["", f"The three parts every exact tick pays, back to back (residual + Jacobian, the active-set QP, the "
              f"EKF): p99 **{floor['p99']:.0f} us = {floor['p99'] / target:.2f} of the target**, before the "
              "preparation (table read, structured Hessian), the bounds, the outer loop, the checks and the "
              "messages.", ""]
    md = "\n".join(lines)
    append_section("results_online_step_floor", "The floor of the online step's time at this problem size (issue 20)", md,
                   {"meta": meta, "baseline": base, "parts": stats, "sizes": sizes})
    print(md)


if __name__ == "__main__":
    main()
