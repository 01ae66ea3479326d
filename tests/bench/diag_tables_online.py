"""Why the online step fails at a cell centre (issue 22): closer starts, and the exact curvature.

At the centre of cell CELL (lower-corner indices, as ``table_verify.feasible_cells`` lists them) of
TABLE: the best verified optimum ``x*`` there (``table_verify.check_interpolation``), then rtctl's
real-time iteration (8 ticks, default ``QpSettings``, the operating point held) started at
``x* + a (x_interp - x*)`` for a = 0, 0.02, ..., 1 (1: the table's start), printing the largest
error per variable scale after each tick. With ``--exact-curvature`` the same from a = 0.02, 0.25,
1 with the QP's constraint-curvature part taken from the exact Lagrangian Hessian at ``x*`` (the
builder's ``point_data`` there) instead of the table's cell corners: if that converges where the
table's does not, the table's interpolated curvature is what the iteration lacks.

With ``--reversal-box`` (a prototype of a globalised step, outside rtctl): from the table's start,
the plain iteration against one whose step box shrinks to half the last step's largest component
(variable scales) when a step reverses the previous one (cosine below -0.5) and doubles otherwise,
up to ``QpSettings.step_limit``; printed with issue 20's tick-5 measures.

With ``--branches`` (issue 22, check 4's other optimum): the best verified optimum at the centre and
the online step's command after 5 ticks, each followed by IPOPT (warm, primal-dual, the optimizer's
independent check at every step) along each continuous axis of the cell from the centre to both
ends, in steps of ``--branch-step`` (axis units: deg for angles): where either branch ends or the
two meet, and where their objectives cross. One branch better than the other only in a patch
around the centre, held by no corner, is a best optimum a continuous command cannot follow.

    python tests/bench/diag_tables_online.py tables/rr_unpowered.npz 1,1,0 [--exact-curvature | --reversal-box]
    python tests/bench/diag_tables_online.py tables/rr_unpowered.npz 2,0,0 --branches [--branch-step 0.1]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from offline.rover.table_builder import _problem, point_data, scenario_at
    from offline.rover.table_verify import check_interpolation, spec_from_table
    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration
    from rtctl.table import load_table

    a = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    a.add_argument("table")
    a.add_argument("cell", help="lower-corner indices, comma-separated")
    a.add_argument("--exact-curvature", action="store_true")
    a.add_argument("--reversal-box", action="store_true")
    a.add_argument("--branches", action="store_true")
    a.add_argument("--branch-step", type=float, default=0.1, help="step of --branches (deg for angles)")
    args = a.parse_args()
    t = load_table(args.table)
    spec = spec_from_table(t)
    lay = t.layout
    xsc = np.asarray(lay.variable_scale, dtype=float)
    cell = tuple(int(v) for v in args.cell.split(","))
    refs: list = []
    check_interpolation(t, spec, [cell], None, refs)
    if not refs:
        raise SystemExit(f"no primitive at the centre of cell {cell}")
    op, xstar = refs[0]
    tp = t.at(**op)
    p = np.array(tp.p, dtype=float)
    for k in ("speed", "slope", "cross_slope"):
        if k in op:
            p[lay.index(k)] = op[k]
    exact = None
    if args.exact_curvature:
        sc = scenario_at(spec.scenario, spec.family, op)
        pb = _problem(sc, spec.solver)
        r = pb.solve(pb.bounds(sc), xstar / xsc)
        if not r["success"]:
            raise SystemExit("the re-solve at the optimum for its multipliers failed")
        exact = point_data(spec, sc, r["x"], r["lam_x"], r["lam_g"])
    print(f"{t.name} cell {cell}, centre {({k: round(v, 6) for k, v in op.items()})}, "
          f"start {float(np.max(np.abs(tp.x - xstar) / xsc)):.3g} scales from the optimum")
    if args.reversal_box:
        _reversal(t, tp, p, xstar)
        return
    if args.branches:
        _branches(t, spec, cell, op, tp, p, xstar, args.branch_step)
        return
    for curv in ((False, True) if exact is not None else (False,)):
        for frac in ((0.02, 0.25, 1.0) if exact is not None else (0.0, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0)):
            s = QpSettings()
            rti = RealTimeIteration(t, s, [lay.index(f"wheel torque {w}") for w in lay.wheels])
            if curv:
                pd = exact
                rti._table_curvature = lambda _tp, rti=rti, pd=pd: rti._corner_curvature(pd["hess_lag"],  # type: ignore
                                                                                          pd["jac_g_x"])
            rti.iterate = xstar + frac * (np.asarray(tp.x, dtype=float) - xstar)
            rti.prepare(tp)
            errs = []
            for _ in range(8):
                xk = rti.iterate
                box = merge_bounds(tp.lbx, tp.ubx, (xk - s.step_limit * xsc, xk + s.step_limit * xsc))
                res = rti.step(p, box)
                errs.append(f"{float(np.max(np.abs(res.x - xstar) / xsc)):.2g}" if res.ok else "refused")
            print(f"  {'exact curvature' if curv else 'table curvature'} start a = {frac:g}: {', '.join(errs)}",
                  flush=True)



def _reversal(t: object, tp: object, p: np.ndarray, xstar: np.ndarray) -> None:
    """The plain iteration and the reversal-box prototype from the table's start (module docstring)."""
    from offline.rover.table_verify import _online_metrics
    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration

    lay = t.layout  # type: ignore[attr-defined]
    xsc = np.asarray(lay.variable_scale, dtype=float)
    for mode in ("plain", "reversal box"):
        s = QpSettings()
        rti = RealTimeIteration(t, s, [lay.index(f"wheel torque {w}") for w in lay.wheels])
        rti.prepare(tp)
        r, prev, errs, m5 = s.step_limit, None, [], {}
        for k in range(8):
            x_old = np.array(rti.iterate, dtype=float)
            res = rti.step(p, merge_bounds(tp.lbx, tp.ubx, (x_old - r * xsc, x_old + r * xsc)))  # type: ignore
            if not res.ok or rti.iterate is None:
                errs.append("refused")
                break
            dx = (rti.iterate - x_old) / xsc
            if mode != "plain" and prev is not None:
                cos = float(dx @ prev) / max(float(np.linalg.norm(dx) * np.linalg.norm(prev)), 1e-300)
                r = max(0.5 * float(np.max(np.abs(dx))), 1e-3) if cos < -0.5 else min(s.step_limit, 2 * r)
            prev = dx
            errs.append(f"{float(np.max(np.abs(rti.iterate - xstar) / xsc)):.2g}")
            if k == 4:
                assert rti.residual is not None
                m5 = _online_metrics(lay, rti.iterate, xstar, rti.residual.residual(rti.iterate, p)[1],
                                     rti.residual.residual(xstar, p)[1])
        print(f"  {mode}: {', '.join(errs)}; tick 5 " + ", ".join(f"{k} {v:.3g}" for k, v in m5.items()), flush=True)


