"""Verification of a lookup table against the model it was built from (``offnominal tables verify``).

Three checks, each at points sampled with a seeded generator:

1. **Jacobians**: the stored wheel-wrench Jacobian against central differences of the numeric
   (numpy) wheel model, and the stored constraint Jacobians ``d g / d x``, ``d g / d p`` and the
   objective gradient against central differences of the NLP's numeric constraint function,
   error relative to the largest entry of each block.
2. **Linearisation** (sizes the trust radius): the first-order prediction ``x + dx/dp dp`` (the
   solution of the QP of one SQP step with the active set held, which is the KKT sensitivity
   system) against a full re-solve of the NLP as the change in speed, slope, cross-slope and
   the offsets (7.26)-(7.27) grows.
3. **Interpolation** (sizes the grid): at the midpoints of cells whose corners are all feasible,
   the interpolated primitive and Jacobians against a direct solve there.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtctl.table import Table, load_table

from .table_builder import (BuildOptions, GridSpec, TableSpec, _derivatives, _problem, decode, linearisation_errors,
                            point_data, scenario_at, scenario_from_header)

__all__ = ["VerifyReport", "spec_from_table", "check_jacobians", "check_interpolation", "verify_table", "JACOBIAN_RTOL"]

JACOBIAN_RTOL = 1e-5
"""Largest accepted Jacobian error against central differences, relative to the block's largest entry."""


@dataclass
class VerifyReport:
    """Outcome of :func:`verify_table` (numbers, not prose; :meth:`text` prints them)."""

    name: str
    load_seconds: float
    jacobians: dict[str, float] = field(default_factory=dict)
    linearisation: dict[str, Any] = field(default_factory=dict)
    interpolation: dict[str, Any] = field(default_factory=dict)
    passed: bool = True
    notes: list[str] = field(default_factory=list)

    def text(self) -> str:
        """Human-readable report."""
        lines = [f"table {self.name}: load + hash/schema check {self.load_seconds * 1e3:.1f} ms"]
        lines.append("Jacobians vs central differences (max error / max |entry|):")
        for k, v in self.jacobians.items():
            lines.append(f"  {k:<12} {v:.2e}  {'ok' if v <= JACOBIAN_RTOL else 'FAIL'}")
        lines.append("Linearisation: first-order prediction vs NLP re-solve (max |error| / variable scale):")
        for pt, errs in self.linearisation.items():
            lines.append(f"  at {pt}:")
            for par, rows in errs.items():
                lines.append(f"    {par:<12} " + "  ".join(f"{dp:.3g}: {('%.1e' % e) if e == e else 'no solve'}" for dp, e in rows))
        lines.append("Interpolation at cell midpoints vs direct solve:")
        for k, v in self.interpolation.items():
            lines.append(f"  {k}: {v}")
        lines += [f"note: {n}" for n in self.notes]
        lines.append("PASSED" if self.passed else "FAILED")
        return "\n".join(lines)


def spec_from_table(t: Table) -> TableSpec:
    """The build spec a table was made from (scenario, grid, family, options), from its header."""
    h = t.header
    grid = GridSpec(tuple((k, tuple(float(v) for v in t.axes[k])) for k in t.axis_order))
    build = decode(h["build_options"]) if "build_options" in h else BuildOptions()
    solver = decode(h["solver_options"]) if "solver_options" in h else None
    return TableSpec(t.name, scenario_from_header(h), grid, h.get("family"), h.get("description", ""),
                     h.get("sources", {}), build, solver)


def _central(fun: Any, x: NDArray[np.float64], step: NDArray[np.float64]) -> NDArray[np.float64]:
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = step[i]
        cols.append((np.asarray(fun(x + e)) - np.asarray(fun(x - e))) / (2 * step[i]))
    return np.stack(cols, axis=-1)


def _rel(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def check_jacobians(t: Table, spec: TableSpec, flats: list[int]) -> dict[str, float]:
    """Largest relative error of the stored Jacobians against central differences (see module doc)."""
    from ..physics.backend import NUMPY

    pb = _problem(spec.scenario, spec.solver)
    lay = t.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    d = _derivatives(pb)
    errs = {"wrench_jac": 0.0, "jac_g_x": 0.0, "jac_g_p": 0.0, "grad_f": 0.0}
    for flat in flats:
        idx = np.unravel_index(flat, t.shape)
        x, p = t.arrays["x"][idx], t.arrays["p"][idx]
        sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
        for k, w in enumerate(lay.wheels):
            if p[lay.index(f"contact {w}")] == 0.0:
                continue
            om, beta, _, h, h0 = (x[lay.var(v, w)] for v in ("omega", "beta", "W", "h", "h0"))
            vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, beta)
            s = np.array([vx, vy, om, h, h0], dtype=float)
            # numpy path of the wheel's own model (its radius) plus the hub drag, if any
            num = _central(lambda z, w=w: np.array(pb.wheel_wrench(w, *z)[0]), s, 1e-6 * np.maximum(np.abs(s), 1e-3))
            errs["wrench_jac"] = max(errs["wrench_jac"], _rel(t.arrays["wrench_jac"][idx][k], num))
        g_phys = lambda z: np.asarray(d.gfun(z / xsc, p)).ravel() * csc  # noqa: E731
        jx = _central(g_phys, x, 1e-6 * xsc)
        errs["jac_g_x"] = max(errs["jac_g_x"], _rel(t.arrays["jac_g_x"][idx], jx))
        jp = _central(lambda q: np.asarray(d.gfun(x / xsc, q)).ravel() * csc, p, 1e-6 * lay_pscale(lay))
        errs["jac_g_p"] = max(errs["jac_g_p"], _rel(t.arrays["jac_g_p"][idx], jp))
        f = lambda z: float(d(z / xsc, p, np.zeros(lay.ng))[1].item())  # noqa: E731
        gf = _central(lambda z: np.array([f(z)]), x, 1e-6 * xsc)[0]
        errs["grad_f"] = max(errs["grad_f"], _rel(t.arrays["grad_f"][idx], gf))
    return errs


