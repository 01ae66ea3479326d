"""Issue 23, audit row B3b: is the mini rover's NLP (7.25) the same before and after issue 23's rewrite?

Issue 23's NLP change is the merge d9ca9e2 (``Merge branch 'i23-nlp'``: ``primitives.py``,
``scenario.py``, ``statics.py`` rewritten for any rover file); its first parent is 5128a7b. This
bench loads each commit's code in its own subprocess (``PYTHONPATH`` = a worktree of that commit)
and, at every grid point of the given shipped mini tables, evaluates what that commit's NLP builds
for the table's scenario at that point (the table builder's own ``scenario_at``, ``_problem`` and
``_derivatives``, identical files at both commits):

* at every grid point: the parameters ``p`` and the bounds ``lbx``, ``ubx``, ``lbg``, ``ubg``;
* at every stored optimum (the table's ``x``, ``lam_g``): the constraint rows ``g`` (eqs. (7.12)-(7.23),
  (7.32)-(7.33) and the failure rows), the objective (7.24), its gradient, ``jac_g_x``, ``jac_g_p``,
  the Lagrangian Hessian ``hess_lag`` and ``hess_lag_xp`` (IPOPT's stored multipliers), all in the
  table's physical units, and the independent check (``primitives.check_solution``: numpy wheel
  model, free-body balance, each failure kind's own check);
* with ``--resolve``: a warm IPOPT solve of the commit's NLP from the stored primitive and its
  multipliers (``SteadyStateProblem.solve``, the table solver options): solution, objective,
  iteration count, status.

The subprocesses exchange arrays through ``.npz`` files in a temporary folder. The parent prints,
per table and quantity, the largest difference between the two commits over all points relative to
the quantity's largest magnitude in the table (its "array scale"), and the same against the values
stored in the shipped file where the table stores them.

Usage (from any folder; the trees are worktrees at the two commits, the tables a copy of the shipped
files)::

    python tests/bench/bench_any_rover_mini_unchanged.py --pre TREE_5128a7b --post TREE_d9ca9e2 \\
        --shipped DIR [--tables nominal,rr_unpowered,...] [--resolve]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

MINI_TABLES = ("nominal", "rr_locked", "rr_rim_speed_cap", "rr_steer_stuck", "rr_trench_clean",
               "rr_trench_clean_mu01", "rr_unpowered")
BOUNDS = ("p", "lbx", "ubx", "lbg", "ubg")
DERIVED = ("g", "objective", "grad_f", "jac_g_x", "jac_g_p", "hess_lag", "hess_lag_xp")
"""Evaluated at every stored optimum; every one is also a field of the table."""


# ------------------------------------------------------------------------------ worker (one commit)
def _header(z: Any) -> dict[str, Any]:
    h: dict[str, Any] = json.loads(bytes(np.asarray(z["header"], dtype=np.uint8)).decode())
    return h


def worker(tree: Path, shipped: Path, out: Path, tables: list[str], resolve: bool, point_data: bool) -> None:
    """Evaluate this process's commit (imported from ``tree``) at every point of ``tables``."""
    from offline.rover import primitives as P
    from offline.rover import table_builder as TB

    res: dict[str, Any] = {}
    for t in tables:
        z = np.load(shipped / f"{t}.npz", allow_pickle=False)
        hd = _header(z)
        path = tree / "tables" / "scenarios" / f"{t}.toml"
        sha = hashlib.sha256(path.read_bytes()).hexdigest()
        if sha != hd["sources"]["scenario_file"]["sha256"]:
            raise SystemExit(f"{path.name}: not the scenario file the shipped {t}.npz was built from")
        spec = TB.table_spec(path)
        grid = TB.GridSpec(tuple((n, tuple(hd["axes"][n]["values"])) for n in hd["axis_order"]))
        if grid.shape != z["status"].shape:
            raise SystemExit(f"{t}: grid {grid.shape} is not the table's {z['status'].shape}")
        fam = spec.family["axis"] if spec.family else None
        if fam != (hd["family"]["axis"] if hd["family"] else None):
            raise SystemExit(f"{t}: family {fam} is not the header's {hd['family']}")
        optimal = hd["status_names"].index("optimal")
        meta: dict[str, Any] = {}
        for flat in range(grid.size):
            idx = np.unravel_index(flat, grid.shape)
            sc = TB.scenario_at(spec.scenario, spec.family, grid.point(flat))
            pb = TB._problem(sc, spec.solver)
            lay = pb.layout
            xsc, csc = np.asarray(lay.variable_scale, float), np.asarray(lay.constraint_scale, float)
            if not meta:
                meta = {"variables": list(lay.variable_names), "constraints": list(lay.constraint_names),
                        "parameters": list(lay.parameter_names), "xscale": xsc.tolist(), "gscale": csc.tolist()}
            b = pb.bounds(sc)
            key = f"{t}/{flat}/"
            res[key + "p"] = np.asarray(b["p"], float)
            for k, s in (("lbx", xsc), ("ubx", xsc), ("lbg", csc), ("ubg", csc)):
                res[key + k] = np.asarray(b[k], float) * s
            if int(z["status"][idx]) != optimal:
                continue
            x_s = np.asarray(z["x"][idx], float) / xsc
            lam_x_s = np.asarray(z["lam_x"][idx], float) * xsc
            lam_g_s = np.asarray(z["lam_g"][idx], float) * csc
            g_s, f, jgx, jgp, gf, h, hxp = TB._derivatives(pb)(x_s, res[key + "p"], lam_g_s)
            res[key + "g"] = g_s.ravel() * csc
            res[key + "objective"] = np.array(float(f.item()))
            res[key + "grad_f"] = gf.ravel() / xsc
            res[key + "jac_g_x"] = csc[:, None] * jgx / xsc[None, :]
            res[key + "jac_g_p"] = csc[:, None] * jgp
            res[key + "hess_lag"] = h / np.outer(xsc, xsc)
            res[key + "hess_lag_xp"] = hxp / xsc[:, None]
            chk, ok = P.check_solution(pb, sc, x_s)
            names = sorted(chk)
            res[key + "check_names"] = np.array(names)
            res[key + "check"] = np.array([chk[n] for n in names], float)
            res[key + "check_ok"] = np.array(bool(ok))
            if resolve:
                r = pb.solve(b, x_s, lam_x_s, lam_g_s)
                res[key + "re_x"] = np.asarray(r["x"], float) * xsc
                res[key + "re_objective"] = np.array(float(r["f"]))
                res[key + "re_iterations"] = np.array(int(r["iterations"]))
                res[key + "re_success"] = np.array(bool(r["success"]))
                res[key + "re_status"] = np.array(str(r["status"]))
            if point_data:
                for k, v in TB.point_data(spec, sc, x_s, lam_x_s, lam_g_s).items():
                    res[key + "pd_" + k] = np.asarray(v)
        res[f"{t}/meta"] = np.array(json.dumps(meta))
    tmp = out.with_suffix(".part.npz")
    np.savez(tmp, **res)
    os.replace(tmp, out)