def _branches(t: object, spec: object, cell: tuple[int, ...], op: dict, tp: object, p: np.ndarray,
              xstar: np.ndarray, step: float) -> None:
    """The best optimum and the online step's command followed along each axis (module docstring)."""
    import math

    from offline.rover.primitives import check_solution
    from offline.rover.table_builder import _problem, scenario_at
    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration

    lay = t.layout  # type: ignore[attr-defined]
    xsc = np.asarray(lay.variable_scale, dtype=float)
    be = [lay.var("beta", w) for w in lay.wheels]
    s = QpSettings()
    rti = RealTimeIteration(t, s, [lay.index(f"wheel torque {w}") for w in lay.wheels])
    rti.prepare(tp)
    for _ in range(5):
        xk = np.asarray(rti.iterate, dtype=float)
        rti.step(p, merge_bounds(tp.lbx, tp.ubx, (xk - s.step_limit * xsc, xk + s.step_limit * xsc)))  # type: ignore
    x_on = np.asarray(rti.iterate, dtype=float)
    print(f"  online step after 5 ticks: {float(np.max(np.abs(x_on - xstar) / xsc)):.3g} scales from the best optimum, "
          f"steering {float(np.max(np.abs(x_on[be] - xstar[be]))) * 180 / math.pi:.2f} deg apart")

    def solve(o: dict, start: tuple) -> tuple[dict, bool]:
        sc = scenario_at(spec.scenario, spec.family, o)  # type: ignore[attr-defined]
        pb = _problem(sc, spec.solver)  # type: ignore[attr-defined]
        r = pb.solve(pb.bounds(sc), *start, max_iter=100)
        return r, bool(r["success"] and check_solution(pb, sc, r["x"])[1])

    angle = {"slope", "cross_slope", "steer_stuck"}
    for i, key in enumerate(t.axis_order):  # type: ignore[attr-defined]
        ax = t.axes[key]  # type: ignore[attr-defined]
        if len(ax) < 2 or key == "speed":
            continue
        unit = math.pi / 180 if key in angle else 1.0
        for end in (float(ax[cell[i]]), float(ax[cell[i] + 1])):
            st: list = [(xstar / xsc,), (x_on / xsc,)]  # best, online
            prev = None
            msg = f"both reach {end / unit:.3g}"
            n = max(1, int(math.ceil(abs(end - op[key]) / (step * unit))))
            for k in range(1, n + 1):
                v = op[key] + (end - op[key]) * k / n
                o = dict(op, **{key: v})
                rs = []
                for j in range(2):
                    r, ok = solve(o, st[j])
                    if not ok:
                        break
                    st[j] = (np.asarray(r["x"]), r["lam_x"], r["lam_g"])
                    rs.append(r)
                if len(rs) < 2:
                    msg = f"the {'best optimum' if len(rs) == 0 else 'online command'}'s branch ends before {v / unit:.3g}"
                    break
                gap = float(np.max(np.abs((np.asarray(rs[0]["x"]) - np.asarray(rs[1]["x"])) * xsc)[be])) * 180 / math.pi
                rel = (float(rs[0]["f"]) - float(rs[1]["f"])) / abs(float(rs[1]["f"]))
                if gap < 0.05:
                    msg = f"the branches meet at {v / unit:.4g} (steering within {gap:.3f} deg)"
                    break
                if prev is not None and (rel < 0) != (prev[1] < 0):
                    print(f"  {key}: objectives cross between {prev[0] / unit:.4g} and {v / unit:.4g} "
                          f"(best - online {prev[1]:+.4%} -> {rel:+.4%})", flush=True)
                prev = (v, rel)
            print(f"  {key} from the centre to {end / unit:.4g}: {msg}; last best - online objective "
                  f"{prev[1]:+.4%} at {prev[0] / unit:.4g}" if prev else f"  {key} to {end / unit:.4g}: {msg}", flush=True)


if __name__ == "__main__":
    main()
