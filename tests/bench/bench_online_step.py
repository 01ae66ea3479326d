"""The online step against the NLP solved at the same point (issue 20), and its step time.

One command each; results go to ``tests/bench/results_online_step_<part>.md`` and ``.json``::

    python tests/bench/bench_online_step.py accuracy [--points 20] [--seed 0] [--tables a,b] [--qp k=v,...]
                                                     [--references refs.json]
    python tests/bench/bench_online_step.py timing   [--baseline 40a08e8] [--steps 3000] [--tag main]
    python tests/bench/bench_online_step.py restart  TABLE.npz [...] [--tag x]

``accuracy``: on every shipped table with primitives, ``--points`` seeded operating points
strictly inside cells whose corners all hold primitives (every axis between two grid values),
plus cross slopes of 3, 4.5, 6 and 8 deg on ``rr_steer_stuck`` (built at cross slope 0 only:
beyond its axis). At each point the reference is the NLP (7.25) solved there
(:func:`offline.rover.primitives.solve_primitive`, its own multi-start strategy started from the
table's interpolated primitive; a point is used only where the result passes the optimizer's
independent check). The online step (:class:`rtctl.rti.RealTimeIteration`, the controller's own
iteration, here without the rover's rate limits) starts from the table's interpolated primitive
and runs at the point's exact parameters; after one tick its iterate's residual is judged by the
independent check (:func:`offline.rover.primitives.check_solution`: numpy wheel model, free-body
balance with explicit 3-D geometry), after five its wheel speeds, steering and objective are
compared with the NLP optimum. The interpolated primitive itself (what the QP of the previous
design converged to between grid points, since it took the interpolated residual as exact) is
judged the same way, as the baseline column.

``timing``: the controller's ``step`` in closed loop with the kinematic rover of
``tests/test_rtctl_controller.py`` on ``rr_steer_stuck`` (RR stuck at -50 deg), thread CPU time per
step, for this tree and for ``--baseline`` (a commit, checked out into a temporary worktree) run
one after the other in the same invocation, so the machine cancels out; the shares of the new step
(exact linearisation, QP solve, preparation, the rest) are measured with the same clock.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

DEG = math.pi / 180


def _meta() -> dict[str, Any]:
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                                capture_output=True, text=True).stdout.strip())
    return {"commit": rev + ("+changes" if dirty else ""), "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()}


_TAG = ""


def _write(part: str, md: str, data: dict[str, Any]) -> None:
    sys.path.insert(0, str(ROOT))
    from offline.files import write_text

    name = f"results_online_step_{part}{'_' + _TAG if _TAG else ''}"
    write_text(HERE / f"{name}.md", md)
    write_text(HERE / f"{name}.json", json.dumps(data, indent=1, sort_keys=True) + "\n")
    print(f"wrote tests/bench/{name}.md and .json")


# ---------------------------------------------------------------------------------- accuracy
def _inner_points(t: Any, n: int, rng: np.random.Generator) -> list[dict[str, float]]:
    """``n`` operating points strictly inside cells whose corners are all feasible."""
    multi = [i for i, m in enumerate(t.shape) if m > 1]
    cells = []
    for c in np.ndindex(*[max(m - 1, 1) for m in t.shape]):
        ok = True
        for b in range(2 ** len(multi)):
            k = list(c)
            for j, a in enumerate(multi):
                k[a] += (b >> j) & 1
            ok = ok and bool(t.feasible[tuple(k)])
        if ok:
            cells.append(c)
    out: list[dict[str, float]] = []
    if not cells:
        return out
    for _ in range(n):
        c = cells[int(rng.integers(len(cells)))]
        op = {}
        for i, k in enumerate(t.axis_order):
            ax = t.axes[k]
            if len(ax) == 1:
                op[k] = float(ax[0])
            else:
                u = float(rng.uniform(0.2, 0.8))  # between grid values, never on one
                op[k] = float(ax[c[i]] + u * (ax[c[i] + 1] - ax[c[i]]))
        out.append(op)
    return out


def _judge(pb: Any, sc: Any, x: np.ndarray, xsc: np.ndarray) -> dict[str, float]:
    from offline.rover.primitives import check_solution

    res, _ = check_solution(pb, sc, x / xsc)
    force = max(abs(v) for k, v in res.items() if k in ("balance Fx", "balance Fy", "balance Fz"))
    moment = max(abs(v) for k, v in res.items() if k.startswith("balance M"))
    load = max([abs(v) for k, v in res.items() if k.startswith(("load ", "zero-slip load "))] or [0.0])
    return {"force_N": force, "moment_Nm": moment, "load_N": load}


def _compare(lay: Any, x: np.ndarray, xstar: np.ndarray, f: float, fstar: float) -> dict[str, float]:
    om = np.array([lay.var("omega", w) for w in lay.wheels])
    be = np.array([lay.var("beta", w) for w in lay.wheels])
    floor = 0.05 * lay.variable_scale[om]  # a locked wheel's speed is compared absolutely
    dw = np.abs(x[om] - xstar[om]) / np.maximum(np.abs(xstar[om]), floor)
    return {"wheel_speed_rel": float(dw.max()), "steer_deg": float(np.abs(x[be] - xstar[be]).max() / DEG),
            "objective_rel": float(abs(f - fstar) / max(abs(fstar), 1e-12))}


def accuracy(points: int, seed: int, only: list[str] | None, qp: dict[str, Any] | None = None,
             ticks_n: int = 5, references: str | None = None) -> None:
    sys.path.insert(0, str(ROOT))
    from offline.rover.primitives import check_solution, solve_primitive
    from offline.rover.table_builder import _problem, scenario_at
    from offline.rover.table_verify import spec_from_table
    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_index

    idx = load_index(ROOT / "tables" / "index.json")
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    # the NLP references per point (status, best optimum, the table branch's local optimum): read
    # from and added to ``references`` when given, so that a sweep of the online step's settings
    # needs the NLP solves once (they are most of this benchmark's time)
    ref_path = Path(references) if references else None
    cache: dict[str, Any] = json.loads(ref_path.read_text()) if (ref_path is not None and ref_path.exists()) else {}
    cached = 0
    t_start = time.perf_counter()
    for name, info in sorted(idx.items()):
        if only and name not in only:
            continue
        t = info.load()
        if not t.feasible.any():
            print(f"{name}: no primitive in the table, skipped")
            continue
        spec = spec_from_table(t)
        pb = _problem(spec.scenario, spec.solver)
        lay = t.layout
        xsc = np.asarray(lay.variable_scale)
        ops = [("between grid values", op) for op in _inner_points(t, points, rng)]
        if name == "rr_steer_stuck":
            for cs in (3.0, 4.5, 6.0, 8.0):
                base = _inner_points(t, 1, rng)[0]
                ops.append((f"cross slope {cs:g} deg (beyond the axis)", {**base, "cross_slope": cs * DEG}))
        for kind, op in ops:
            sc = scenario_at(spec.scenario, spec.family, op)
            tp = t.at(**op)
            key = f"{name} {json.dumps(op, sort_keys=True)}"
            hit = cache.get(key)
            t0 = time.perf_counter()
            if hit is None:
                r = solve_primitive(sc, spec.solver, x0=tp.x / xsc)
                hit = {"status": r.status, "xstar": (np.asarray(r.x, dtype=float) * xsc).tolist() if r.status == "optimal" else None}
                if r.status == "optimal":
                    # the optimum of the table's own branch: one local IPOPT solve from the interpolated
                    # primitive (the multi-start reference above may sit in another basin of this nonconvex NLP)
                    loc = pb.solve(pb.bounds(sc), tp.x / xsc)
                    ok_loc = bool(loc["success"]) and bool(check_solution(pb, sc, loc["x"])[1])
                    hit["xloc"] = (np.asarray(loc["x"], dtype=float) * xsc).tolist() if ok_loc else None
                cache[key] = hit
            else:
                cached += 1
            nlp_s = time.perf_counter() - t0
            row: dict[str, Any] = {"table": name, "kind": kind, "op": {k: round(v, 6) for k, v in op.items()},
                                   "nlp_status": hit["status"], "nlp_seconds": round(nlp_s, 2)}
            if hit["status"] != "optimal":
                rows.append(row)
                print(f"{name} {kind}: NLP {hit['status']}, point not used")
                continue
            xstar = np.asarray(hit["xstar"], dtype=float)
            xloc = np.asarray(hit["xloc"], dtype=float) if hit.get("xloc") is not None else None
            settings = replace(QpSettings(), **(qp or {}))
            rti = RealTimeIteration(t, settings, [lay.index(f"wheel torque {w}") for w in lay.wheels])
            rti.prepare(tp)
            p = np.array(tp.p, dtype=float)
            for k in ("speed", "slope", "cross_slope"):
                if k in op:
                    p[lay.index(k)] = op[k]
            _, fstar = rti.residual.residual(xstar, p) if rti.residual else (None, math.nan)
            floc = rti.residual.residual(xloc, p)[1] if (rti.residual and xloc is not None) else math.nan
            row["baseline_interpolated"] = {**_judge(pb, sc, tp.x, xsc),
                                            **_compare(lay, tp.x, xstar, rti.residual.residual(tp.x, p)[1], fstar)}
            ticks = []
            for k in range(ticks_n):
                x = rti.iterate if rti.iterate is not None else rti.allocator.x0
                sl = settings.step_limit
                box = merge_bounds(tp.lbx, tp.ubx, (x - sl * xsc, x + sl * xsc))
                res = rti.step(p, box)
                if not res.ok:
                    row["rti_refused"] = f"tick {k + 1}: {res.status}"
                    break
                f = rti.residual.residual(res.x, p)[1]
                tick = {**_judge(pb, sc, res.x, xsc), **_compare(lay, res.x, xstar, f, fstar),
                        "slack": res.slack, "qp_iterations": res.iterations}
                if xloc is not None:
                    tick["local"] = _compare(lay, res.x, xloc, f, floc)
                ticks.append(tick)
            row["ticks"] = ticks
            if len(ticks) >= 5:
                # the online step's own tick-5 command, where it passes the independent check at a
                # lower objective than the NLP's reference: a better verified optimum (the reference
                # is the best of several IPOPT starts, not a global one)
                x5 = np.asarray(res.x, dtype=float)
                f5 = rti.residual.residual(x5, p)[1]
                if f5 < fstar * (1.0 - 1e-6) and bool(check_solution(pb, sc, x5 / xsc)[1]):
                    row["online_better_objective_rel"] = float((f5 - fstar) / fstar)
            row["local_reference"] = xloc is not None
            row["local_is_best"] = bool(xloc is not None and floc <= fstar * (1 + 1e-6))
            rows.append(row)
            last = ticks[-1] if ticks else {}
            print(f"{name} {kind}: NLP {nlp_s:.1f} s; tick 1 force {ticks[0]['force_N'] if ticks else float('nan'):.2g} N; "
                  f"tick 5 speeds {last.get('wheel_speed_rel', float('nan')):.2%}, steer {last.get('steer_deg', float('nan')):.3f} deg, "
                  f"objective {last.get('objective_rel', float('nan')):.2%}", flush=True)
    used = [r for r in rows if r.get("ticks")]
    refused = [r for r in rows if r.get("rti_refused")]
    lim1 = {"force_N": 0.1, "moment_Nm": 0.01, "load_N": 0.2}
    lim5 = {"wheel_speed_rel": 0.02, "steer_deg": 0.3, "objective_rel": 0.005}

    def ok1(r: dict[str, Any]) -> bool:
        return bool(r["ticks"]) and all(r["ticks"][0][k] <= v for k, v in lim1.items())

    def ok5(r: dict[str, Any]) -> bool:
        return len(r["ticks"]) >= 5 and all(r["ticks"][4][k] <= v for k, v in lim5.items())

    def ok5_best(r: dict[str, Any]) -> bool:
        return ok5(r) or "online_better_objective_rel" in r

    def ok5_local(r: dict[str, Any]) -> bool:
        return (len(r["ticks"]) >= 5 and "local" in r["ticks"][4]
                and all(r["ticks"][4]["local"][k] <= v for k, v in lim5.items()))

    def base_ok1(r: dict[str, Any]) -> bool:
        return all(r["baseline_interpolated"][k] <= v for k, v in lim1.items())

    def base_ok5(r: dict[str, Any]) -> bool:
        return all(r["baseline_interpolated"][k] <= v for k, v in lim5.items())

    lines = ["# The online step against the NLP at the same point (issue 20)", "",
             f"`python tests/bench/bench_online_step.py accuracy --points {points} --seed {seed}"
             + (f" --tables {','.join(only)}" if only else "") + (f" --ticks {ticks_n}" if ticks_n != 5 else "")
             + (f" --tag {_TAG}" if _TAG else "")
             + (f" --qp {','.join(f'{k}={v}' for k, v in (qp or {}).items())}" if qp else "")
             + (f" --references {ref_path.name}" if ref_path is not None else "") + "`; "
             f"{_meta()['commit']}, {_meta()['date']}, {time.perf_counter() - t_start:.0f} s"
             + (f" (NLP references of {cached} points read from {ref_path.name})" if cached else "") + ".", "",
             "Targets: after 1 tick the iterate's residual by the independent check <= 0.1 N force, 0.01 N m moment, "
             "0.2 N load; after 5 ticks wheel speeds within 2 %, steering within 0.3 deg, objective within 0.5 % of "
             "the NLP optimum. Baseline: the table's interpolated primitive (the previous design's answer between "
             "grid points).", "",
             f"Points: {len(rows)} drawn, {len(used)} with a verified NLP optimum used, {len(refused)} where the "
             f"online step's QP was refused.", "",
             "| table | points | tick-1 residual within targets | tick-5 within targets | tick-5 within targets of the "
             "table branch's local optimum | worst tick-1 force / moment / load "
             "| worst tick-5 speed / steer / objective | baseline: residual within / optimum within |",
             "|---|---|---|---|---|---|---|---|"]
    for name in sorted({r["table"] for r in used}):
        rs = [r for r in used if r["table"] == name]
        for kind in sorted({r["kind"] for r in rs}, key=lambda s: (s != "between grid values", s)):
            sub = [r for r in rs if r["kind"] == kind]
            t1 = [r["ticks"][0] for r in sub]
            t5 = [r["ticks"][min(4, len(r["ticks"]) - 1)] for r in sub]
            lines.append(
                f"| {name} ({kind}) | {len(sub)} | {sum(ok1(r) for r in sub)}/{len(sub)} | {sum(ok5(r) for r in sub)}/{len(sub)} | "
                f"{sum(ok5_local(r) for r in sub)}/{sum(bool(r.get('local_reference')) for r in sub)} | "
                f"{max(a['force_N'] for a in t1):.2g} N / {max(a['moment_Nm'] for a in t1):.2g} N m / "
                f"{max(a['load_N'] for a in t1):.2g} N | {max(a['wheel_speed_rel'] for a in t5):.2%} / "
                f"{max(a['steer_deg'] for a in t5):.3f} deg / {max(a['objective_rel'] for a in t5):.3%} | "
                f"{sum(base_ok1(r) for r in sub)}/{len(sub)} / {sum(base_ok5(r) for r in sub)}/{len(sub)} |")
    lines += ["", f"All: tick-1 {sum(ok1(r) for r in used)}/{len(used)}, tick-5 {sum(ok5(r) for r in used)}/{len(used)} "
              f"(against the local optimum of the table's branch {sum(ok5_local(r) for r in used)}/"
              f"{sum(bool(r.get('local_reference')) for r in used)}; the local optimum is the best found at "
              f"{sum(bool(r.get('local_is_best')) for r in used)} points); "
              f"baseline {sum(base_ok1(r) for r in used)}/{len(used)} and {sum(base_ok5(r) for r in used)}/{len(used)}.", "",
              f"Against the best verified optimum (the NLP reference, or the online step's own tick-5 command where it "
              f"passes the independent check at a lower objective): tick-5 {sum(ok5_best(r) for r in used)}/{len(used)}"
              + ("; the online step's command better than the reference at " + "; ".join(
                  f"{r['table']} {r['op']} (objective {r['online_better_objective_rel']:+.2%})"
                  for r in used if "online_better_objective_rel" in r) if any("online_better_objective_rel" in r for r in used)
                 else "") + ".", ""]
    if refused:
        lines += ["Refused: " + "; ".join(f"{r['table']} {r['op']}: {r['rti_refused']}" for r in refused), ""]
    if ref_path is not None and len(cache) > cached:
        from offline.files import write_text

        write_text(ref_path, json.dumps(cache, sort_keys=True) + "\n")
        print(f"wrote the NLP references of {len(cache)} points to {ref_path}")
    _write("accuracy", "\n".join(lines), {"meta": _meta(), "rows": rows})


# ---------------------------------------------------------------------------------- timing
_TIMING_SCRIPT = r'''
import json, math, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1] + "/tests")
sys.path.insert(0, sys.argv[1])
from rtctl.config import ControllerConfig
from rtctl.controller import Controller
from rtctl.messages import FailureDeclaration, Measurements, Pose
from rtctl.table import load_index
steps = int(sys.argv[2])
tables = {k: v.load() for k, v in load_index(sys.argv[3]).items()}
ctl = Controller(tables, ControllerConfig())
shares = {}
probe = sys.argv[4] == "1"
if probe:
    import rtctl.rti as R, rtctl.allocator as A, rtctl.controller as C
    def wrap(obj, name, key):
        f = getattr(obj, name)
        def g(*a, **k):
            t0 = time.thread_time_ns(); out = f(*a, **k); shares[key] = shares.get(key, 0) + time.thread_time_ns() - t0
            return out
        setattr(obj, name, g)
    wrap(R.RealTimeIteration, "linearise", "exact linearisation")
    wrap(A.QpAllocator, "solve_at", "QP (update, warm start, solve)")
    wrap(C.Controller, "prepare", "preparation (table read, Hessian, factorisation)")
fail = (FailureDeclaration("RR", "steer_stuck", math.radians(-50.0)),)
rng = np.random.default_rng(0)
beta = [0.0, 0.0, math.radians(-50.0), 0.0]
om = [0.03 / 0.063 * 1.1] * 4
t = 0.0; x = y = psi = 0.0
times = []
for k in range(steps):
    t += 0.2
    x += 0.2 * 0.03 * math.cos(psi); y += 0.2 * 0.03 * math.sin(psi)
    pose = Pose(t - 0.4, x + rng.normal(0, 0.003), y + rng.normal(0, 0.003), psi + rng.normal(0, 0.01)) if k % 5 == 0 else None
    m = Measurements(t=t, seq=k, wheel_speed=tuple(w + rng.normal(0, 0.01) for w in om), steer_angle=tuple(beta),
                     yaw_rate=rng.normal(0, 0.002), pitch=0.0, roll=math.radians(3.0), pose=pose, failures=fail)
    t0 = time.thread_time_ns()
    cmd, d = ctl.step(m)
    times.append(time.thread_time_ns() - t0)
    om = [c / 0.063 for c in cmd.rim_speed]
    beta = list(cmd.steer_angle)
    psi += 0.2 * 0.0
times = np.array(times[50:]) / 1e6
print(json.dumps({"p50": float(np.percentile(times, 50)), "p99": float(np.percentile(times, 99)),
                  "max": float(times.max()), "mean": float(times.mean()), "n": int(times.size),
                  "shares": {k: v / 1e6 / steps for k, v in shares.items()}}))
'''


def timing(baseline: str, steps: int) -> None:
    out: dict[str, Any] = {"meta": _meta(), "baseline": baseline, "steps": steps}
    index = str(ROOT / "tables" / "index.json")
    with tempfile.TemporaryDirectory() as tmp:
        wt = Path(tmp) / "baseline"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(wt), baseline], check=True,
                       capture_output=True)
        try:
            runs = {}
            order = [("baseline", wt, "0"), ("new", ROOT, "0"), ("baseline (again)", wt, "0"), ("new (again)", ROOT, "0"),
                     ("new, shares", ROOT, "1")]
            if (wt / "rtctl" / "rti.py").exists():  # a baseline with the same parts: its shares too, same clock
                order.append(("baseline, shares", wt, "1"))
            for label, tree, probe in order:
                env = {**os.environ, "PYTHONPATH": str(tree)}
                r = subprocess.run([sys.executable, "-c", _TIMING_SCRIPT, str(tree), str(steps), index, probe],
                                   capture_output=True, text=True, env=env, cwd=str(tree))
                if r.returncode != 0:
                    raise SystemExit(f"{label} run failed:\n{r.stderr[-3000:]}")
                runs[label] = json.loads(r.stdout.strip().splitlines()[-1])
                print(label, runs[label], flush=True)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(wt)], capture_output=True)
    out["runs"] = runs
    b = min(runs["baseline"]["p99"], runs["baseline (again)"]["p99"])
    n = min(runs["new"]["p99"], runs["new (again)"]["p99"])
    sh = runs["new, shares"]["shares"]
    tot = runs["new, shares"]["mean"]
    lines = ["# Step time of the online step against the previous design (issue 20)", "",
             f"`python tests/bench/bench_online_step.py timing --baseline {baseline} --steps {steps}`; "
             f"{out['meta']['commit']}, {out['meta']['date']}, {out['meta']['machine']}, {out['meta']['cpus']} cpus.", "",
             "Thread CPU time per `Controller.step` (feedback + preparation), closed loop, RR stuck at -50 deg on "
             "rr_steer_stuck with 3 deg of roll, first 50 steps dropped; each tree run twice, alternating, in this "
             "invocation (the better of the two kept).", "",
             "| run | p50 [ms] | p99 [ms] | max [ms] | mean [ms] |", "|---|---|---|---|---|"]
    for k, v in runs.items():
        lines.append(f"| {k} | {v['p50']:.3f} | {v['p99']:.3f} | {v['max']:.3f} | {v['mean']:.3f} |")
    lines += ["", f"p99 ratio new / baseline: **{n / b:.2f}** (target <= 0.5).", "",
              "Shares of the new step (mean per step, same clock; the probe's own overhead is in the mean):", "",
              "| part | ms | share |", "|---|---|---|"]
    base_sh = runs.get("baseline, shares")
    if base_sh is not None:
        lines[-2:] = ["| part | new ms | new share | baseline ms | baseline share |", "|---|---|---|---|---|"]
    for k, v in sorted(sh.items(), key=lambda kv: -kv[1]):
        row = f"| {k} | {v:.3f} | {v / tot:.0%} |"
        if base_sh is not None:
            bv = base_sh["shares"].get(k, float("nan"))
            row += f" {bv:.3f} | {bv / base_sh['mean']:.0%} |"
        lines.append(row)
    rest = tot - sum(sh.values())
    row = f"| the rest (structured Hessian, EKF, outer loop, bounds, checks) | {rest:.3f} | {rest / tot:.0%} |"
    if base_sh is not None:
        brest = base_sh["mean"] - sum(base_sh["shares"].values())
        row += f" {brest:.3f} | {brest / base_sh['mean']:.0%} |"
    lines.append(row)
    _write("timing", "\n".join(lines) + "\n", out)


def restart(tables: list[str]) -> None:
    """Thread CPU of a restart (``prepare`` and the first tick) at every cell centre of each table,
    with the default settings and without the continuation (``restart_continuation_stages = 0``),
    best of two runs each (the continuation of issue 22 costs iterations on a restart only); and
    the restart spread over ticks as the controller runs it (``QpSettings.restart_work_per_tick``):
    per tick a ``step`` (refused while the restart is in progress: the controller's fallback) and
    a ``prepare`` with the budget, from the tick whose preparation begins the restart to the
    first tick that commands the QP; the worst such tick per centre, and the number of ticks."""
    sys.path.insert(0, str(ROOT))
    from offline.rover.table_verify import feasible_cells
    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_table

    lines = ["# A restart's first tick: thread CPU (issue 22)", "",
             f"`python tests/bench/bench_online_step.py restart {' '.join(tables)}`; {_meta()['commit']}, "
             f"{_meta()['date']}. Every cell centre (corners all feasible) of each table; prepare + the first tick, "
             "thread CPU, best of 2; spread: the worst tick of the restart (step + prepare with the budget).", "",
             "| table | centres | with the continuation, in one tick: median / p90 / max ms | without: median / p90 / "
             f"max ms | spread, {QpSettings().restart_work_per_tick} units a tick, worst tick: median / p90 / max ms | "
             "ticks until the QP commands: median / max |", "|---|---|---|---|---|---|"]
    data: dict[str, Any] = {"meta": _meta(), "tables": {}}
    for path in tables:
        t = load_table(path)
        lay = t.layout
        xsc = np.asarray(lay.variable_scale)
        keep = [lay.index(f"wheel torque {w}") for w in lay.wheels]
        ops = [{k: float(0.5 * (t.axes[k][i] + t.axes[k][i + 1])) if len(t.axes[k]) > 1 else float(t.axes[k][0])
                for k, i in zip(t.axis_order, c)} for c in feasible_cells(t)]
        row: dict[str, list[float]] = {}
        for name, settings in (("continuation", QpSettings()),
                               ("none", replace(QpSettings(), restart_continuation_stages=0))):
            ms = []
            for op in ops:
                tp = t.at(**op)
                p = np.array(tp.p, dtype=float)
                best = math.inf
                for _ in range(2):
                    rti = RealTimeIteration(t, settings, keep)
                    c0 = time.thread_time()
                    rti.prepare(tp)
                    x = rti.iterate if rti.iterate is not None else rti.allocator.x0
                    rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - settings.step_limit * xsc, x + settings.step_limit * xsc)))
                    best = min(best, (time.thread_time() - c0) * 1e3)
                ms.append(best)
            row[name] = ms
        s0 = QpSettings()
        worst, nticks = [], []
        for op in ops:
            tp = t.at(**op)
            p = np.array(tp.p, dtype=float)
            best, n = math.inf, 0
            for _ in range(2):
                rti = RealTimeIteration(t, s0, keep)
                c0 = time.thread_time()
                rti.prepare(tp, s0.restart_work_per_tick)  # the tick whose preparation begins the restart
                ticks = [time.thread_time() - c0]
                while True:
                    c0 = time.thread_time()
                    x = rti.iterate if rti.iterate is not None else rti.allocator.x0
                    rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x - s0.step_limit * xsc, x + s0.step_limit * xsc)))
                    started = not rti.restarting
                    rti.prepare(tp, s0.restart_work_per_tick)
                    ticks.append(time.thread_time() - c0)
                    if started or len(ticks) > 100:
                        break
                if not started:
                    raise RuntimeError(f"{t.name} at {op}: the restart did not finish in 100 ticks")
                best, n = min(best, max(ticks) * 1e3), len(ticks) - 1
            worst.append(best)
            nticks.append(n)
        row["spread"] = worst
        data["tables"][t.name] = {**row, "spread_ticks": nticks}
        if not ops:
            continue
        q = {k: (float(np.median(v)), float(np.percentile(v, 90)), float(np.max(v))) for k, v in row.items()}
        lines.append(f"| {t.name} | {len(ops)} | " + " | ".join("{:.1f} / {:.1f} / {:.1f}".format(*q[k])
                                                               for k in ("continuation", "none", "spread"))
                     + f" | {float(np.median(nticks)):.0f} / {max(nticks)} |")
        print(lines[-1], flush=True)
    _write("restart", "\n".join(lines) + "\n", data)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="part", required=True)
    a = sub.add_parser("accuracy", help="the online step against the NLP at off-grid points")
    a.add_argument("--points", type=int, default=20)
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--tables", default="", help="comma list of table names (default: all shipped)")
    a.add_argument("--qp", default="", help="QP settings to override, e.g. step_limit=1,regularization=1e-4")
    a.add_argument("--ticks", type=int, default=5, help="ticks per point (targets are judged at ticks 1 and 5)")
    a.add_argument("--tag", default="", help="suffix of the results file names")
    a.add_argument("--references", default="", help="JSON file of the NLP references per point: read, and the "
                   "missing ones added (a settings sweep solves the NLPs once)")
    t = sub.add_parser("timing", help="step time against a baseline commit, side by side")
    t.add_argument("--baseline", default="40a08e8")
    t.add_argument("--steps", type=int, default=3000)
    t.add_argument("--tag", default="", help="suffix of the results file names (e.g. main for --baseline main)")
    r = sub.add_parser("restart", help="thread CPU of a restart's first tick at every cell centre")
    r.add_argument("tables", nargs="+", help="table files")
    r.add_argument("--tag", default="", help="suffix of the results file names")
    args = ap.parse_args()
    global _TAG
    if args.part == "accuracy":
        qp: dict[str, Any] = {}
        for item in (s for s in args.qp.split(",") if s):
            k, _, v = item.partition("=")
            qp[k] = v.lower() == "true" if v.lower() in ("true", "false") else (int(v) if v.lstrip("-").isdigit() else float(v))
        _TAG = args.tag
        accuracy(args.points, args.seed, [s for s in args.tables.split(",") if s] or None, qp, args.ticks,
                 args.references or None)
    elif args.part == "restart":
        _TAG = args.tag
        restart(args.tables)
    else:
        _TAG = args.tag
        timing(args.baseline, args.steps)


if __name__ == "__main__":
    main()
