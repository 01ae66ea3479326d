"""Verification of a lookup table against the model it was built from (``offnominal tables verify``).

Four checks, each at points sampled with a seeded generator; the verdict is PASSED only when
every gated part of every check is within its tolerance (:attr:`VerifyReport.passed`). Check 3's
raw interpolation distance is reported, not gated, since issue 22 (2026-11-27): check 4 measures
what the controller commands between grid points instead (why: under check 3).

1. **Jacobians**: the stored wheel-wrench Jacobian against difference quotients of the numeric
   (numpy) wheel model, and the stored constraint Jacobians ``d g / d x``, ``d g / d p`` and the
   objective gradient against difference quotients of the NLP's numeric constraint function
   (7.12)-(7.23), error relative to the largest entry of each block. Tolerance
   :data:`JACOBIAN_RTOL` (1e-5) at the standard central step (:data:`FD_STEP`, 1e-6 of each
   variable's or parameter's scale): a central difference's truncation error is
   ``h^2 |g_xxx| / 6`` and its rounding error ``eps |g| / h``, together about 1e-8 of the
   block's largest entry on smooth rows (measured: 1e-9 to 2e-7 on every shipped table). An
   entry off by more than that is re-examined with steps 10 to 1e7 times smaller (central,
   forward and backward quotients, each divided by the step as actually represented,
   ``(x + h) - x``): the stored value passes when it is the limit of the quotients, i.e. when
   at some step a quotient is within :data:`STEEP_RTOL` (1e-3) both of the stored value and of
   the same quotient at the 10 times larger step (converged). Why the second tier, and why
   1e-3: the constraint function of (7.25) is not smooth everywhere, and optima sit where it is
   not. On the shipped tables (issue 22) every entry the standard step rejected is of one of
   three kinds, and in each the stored Jacobian (casadi's exact derivative of the same
   function) is the limit of the difference quotients, while the central difference at the
   standard step straddled a boundary layer narrower than the step:

   * ``trench flat width`` in ``h`` (``rr_trench_clean``, ``rr_trench_clean_mu01``): the flat
     fill of (4.11)-(4.12), ``e = -p T / 2 + sqrt((p T / 2)^2 + A T)``, at a pointy trench
     (``p`` ~ 0) with almost no soil set aside (``A`` ~ 0) is the square root of a quantity of
     the order of the square-root floor (1e-24), so it is differentiable only within about
     1e-12 m: the central quotient is 671 at a 1.6e-8 m step and 4.09e4 at 1.6e-14 m, the
     stored value 4.09e4. Quotients at such steps are limited by the rounding noise of ``g``
     itself (measured 5e-5 to 2e-4 of the entry), hence :data:`STEEP_RTOL`. The row has no
     bounds in these tables (no minimum flat width), so it constrains nothing and rtctl zeroes
     it (``rtctl.controller._BoundedRows``).
   * ``trench depth`` in ``h`` at a clean-sided trench: the rim-side pile is ``A_R2 = 0``
     there and its height ``sqrt(2 A_R2 tan phi)`` (4.4) has an infinite one-sided
     derivative, so the optimum is a cusp: the backward quotient is 0.224157 at every step,
     the forward one grows like ``h^-1/2``. The stored value is the backward (clean-side,
     feasible-side) derivative; such entries are listed with their side.
   * wheel rows in ``omega`` at a rim-speed cap equal to the travel speed
     (``rr_rim_speed_cap``, fraction 1): the capped wheel runs at zero slip, where the
     quadrature break ``theta* = arccos(r w / v_x)`` of the wheel model moves like
     ``sqrt(1 - r w / v_x)`` on the skid side and the 8-node Gauss-Legendre error moves with
     it: a layer of about 1e-9 rad/s below the cap (the optimum sits 5e-10 rad/s above it).
     This one is a quadrature artifact of the wheel model, not physics: with 32 or 64 nodes per
     segment the layer disappears (slope about 2300 N s/rad on both sides, against 160 in the
     8-node model). The table stores the exact derivative of the 8-node model the NLP solved;
     the artifact is recorded here, not fixed (the wheel model is being moved to
     ``rtctl/physics``).

   * (not a boundary layer but the model's edge) a wheel stuck at +-90 deg (``rr_steer_stuck``)
     moves sideways: ``v_x = 0`` at the optimum, and the numpy wheel model refuses ``v_x < 0``
     with ``omega > 0`` (slip ratio outside its domain). There the quotient in ``v_x`` is the
     one-sided one from inside the domain (:func:`_central`; the smaller steps likewise use only
     the sides that exist); the check crashed there before (issue 22's rebuild).

   Every entry that needed the smaller steps is listed with its row, column, side and step
   (:attr:`VerifyReport.jacobian_entries`), so the second tier hides nothing.
2. **Linearisation** (the trust radius): at each sampled point and for each continuous
   parameter whose stored trust radius the build verified (``trust_unverified`` = 0), the
   first-order prediction ``x + dx/dp dp`` (the QP of one SQP step with the active set held,
   i.e. the KKT sensitivity system) against a re-solve of the NLP at ``dp = +-`` the point's
   stored radius, started at the prediction (the re-solve the radius claims: IPOPT warm with the
   primitive's multipliers, then with its own dual initialisation, each with the optimizer's
   full per-run budget, then the optimizer's search from the prediction), whose result must
   pass the optimizer's independent numeric check. rtctl clips every parameter step to that
   radius, so this is the table's contract. (A cold search alone is not enough here: at a
   rim-speed-cap point with the cap active it found no primitive 1e-4 rad of slope away, where
   the warm run converges at once.) Tolerance: the build's
   ``trust_tolerance`` (0.02 variable scales), the number the radius was sized to; the
   re-solve is exact to IPOPT's tolerance (1e-8 scaled), so nothing is added to it. A re-solve
   without a primitive fails. The ladder of larger steps (1/16 to 2 parameter scales) is still
   printed as information: it sizes the radius and is expected to exceed the tolerance beyond
   it (e.g. 0.85 scales at a 0.025 rad slope step on ``rr_trench_clean_mu01``, whose slope
   radius is 0.001 rad).
3. **Interpolation** (the grid): at the midpoints of cells whose corners are all feasible, the
   interpolated primitive against a direct solve there. Gated: a primitive exists at every
   sampled centre. Reported, not gated since issue 22: the raw distance below, with the former
   tolerance and whether it was met. Why no longer gated: since issue 20 the interpolated
   primitive is not what rtctl commands between grid points; each 5 Hz tick is an SQP real-time
   iteration on the exact residual started from it (``rtctl.rti``), so the product between grid
   points is check 4's iterate, and the raw distance only says how far that iteration starts.
   Measured on every cell of the shipped tables (``tests/bench/results_tables_online_i22.md``):
   where a wheel reaches its motor limit inside a cell the raw distance is 1-4 scales at centres
   where the iteration reaches the optimum within issue 20's targets in 1-3 ticks (e.g. nominal
   1.73 scales, first tick 0.007), while it fails at others with a smaller raw distance (a cell
   whose corners straddle that kink: the interpolated curvature; another optimum's basin), so the
   raw distance neither implied nor excluded a failure of the product. The former gate was: tolerance on ``x``: the table's own
   refinement tolerance when it was refined (header ``refinement.tolerance_per_scale``), else
   :data:`INTERP_TOL` (0.5 variable scales, the tolerance the shipped nominal table is refined
   to). A midpoint without a primitive between feasible corners fails (interpolation would
   bridge a hole). The interpolated Jacobians (``jac_g_x``, ``wrench_jac``) are held to the
   same number relative to their block's largest entry: a relative Jacobian error ``e``
   changes the QP's constraint prediction over a step of ``s`` variable scales by ``e s``
   times the largest entry, as a primitive error of ``e s`` scales would, and the QP's steps
   are at most about one scale. The direct solve is the optimum the table's own rule would
   store at the midpoint (:func:`check_interpolation`): every start is run and each corner's
   optimum is followed to the midpoint by a continuation, and the best result by the builder's
   order (lowest objective) is the reference; the first start that converged, the former
   reference, can be another local optimum (issue 22: at one ``rr_unpowered`` midpoint it was,
   4.09 scales off where the corners' branch is 2.0 off). The check's own accuracy (a direct
   solve, 1e-8) is far below these numbers, so a failure is the table's: a grid too coarse for
   the primitive's curvature, a kink (a wheel reaching a bound between the corners), or a
   branch the corners do not share (reported per midpoint: ``optima``).
4. **Online step** (gated; issue 22): at the same centres, :data:`ONLINE_TICKS` ticks of rtctl's
   own real-time iteration (:class:`rtctl.rti.RealTimeIteration`, the class the controller
   runs, with the default :class:`rtctl.config.QpSettings`) from its restart (since issue 22 a
   parameter continuation from the cell's corners, :meth:`rtctl.rti.RealTimeIteration.start`;
   before, the interpolated primitive) at the constant operating point, against check 3's reference (the best verified optimum there,
   every start and continuation run). Gates, issue 20's targets (``bench_online_step.py``): the
   first tick's command balanced by the optimizer's independent check
   (:data:`ONLINE_TICK1_TARGETS`, set for the mini rover; another rover's scaled by its weight and
   length, :func:`tick1_targets`), and after :data:`ONLINE_TICKS` ticks wheel speeds, steering and
   objective at the reference (:data:`ONLINE_TARGETS`); a refused QP fails. Since 2026-11-28 a
   command at another local optimum than the reference also passes when it is a converged,
   balanced KKT point of (7.25) at the centre whose objective (7.24) is at most
   :data:`ONLINE_OTHER_OPTIMUM` ``objective_rel`` (0.5 %, issue 20's objective target) above the
   reference's: its last tick's step within ``step_per_scale`` (1e-3 variable scales; with the exact
   Jacobian a zero SQP step is a KKT point of the NLP), its balance by the independent check
   within the first-tick targets. Why, from what the controller promises: a command that holds
   the rover in balance (7.12)-(7.23) within the failure's constraints at a local minimum of the
   torque objective, steady at a constant operating point and continuous as it moves. The
   builder's "best optimum" is a rule for choosing the grid's values, not a promise between them:
   where two branches cross inside a cell the best optimum jumps, and a controller that followed
   it would jump its steering. Measured on ``rr_unpowered`` at (12.5, -5 deg, 3 cm/s), the centre
   that failed (``tests/bench/results_tables_online_i22.md``, 2026-11-28 h2): the best optimum
   there is a branch that exists only for slopes of about 11.0-13.95 deg (at -5 deg cross slope)
   and cross slopes below about -1.7 deg (at 12.5 deg), holds none of the cell's corners, and is
   better than the corners' branch only inside a patch of about 12.15-12.65 deg by -5.55 to -4.75
   deg (by at most 0.22 %, at the centre; elsewhere up to 21 % worse); the online step stays on
   the corners' branch (steering 7.4 deg from the patch's optimum), as every corner's IPOPT
   continuation does. A notably worse optimum (above the tolerance), an unbalanced command or one
   still moving fails; ``tests/test_tables_verify.py`` checks all three. This is what a table is for since issue 20: its start must lie where the
   iteration converges in a few ticks, and its Hessian, bounds and active sets must lead there;
   corrupted wheel speeds or wrong bounds fail it (``tests/test_tables_verify.py``; a wrong
   steering branch at every grid point no longer does since the continuation, which recovers the
   optimum from it: such a table fails check 1). Not included: the drive's outer-loop offsets and actuator
   rate limits, which are not the table's.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.table import Table, load_table

from .table_builder import (_LIN_PARAMS, BuildOptions, GridSpec, TableSpec, _derivatives, _fam_follow, _problem, decode,
                            linearisation_errors, scenario_at, scenario_from_header)

__all__ = ["VerifyReport", "spec_from_table", "check_jacobians", "check_trust_radius", "check_interpolation",
           "check_online", "verify_table", "JACOBIAN_RTOL", "STEEP_RTOL", "INTERP_TOL", "FD_STEP", "ONLINE_TICKS",
           "ONLINE_TICK1_TARGETS", "ONLINE_TARGETS", "ONLINE_OTHER_OPTIMUM", "TARGET_ROVER", "tick1_targets"]

JACOBIAN_RTOL = 1e-5
"""Largest accepted Jacobian error against central differences at the standard step, relative to
the block's largest entry (module docstring)."""