# ------------------------------------------------------------------------------ parent: compare
def _rel(a: NDArray[np.float64], b: NDArray[np.float64], scale: float) -> tuple[float, bool]:
    """Largest |a - b| over the finite entries, relative to ``scale``; and whether the
    non-finite entries (infinite bounds) agree exactly."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    same_nonfinite = bool(np.array_equal(~np.isfinite(a), ~np.isfinite(b))
                          and np.array_equal(a[~np.isfinite(a)], b[~np.isfinite(b)]))
    m = np.isfinite(a) & np.isfinite(b)
    d = float(np.max(np.abs(a[m] - b[m]))) if m.any() else 0.0
    return (d / scale if scale > 0 else d), same_nonfinite


def _fmt(v: float) -> str:
    return "0" if v == 0 else f"{v:.1e}"


def compare(pre: dict[str, Any], post: dict[str, Any], shipped: Path, tables: list[str], resolve: bool) -> str:
    """Markdown tables of the differences (module docstring)."""
    out = ["| table | points (optimal) | quantity | array scale | pre vs post (rel.) | pre vs shipped (rel.) | post vs shipped (rel.) |",
           "|---|---|---|---|---|---|---|"]
    rows2 = ["| table | optimal points | warm re-solve pre vs post: x (max, variable scales) | objective (max rel.) "
             "| iterations equal | iterations pre / post (total) | re-solve vs stored x (max, scales) | both optimal |",
             "|---|---|---|---|---|---|---|---|"]
    chk_rows = ["| table | check_solution ok pre / post | largest check residual difference pre vs post | largest residual |",
                "|---|---|---|---|"]
    for t in tables:
        z = np.load(shipped / f"{t}.npz", allow_pickle=False)
        hd = _header(z)
        meta_a, meta_b = json.loads(str(pre[f"{t}/meta"])), json.loads(str(post[f"{t}/meta"]))
        if meta_a != meta_b:
            raise SystemExit(f"{t}: layouts differ between the commits: {meta_a} / {meta_b}")
        opt = hd["status_names"].index("optimal")
        shape = z["status"].shape
        n = int(np.prod(shape))
        flats = [f for f in range(n) if int(z["status"][np.unravel_index(f, shape)]) == opt]
        for q in BOUNDS + DERIVED:
            pts = range(n) if q in BOUNDS else flats
            if not pts:
                continue
            a = np.stack([pre[f"{t}/{f}/{q}"] for f in pts])
            b = np.stack([post[f"{t}/{f}/{q}"] for f in pts])
            fin = a[np.isfinite(a)]
            scale = float(np.max(np.abs(fin))) if fin.size else 0.0
            r_ab, ok_ab = _rel(a, b, scale)
            flag = lambda ok: "" if ok else " (inf pattern differs)"  # noqa: E731
            col = [f"{_fmt(r_ab)}{flag(ok_ab)}", "-", "-"]
            if flats:  # the table stores a point's data at its optima only (NaN elsewhere)
                sel = [list(pts).index(f) for f in flats]
                s = np.stack([z[q][np.unravel_index(f, shape)] for f in flats]).astype(float)
                r_as, ok_as = _rel(a[sel], s, scale)
                r_bs, ok_bs = _rel(b[sel], s, scale)
                col[1:] = [f"{_fmt(r_as)}{flag(ok_as)}", f"{_fmt(r_bs)}{flag(ok_bs)}"]
            out.append(f"| {t} | {n} ({len(flats)}) | {q} | {scale:.3g} | {' | '.join(col)} |")
        if flats:
            oks = [(bool(pre[f"{t}/{f}/check_ok"]), bool(post[f"{t}/{f}/check_ok"])) for f in flats]
            if any(list(pre[f"{t}/{f}/check_names"]) != list(post[f"{t}/{f}/check_names"]) for f in flats):
                raise SystemExit(f"{t}: the independent check's residual names differ between the commits")
            d = max(float(np.max(np.abs(pre[f"{t}/{f}/check"] - post[f"{t}/{f}/check"]))) for f in flats)
            big = max(float(np.max(np.abs(pre[f"{t}/{f}/check"]))) for f in flats)
            chk_rows.append(f"| {t} | {sum(a for a, _ in oks)} / {sum(b for _, b in oks)} of {len(flats)} | "
                            f"{_fmt(d)} | {_fmt(big)} |")
        if resolve and flats:
            xsc = np.asarray(meta_a["xscale"])
            dx = max(float(np.max(np.abs(pre[f"{t}/{f}/re_x"] - post[f"{t}/{f}/re_x"]) / xsc)) for f in flats)
            dfo = max(abs(float(pre[f"{t}/{f}/re_objective"]) - float(post[f"{t}/{f}/re_objective"]))
                      / max(abs(float(pre[f"{t}/{f}/re_objective"])), 1e-300) for f in flats)
            it_a = [int(pre[f"{t}/{f}/re_iterations"]) for f in flats]
            it_b = [int(post[f"{t}/{f}/re_iterations"]) for f in flats]
            dxs = max(max(float(np.max(np.abs(pre[f"{t}/{f}/re_x"] - z["x"][np.unravel_index(f, shape)]) / xsc)),
                          float(np.max(np.abs(post[f"{t}/{f}/re_x"] - z["x"][np.unravel_index(f, shape)]) / xsc)))
                      for f in flats)
            both = sum(bool(pre[f"{t}/{f}/re_success"]) and bool(post[f"{t}/{f}/re_success"]) for f in flats)
            rows2.append(f"| {t} | {len(flats)} | {_fmt(dx)} | {_fmt(dfo)} | {sum(a == b for a, b in zip(it_a, it_b))}"
                         f" of {len(flats)} | {sum(it_a)} / {sum(it_b)} | {_fmt(dxs)} | {both} |")
    text = "\n".join(out) + "\n\nIndependent check (`primitives.check_solution`) at the stored optima:\n\n" + "\n".join(chk_rows)
    if resolve:
        text += "\n\nWarm IPOPT re-solve from the stored primitive and multipliers:\n\n" + "\n".join(rows2)
    return text + "\n"


def compare_point_data(pre: dict[str, Any], post: dict[str, Any], shipped: Path, tables: list[str]) -> str:
    """Per table and field of :func:`offline.rover.table_builder.point_data`: points whose field is
    bit-identical between the commits, and the largest difference relative to the field's largest
    magnitude over the table."""
    rows = ["| table | field | bit-identical points | largest difference pre vs post (rel.) |", "|---|---|---|---|"]
    for t in tables:
        keys = sorted({k.split("/", 2)[2] for k in pre if k.startswith(f"{t}/") and "/pd_" in k})
        flats = sorted({int(k.split("/")[1]) for k in pre if k.startswith(f"{t}/") and "/pd_" in k})
        if sorted(k for k in pre if "/pd_" in k and k.startswith(f"{t}/")) != \
                sorted(k for k in post if "/pd_" in k and k.startswith(f"{t}/")):
            raise SystemExit(f"{t}: the commits' point records have different fields")
        for q in keys:
            a = [np.asarray(pre[f"{t}/{f}/{q}"], float) for f in flats]
            b = [np.asarray(post[f"{t}/{f}/{q}"], float) for f in flats]
            same = sum(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))
            fin = np.concatenate([x[np.isfinite(x)].ravel() for x in a])
            scale = float(np.max(np.abs(fin))) if fin.size else 0.0
            r = max(_rel(x, y, scale)[0] for x, y in zip(a, b))
            rows.append(f"| {t} | {q[3:]} | {same} of {len(flats)} | {_fmt(r)} |")
    return "Whole per-point record (`table_builder.point_data`) from the stored primitive:\n\n" + "\n".join(rows) + "\n"


def _run_worker(tree: Path, shipped: Path, out: Path, tables: list[str], resolve: bool, point_data: bool) -> float:
    """Run :func:`worker` with ``tree``'s code in a subprocess; its CPU seconds (user + sys)."""
    env = dict(os.environ, PYTHONPATH=str(tree), OPENBLAS_NUM_THREADS="1")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [sys.executable, str(Path(__file__).resolve()), "worker", "--tree", str(tree), "--shipped", str(shipped),
           "--out", str(out), "--tables", ",".join(tables)] + (["--resolve"] if resolve else []) \
        + (["--point-data"] if point_data else [])
    subprocess.run(cmd, cwd=tree, env=env, check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", nargs="?", default="compare", choices=("compare", "worker"))
    ap.add_argument("--pre", type=Path, help="worktree at 5128a7b (before issue 23's NLP rewrite)")
    ap.add_argument("--post", type=Path, help="worktree at d9ca9e2 (after it)")
    ap.add_argument("--tree", type=Path, help="(worker) the tree whose code this process runs")
    ap.add_argument("--out", type=Path, help="(worker) result .npz")
    ap.add_argument("--shipped", type=Path, required=True, help="folder with copies of the shipped mini tables")
    ap.add_argument("--tables", default=",".join(MINI_TABLES))
    ap.add_argument("--resolve", action="store_true", help="also a warm IPOPT re-solve at every stored optimum")
    ap.add_argument("--point-data", action="store_true",
                    help="also the builder's whole per-point record (table_builder.point_data: controllers' re-solves, "
                         "trust radii, dx/dp, ...) from the stored primitive and multipliers")
    a = ap.parse_args(argv)
    tables = [t for t in a.tables.split(",") if t]
    bad = [t for t in tables if not (a.shipped / f"{t}.npz").is_file()]
    if bad:
        ap.error(f"no {bad} in {a.shipped}")
    if a.mode == "worker":
        if a.tree is None or a.out is None:
            ap.error("worker needs --tree and --out")
        worker(a.tree.resolve(), a.shipped.resolve(), a.out, tables, a.resolve, a.point_data)
        return 0
    if a.pre is None or a.post is None:
        ap.error("compare needs --pre and --post")
    with tempfile.TemporaryDirectory() as d:
        cpu = {}
        for tag, tree in (("pre", a.pre), ("post", a.post)):
            cpu[tag] = _run_worker(tree.resolve(), a.shipped.resolve(), Path(d) / f"{tag}.npz", tables, a.resolve,
                                   a.point_data)
        pre = dict(np.load(Path(d) / "pre.npz", allow_pickle=False))
        post = dict(np.load(Path(d) / "post.npz", allow_pickle=False))
        commits = {tag: subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=tree, capture_output=True,
                                       text=True).stdout.strip() for tag, tree in (("pre", a.pre), ("post", a.post))}
    print(f"pre = {commits['pre']}, post = {commits['post']}; worker CPU (user + sys): pre {cpu['pre']:.1f} s, "
          f"post {cpu['post']:.1f} s\n")
    print(compare(pre, post, a.shipped, tables, a.resolve))
    if a.point_data:
        print(compare_point_data(pre, post, a.shipped, tables))
    return 0 if math.isfinite(cpu["pre"]) else 1


if __name__ == "__main__":
    sys.exit(main())
