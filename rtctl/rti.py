"""One table's real-time iteration of the steady-state problem (7.25) (acados' SQP-RTI).

:class:`RealTimeIteration` joins the table (Hessian, bounds, active-set hints, the starting
iterate), the shared physics (exact residual, objective gradient and Jacobian at the iterate and
the measured parameters: :class:`rtctl.physics.steady_state.SteadyStateResidual`) and the QP
(:meth:`rtctl.allocator.QpAllocator.solve_at`). Each :meth:`RealTimeIteration.step` is one SQP
iteration; the iterate is carried to the next, so at a constant operating point the iterates
converge to the NLP's KKT point there (with the exact Jacobian), wherever the table's grid
points are. The controller (:mod:`rtctl.controller`) adds the measurements, the outer loop,
actuator and rate limits and the declared failures; the benchmark
``tests/bench/bench_online_step.py`` drives this class alone against the NLP.

A tick may take more than one iteration (``QpSettings.iterations_per_tick``): another while the
last step was longer than ``extra_iteration_step`` variable scales, so that after a jump of the
operating point (a new table, a cross slope beyond the axes) the commanded point is balanced at
the first tick; in steady driving the steps are short and a tick is one iteration. A restart of
the iterate (a new table, a refused QP) starts on one branch of the NLP's optima, not between two
(:meth:`RealTimeIteration.start`), and its first tick may take up to ``restart_iterations``. With
``gauss_newton`` (the default) the QP's Hessian is structured: the exact Gauss-Newton part of
the objective (7.24), from the wheel-torque rows of each iteration's exact Jacobian, plus the
constraints' curvature from the table's cell corners (a corner on the wheel model's zero-slip
kink left out); with ``quasi_newton`` that curvature part is corrected by damped BFGS updates
along the way (the table's Hessian is another point's, worst in the objective's flat
directions).

A table whose header does not define the physics (no ``params`` / ``rover`` records, as in a
hand-made table) is iterated on its own first-order model at the iterate
(:attr:`RealTimeIteration.no_model`: why; callers flag it).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Generator, Sequence

import numpy as np
from numpy.typing import NDArray

from .allocator import Allocation, QpAllocator, merge_bounds
from .config import QpSettings
from .physics.parameters import ParameterError
from .physics.steady_state import SteadyStateModel, SteadyStateResidual

__all__ = ["RealTimeIteration", "BoundedRows", "free_rows"]

_CURVATURE_OUTLIER = 100.0
"""A cell corner whose curvature part exceeds this many times the median corner's is left out
(:meth:`RealTimeIteration._table_curvature`)."""

_TILT_JUMP = math.radians(1.0)
"""A change of slope or cross slope between ticks (rad) beyond which a tick may iterate again."""

_BRANCH_STEER = math.radians(30.0)
"""Two cell corners whose primitives steer some wheel more than this apart (rad) lie on different
branches of the NLP's optima (:meth:`RealTimeIteration.start`)."""

_CONVERGED_STEP = 1e-4
"""Largest last step (variable scales) of the restart's former start iterated at the point for it to
count as converged (:meth:`RealTimeIteration._continued_start`: no continuation then)."""

_CONVERGED_VIOLATION = 1e-6
"""Largest l1 violation of the row bounds (scaled rows) for the same."""

_MAX_BRANCHES = 3
"""Most branches of a cell tried as a start (the heaviest), besides the whole cell's interpolation."""


def free_rows(lbg: NDArray[np.float64], ubg: NDArray[np.float64], keep: Sequence[int] = ()) -> NDArray[np.bool_]:
    """Rows without bounds (``lbg = -inf``, ``ubg = +inf``), except the rows in ``keep`` (the
    wheel-torque rows, which a declared failure bounds)."""
    free = (np.asarray(lbg, dtype=float) <= -1e20) & (np.asarray(ubg, dtype=float) >= 1e20)
    free[[int(j) for j in keep if j >= 0]] = False
    return free


class BoundedRows:
    """A table point whose rows without bounds (:func:`free_rows`) have zero value and Jacobian.

    Such a row constrains nothing, so the QP is the same; but its Jacobian can be huge (the trench
    flat width ``p`` of ch. 4 near the pointy/flat switch: 1.3e5 in the QP's scaled units against
    <= 8 for every other row), and that ruins OSQP's conditioning (measured on the trench table:
    the QP stops at its iteration budget on most ticks)."""

    def __init__(self, tp: Any, keep: Sequence[int]) -> None:
        self._tp = tp
        free = free_rows(tp.lbg, tp.ubg, keep)
        self.free_mask = free
        """The rows without bounds (:func:`free_rows`), all False when none."""
        self._free = free if bool(free.any()) else None

    def __getattr__(self, name: str) -> Any:
        v = getattr(self._tp, name)
        if self._free is not None and name in ("g", "jac_g_x", "jac_g_p"):
            v = np.array(v, dtype=float)
            v[self._free] = 0.0
        return v