STEEP_RTOL = 1e-3
"""Largest accepted error, and convergence, of an entry that needed smaller steps, relative to the
block's largest entry: the rounding noise of difference quotients at 1e-12 of a scale (module
docstring)."""

INTERP_TOL = 0.5
"""Largest accepted interpolation error at a cell midpoint, in variable scales, for a table built
without refinement (a refined table is held to its own refinement tolerance)."""

FD_STEP = 1e-6
"""Standard difference step, a fraction of each variable's (or parameter's) scale."""

_LADDER = tuple(10.0 ** -k for k in range(1, 8))
"""Step reductions tried for an entry the standard step rejects (down to 1e-13 of a scale)."""


@dataclass
class VerifyReport:
    """Outcome of :func:`verify_table` (numbers, not prose; :meth:`text` prints them).

    Attributes
    ----------
    jacobians : dict
        Per block, the largest error relative to the block's largest entry (for an entry checked
        with smaller steps: its error or its convergence, whichever is larger).
    jacobian_tolerances : dict
        Per block, the tolerance applied: :data:`JACOBIAN_RTOL`, or :data:`STEEP_RTOL` when some
        entry needed smaller steps (the others still met :data:`JACOBIAN_RTOL`).
    jacobian_entries : list
        Every entry that needed smaller steps (dicts: point, block, row, column, stored, limit,
        side -- ``central``, or ``forward`` / ``backward`` when the limit is one-sided, a cusp --
        step as a fraction of the scale, the standard-step quotient, error).
    linearisation : dict
        Per sampled point, the informational step ladder (parameter -> [(dp, error)]).
    trust : list
        The gated trust-radius checks (dicts: point, parameter, step, error in variable scales
        -- NaN when the re-solve found no primitive -- and tolerance).
    interpolation : dict
        Largest raw interpolation errors at the sampled cell centres (information since issue 22;
        ``raw_within_tolerance`` says whether they meet the former gate), the centres without a
        primitive (gated).
    online : dict
        Check 4 (:func:`check_online`): rtctl's online step at the same centres.
    references : list
        Check 3's reference at each centre with a primitive, ``(midpoint, x physical)``: check 4's
        input, kept so that check 4 can be re-run at a centre (another ``settings`` or tolerance).
    verdicts : dict
        Per check (``jacobians``, ``linearisation``, ``interpolation`` -- a primitive at every
        sampled centre --, ``online step``), whether it passed.
    passed : bool
        Every gate of every check held.
    """

    name: str
    load_seconds: float
    jacobians: dict[str, float] = field(default_factory=dict)
    jacobian_tolerances: dict[str, float] = field(default_factory=dict)
    jacobian_entries: list[dict[str, Any]] = field(default_factory=list)
    linearisation: dict[str, Any] = field(default_factory=dict)
    trust: list[dict[str, Any]] = field(default_factory=list)
    interpolation: dict[str, Any] = field(default_factory=dict)
    online: dict[str, Any] = field(default_factory=dict)
    references: list[tuple[dict[str, float], NDArray[np.float64]]] = field(default_factory=list)
    verdicts: dict[str, bool] = field(default_factory=dict)
    passed: bool = True
    notes: list[str] = field(default_factory=list)

    def text(self) -> str:
        """Human-readable report."""
        def ok(b: bool) -> str:
            return "ok" if b else "FAIL"

        lines = [f"table {self.name}: load + hash/schema check {self.load_seconds * 1e3:.1f} ms"]
        lines.append(f"1. Jacobians vs difference quotients (max error / max |entry| of the block; tolerance "
                     f"{JACOBIAN_RTOL:.0e} at the standard step, {STEEP_RTOL:.0e} for entries in a boundary layer):")
        for k, v in self.jacobians.items():
            tol = self.jacobian_tolerances.get(k, JACOBIAN_RTOL)
            lines.append(f"  {k:<12} {v:.2e}  (tol {tol:.0e})  {ok(v <= tol)}")
        if self.jacobian_entries:
            lines.append(f"  {len(self.jacobian_entries)} entries needed smaller steps (g not smooth within the "
                         "standard step; module docstring):")
            for e in self.jacobian_entries[:12]:
                lines.append(f"    {e['block']} [{e['row']}, {e['column']}] at {e['point']}: stored {e['stored']:.6g}, "
                             f"{e['side']} limit {e['limit']:.6g} at step {e['step']:.0e}, standard step "
                             f"{e['standard']:.6g}; error {e['error']:.1e}")
            if len(self.jacobian_entries) > 12:
                lines.append(f"    ... {len(self.jacobian_entries) - 12} more")
        lines.append("2. Linearisation: first-order prediction vs NLP re-solve (max |error| / variable scale)")
        lines.append("   gated at +- each point's stored trust radius (rtctl clips its parameter steps to it):")
        for c in self.trust:
            e = c["error"]
            lines.append(f"    at {c['point']} {c['parameter']:<12} dp {c['step']:+.3g}: "
                         f"{('%.1e' % e) if e == e else 'no primitive'} (tol {c['tolerance']:.2g})  "
                         f"{ok(bool(e == e and e <= c['tolerance']))}")
        if self.linearisation:
            lines.append("   information, the step ladder (beyond the radius the error is expected to exceed it):")
        for pt, errs in self.linearisation.items():
            lines.append(f"    at {pt}:")
            for par, rows in errs.items():
                lines.append(f"      {par:<12} " + "  ".join(f"{dp:.3g}: {('%.1e' % e) if e == e else 'no solve'}"
                                                           for dp, e in rows))
        if self.interpolation:
            it = self.interpolation
            lines.append("3. Interpolation at cell centres vs the best verified optimum there (direct solve):")
            lines.append(f"   gated: a primitive at every sampled centre between feasible corners: "
                         f"{it['midpoints'] - it['no_direct_solution']} of {it['midpoints']}  "
                         f"{ok(it['no_direct_solution'] == 0)}")
            if it["midpoints_without_primitive"]:
                lines.append(f"     without a primitive: {it['midpoints_without_primitive']}")
            lines.append(f"   information, the raw interpolated primitive (not gated since issue 22: between grid "
                         f"points rtctl commands check 4's iterate, not the interpolation): x {it['x_error_per_scale']:.3g} "
                         f"variable scales, jac_g_x {it['jac_g_x_rel_error']:.3g}, wrench_jac "
                         f"{it['wrench_jac_rel_error']:.3g} (the former gate {it['tolerance_per_scale']:.2g}: "
                         f"{'within' if it['raw_within_tolerance'] else 'EXCEEDED'}); worst centre {it['worst_midpoint']}")
            for m in it["per_midpoint"]:
                lines.append(f"     {m['midpoint']}: x {m['x_error_per_scale']:.3g}, reference {m['reference']}, "
                             f"objective {m['objective']:.6g}, optima found {m['optima']}")
        if self.online:
            on = self.online
            lines.append(f"4. Online step (gated): rtctl's real-time iteration from its restart (continuation from the corners), "
                         f"{on['ticks']} ticks at each centre of check 3, against that optimum; targets (issue 20) "
                         f"tick 1 balance {on['tick1_targets']}, tick {on['ticks']} {on['targets']}"
                         + (f" (or another local optimum: {on['other_optimum']})" if "other_optimum" in on else "") + ":")
            for r in on["per_centre"]:
                errs = ", ".join(f"{e:.2g}" for e in r.get("x_error_per_scale_by_tick", []))
                head = f"    at {r['midpoint']}: x error per tick (variable scales) [{errs}]"
                if "tick1_balance" in r:
                    head += "; tick 1 " + ", ".join(f"{k} {v:.2g}" for k, v in r["tick1_balance"].items())
                if "last" in r:
                    head += f"; tick {on['ticks']} " + ", ".join(f"{k} {v:.2g}" for k, v in r["last"].items()
                                                              if k in on["targets"])
                if r.get("accepted") == "other optimum":
                    o = r["other"]
                    head += (f"; another local optimum: converged (last step {o['last_step_per_scale']:.2g}), "
                             f"balanced ({', '.join(f'{k} {v:.2g}' for k, v in o['balance'].items())}), objective "
                             f"{100 * o['objective_above_reference']:+.3f} % against the reference's")
                if r.get("why"):
                    head += f"; {r['why']}"
                lines.append(f"{head}  {ok(bool(r['passed']))}")
        lines += [f"note: {n}" for n in self.notes]
        if self.verdicts:
            lines.append("verdicts: " + ", ".join(f"{k} {'passed' if v else 'FAILED'}" for k, v in self.verdicts.items()))
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
    """Central quotients; where one side is outside the function's domain (``fun`` returns NaN
    there), the one-sided quotient from the other side (the point itself is in the domain)."""
    f0 = np.asarray(fun(x), dtype=float)
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = step[i]
        fp, fm = np.asarray(fun(x + e), dtype=float), np.asarray(fun(x - e), dtype=float)
        if np.all(np.isfinite(fp)) and np.all(np.isfinite(fm)):
            cols.append((fp - fm) / (2 * step[i]))
        elif np.all(np.isfinite(fp)):
            cols.append((fp - f0) / step[i])
        elif np.all(np.isfinite(fm)):
            cols.append((f0 - fm) / step[i])
        else:
            raise ValueError(f"Jacobian check: both sides of variable {i} at step {step[i]:.3g} are outside the "
                             "model's domain; no difference quotient exists there")
    return np.stack(cols, axis=-1)