def lay_pscale(lay: Any) -> NDArray[np.float64]:
    """Parameter scales of a layout (finite-difference steps are a fraction of them)."""
    return np.array([b.scale for b in lay.parameters])


def check_interpolation(t: Table, spec: TableSpec, cells: list[tuple[int, ...]]) -> dict[str, Any]:
    """At each cell midpoint: interpolated ``x``, ``jac_g_x`` and ``wrench_jac`` against a direct solve.

    Returns the largest errors (x: per variable scale; Jacobians: relative to the largest entry)
    and the number of midpoints where the direct solve found no primitive.
    """
    from .primitives import solve_primitive

    lay = t.layout
    xsc = lay.variable_scale
    ex, ej, ew, fails, where = 0.0, 0.0, 0.0, 0, None
    for c in cells:
        op = {k: float(0.5 * (t.axes[k][i] + t.axes[k][i + 1])) if len(t.axes[k]) > 1 else float(t.axes[k][0])
              for k, i in zip(t.axis_order, c)}
        tp = t.at(**op)
        sc = scenario_at(spec.scenario, spec.family, op)
        r = solve_primitive(sc, spec.solver, x0=tp.x / xsc)
        if r.status != "optimal":
            fails += 1
            continue
        dd = point_data(spec, sc, np.asarray(r.x, dtype=float),
                        np.asarray(r.stats["lam_x"], dtype=float).ravel(), np.asarray(r.stats["lam_g"], dtype=float).ravel())
        e = float(np.max(np.abs(tp.x - dd["x"]) / xsc))
        if e > ex:
            ex, where = e, op
        ej = max(ej, _rel(tp.jac_g_x, dd["jac_g_x"]))
        ew = max(ew, _rel(tp.wrench_jac, dd["wrench_jac"]))
    return {"midpoints": len(cells), "no_direct_solution": fails, "x_error_per_scale": ex,
            "jac_g_x_rel_error": ej, "wrench_jac_rel_error": ew,
            "worst_midpoint": {k: round(v, 6) for k, v in where.items()} if where else None}


def verify_table(path: str | Path, points: int = 3, seed: int = 0, steps: tuple[float, ...] | None = None) -> VerifyReport:
    """Run the three checks of the module docstring on ``points`` sampled points each."""
    t0 = time.perf_counter()
    t = load_table(path)
    rep = VerifyReport(t.name, time.perf_counter() - t0)
    spec = spec_from_table(t)
    rng = np.random.default_rng(seed)
    feas = np.flatnonzero(t.feasible.ravel())
    if feas.size == 0:
        rep.notes.append("no feasible grid point: nothing to verify beyond the file checks")
        return rep
    flats = sorted(int(i) for i in rng.choice(feas, size=min(points, feas.size), replace=False))
    rep.jacobians = check_jacobians(t, spec, flats)
    rep.passed = all(v <= JACOBIAN_RTOL for v in rep.jacobians.values())
    for f in flats[:max(1, points // 2)]:
        idx = np.unravel_index(f, t.shape)
        data = {k: t.arrays[k][idx] for k in ("x", "dx_dp")}
        errs = linearisation_errors(spec, f, data, data["x"] / t.layout.variable_scale, steps=steps)
        rep.linearisation[str(t.grid_point(tuple(int(i) for i in idx)))] = errs
    # cells whose corners are all feasible
    multi = [i for i, n in enumerate(t.shape) if n > 1]
    cells = []
    for c in np.ndindex(*[max(n - 1, 1) for n in t.shape]):
        corners = []
        for b in range(2 ** len(multi)):
            k = list(c)
            for j, a in enumerate(multi):
                k[a] += (b >> j) & 1
            corners.append(tuple(k))
        if all(t.feasible[k] for k in corners):
            cells.append(tuple(c))
    if cells:
        pick = rng.choice(len(cells), size=min(points, len(cells)), replace=False)
        rep.interpolation = check_interpolation(t, spec, [cells[int(i)] for i in sorted(pick)])
    else:
        rep.notes.append("no cell with all corners feasible: interpolation not checked")
    tr = t.header.get("trust_radius", {})
    rep.notes.append("stored trust radius (SI): " + ", ".join(f"{k} {v:.3g}" if v is not None else f"{k} none"
                                                              for k, v in tr.items()))
    return rep