class RealTimeIteration:
    """The real-time iteration of one table (module docstring).

    Parameters
    ----------
    table : rtctl.table.Table
        Its header defines the physics (``params``, ``rover``, ``scenario``, ``solver_options``,
        ``world``) and its layout the variables and rows.
    settings : QpSettings
        QP penalties and budgets; ``exact_jacobian`` chooses the Jacobian of the rows.
    keep_rows : sequence of int
        Rows kept even without bounds (the wheel-torque rows a declared failure bounds).
    """

    def __init__(self, table: Any, settings: QpSettings, keep_rows: Sequence[int] = ()) -> None:
        self.table = table
        self.settings = settings
        self.allocator = QpAllocator(table.layout, settings)
        self.keep_rows = tuple(int(j) for j in keep_rows)
        self.residual: SteadyStateResidual | None = None
        self.no_model = ""
        """Empty when the header defines the physics; else why not (the first-order model is used)."""
        try:
            self.residual = SteadyStateResidual(SteadyStateModel.from_table_header(table.header, table.layout.wheels),
                                                table.layout)
        except (ParameterError, KeyError, TypeError, ValueError) as exc:
            self.no_model = (f"table {getattr(table, 'name', '?')}: no exact residual ({exc}); the QP's residual is the "
                             "table's first-order model at the iterate")
        self.iterate: NDArray[np.float64] | None = None
        """The physical iterate carried from step to step (None: start from the next prepared primitive)."""
        self._H: NDArray[np.float64] | None = None  # quasi-Newton Hessian (scaled, not normalised)
        # the last iteration's (x, Lagrangian gradient, multipliers, parameters): BFGS pairs are
        # taken only at equal parameters (a change of p moves the gradient without any step)
        self._prev: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None = None
        self.hessian_updates = 0
        """Quasi-Newton updates applied since the iterate last restarted (diagnostics)."""
        self._A: NDArray[np.float64] | None = None  # structured Hessian: the constraints' curvature part
        self._corner_cache: dict[int, NDArray[np.float64]] = {}  # curvature part per grid point
        self._cell_cache: dict[bytes, tuple[NDArray[np.float64], NDArray[np.bool_]]] = {}  # per cell: stack, kept
        self._A_table: NDArray[np.float64] | None = None  # the prepared point's curvature part
        self._convex = True  # the last structured Hessian needed no convexification (try a Cholesky factor first)
        self._torque_rows = np.array([table.layout.index(f"wheel torque {w}") for w in table.layout.wheels], dtype=int) \
            if self.residual is not None else np.zeros(0, dtype=int)
        self._point: Any = None
        self._free: NDArray[np.bool_] = np.zeros(table.layout.ng, dtype=bool)
        self.sqp_iterations = 0
        """SQP iterations of the last :meth:`step` (diagnostics)."""
        self._last_p: NDArray[np.float64] | None = None
        names = list(table.layout.parameter_names)
        self._i_speed = names.index("speed") if "speed" in names else -1
        self._i_tilt = np.array([names.index(k) for k in ("slope", "cross_slope") if k in names], dtype=int)
        self._beta = np.array([table.layout.var("beta", w) for w in table.layout.wheels], dtype=int)
        self.start_status = ""
        """How the last restart chose its iterate (:meth:`start`; diagnostics)."""
        self.last_objective = math.nan
        """The objective (7.24) at the last :meth:`linearise` (NaN without a model)."""
        self._restarted = False  # the iterate restarted (:meth:`start`) and no tick has run since
        self.last_continuation_step = math.inf  # the last step of the last continuation (scales)
        self._job: Generator[None, None, NDArray[np.float64]] | None = None  # a restart spread over ticks
        self.restart_work = 0
        """Units of restart work (SQP iterations, predicted-merit QPs) done in the last :meth:`prepare`
        (diagnostics; 0 when it ran none)."""
        self.restart_work_total = 0
        """Units of restart work done by the restart in progress or the last one (diagnostics)."""

    @property
    def restarting(self) -> bool:
        """A restart is in progress, spread over preparations (:meth:`prepare` with a ``budget``):
        :meth:`step` refuses (``ok`` False) until it has finished; the caller commands its fallback."""
        return self._job is not None

    def reset(self) -> None:
        """Drop the iterate and any restart in progress: the next :meth:`prepare` restarts (a new table)."""
        self.iterate, self._job = None, None

    def prepare(self, tp: Any, budget: int | None = None) -> None:
        """Load a table point (the preparation phase): Hessian, bounds, the QP's factorisation;
        the iterate restarts (:meth:`start`) when there is none.

        ``budget``: None, the whole restart in this call; else at most that many units of its
        work (one unit: one SQP iteration of the continuation, or one predicted-merit QP of
        :meth:`_branch_start`), the rest in the next calls, each with its own budget, toward the
        table point of the call that began it (:attr:`restarting` until it has finished; the
        work and its order are the same as in one call, so the result is deterministic and
        differs from one call's only through the table point each later call loads: its QP
        normalisation and the cell's curvature that the former start and the end use). Why: a
        restart is up to (corners + 1) x 7 SQP iterations and the branch candidates' QPs, measured
        39-121 ms of thread CPU at the shipped tables' cell centres and once 429 ms under load 14,
        more than the 200 ms tick (``results_online_step_restart.md``)."""
        pending = self._job is not None
        if self.iterate is None and not pending:
            self._H, self._prev, self.hessian_updates = None, None, 0
        # the iteration goes on: keep what it learnt of the curvature (else the table's, convexified)
        bounded = BoundedRows(tp, self.keep_rows)
        self._point = tp
        if self._structured():
            # the table's Lagrangian Hessian less its objective's Gauss-Newton part: what the
            # constraints' curvature contributes (the exact Gauss-Newton part is added per
            # iteration); an iteration that goes on keeps what it learnt
            A_table = self._A_table = self._table_curvature(tp)
            if self._H is None and not pending:  # a restart in progress keeps its corner's curvature
                self._A = A_table
            # the QP's matrix is replaced at every iteration (_structured_hessian) before any
            # solve; here it sets the objective's normalisation only, so it needs no convexifying
            start = self._H if self._H is not None else self._gauss_newton(np.asarray(tp.jac_g_x, dtype=float)) + A_table
            if not self.allocator.set_up:  # OSQP's set-up (once) needs a convex P
                w, V = np.linalg.eigh(0.5 * (start + start.T))
                start = (V * np.maximum(w, self.settings.regularization * max(float(np.abs(w).max()), 1e-12))) @ V.T
            self.allocator.prepare(bounded, hessian=start, scale_by_hessian=True)
        else:
            self.allocator.prepare(bounded, hessian=self._H)
        self._free = bounded.free_mask
        self.restart_work = 0
        if self._job is None and self.iterate is None:
            self._job, self.restart_work_total = self._start_steps(tp), 0
        if self._job is not None:
            self._advance(budget)

    def _advance(self, budget: int | None) -> None:
        """At most ``budget`` units (None: all) of the restart in progress; at its end the iterate."""
        assert self._job is not None
        while budget is None or self.restart_work < budget:
            try:
                next(self._job)
            except StopIteration as stop:
                self._job = None
                self.iterate = np.asarray(stop.value, dtype=float)
                self._restarted = True
                return
            self.restart_work += 1
            self.restart_work_total += 1
        self.iterate = None  # the work's iterates are candidates at other parameters, not a command

    def start(self, tp: Any) -> NDArray[np.float64]:
        """The iterate a restart begins from: of the ends of a parameter continuation from each
        of the cell's corners and of the table's interpolated primitive or one branch's
        (:meth:`_branch_start`) iterated at the point, the one of least exact merit
        (:meth:`_continued_start`). ``start_status`` says which."""
        return _finish(self._start_steps(tp))

    def _start_steps(self, tp: Any) -> Generator[None, None, NDArray[np.float64]]:
        """:meth:`start` as a generator that yields after each unit of work (:meth:`prepare`)."""
        x = yield from self._branch_start(tp)
        return (yield from self._continued_start(tp, x))

    def _branch_start(self, tp: Any) -> Generator[None, None, NDArray[np.float64]]:
        """The table's interpolated primitive, unless the cell's corners lie on different branches
        of the NLP's optima.

        Corners whose primitives steer some wheel more than ``_BRANCH_STEER`` apart are on
        different branches (single linkage over the corners that carry weight). Interpolating
        across branches starts between two optima, in the basin of neither (measured on
        ``rr_steer_stuck`` at the stuck angle 41 deg: two of the eight corners, 52 % of the weight,
        steer RL at -89 deg, the others at -26 to -39 deg; from their mix the iterate was 4.2 N
        out of balance after its first tick and its objective 3.2 times the optimum's after
        five). Then each branch's own interpolation (its corners' weights renormalised, the
        ``_MAX_BRANCHES`` heaviest, clipped into the point's bounds) and the whole cell's are
        candidates, and the start is the one whose first SQP iteration, at the table point's
        parameters, predicts the least merit (:meth:`_predicted_merit`): at most
        ``_MAX_BRANCHES + 1`` linearisations and QP solves, on a restart only (a new table, a
        refused QP), never in a tick's feedback phase. ``start_status`` says which. A generator that
        yields after each candidate's QP (:meth:`prepare`'s budget)."""
        x_interp = self.allocator.x0.copy()
        self.start_status = "interpolated primitive"
        cell = getattr(tp, "cell", None)
        table = getattr(tp, "_table", None)
        if self.residual is None or cell is None or table is None or not hasattr(table, "point_field"):
            return x_interp
        idx, w = cell
        use = np.asarray(w) > 0.0
        idx, w = np.asarray(idx)[use], np.asarray(w, dtype=float)[use]
        if idx.size < 2:
            return x_interp
        X = np.stack([np.asarray(table.point_field(int(c), "x"), dtype=float) for c in idx])
        beta = X[:, self._beta]
        near = np.abs(beta[:, None, :] - beta[None, :, :]).max(axis=2) <= _BRANCH_STEER
        label = np.full(idx.size, -1)
        for i in range(idx.size):  # single linkage: connected components of the "near" graph
            if label[i] >= 0:
                continue
            label[i] = i
            todo = [i]
            while todo:
                j = todo.pop()
                for k in np.flatnonzero(near[j] & (label < 0)):
                    label[k] = i
                    todo.append(int(k))
        branches = sorted(set(label.tolist()), key=lambda b: -float(w[label == b].sum()))
        if len(branches) < 2:
            return x_interp
        lo, hi = np.asarray(tp.lbx, dtype=float), np.asarray(tp.ubx, dtype=float)
        p = np.asarray(tp.p, dtype=float)
        cands = [("interpolated primitive", x_interp)]
        for b in branches[:_MAX_BRANCHES]:
            m = label == b
            xb = np.minimum(np.maximum((w[m] @ X[m]) / float(w[m].sum()), lo), hi)
            cands.append((f"branch of {int(m.sum())} of {idx.size} corners ({float(w[m].sum()):.2f} of the weight)", xb))
        best, best_phi = cands[0], math.inf
        sl = self.settings.step_limit * self.allocator.sx
        for c in cands:
            phi = self._predicted_merit(c[1], p, (np.maximum(c[1] - sl, lo), np.minimum(c[1] + sl, hi)))
            if phi < best_phi:
                best, best_phi = c, phi
            yield
        self.start_status = best[0]
        return best[1].copy()

    def _continued_start(self, tp: Any, x_fallback: NDArray[np.float64]) -> Generator[None, None, NDArray[np.float64]]:
        """A restart by parameter continuation from the cell's corners (the table point ``tp``).

        Each grid point of the table is an exact optimum of the NLP at its own parameters
        (speed, slope, cross slope) and its own failure's bounds (a stuck angle, a rim-speed cap:
        the table's ``lbx`` / ``ubx`` there); interpolated between corners, the primitive is not,
        and across a kink of the wheel model (the zero-slip kink, a motor limit) it can start
        outside the basin of the SQP iteration, or in another optimum's (measured at the failing
        cell centres of the shipped tables, ``tests/bench/bench_tables_online.py``: a period-2
        cycle of 0.8 / 1.2 scales on rr_rim_speed_cap, a start 2.8 scales off near a 90 deg
        stuck angle that the iteration only brought to 2.1 in 5 ticks). From each corner of the
        cell with weight (one speed layer: the nearest to the point's speed, the lower one on a
        tie; the other layer's primitives are the same ones scaled, the builder's speed twins),
        the parameters, the variable bounds and the row bounds move linearly to the point's in
        ``restart_continuation_stages`` stages of ``restart_continuation_iterations`` SQP
        iterations each, then ``restart_continuation_polish`` more at the point (a path-following
        homotopy, Allgower & Georg, "Introduction to Numerical Continuation Methods", ch. 10: one
        SQP iteration at the next stage's parameters from the last stage's iterate is the
        predictor-corrector step to first order). The QP's curvature part on the way is the
        corner's own (:meth:`_corner_curvature`, exact at the corner), except for a corner the
        cell's curvature leaves out (on the zero-slip kink, :meth:`_table_curvature`), which
        follows its path with the cell's. ``x_fallback`` (:meth:`_branch_start`) is iterated as
        many times at the point itself, with the cell's curvature.

        The start is the end of least exact l1 merit at the point, ``f + 2 sum_j |y_j| v_j``
        (``v`` the violation of each row's bounds by the exact residual, ``y`` the end's last QP
        multipliers; Nocedal & Wright, 2nd ed., eq. (18.27) with a penalty per row above its
        multiplier): at a converged end it is the objective (7.24), so of two balanced ends the
        better local optimum wins, and an end not yet balanced pays at least what its imbalance
        saves in the objective (measured on rr_rim_speed_cap at cap 0.94: an end 0.47 scales from
        the optimum, violating the rows by 7e-5 scaled, had an objective 1.8 % below the
        optimum's; the bare objective among ends within a violation threshold picked it). A
        fixed count of iterations: at most (corners of one speed layer + 1) x (stages x
        iterations + polish), on a restart only (a new table, a refused QP), never in a steady
        tick. The former start goes first, and when it has converged at the point (its last step
        within ``_CONVERGED_STEP`` scales, its rows within ``_CONVERGED_VIOLATION``) the corners
        are not followed (measured on the trench table: a restart's first tick 29-31 ms of thread
        CPU instead of 51-122 at three of four points; the same verdicts at the 36 centres of the
        failure tables and the 73 accuracy points, where the former start had not converged). A
        generator that yields after each SQP iteration (:meth:`prepare`'s budget); the table
        point's data are read when it begins."""
        s = self.settings
        per = s.restart_continuation_stages * s.restart_continuation_iterations + s.restart_continuation_polish
        cell = getattr(tp, "cell", None)
        table = getattr(tp, "_table", None)
        if (self.residual is None or s.restart_continuation_stages <= 0 or cell is None or table is None
                or not hasattr(table, "point_field")):
            return x_fallback
        all_idx = np.asarray(cell[0])[np.asarray(cell[1], dtype=float) > 0.0]
        idx = all_idx
        p1 = np.asarray(tp.p, dtype=float)
        if self._i_speed >= 0 and idx.size > 1:
            sp = np.array([float(table.point_field(int(c), "p")[self._i_speed]) for c in idx])
            d = np.abs(sp - p1[self._i_speed])
            near = d <= float(d.min()) + 1e-12 * max(1.0, float(np.abs(sp).max()))
            idx = idx[near & (sp <= float(sp[near].min()))]
        hit = self._cell_cache.get(all_idx.tobytes())
        outlier = {int(c) for c, k in zip(all_idx, hit[1]) if not k} if hit is not None else set()
        xb = (np.asarray(tp.lbx, dtype=float), np.asarray(tp.ubx, dtype=float))
        gb = (np.asarray(tp.lbg, dtype=float), np.asarray(tp.ubg, dtype=float))
        sl = s.step_limit * self.allocator.sx
        best_x, best_phi, best_c = x_fallback, math.inf, -1
        for c in [-1, *[int(c) for c in idx]]:
            try:
                if c < 0:  # the fallback, at the point throughout, with the cell's curvature
                    x0, p0, b0, A = x_fallback, p1, [*xb, *gb], self._A_table
                else:
                    x0 = np.asarray(table.point_field(c, "x"), dtype=float)
                    p0 = np.asarray(table.point_field(c, "p"), dtype=float)
                    b0 = [np.asarray(table.point_field(c, k), dtype=float) for k in ("lbx", "ubx", "lbg", "ubg")]
                    A = self._A_table if c in outlier else self._corner_curvature_at(table, c)
                end = yield from self._continue_from(x0, p0, b0, A, p1, [*xb, *gb], sl, per)
                if end is None:
                    continue
                phi = self._merit(end[0], end[1], p1, gb)
            except (np.linalg.LinAlgError, FloatingPointError, ValueError):
                continue
            if phi < best_phi:
                best_x, best_phi, best_c = end[0], phi, c
            if c < 0 and self.last_continuation_step <= _CONVERGED_STEP:
                g, _ = self.residual.residual(end[0], p1)
                v = np.maximum(gb[0] - g, 0.0) + np.maximum(g - gb[1], 0.0)
                if float(np.sum(np.where(self._free | ~np.isfinite(v), 0.0, v) / self.allocator.sg)) <= _CONVERGED_VIOLATION:
                    break
        # the iteration goes on at the point with the cell's curvature (the last corner's and what
        # BFGS learnt on the way belong to other parameters)
        self._A, self._H, self._prev, self.hessian_updates = self._A_table, None, None, 0
        if best_c >= 0:
            self.start_status = f"continuation from grid point {best_c} (else {self.start_status})"
        return best_x.copy()

    def _corner_curvature_at(self, table: Any, c: int) -> NDArray[np.float64]:
        """:meth:`_corner_curvature` of grid point ``c`` (flat index), cached."""
        A = self._corner_cache.get(c)
        if A is None:
            A = self._corner_cache[c] = self._corner_curvature(table.point_field(c, "hess_lag"),
                                                               table.point_field(c, "jac_g_x"))
        return A

    def _continue_from(self, x: NDArray[np.float64], p0: NDArray[np.float64], b0: Sequence[NDArray[np.float64]],
                       A: NDArray[np.float64] | None, p1: NDArray[np.float64], b1: Sequence[NDArray[np.float64]],
                       sl: NDArray[np.float64], total: int
                       ) -> Generator[None, None, tuple[NDArray[np.float64], NDArray[np.float64]] | None]:
        """The continuation of :meth:`_continued_start` from ``x`` at parameters ``p0`` and bounds
        ``b0`` (lbx, ubx, lbg, ubg) to ``p1``, ``b1``, with the curvature part ``A``: ``total``
        SQP iterations, the last ``restart_continuation_polish`` (all, when ``p0`` and ``b0`` are
        the point's) at the point. Returns the end and its last QP's row multipliers; None when
        a QP failed or the shapes or values are not usable."""
        s = self.settings
        x = np.array(x, dtype=float)
        if not (p0.shape == p1.shape and all(a.shape == b.shape for a, b in zip(b0, b1))
                and math.isfinite(float(x.sum() + p0.sum()))):
            return None
        if self._structured() and A is not None:
            self._A = A
        self._H, self._prev = None, None
        n = s.restart_continuation_stages
        same = np.array_equal(p0, p1) and all(np.array_equal(a, b) for a, b in zip(b0, b1))
        y: NDArray[np.float64] | None = None
        for i in range(total):
            k = i // max(s.restart_continuation_iterations, 1) + 1
            t = 1.0 if (same or k > n) else k / n
            # bounds move linearly where the two ends differ (an infinite bound stays)
            lo, hi, lg, ug = (np.where(a == b, b, a + t * (b - a)) for a, b in zip(b0, b1))
            res = self._one(x, p0 + t * (p1 - p0), merge_bounds(lo, hi, (x - sl, x + sl)), lg, ug, None)
            if not (math.isfinite(res.slack) and bool(np.all(np.isfinite(res.x)))):
                return None
            x_new = np.minimum(np.maximum(res.x, b1[0]), b1[1]) if t >= 1.0 else res.x.copy()
            self.last_continuation_step = float(np.max(np.abs(x_new - x) / self.allocator.sx))
            x = x_new
            y = self.allocator.row_duals
            yield
        if y is None:
            return None
        return x, np.array(y, dtype=float)

    def _merit(self, x: NDArray[np.float64], y: NDArray[np.float64], p: NDArray[np.float64],
               gb: Sequence[NDArray[np.float64]]) -> float:
        """The exact l1 merit ``f + 2 sum_j |y_j| v_j`` at ``(x, p)`` (:meth:`_continued_start`):
        ``v`` the violation of the row bounds ``gb`` by the exact residual (rows without bounds
        excluded), ``y`` multipliers in physical units (:attr:`rtctl.allocator.QpAllocator.row_duals`)."""
        assert self.residual is not None
        g, f = self.residual.residual(x, p)
        v = np.maximum(gb[0] - g, 0.0) + np.maximum(g - gb[1], 0.0)
        v = np.where(self._free | ~np.isfinite(v), 0.0, v)
        phi = float(f) + 2.0 * float(np.abs(y) @ v)
        return phi if math.isfinite(phi) else math.inf

    def _predicted_merit(self, x: NDArray[np.float64], p: NDArray[np.float64],
                         box: tuple[NDArray[np.float64], NDArray[np.float64]]) -> float:
        """The l1 exact-penalty merit that one SQP iteration from ``x`` predicts, in the QP's
        normalised units (:meth:`rtctl.allocator.QpAllocator.solve_at`): the objective there,
        ``f(x) / c_f``, plus the QP's optimal value (the model's change of the objective and
        ``slack_l1`` times the linearised rows' l1 slack; Nocedal & Wright, 2nd ed., eq. (18.27)).
        Where the first iteration leads by the model the iteration itself trusts: the merit at
        ``x`` itself would weigh its imbalance, which that iteration removes, above its
        objective, which tells the basin (measured at the 41 deg stuck-angle point of
        ``rr_steer_stuck``, merit at the candidate: 2.96 on the wrong branch, 3.65 on the
        optimum's; the predicted merit picks the optimum's). Infinite when the residual, its
        Jacobian or the objective is not finite there, or the QP fails (the candidate is then
        never the start)."""
        g, grad, jac = self.linearise(x, p)
        f = self.last_objective
        if not (math.isfinite(float(f)) and math.isfinite(float(g.sum() + grad.sum()))
                and (jac is None or math.isfinite(float(jac.sum())))):
            return math.inf
        try:
            if jac is not None and self._structured():
                self._structured_hessian(x, grad, jac, p)
            res = self.allocator.solve_at(x, g, grad, jac, box)
        except np.linalg.LinAlgError:
            return math.inf
        phi = float(f) / self.allocator.objective_scale + float(res.objective)
        return phi if (res.ok and math.isfinite(phi)) else math.inf

    def linearise(self, x: NDArray[np.float64], p: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
        """Residual, objective gradient and (with ``exact_jacobian``) the rows' Jacobian at
        ``(x, p)``; rows without bounds zeroed. Without a model: the table point's first-order
        model (Jacobian None: the prepared table's)."""
        if self.residual is not None:
            g, self.last_objective, grad, jac = self.residual.evaluate(x, p, jacobian=self.settings.exact_jacobian)
        else:
            g, grad, jac = first_order_model(self._point, x, p)
            self.last_objective = math.nan
        if self._free.any():
            g = np.where(self._free, 0.0, g)
            if jac is not None:
                jac = np.where(self._free[:, None], 0.0, jac)
        return g, grad, jac

    def step(self, p: NDArray[np.float64], box: tuple[NDArray[np.float64], NDArray[np.float64]],
             lbg: NDArray[np.float64] | None = None, ubg: NDArray[np.float64] | None = None,
             x_ref: NDArray[np.float64] | None = None) -> Allocation:
        """SQP iterations at the measured parameters ``p`` from the carried iterate (the feedback
        phase): one, and on a tick that starts the iterate or follows a jump of the operating
        point (speed by more than 10 %, slope or cross slope by more than 1 deg since the last
        tick; not the outer loop's offsets, which move every tick) more, up to
        ``iterations_per_tick`` and all inside the same ``box``, while the last step was exact
        with zero slack and longer than ``extra_iteration_step`` variable scales, so that after a
        jump of the operating point the commanded point is balanced at once (a long step leaves
        a second-order residual; a short one, the steady case, none worth another linearisation).
        The first tick after a restart (:meth:`start`) goes on up to ``restart_iterations``
        while the step is longer than ``restart_iteration_step``: the start is the table's
        interpolated primitive, far from the optimum in the objective's flat directions, where
        the one iteration of each steady tick that follows converges slowly.
        The new iterate is carried when the QP succeeded, else the next preparation restarts
        from the table's primitive. The returned allocation's ``dx`` is the whole step of the
        tick and ``iterations`` the QP iterations of every SQP iteration."""
        s = self.settings
        if self._job is not None:  # a restart in progress (prepare's budget): nothing to command yet
            x0 = np.array(self.allocator.x0, dtype=float)
            self.sqp_iterations = 0
            return Allocation(x0, np.zeros_like(x0), False, f"restart in progress ({self.restart_work_total} units of "
                              "work done)", 0, math.inf, math.nan)
        if self._H is not None and self._prev is not None and not np.array_equal(self._prev[3], np.asarray(p, dtype=float)):
            # the parameters moved: what BFGS learnt belongs to the last operating point, so the
            # table's Hessian again (measured in closed loop, RR stuck at -65 deg on a 6 deg cross
            # slope: max heading 2.4 deg keeping the learnt matrix across ticks, 2.1 without QN)
            self._H, self.hessian_updates = None, 0
            if self._structured():
                self._A = self._A_table  # the next iteration sets the QP's matrix from it
            else:
                self.allocator.prepare(BoundedRows(self._point, self.keep_rows))
        fresh = self.iterate is None
        x_start = self.iterate if self.iterate is not None else self.allocator.x0
        p = np.asarray(p, dtype=float)
        jumped = fresh or self._jumped(p)
        self._last_p = p.copy()
        res = self._one(x_start, p, box, lbg, ubg, x_ref)
        n, qp_it = 1, res.iterations
        limit = max(s.restart_iterations, s.iterations_per_tick) if self._restarted else (s.iterations_per_tick if jumped else 1)
        thr = s.restart_iteration_step if self._restarted else s.extra_iteration_step
        self._restarted = False
        # again only after an exact zero-slack step (the active-set solve): a step that needed
        # slack was held by the tick's box (rate limits, a pinned variable), and another
        # linearisation cannot reach further inside the same box
        while res.ok and n < limit and self.allocator.last_solver == "active set" and \
                float(np.max(np.abs(res.dx) / self.allocator.sx)) > thr:
            more = self._one(res.x, p, box, lbg, ubg, x_ref)
            n += 1
            qp_it += more.iterations
            if not more.ok:  # keep the last good iterate; the next tick goes on from it
                self.iterate = res.x.copy()
                break
            res = more
        self.sqp_iterations = n
        if n > 1:
            res = replace(res, dx=res.x - x_start, iterations=qp_it, status=f"{res.status}; {n} SQP iterations")
        return res

    def _jumped(self, p: NDArray[np.float64]) -> bool:
        """The operating point jumped since the last tick: speed by more than 10 %, slope or cross
        slope by more than 1 deg (:meth:`step`)."""
        last = self._last_p
        if last is None or last.shape != p.shape:
            return True
        if self._i_speed >= 0 and abs(p[self._i_speed] - last[self._i_speed]) > 0.1 * abs(last[self._i_speed]):
            return True
        return bool(np.any(np.abs(p[self._i_tilt] - last[self._i_tilt]) > _TILT_JUMP))

    def _one(self, xk: NDArray[np.float64], p: NDArray[np.float64], box: tuple[NDArray[np.float64], NDArray[np.float64]],
             lbg: NDArray[np.float64] | None, ubg: NDArray[np.float64] | None,
             x_ref: NDArray[np.float64] | None) -> Allocation:
        """One SQP iteration from ``xk``; carries the iterate (see :meth:`step`)."""
        g, grad, jac = self.linearise(xk, p)
        if jac is not None and self._structured():
            self._structured_hessian(xk, grad, jac, p)
        elif self.settings.quasi_newton and jac is not None:
            self._update_hessian(xk, grad, jac, p)
        res = self.allocator.solve_at(xk, g, grad, jac, box, lbg, ubg, x_ref=x_ref)
        if res.ok:
            self.iterate = res.x.copy()
            y = self.allocator.row_duals
            self._prev = (xk.copy(), self._lagrangian_gradient(grad, jac, y), y, np.array(p, dtype=float)) \
                if (jac is not None and y is not None) else None
        elif math.isfinite(res.slack) and np.all(np.isfinite(res.x)):
            # solved, but the linearised balance was out of reach this tick (slack above the
            # tolerance: the caller commands its fallback): the step still went toward it, so the
            # iteration goes on from there (restarting from the table's primitive each time made the
            # rover alternate between the QP and the fallback, measured with a front wheel capped)
            self.iterate, self._prev = res.x.copy(), None
        else:
            self.iterate, self._prev = None, None
        return res

    @staticmethod
    def _lagrangian_gradient(grad: NDArray[np.float64], jac: NDArray[np.float64] | None,
                             y: NDArray[np.float64] | None) -> NDArray[np.float64]:
        return grad if (jac is None or y is None) else grad + jac.T @ y

    def _structured(self) -> bool:
        return bool(self.settings.gauss_newton and self.settings.exact_jacobian and self._torque_rows.size)

    def _gauss_newton(self, jac: NDArray[np.float64]) -> NDArray[np.float64]:
        """The Gauss-Newton part of the objective's Hessian (7.24), ``2 J_T^T J_T / torque_scale^2``
        with ``J_T`` the wheel-torque rows' Jacobian, in scaled variables (not normalised)."""
        assert self.residual is not None
        Jt = jac[self._torque_rows] * self.allocator.sx[None, :]
        return (2.0 / self.residual.model.torque_scale ** 2) * (Jt.T @ Jt)

    def _corner_curvature(self, hess_lag: NDArray[np.float64], jac_g_x: NDArray[np.float64]) -> NDArray[np.float64]:
        """A Lagrangian Hessian less the Gauss-Newton part of its objective (scaled variables, not
        normalised): the constraints' curvature with IPOPT's multipliers, plus the objective's
        own second-order term."""
        sx = self.allocator.sx
        H = (sx[:, None] * sx[None, :]) * np.asarray(hess_lag, dtype=float)
        A = 0.5 * (H + H.T) - self._gauss_newton(np.asarray(jac_g_x, dtype=float))
        return 0.5 * (A + A.T)

    def _table_curvature(self, tp: Any) -> NDArray[np.float64]:
        """The curvature part of the table's Hessian at a point: the corners' curvature parts
        (:meth:`_corner_curvature`, each from the corner's own Hessian and Jacobian) combined with
        the interpolation weights, leaving out a corner whose curvature is more than
        ``_CURVATURE_OUTLIER`` times the median corner's (largest entry) while another corner
        carries weight.

        Why: a corner whose primitive puts a wheel on the wheel model's zero-slip kink (the
        rim-speed cap at fraction 1 and cross slope 0: the capped wheel's rim speed is the
        rover's speed) has a Lagrangian Hessian of 1e5-1e6 in that wheel's omega and beta,
        against 2-40 at the other corners of the cell; interpolated, it sets the curvature a
        few % inside the cell, where the wheel slips and the exact curvature is 1e-5 of it, so
        the iterate crawled along the wheel's steering (measured: normalised reduced Hessian's
        largest eigenvalue 7e-3 against 1.3e-6 exact). An underestimated curvature costs a step
        that the trust region bounds and BFGS corrects along it; an overestimated one is never
        corrected, since BFGS learns only along the steps it takes. A table point without
        ``cell`` (a hand-made point) uses its own Hessian."""
        cell = getattr(tp, "cell", None)
        table = getattr(tp, "_table", None)
        if cell is None or table is None or not hasattr(table, "point_field"):
            return self._corner_curvature(tp.hess_lag, tp.jac_g_x)
        idx, w = cell
        use = w > 0.0
        idx, w = idx[use], w[use]
        key = idx.tobytes()
        hit = self._cell_cache.get(key)
        if hit is None:
            As = []
            for c in idx:
                A = self._corner_cache.get(int(c))
                if A is None:
                    A = self._corner_curvature(table.point_field(int(c), "hess_lag"), table.point_field(int(c), "jac_g_x"))
                    self._corner_cache[int(c)] = A
                As.append(A)
            stack = np.stack(As).reshape(len(As), -1)
            size = np.abs(stack).max(axis=1)
            keep = size <= _CURVATURE_OUTLIER * float(np.median(size))
            hit = self._cell_cache[key] = (stack, keep if (keep.any() and not keep.all()) else np.ones(len(As), dtype=bool))
        stack, keep = hit
        w = w * keep
        n = self.allocator.nx
        A = ((w / float(w.sum())) @ stack).reshape(n, n)  # each corner's is symmetric
        return A

    def _structured_hessian(self, x: NDArray[np.float64], grad: NDArray[np.float64], jac: NDArray[np.float64],
                            p: NDArray[np.float64]) -> None:
        """The QP's Hessian as the exact Gauss-Newton part of (7.24) at the iterate plus a
        curvature part ``A`` (the table's, then corrected by Powell-damped BFGS updates with the
        exact Lagrangian gradients when ``quasi_newton``; a structured quasi-Newton method, Dennis,
        Gay & Welsch 1981 and Nocedal & Wright, 2nd ed., section 10.3 / procedure 18.2).

        Why: the objective is a sum of squared wheel torques, and the table's interpolated Hessian
        is dominated by its Gauss-Newton part ``2 J_T^T J_T``, which changes by orders of
        magnitude across a cell where a wheel's torque-slip curve flattens (measured at an
        off-grid rim-speed-cap point: the table's normalised Hessian 0.47 and 0.023 on the capped
        wheel's omega and beta, the exact Lagrangian's -4e-5 and -8e-8; reduced-Hessian largest
        eigenvalue 1.7e-2 against 1.3e-6 exact, so the step along it was 1e-4 of what the
        gradient asked, and the iterate crept). BFGS learns only along the steps it takes, and a
        direction the Hessian overestimates is one it never steps along. The exact Jacobian is
        there each iteration, so its torque rows give the exact Gauss-Newton part for free.

        The matrix handed to the QP is convexified (eigenvalues floored at ``regularization``
        relative to the objective's normalisation, capped at 10 times it); ``A`` keeps the
        unconvexified update, so the floor does not accumulate from tick to tick. Whether the
        matrix needs it is proved by a Cholesky factor while the last one did not, else read off
        the eigenvalues that the floor needs anyway (the matrix is indefinite at most points of
        the shipped tables, where the failed factorisation cost a quarter of this method)."""
        G = self._gauss_newton(jac)
        A = self._A if self._A is not None else self._table_curvature(self._point)
        B = G + A
        if self.settings.quasi_newton and self._prev is not None:
            x0, gl0, lam, p0 = self._prev
            if np.array_equal(p0, np.asarray(p, dtype=float)):
                sx = self.allocator.sx
                s = (x - x0) / sx
                yv = (self._lagrangian_gradient(grad, jac, lam) - gl0) * sx
                Bs = B @ s
                sBs, sy = float(s @ Bs), float(s @ yv)
                if np.any(s) and math.isfinite(sBs) and math.isfinite(sy) and sBs > 0.0:
                    if sy < 0.2 * sBs:
                        theta = 0.8 * sBs / (sBs - sy)
                        yv = theta * yv + (1.0 - theta) * Bs
                        sy = float(s @ yv)
                    B = B + np.outer(yv, yv) / sy - np.outer(Bs, Bs) / sBs
                    B = 0.5 * (B + B.T)
                    self.hessian_updates += 1
        self._A = B - G
        cf = self.allocator.objective_scale
        floor = self.settings.regularization * cf
        H: NDArray[np.float64] | None = None
        if self._convex:
            Bf = B.copy()
            Bf.flat[::Bf.shape[0] + 1] -= floor
            try:  # every eigenvalue above the floor (a Cholesky factor proves it) ...
                np.linalg.cholesky(Bf)
                H = B if float(np.abs(B).max()) <= 10.0 * cf else None
            except np.linalg.LinAlgError:
                self._convex = False
        if H is None:  # ... else floor (and cap) the eigenvalues
            w, V = np.linalg.eigh(B)
            if float(w[0]) > floor and float(np.abs(B).max()) <= 10.0 * cf:  # convex after all: as the factor says
                H, self._convex = B, True
            else:
                H = (V * np.clip(w, floor, 10.0 * cf)) @ V.T
        self._H = 0.5 * (H + H.T)
        self.allocator.set_hessian(self._H)

    def _update_hessian(self, x: NDArray[np.float64], grad: NDArray[np.float64], jac: NDArray[np.float64],
                        p: NDArray[np.float64]) -> None:
        """Powell-damped BFGS update of the QP's Hessian from the last step (Nocedal & Wright,
        Numerical Optimization, 2nd ed., procedure 18.2): ``s`` the step, ``y`` the change of the
        Lagrangian's gradient ``grad f + J^T lambda`` (exact, with the last QP's multipliers),
        both in scaled variables, taken only when the parameters are the same as at the last
        iteration (another iteration of the same tick, or a tick at an unchanged operating
        point): across a change of ``p`` the gradient moves without any step, and a pair taken
        there teaches a curvature that is not the problem's (measured in closed loop with the
        outer loop's offsets changing every tick: balance slack on 50 of 550 ticks, none
        without). Damping keeps the matrix positive definite; the table's Hessian is the start,
        so on a grid point at its own parameters nothing changes."""
        if self._prev is None:
            return
        x0, gl0, lam, p0 = self._prev
        if not np.array_equal(p0, np.asarray(p, dtype=float)):
            return
        sx = self.allocator.sx
        s = (x - x0) / sx
        if not np.any(s):
            return
        yv = (self._lagrangian_gradient(grad, jac, lam) - gl0) * sx
        H = self.allocator.hessian if self._H is None else self._H
        Hs = H @ s
        sHs = float(s @ Hs)
        sy = float(s @ yv)
        if not (math.isfinite(sHs) and math.isfinite(sy)) or sHs <= 0.0:
            return
        if sy < 0.2 * sHs:
            theta = 0.8 * sHs / (sHs - sy)
            yv = theta * yv + (1.0 - theta) * Hs
            sy = float(s @ yv)
        H = H + np.outer(yv, yv) / sy - np.outer(Hs, Hs) / sHs
        # keep the QP as well conditioned as the table's convexified Hessian: eigenvalues floored at
        # the same regularisation, relative to the objective's normalisation (without the floor the
        # updates left near-singular directions and OSQP's iterations rose from 225 to 2600 at p99)
        w, V = np.linalg.eigh(0.5 * (H + H.T))
        floor = self.settings.regularization * self.allocator.objective_scale
        H = (V * np.clip(w, floor, 10.0 * self.allocator.objective_scale)) @ V.T
        self._H = 0.5 * (H + H.T)
        self.allocator.set_hessian(self._H)
        self.hessian_updates += 1


def _finish(job: Generator[None, None, NDArray[np.float64]]) -> NDArray[np.float64]:
    """Run a generator of :meth:`RealTimeIteration.start`'s work to its end; its value."""
    while True:
        try:
            next(job)
        except StopIteration as stop:
            return np.asarray(stop.value, dtype=float)


def first_order_model(tp: Any, x: NDArray[np.float64], p: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64], None]:
    """The table point's first-order model of the residual and objective gradient at ``(x, p)``
    (for a table whose header does not define the physics)."""
    dx, dp = x - np.asarray(tp.x, dtype=float), p - np.asarray(tp.p, dtype=float)
    g = np.asarray(tp.g, dtype=float) + np.asarray(tp.jac_g_x, dtype=float) @ dx + np.asarray(tp.jac_g_p, dtype=float) @ dp
    grad = np.asarray(tp.grad_f, dtype=float) + np.asarray(tp.hess_lag, dtype=float) @ dx
    hxp = getattr(tp, "hess_lag_xp", None)
    if hxp is not None:
        grad = grad + np.asarray(hxp, dtype=float) @ dp
    return g, grad, None