def _rel(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def _quotients(fun: Callable[[NDArray[np.float64]], NDArray[np.float64]], z: NDArray[np.float64], j: int,
               step: float) -> dict[str, NDArray[np.float64]]:
    """Central, forward and backward quotients of ``fun`` in ``z[j]`` at each step of ``step`` times
    (1, :data:`_LADDER`), each divided by the step as represented (``(z + h) - z``). Returns
    ``{side: array (steps, rows)}``."""
    f0 = np.asarray(fun(z), dtype=float).ravel()
    out: dict[str, list[NDArray[np.float64]]] = {"central": [], "forward": [], "backward": []}
    for r in (1.0, *_LADDER):
        zp, zm = z.copy(), z.copy()
        zp[j] = z[j] + r * step
        zm[j] = z[j] - r * step
        hp, hm = zp[j] - z[j], z[j] - zm[j]
        fp, fm = np.asarray(fun(zp), dtype=float).ravel(), np.asarray(fun(zm), dtype=float).ravel()
        out["central"].append((fp - fm) / (hp + hm))
        out["forward"].append((fp - f0) / hp)
        out["backward"].append((f0 - fm) / hm)
    return {k: np.array(v) for k, v in out.items()}


def _check_block(fun: Callable[[NDArray[np.float64]], NDArray[np.float64]], z: NDArray[np.float64],
                 step: NDArray[np.float64], stored: NDArray[np.float64], block: str, point: dict[str, float],
                 rows: Sequence[str], cols: Sequence[str], entries: list[dict[str, Any]]) -> float:
    """One Jacobian block at one point (module docstring, check 1). Returns the block's error (entries
    that needed smaller steps count with ``max(error, convergence)``) and appends those entries to
    ``entries``."""
    stored = np.atleast_2d(np.asarray(stored, dtype=float))
    num = np.atleast_2d(_central(fun, z, step))
    scale = max(float(np.max(np.abs(num))), float(np.max(np.abs(stored))), 1e-300)
    err = np.abs(stored - num) / scale
    worst = float(np.max(err, initial=0.0))
    bad = np.argwhere(err > JACOBIAN_RTOL)
    if bad.size == 0:
        return worst
    # the block's scale without the rejected quotients (a quotient across a cusp can be huge): the
    # accepted ones and the stored values (a huge wrong stored entry then fails against its limit)
    good = err <= JACOBIAN_RTOL
    scale = max(float(np.max(np.abs(num[good]), initial=0.0)), float(np.max(np.abs(stored))), 1e-300)
    err = np.abs(stored - num) / scale
    worst = float(np.max(np.where(good, err, 0.0), initial=0.0))
    for j in sorted({int(c) for c in bad[:, 1]}):
        q = _quotients(fun, z, j, float(step[j]))
        for i in (int(r) for r in bad[bad[:, 1] == j, 0]):
            best: tuple[float, str, int] = (math.inf, "central", 0)
            for side, d in q.items():
                for k in range(1, d.shape[0]):
                    e = max(abs(stored[i, j] - d[k, i]), abs(d[k, i] - d[k - 1, i])) / scale
                    if e < best[0]:
                        best = (e, side, k)
            e, side, k = best
            worst = max(worst, e)
            entries.append({"point": point, "block": block, "row": rows[i], "column": cols[j],
                            "stored": float(stored[i, j]), "limit": float(q[side][k, i]), "side": side,
                            "step": FD_STEP * (_LADDER[k - 1] if k else 1.0), "standard": float(num[i, j]),
                            "error": e})
    return worst


def check_jacobians(t: Table, spec: TableSpec, flats: list[int],
                    entries: list[dict[str, Any]] | None = None) -> dict[str, float]:
    """Largest relative error of the stored Jacobians against difference quotients (module
    docstring, check 1). ``entries`` (optional) collects every entry that needed smaller steps;
    a block with such entries is held to :data:`STEEP_RTOL`, every other one to
    :data:`JACOBIAN_RTOL`."""
    from ..physics.backend import NUMPY

    pb = _problem(spec.scenario, spec.solver)
    lay = t.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    psc = lay_pscale(lay)
    d = _derivatives(pb)
    found: list[dict[str, Any]] = [] if entries is None else entries
    errs = {"wrench_jac": 0.0, "jac_g_x": 0.0, "jac_g_p": 0.0, "grad_f": 0.0}
    wheel_inputs = ("v_x", "v_y", "omega", "h", "h0")
    wrench_rows = ("F_x", "F_y", "F_z", "M_x", "M_y", "M_z")
    for flat in flats:
        idx = np.unravel_index(flat, t.shape)
        x, p = t.arrays["x"][idx], t.arrays["p"][idx]
        op = spec.grid.point(flat)
        pt = {k: round(v, 6) for k, v in op.items()}
        sc = scenario_at(spec.scenario, spec.family, op)
        for k, w in enumerate(lay.wheels):
            if p[lay.index(f"contact {w}")] == 0.0:
                continue
            om, beta, _, h, h0 = (x[lay.var(v, w)] for v in ("omega", "beta", "W", "h", "h0"))
            vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, beta)
            s = np.array([vx, vy, om, h, h0], dtype=float)
            # numpy path of the wheel's own model (its radius) plus the hub drag, if any

            def wrench(z: NDArray[np.float64], w: str = w) -> NDArray[np.float64]:
                # NaN outside the numpy model's domain (omega against the travel direction): a wheel
                # steered at +-90 deg (stuck) moves sideways, v_x = 0 at the optimum, and a step of
                # v_x to the negative side leaves the domain; the quotients then take the inside side
                try:
                    return np.array(pb.wheel_wrench(w, *z)[0], dtype=float)
                except ValueError as exc:
                    if "outside the model's domain" not in str(exc):
                        raise
                    return np.full(len(wrench_rows), np.nan)

            e = _check_block(wrench, s, FD_STEP * np.maximum(np.abs(s), 1e-3), t.arrays["wrench_jac"][idx][k],
                             "wrench_jac", pt, [f"{r} {w}" for r in wrench_rows], [f"{c} {w}" for c in wheel_inputs],
                             found)
            errs["wrench_jac"] = max(errs["wrench_jac"], e)

        def g_x(z: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.asarray(d.gfun(z / xsc, p), dtype=float).ravel() * csc

        def g_p(q: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.asarray(d.gfun(x / xsc, q), dtype=float).ravel() * csc

        def f_x(z: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.array([float(d(z / xsc, p, np.zeros(lay.ng))[1].item())])

        errs["jac_g_x"] = max(errs["jac_g_x"], _check_block(g_x, x, FD_STEP * xsc, t.arrays["jac_g_x"][idx], "jac_g_x",
                                                            pt, lay.constraint_names, lay.variable_names, found))
        errs["jac_g_p"] = max(errs["jac_g_p"], _check_block(g_p, p, FD_STEP * psc, t.arrays["jac_g_p"][idx], "jac_g_p",
                                                            pt, lay.constraint_names, lay.parameter_names, found))
        errs["grad_f"] = max(errs["grad_f"], _check_block(f_x, x, FD_STEP * xsc, t.arrays["grad_f"][idx], "grad_f",
                                                          pt, ["objective"], lay.variable_names, found))
    return errs


def jacobian_tolerances(entries: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Tolerance per block: :data:`STEEP_RTOL` for a block with entries that needed smaller steps,
    else :data:`JACOBIAN_RTOL`."""
    steep = {e["block"] for e in entries}
    return {b: (STEEP_RTOL if b in steep else JACOBIAN_RTOL) for b in ("wrench_jac", "jac_g_x", "jac_g_p", "grad_f")}


def lay_pscale(lay: Any) -> NDArray[np.float64]:
    """Parameter scales of a layout (finite-difference steps are a fraction of them)."""
    return np.array([b.scale for b in lay.parameters])


def _resolve_from(pb: Any, sc: Any, spec: TableSpec, x0: NDArray[np.float64], lam_x: NDArray[np.float64] | None,
                  lam_g: NDArray[np.float64] | None,
                  more: Sequence[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = ()
                  ) -> NDArray[np.float64] | None:
    """The NLP's solution at ``sc`` reached from ``x0`` (scaled), or None: one IPOPT run warm with the
    multipliers ``lam_x``, ``lam_g`` (scaled; skipped when None), then one with IPOPT's own dual
    initialisation (the re-solve a trust radius claims, with the optimizer's full per-run budget
    instead of the build's 30 iterations), then warm runs from the further starts ``more``
    (``(x0, lam_x, lam_g)``), then the optimizer's search from ``x0``. The first that converges
    must also pass the optimizer's independent numeric check
    (:func:`~offline.rover.primitives.check_solution`)."""
    from .primitives import check_solution, solve_primitive

    b = pb.bounds(sc)
    runs: list[tuple[Any, ...]] = ([(x0, lam_x, lam_g)] if lam_x is not None else []) + [(x0,)] + list(more)
    for args in runs:
        r = pb.solve(b, *args)
        if r["success"]:
            xr = np.asarray(r["x"], dtype=float)
            return xr if check_solution(pb, sc, xr)[1] else None
    res = solve_primitive(sc, spec.solver, x0=x0)
    return np.asarray(res.x, dtype=float) if res.status == "optimal" else None


def check_trust_radius(t: Table, spec: TableSpec, flats: Sequence[int]) -> tuple[list[dict[str, Any]], list[str]]:
    """The gated linearisation check (module docstring, check 2): at each point and each continuous
    parameter with a verified radius, the prediction at ``+-`` the radius against a re-solve.

    Returns the checks (dicts: point, parameter, step, error, tolerance) and notes (parameters
    skipped because their radius is the unverified fallback).
    """
    from .primitives import solve_primitive

    lay = t.layout
    xsc = lay.variable_scale
    tol = spec.build.trust_tolerance
    out: list[dict[str, Any]] = []
    notes: list[str] = []
    for flat in flats:
        idx = np.unravel_index(flat, t.shape)
        op = spec.grid.point(flat)
        pt = {k: round(v, 6) for k, v in op.items()}
        sc = scenario_at(spec.scenario, spec.family, op)
        x, dxdp = t.arrays["x"][idx], t.arrays["dx_dp"][idx]
        pb = _problem(sc, spec.solver)
        lam_x = t.arrays["lam_x"][idx] * xsc  # IPOPT's scaled multipliers (the table stores physical ones)
        lam_g = t.arrays["lam_g"][idx] * lay.constraint_scale
        radius, unverified = t.arrays["trust_radius"][idx], t.arrays["trust_unverified"][idx]
        for name in _LIN_PARAMS:
            j = lay.index(name)
            if unverified[j] != 0.0:
                notes.append(f"{pt} {name}: trust radius is the unverified fallback {radius[j]:.3g} (not gated)")
                continue
            for sgn in (1.0, -1.0):
                dp = sgn * float(radius[j])
                kw: dict[str, Any] = {name: getattr(sc, name) + dp}
                if name == "speed":
                    kw.update(_fam_follow(spec, sc, sc.speed + dp))
                pred = x + dxdp[:, j] * dp
                sc2 = replace(sc, **kw)
                xr = _resolve_from(pb, sc2, spec, pred / xsc, lam_x, lam_g)
                e = float(np.max(np.abs(pred - xr * xsc) / xsc)) if xr is not None else math.nan
                out.append({"point": pt, "parameter": name, "step": dp, "error": e, "tolerance": tol})
    return out, notes


def _direct_data(spec: TableSpec, sc: Any, x_s: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
    """``x``, ``jac_g_x`` and ``wrench_jac`` of a directly solved point, in physical units, computed
    as :func:`~offline.rover.table_builder.point_data` does (without its controllers and trust
    radius, which the interpolation check does not compare)."""
    from ..physics.backend import NUMPY

    pb = _problem(sc, spec.solver)
    lay = pb.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    p = np.asarray(pb.bounds(sc)["p"], dtype=float)
    jgx_s = _derivatives(pb)(x_s, p, np.zeros(lay.ng))[2]
    x = x_s * xsc
    wj = np.zeros((len(lay.wheels), 6, 5))
    for k, w in enumerate(lay.wheels):
        if p[lay.index(f"contact {w}")] == 0.0:
            continue
        om, beta, _, h, h0 = (x[lay.var(v, w)] for v in ("omega", "beta", "W", "h", "h0"))
        vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, beta)
        wj[k] = np.asarray(pb.wheel_function(w)(np.array([vx, vy, om, h, h0], dtype=float))[1])
    return {"x": x, "jac_g_x": csc[:, None] * jgx_s / xsc[None, :], "wrench_jac": wj}


def _corner_starts(t: Table, cell: tuple[int, ...], op: dict[str, float]
                   ) -> list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]]:
    """Warm starts (scaled) at a cell midpoint from each feasible corner: its primitive moved by its
    sensitivity to the midpoint's slope, cross slope and speed, with its multipliers."""
    lay = t.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    multi = [i for i, n in enumerate(t.shape) if n > 1]
    out = []
    for b in range(2 ** len(multi)):
        k = list(cell)
        for j, a in enumerate(multi):
            k[a] += (b >> j) & 1
        idx = tuple(k)
        if not t.feasible[idx]:
            continue
        corner = t.grid_point(idx)
        dp = np.zeros(lay.np_)
        for name in ("slope", "cross_slope", "speed"):
            if name in op and name in corner:
                dp[lay.index(name)] = op[name] - corner[name]
        x = (t.arrays["x"][idx] + t.arrays["dx_dp"][idx] @ dp) / xsc
        out.append((x, t.arrays["lam_x"][idx] * xsc, t.arrays["lam_g"][idx] * csc))
    return out


CONTINUATION_STEPS = 4
"""Initial steps of the continuation from each corner of a cell to its midpoint (check 3); a step
that does not converge is halved, down to :data:`CONTINUATION_MIN_STEP` of the way."""

CONTINUATION_MIN_STEP = 1.0 / 64
"""Smallest continuation step, as a fraction of the corner-to-midpoint way."""


def _better(f: float, x: NDArray[np.float64], f0: float, x0: NDArray[np.float64], ib: Sequence[int]) -> bool:
    """The builder's order of optima (``table_builder.polish_point``): a lower objective by more
    than 1e-6 relative; at an equal objective, the lexicographically lower steering angles (the
    first one differing by more than 1e-3, scaled)."""
    tol_f = 1e-6 * max(abs(f0), 1e-3)
    if f < f0 - tol_f:
        return True
    if f > f0 + tol_f:
        return False
    d = np.asarray(x)[list(ib)] - np.asarray(x0)[list(ib)]
    k = np.flatnonzero(np.abs(d) > 1e-3)
    return bool(k.size) and d[k[0]] < 0


def _continue_from_corner(t: Table, spec: TableSpec, idx: tuple[int, ...], op: dict[str, float]) -> dict[str, Any] | None:
    """The corner ``idx``'s optimum followed to the midpoint ``op`` along the straight line of every
    axis at once: steps of 1 / :data:`CONTINUATION_STEPS` of the way, each one IPOPT run warm from
    the previous step's primal-dual point (the first from the corner's primitive moved by its
    sensitivity) with the build's warm budget (``build.trust_max_iter``, 30 iterations: a short
    step from a converged point needs a few), a step that does not converge or fails the independent check halved down to
    :data:`CONTINUATION_MIN_STEP`. Returns the last run's result at the midpoint (the corner's
    own branch there), or None where the branch cannot be followed (it ends, or turns, inside the
    cell)."""
    from .primitives import check_solution

    lay = t.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    corner = t.grid_point(idx)
    x_c = t.arrays["x"][idx]
    state: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None
    s, h = 0.0, 1.0 / CONTINUATION_STEPS
    r: dict[str, Any] | None = None
    while s < 1.0 - 1e-12:
        sn = min(1.0, s + h)
        opk = {a: corner[a] + (op[a] - corner[a]) * sn for a in op}
        if state is None:
            dp = np.zeros(lay.np_)
            for name in ("slope", "cross_slope", "speed"):
                if name in op:
                    dp[lay.index(name)] = opk[name] - corner[name]
            start = ((x_c + t.arrays["dx_dp"][idx] @ dp) / xsc, t.arrays["lam_x"][idx] * xsc, t.arrays["lam_g"][idx] * csc)
        else:
            start = state
        sc = scenario_at(spec.scenario, spec.family, opk)
        pb = _problem(sc, spec.solver)
        r = pb.solve(pb.bounds(sc), *start, max_iter=spec.build.trust_max_iter)
        if r["success"] and check_solution(pb, sc, r["x"])[1]:
            state, s = (r["x"], r["lam_x"], r["lam_g"]), sn
            h = min(2 * h, 1.0 / CONTINUATION_STEPS)
            continue
        h /= 2
        if h < CONTINUATION_MIN_STEP - 1e-15:
            return None
    return r


def _best(found: Sequence[tuple[str, dict[str, Any]]], ib: Sequence[int]) -> tuple[str, dict[str, Any]]:
    """The best of ``(label, solver result)`` pairs by :func:`_better` (the first of equals)."""
    best = found[0]
    for cand in found[1:]:
        if _better(float(cand[1]["f"]), cand[1]["x"], float(best[1]["f"]), best[1]["x"], ib):
            best = cand
    return best


def _x_error(x_interp: NDArray[np.float64], x_scaled: NDArray[np.float64], xsc: NDArray[np.float64]) -> float:
    """Largest ``|x_interp - x|`` per variable scale (``x_interp`` physical, ``x_scaled`` scaled)."""
    return float(np.max(np.abs(x_interp / xsc - np.asarray(x_scaled, dtype=float))))


def _cell_corners(t: Table, cell: tuple[int, ...]) -> list[tuple[int, ...]]:
    """The feasible corners of a cell, one per speed-equivalence class: corners that differ only in
    speed hold the same NLP scaled exactly (the speed twins' rule), so the lower speed stands for
    both."""
    multi = [i for i, n in enumerate(t.shape) if n > 1]
    speed_axis = t.axis_order.index("speed") if "speed" in t.axis_order else -1
    out = []
    for b in range(2 ** len(multi)):
        k = list(cell)
        for j, a in enumerate(multi):
            if a == speed_axis and (b >> j) & 1:
                break
            k[a] += (b >> j) & 1
        else:
            if t.feasible[tuple(k)]:
                out.append(tuple(k))
    return out


def check_interpolation(t: Table, spec: TableSpec, cells: list[tuple[int, ...]], tol: float | None = None,
                        references: list[tuple[dict[str, float], NDArray[np.float64]]] | None = None
                        ) -> dict[str, Any]:
    """At each cell midpoint: interpolated ``x``, ``jac_g_x`` and ``wrench_jac`` against a direct solve.

    The direct solve must be the optimum the table's rule would store there, not whichever local
    optimum a start happens to reach first: (7.25) has several (a wheel at the motor limit or not,
    mirrored steering), and the builder keeps, of the optima its neighbours reach, the one with
    the lowest objective (``table_builder.polish_point``). So every start is run -- the
    interpolated primitive (warm with the interpolated multipliers, then cold) and each corner's
    primitive moved by its sensitivity (one warm run, :func:`_corner_starts`) -- and each
    feasible corner's optimum is followed to the midpoint by a continuation in
    :data:`CONTINUATION_STEPS` steps (:func:`_continue_from_corner`: the corner's own branch);
    of all the results that pass the optimizer's independent check, the best by the builder's
    order (:func:`_better`) is the reference (warm runs with the builder's warm budgets,
    ``build.polish_max_iter`` and ``build.trust_max_iter``); only when none converges, the optimizer's search from the
    interpolated primitive. Until issue 22 (2026-11-27) the check took the first start that
    converged: at ``rr_unpowered``'s midpoint (7.5 deg slope, 5 deg cross slope) that was a
    second optimum, the front-right wheel at 4.09 rad/s with an objective of 1.062, while the
    corners' branch continues to 1.56 rad/s at 0.909 (a "4.09 scales" error that was a branch
    change, not the grid's; measured by a continuation along the slope, forward and backward).

    ``tol`` (variable scales): the continuations run only when the best optimum of the direct
    starts is farther than ``tol`` from the interpolation; None: always, as :func:`verify_table`
    does since check 4 (the online step is judged against the best optimum at every centre, also
    where the interpolation is close to some optimum). Cost on the quick verify of the 7 shipped
    tables (2 points and cells each): 12.9 CPU s with the former first-start reference, 40.5 with
    continuations at every midpoint, 38.3 gated by the raw tolerance, the same verdicts and errors.

    ``references``: when given, ``(midpoint, reference optimum x, physical)`` is appended for every
    centre with a primitive (check 4's input).

    Returns the largest errors (x: per variable scale; Jacobians: relative to the largest entry),
    the number of midpoints where no primitive was found and those midpoints, and per midpoint
    the distinct optima found (``optima``: objectives of results more than 1e-3 variable scales
    apart) and whether the first converged start (the former reference) was another optimum
    (``first_start_other_optimum``).
    """
    from .primitives import check_solution, solve_primitive

    lay = t.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    ib = [lay.var("beta", w) for w in lay.wheels]
    ex, ej, ew, fails, where = 0.0, 0.0, 0.0, 0, None
    holes, per_mid = [], []
    for c in cells:
        op = {k: float(0.5 * (t.axes[k][i] + t.axes[k][i + 1])) if len(t.axes[k]) > 1 else float(t.axes[k][0])
              for k, i in zip(t.axis_order, c)}
        tp = t.at(**op)
        sc = scenario_at(spec.scenario, spec.family, op)
        pb = _problem(sc, spec.solver)
        b = pb.bounds(sc)
        found: list[tuple[str, dict[str, Any]]] = []
        runs = [("interpolated, warm", (tp.x / xsc, tp.lam_x * xsc, tp.lam_g * csc)), ("interpolated", (tp.x / xsc,))]
        runs += [(f"corner {k} start", s) for k, s in enumerate(_corner_starts(t, c, op))]
        for label, args in runs:  # warm runs with the build's warm budget (neighbour pass), the cold one the full
            r = pb.solve(b, *args, max_iter=spec.build.polish_max_iter if len(args) == 3 else None)
            if r["success"] and check_solution(pb, sc, r["x"])[1]:
                found.append((label, r))
        if tol is None or not found or _x_error(tp.x, _best(found, ib)[1]["x"], xsc) > tol:
            for idx in _cell_corners(t, c):
                r = _continue_from_corner(t, spec, idx, op)
                if r is not None:
                    found.append((f"continued from {t.grid_point(idx)}", r))
        if not found:
            res = solve_primitive(sc, spec.solver, x0=tp.x / xsc)
            if res.status == "optimal":
                found.append(("optimizer search", {"x": np.asarray(res.x, dtype=float), "f": float(res.objective)}))
        opr = {k: round(v, 6) for k, v in op.items()}
        if not found:
            fails += 1
            holes.append(opr)
            continue
        best = _best(found, ib)
        optima: list[tuple[float, NDArray[np.float64]]] = []
        for _, r in found:
            xr = np.asarray(r["x"], dtype=float)
            if all(np.max(np.abs(xr - xo)) > 1e-3 for _, xo in optima):
                optima.append((float(r["f"]), xr))
        first = np.asarray(found[0][1]["x"], dtype=float)
        xr = np.asarray(best[1]["x"], dtype=float)
        dd = _direct_data(spec, sc, xr)
        e = float(np.max(np.abs(tp.x - dd["x"]) / xsc))
        if e > ex:
            ex, where = e, op
        ej = max(ej, _rel(tp.jac_g_x, dd["jac_g_x"]))
        ew = max(ew, _rel(tp.wrench_jac, dd["wrench_jac"]))
        per_mid.append({"midpoint": opr, "x_error_per_scale": e, "reference": best[0],
                        "objective": float(best[1]["f"]), "optima": sorted(round(f, 6) for f, _ in optima),
                        "first_start_other_optimum": bool(np.max(np.abs(first - xr)) > 1e-3)})
        if references is not None:
            references.append((op, dd["x"]))
    return {"midpoints": len(cells), "no_direct_solution": fails, "x_error_per_scale": ex,
            "jac_g_x_rel_error": ej, "wrench_jac_rel_error": ew,
            "worst_midpoint": {k: round(v, 6) for k, v in where.items()} if where else None,
            "midpoints_without_primitive": holes, "per_midpoint": per_mid}


ONLINE_TICKS = 5
"""Ticks of rtctl's online step run at each sampled cell centre (check 4): one second at 5 Hz, the
tick at which issue 20's accuracy targets are stated (``tests/bench/bench_online_step.py``)."""

ONLINE_TICK1_TARGETS = {"force_N": 0.1, "moment_Nm": 0.01, "load_N": 0.2}
"""Issue 20's first-tick targets for the mini rover of Table 7.2: the largest residual of the first
tick's command by the optimizer's independent check (free-body force and moment balance, wheel load
balance). Another rover's are these times its weight (force, load) or weight times length (moment)
over the mini rover's (:data:`TARGET_ROVER`; :func:`tick1_targets`)."""

TARGET_ROVER = (34.3, 0.32)
"""Weight (N) and length (m, ``SteadyStateProblem.length``) of the mini rover the first-tick
targets were set for (the values its problem reports)."""


def tick1_targets(weight: float, length: float) -> dict[str, float]:
    """:data:`ONLINE_TICK1_TARGETS` scaled to a rover of ``weight`` (N) and ``length`` (m): the
    same fraction of its weight, and of weight times length for the moment (a 645 N six-wheel
    rover's first tick is held to 1.9 N, 0.76 N m, 3.8 N)."""
    w0, l0 = TARGET_ROVER
    f, m = weight / w0, weight * length / (w0 * l0)
    return {"force_N": ONLINE_TICK1_TARGETS["force_N"] * f, "moment_Nm": ONLINE_TICK1_TARGETS["moment_Nm"] * m,
            "load_N": ONLINE_TICK1_TARGETS["load_N"] * f}

ONLINE_TARGETS = {"wheel_speed_rel": 0.02, "steer_deg": 0.3, "objective_rel": 0.005}
"""Issue 20's targets after :data:`ONLINE_TICKS` ticks, against the verified NLP optimum at the same
point: wheel speeds within 2 % (a speed below 5 % of its scale compared absolutely to that floor),
steering within 0.3 deg, objective (7.24) within 0.5 %."""

ONLINE_OTHER_OPTIMUM = {"objective_rel": 0.005, "step_per_scale": 1e-3}
"""Check 4's acceptance of another local optimum than the reference after :data:`ONLINE_TICKS`
ticks (module docstring, check 4): its objective (7.24) at most ``objective_rel`` above the
reference's (relative; issue 20's objective target), the last tick's step at most
``step_per_scale`` (largest change of the command per variable scale: the iteration has
converged, so with the exact Jacobian the command is a KKT point of (7.25)), and its balance by
the independent check within the first-tick targets (:func:`tick1_targets`)."""


def _online_metrics(lay: Any, x: NDArray[np.float64], xstar: NDArray[np.float64], f: float,
                    fstar: float) -> dict[str, float]:
    """Issue 20's accuracy measures of a command ``x`` against the optimum ``xstar`` (physical)."""
    om = np.array([lay.var("omega", w) for w in lay.wheels])
    be = np.array([lay.var("beta", w) for w in lay.wheels])
    xsc = np.asarray(lay.variable_scale, dtype=float)
    floor = 0.05 * xsc[om]
    return {"wheel_speed_rel": float(np.max(np.abs(x[om] - xstar[om]) / np.maximum(np.abs(xstar[om]), floor))),
            "steer_deg": float(np.max(np.abs(x[be] - xstar[be])) * 180.0 / math.pi),
            "objective_rel": float(abs(f - fstar) / max(abs(fstar), 1e-12)),
            "x_error_per_scale": float(np.max(np.abs(x - xstar) / xsc))}


def _balance(spec: TableSpec, sc: Any, x: NDArray[np.float64], xsc: NDArray[np.float64]) -> dict[str, float]:
    """Largest force, moment and load residual of a physical ``x`` by the optimizer's independent
    check (``primitives.check_solution``)."""
    from .primitives import check_solution

    res, _ = check_solution(_problem(sc, spec.solver), sc, x / xsc)
    return {"force_N": max(abs(v) for k, v in res.items() if k in ("balance Fx", "balance Fy", "balance Fz")),
            "moment_Nm": max(abs(v) for k, v in res.items() if k.startswith("balance M")),
            "load_N": max([abs(v) for k, v in res.items() if k.startswith(("load ", "zero-slip load "))] or [0.0])}


def check_online(t: Table, spec: TableSpec, references: Sequence[tuple[dict[str, float], NDArray[np.float64]]],
                 ticks: int = ONLINE_TICKS, settings: Any = None,
                 other_optimum: dict[str, float] | None = None) -> dict[str, Any]:
    """Check 4: what rtctl commands at a cell centre, against the verified NLP optimum there.

    Since issue 20 the table is not the command between grid points: each 5 Hz tick is one SQP
    real-time iteration on the exact residual of (7.12)-(7.23) at the measured parameters
    (:class:`rtctl.rti.RealTimeIteration`, the controller's own class, called through its public
    ``prepare`` / ``step``), started as a restart of the controller starts (the corners' optima
    followed to the centre by a parameter continuation, or the interpolated primitive, whichever
    ends at the least exact merit: :meth:`rtctl.rti.RealTimeIteration.start`) and carrying its
    iterate; the table supplies those starts, the Lagrangian Hessian's constraint curvature, the bounds
    and the active-set hints. At each centre whose reference optimum check 3 verified
    (``references``: the midpoint and the best optimum found there, physical), the operating point
    is held constant and ``ticks`` ticks are run as the controller's QP runs them (the table's
    bounds merged with the step limit of ``settings.step_limit`` variable scales around the
    iterate; no outer-loop offsets or actuator rate limits: those are the drive's, not the
    table's). Gated by issue 20's targets: the first tick's command balanced by the independent
    check (:data:`ONLINE_TICK1_TARGETS`, scaled to the table's rover by :func:`tick1_targets`) and the command after ``ticks`` ticks at the optimum
    (:data:`ONLINE_TARGETS`), or, at another local optimum, a converged and balanced KKT point whose
    objective is within ``other_optimum`` of the reference's (default :data:`ONLINE_OTHER_OPTIMUM`;
    module docstring, check 4: why). A tick whose QP is refused fails. What makes a table fail here: a
    start outside the iteration's reach in one tick (an unbalanced first command), a start in the
    basin of a notably worse optimum, wrong bounds or curvature.

    Returns per centre the first tick's balance, the errors after each tick (``x_error_per_scale``
    and the target measures after the last), the table's interpolated start's error, whether it
    passed and how (``accepted``: ``"reference optimum"`` or ``"other optimum"``, whose last step,
    balance and objective above the reference are in ``other``); the largest of each; the number
    of centres that failed.
    """
    from rtctl.allocator import merge_bounds
    from rtctl.config import QpSettings
    from rtctl.rti import RealTimeIteration

    s = settings if settings is not None else QpSettings()
    oo = dict(ONLINE_OTHER_OPTIMUM if other_optimum is None else other_optimum)
    lay = t.layout
    xsc = np.asarray(lay.variable_scale, dtype=float)
    keep = [lay.index(f"wheel torque {w}") for w in lay.wheels]
    pb0 = _problem(spec.scenario, spec.solver)
    lim1 = tick1_targets(float(pb0.weight), float(pb0.length))
    rows: list[dict[str, Any]] = []
    for op, xstar in references:
        tp = t.at(**op)
        sc = scenario_at(spec.scenario, spec.family, op)
        rti = RealTimeIteration(t, s, keep)
        row: dict[str, Any] = {"midpoint": {k: round(v, 6) for k, v in op.items()}}
        if rti.residual is None:
            row.update(passed=False, why=rti.no_model)
            rows.append(row)
            continue
        rti.prepare(tp)
        p = np.array(tp.p, dtype=float)
        for k in ("speed", "slope", "cross_slope"):
            if k in op:
                p[lay.index(k)] = op[k]
        fstar = rti.residual.residual(xstar, p)[1]
        row["start"] = _online_metrics(lay, np.asarray(tp.x, dtype=float), xstar, rti.residual.residual(tp.x, p)[1], fstar)
        errs: list[float] = []
        x = np.asarray(tp.x, dtype=float)
        step = math.inf
        for tick in range(ticks):
            xk = rti.iterate if rti.iterate is not None else rti.allocator.x0
            box = merge_bounds(tp.lbx, tp.ubx, (xk - s.step_limit * xsc, xk + s.step_limit * xsc))
            res = rti.step(p, box)
            if not res.ok:
                row["why"] = f"tick {tick + 1}: QP refused ({res.status})"
                break
            x_new = np.asarray(res.x, dtype=float)
            step = float(np.max(np.abs(x_new - x) / xsc))
            x = x_new
            if tick == 0:
                row["tick1_balance"] = _balance(spec, sc, x, xsc)
            errs.append(float(np.max(np.abs(x - xstar) / xsc)))
        row["x_error_per_scale_by_tick"] = errs
        row["passed"] = False
        if len(errs) == ticks:
            f_last = rti.residual.residual(x, p)[1]
            row["last"] = _online_metrics(lay, x, xstar, f_last, fstar)
            tick1 = all(row["tick1_balance"][k] <= v for k, v in lim1.items())
            if tick1 and all(row["last"][k] <= v for k, v in ONLINE_TARGETS.items()):
                row.update(passed=True, accepted="reference optimum")
            elif tick1:
                # another local optimum? converged, balanced, and not notably worse (module docstring)
                bal = _balance(spec, sc, x, xsc)
                above = float((f_last - fstar) / max(abs(fstar), 1e-12))
                row["other"] = {"last_step_per_scale": step, "balance": bal, "objective_above_reference": above}
                if (step <= oo["step_per_scale"] and above <= oo["objective_rel"]
                        and all(bal[k] <= v for k, v in lim1.items())):
                    row.update(passed=True, accepted="other optimum")
                else:
                    row["why"] = (f"off the reference and not an accepted other optimum: last step {step:.2g} "
                                  f"(<= {oo['step_per_scale']:g}), objective {100 * above:+.3f} % (<= "
                                  f"{100 * oo['objective_rel']:g} %), balance "
                                  + ", ".join(f"{k} {v:.2g}" for k, v in bal.items()))
        rows.append(row)
    worst: dict[str, float] = {}
    for r in rows:
        for part in ("tick1_balance", "last"):
            for k, v in r.get(part, {}).items():
                worst[f"{part} {k}"] = max(worst.get(f"{part} {k}", 0.0), float(v))
    return {"ticks": ticks, "centres": len(rows), "failed": sum(not r["passed"] for r in rows), "worst": worst,
            "tick1_targets": {k: float(f"{v:.3g}") for k, v in lim1.items()}, "targets": dict(ONLINE_TARGETS),
            "other_optimum": oo, "other_optimum_accepted": sum(r.get("accepted") == "other optimum" for r in rows),
            "per_centre": rows}


def interpolation_tolerance(t: Table) -> float:
    """The table's own refinement tolerance if it was refined, else :data:`INTERP_TOL`."""
    ref = t.header.get("refinement") or {}
    tol = ref.get("tolerance_per_scale") if isinstance(ref, dict) else None
    return float(tol) if tol is not None else INTERP_TOL


def feasible_cells(t: Table) -> list[tuple[int, ...]]:
    """Cells (lower-corner indices) whose corners are all feasible (single-value axes kept)."""
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
            cells.append(tuple(int(i) for i in c))
    return cells


def verify_table(path: str | Path, points: int = 3, seed: int = 0, steps: tuple[float, ...] | None = None,
                 ladder: bool = True) -> VerifyReport:
    """Run the four checks of the module docstring on ``points`` sampled points (and cells) each.

    ``ladder``: also compute the informational linearisation ladder (off in the quick test of the
    shipped tables: it is not gated and costs most of the time).
    """
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
    # 1. Jacobians
    rep.jacobians = check_jacobians(t, spec, flats, rep.jacobian_entries)
    rep.jacobian_tolerances = jacobian_tolerances(rep.jacobian_entries)
    rep.verdicts["jacobians"] = all(v <= rep.jacobian_tolerances[k] for k, v in rep.jacobians.items())
    # 2. linearisation: gated at the stored trust radius; the ladder is information
    lin_flats = flats[:max(1, points // 2)]
    rep.trust, notes = check_trust_radius(t, spec, lin_flats)
    rep.notes += notes
    rep.verdicts["linearisation"] = all(c["error"] == c["error"] and c["error"] <= c["tolerance"] for c in rep.trust)
    if ladder:
        for f in lin_flats:
            idx = np.unravel_index(f, t.shape)
            data = {k: t.arrays[k][idx] for k in ("x", "dx_dp")}
            errs = linearisation_errors(spec, f, data, data["x"] / t.layout.variable_scale, steps=steps)
            rep.linearisation[str(t.grid_point(tuple(int(i) for i in idx)))] = errs
    # 3. interpolation at midpoints of cells whose corners are all feasible: a primitive at every
    # centre (gated) and the raw distance (information); 4. the online step from there (gated)
    cells = feasible_cells(t)
    if cells:
        pick = rng.choice(len(cells), size=min(points, len(cells)), replace=False)
        tol = interpolation_tolerance(t)
        refs: list[tuple[dict[str, float], NDArray[np.float64]]] = []
        # no shortcut (tol None): check 4 needs the best optimum at every centre, also where the
        # interpolation is close to some optimum
        res = check_interpolation(t, spec, [cells[int(i)] for i in sorted(pick)], None, refs)
        res["tolerance_per_scale"] = tol
        res["raw_within_tolerance"] = bool(res["x_error_per_scale"] <= tol and res["jac_g_x_rel_error"] <= tol
                                           and res["wrench_jac_rel_error"] <= tol)
        rep.interpolation = res
        rep.verdicts["interpolation"] = res["no_direct_solution"] == 0
        rep.references = refs
        rep.online = check_online(t, spec, refs)
        rep.verdicts["online step"] = rep.online["failed"] == 0 and rep.online["centres"] == len(refs) > 0
    else:
        rep.notes.append("no cell with all corners feasible: interpolation and the online step not checked")
    tr = t.header.get("trust_radius", {})
    rep.notes.append("stored trust radius (SI, smallest over the points): "
                     + ", ".join(f"{k} {v:.3g}" if v is not None else f"{k} none" for k, v in tr.items()))
    rep.passed = all(rep.verdicts.values())
    return rep
