"""The allocation QP: one SQP step of the steady-state problem (7.25) around the tabulated primitive.

Decision (scaled): ``z = dx / s_x``, the change of every wheel's variables (omega, beta, W, h,
h0; :mod:`rtctl.layout`) from the interpolated primitive ``x0``, plus two non-negative slacks per
model row. With the table's data at the operating point (all physical, contract C2):

.. math::

    \\min_{z,\\sigma^\\pm}\\ & \\tfrac12 z^T \\bar H z + \\bar g^T z
        + \\rho_1 \\mathbf 1^T(\\sigma^+ + \\sigma^-) + \\rho_2 (\\|\\sigma^+\\|^2 + \\|\\sigma^-\\|^2)
        + w\\,\\|z_c - z_{c,prev}\\|^2 \\\\
    \\text{s.t. }\\ & l_g \\le \\frac{g_0 + J_x S_x z + J_p\\,\\Delta p}{s_g} - \\sigma^+ + \\sigma^- \\le u_g,
    \\qquad z_{lo} \\le z \\le z_{hi}, \\qquad \\sigma^\\pm \\ge 0,

where ``H_bar = S_x hess_lag S_x / c_f`` (the Hessian of the Lagrangian of (7.24)-(7.25),
normalised by ``c_f``, plus ``regularization * I``; an indefinite one is first convexified by
an eigenvalue floor), ``g_bar = S_x (grad_f + hess_lag_xp \\Delta p) / c_f`` (the cross
derivative ``d^2 L / dx dp`` makes the step an exact SQP step in the parameters as well: its
first-order response to a parameter change is the table's ``dx*/dp``; a table point without
``hess_lag_xp`` gives zero there, the step is then exact only in the additive parameters),
``Delta p`` the change of the parameters (speed, slope, cross slope, and the offsets of
(7.26)-(7.27)) from the table's point, and ``s_g`` the layout's row scales. The model rows are
soft with an exact L1 penalty (``rho_1`` larger than any multiplier of the normalised problem),
so a QP whose hard box leaves the linearised balance unreachable (a rate limit, a failure, the
trust region) stays feasible and reports its slack; a feasible one has zero slack. The box
``[z_lo, z_hi]`` is built by :func:`merge_bounds` so that it is never empty.

Two solvers answer the same QP. First the exact active-set solve (:mod:`rtctl.active_set`,
``QpSettings.active_set_iterations``): from the last tick's active set (at the start, the
table's active-set hints; when that set does not settle, once more from the equality rows,
``active_set_restart_iterations``) the QP with zero slack is one dense KKT system, solved to rounding;
it is taken when every KKT condition holds and every row multiplier is below ``rho_1`` (then
zero slack is optimal for the soft QP too, so it is the same QP's minimiser). Otherwise OSQP,
whose answer also gives the next tick's active set: a tick whose balance needs slack (a rate
limit, a pinned variable), or whose active set does not settle within the budget. A model row
that no step within the box can move and whose value violates its bounds (the skid-steer's
``balance Fy`` under a measured cross slope) is left out of both solves, its slack read off
(:func:`_unreachable_rows`): the same minimiser.

Set up once per table layout with OSQP (fixed sparsity: the Jacobian block is dense with
explicit zeros); each tick changes values only: :meth:`QpAllocator.prepare` (between ticks:
matrix values and the refactorisation, the preparation phase of real-time iteration) and
:meth:`QpAllocator.solve` (on the new measurement: vectors, warm start, solve; the feedback
phase). qpsolvers is used only by :func:`solve_with_qpsolvers` (cross-checks; imported lazily).
The smoothness weight ``w`` on the commanded variables (every wheel's omega and beta) is fixed
(``QpSettings.command_weight``) so that it lives in P and never forces a refactorisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import osqp
import scipy.sparse as sp
from numpy.typing import NDArray

from .active_set import ActiveSet, solve_active_set, starts_alike
from .config import QpSettings
from .layout import NlpLayout

__all__ = ["AllocatorError", "TablePointLike", "QpProblem", "Allocation", "merge_bounds", "QpAllocator",
           "solve_with_qpsolvers"]

_INF = 1e30
_ZERO_ROW = 1e-12
"""A row's free part at most this fraction of the scaled Jacobian's largest entry is zero
(:func:`_unreachable_rows`; the active set's dual regularisation is the same fraction)."""


class AllocatorError(ValueError):
    """QP data of the wrong shape or not finite (a table or caller bug; never raised by a bad
    measurement, which the controller filters before)."""


class TablePointLike(Protocol):
    """The fields of :class:`rtctl.table.TablePoint` the allocator reads (contract C2)."""

    x: NDArray[np.float64]
    p: NDArray[np.float64]
    g: NDArray[np.float64]
    jac_g_x: NDArray[np.float64]
    jac_g_p: NDArray[np.float64]
    grad_f: NDArray[np.float64]
    hess_lag: NDArray[np.float64]
    lbx: NDArray[np.float64]
    ubx: NDArray[np.float64]
    lbg: NDArray[np.float64]
    ubg: NDArray[np.float64]
    dx_dp: NDArray[np.float64]
    # optional: hess_lag_xp (nx, np), d^2 L / dx dp; read with getattr (absent: zeros)


@dataclass(frozen=True)
class QpProblem:
    """One QP as solved, in OSQP form ``min 1/2 z'Pz + q'z, l <= Az <= u`` (P upper triangle)."""

    P: Any
    q: NDArray[np.float64]
    A: Any
    l: NDArray[np.float64]
    u: NDArray[np.float64]


@dataclass(frozen=True)
class Allocation:
    """Result of one allocation.

    Attributes
    ----------
    x : ndarray
        Physical decision variables ``x0 + dx`` (nx,), clipped into the box.
    dx : ndarray
        The step from the primitive (nx,).
    ok : bool
        Solved, finite, and the model-row slack within the tolerance.
    status : str
        Solver status text (``"solved (active set)"`` or OSQP's; or why the result was refused).
    iterations : int
        KKT systems of the active-set solve, or ADMM iterations of OSQP.
    slack : float
        Largest slack of a model row (scaled units); 0 when the linearised balance is met.
    objective : float
        Optimal value of the normalised QP.
    """

    x: NDArray[np.float64]
    dx: NDArray[np.float64]
    ok: bool
    status: str
    iterations: int
    slack: float
    objective: float


def merge_bounds(hard_lo: NDArray[np.float64], hard_hi: NDArray[np.float64],
                 *soft: tuple[NDArray[np.float64], NDArray[np.float64]]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Intersect a hard box with softer boxes in priority order, never leaving it empty.

    Each soft box ``(a, b)`` is intersected with the current one where they overlap; where they
    do not, the current box collapses to its point nearest the soft box (e.g. a rate limit that
    cannot reach a declared stuck angle yields to it). The hard box must be non-empty.
    """
    lo, hi = np.array(hard_lo, dtype=float), np.array(hard_hi, dtype=float)
    if np.any(lo > hi):
        i = int(np.argmax(lo > hi))
        raise AllocatorError(f"hard bounds empty at entry {i}: [{lo[i]}, {hi[i]}]")
    for a, b in soft:
        nlo, nhi = np.maximum(lo, a), np.minimum(hi, b)
        empty = nlo > nhi
        if np.any(empty):
            point = np.where(b < lo, lo, hi)
            nlo = np.where(empty, point, nlo)
            nhi = np.where(empty, point, nhi)
        lo, hi = nlo, nhi
    return lo, hi


class QpAllocator:
    """OSQP allocator for one table layout (module docstring).

    Parameters
    ----------
    layout : NlpLayout
        The table's variable / parameter / constraint layout.
    settings : QpSettings
        Penalties, regularisation, budgets.
    """

    def __init__(self, layout: NlpLayout, settings: QpSettings) -> None:
        self.layout = layout
        self.settings = settings
        nx, ng = layout.nx, layout.ng
        self.nx, self.ng = nx, ng
        self.n = nx + 2 * ng
        self.m = ng + nx + 2 * ng
        self.sx = layout.variable_scale
        self.sg = layout.constraint_scale
        self._sxx = self.sx[:, None] * self.sx[None, :]
        self._sx_over_sg = self.sx[None, :] / self.sg[:, None]
        # ---- fixed sparsity of P: dense upper triangle of the nx block, diagonal slack block
        cols_p: list[int] = []
        rows_p: list[int] = []
        for j in range(nx):
            rows_p.extend(range(j + 1))
            cols_p.extend([j] * (j + 1))
        for j in range(nx, self.n):
            rows_p.append(j)
            cols_p.append(j)
        self._p_rows = np.array(rows_p)
        self._p_cols = np.array(cols_p)
        self._p_indptr = np.searchsorted(self._p_cols, np.arange(self.n + 1)).astype(np.int64)
        # ---- fixed sparsity of A: [J | -I | I] over the model rows, I for z, I for the slacks
        rows_a: list[int] = []
        self._a_jac_pos: list[int] = []  # positions of the Jacobian entries in A.data, column-major
        for j in range(nx):
            self._a_jac_pos.extend(range(len(rows_a), len(rows_a) + ng))
            rows_a.extend(range(ng))
            rows_a.append(ng + j)
        for k in range(ng):  # sigma+ columns
            rows_a.extend([k, ng + nx + k])
        for k in range(ng):  # sigma- columns
            rows_a.extend([k, ng + nx + ng + k])
        self._a_rows = np.array(rows_a)
        counts = [ng + 1] * nx + [2] * (2 * ng)
        self._a_indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self._a_data = np.ones(len(rows_a))
        for k in range(ng):
            self._a_data[self._a_indptr[nx + k]] = -1.0
        self._a_jac_pos_arr = np.array(self._a_jac_pos)
        self._w = np.zeros(nx)
        for w_ in layout.wheels:
            self._w[layout.var("omega", w_)] = settings.command_weight
            self._w[layout.var("beta", w_)] = settings.command_weight
        self._w_diag = np.diag(2.0 * self._w)
        self._p_k = nx * (nx + 1) // 2
        self._p_rows_h, self._p_cols_h = self._p_rows[:self._p_k], self._p_cols[:self._p_k]
        self._p_slack = np.full(len(self._p_rows), 2.0 * settings.slack_l2)
        self._l_tail, self._u_tail = np.zeros(2 * ng), np.full(2 * ng, _INF)
        self._solver: Any = None
        # OSQP's matrix values are built only when OSQP solves (a fallback tick, a recording's
        # problem()): from their sources, the dense Hessian with the command weights (P) and the
        # scaled Jacobian (A); which of the two changed since OSQP's last update is pending
        self._pending: set[str] = set()
        self._px_src: NDArray[np.float64] = np.zeros((nx, nx))
        self._ax_src: NDArray[np.float64] = np.zeros((ng, nx))
        self._res_y: NDArray[np.float64] | None = None
        self._prepared = False
        self._x0 = np.zeros(nx)
        self._p0 = np.zeros(layout.np_)
        self._last_z: NDArray[np.float64] | None = None
        self._last_y: NDArray[np.float64] | None = None
        self._last_x: NDArray[np.float64] | None = None
        self.last_solution: NDArray[np.float64] = np.full(self.n, np.nan)
        self._active: ActiveSet | None = None  # the last tick's active set (the next guess)
        self._last_box: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # its physical box
        self.last_active_set_iterations = 0
        self.last_solver = ""
        """Which solver answered the last :meth:`solve_at`: ``"active set"`` or ``"osqp"``."""

    # ------------------------------------------------------------------ preparation phase
    def prepare(self, tp: TablePointLike, hessian: NDArray[np.float64] | None = None,
                scale_by_hessian: bool = False) -> None:
        """Load a table point: matrix values (convexified Hessian, scaled Jacobian) and OSQP's
        refactorisation. Needs no measurement (the preparation phase). ``hessian``: use this
        positive definite matrix (scaled, not normalised, as :attr:`hessian`) instead of the
        table point's (a quasi-Newton iteration that goes on, or the structured Hessian of
        :class:`rtctl.rti.RealTimeIteration`); ``scale_by_hessian``: the objective's
        normalisation ``c_f`` from that matrix and the gradient, not from the table point's
        Hessian (which may be a corner's kink interpolated, many orders larger)."""
        nx, ng, npar = self.nx, self.ng, self.layout.np_
        shapes = {"x": (nx,), "p": (npar,), "g": (ng,), "jac_g_x": (ng, nx), "jac_g_p": (ng, npar), "grad_f": (nx,),
                  "hess_lag": (nx, nx), "lbx": (nx,), "ubx": (nx,), "lbg": (ng,), "ubg": (ng,)}
        f: dict[str, NDArray[np.float64]] = {}
        # a TablePoint's interpolated row holds every field: when its one sum is finite, so is
        # every field (and the per-field sums are skipped); otherwise each field is judged alone
        row = getattr(tp, "_row", None)
        all_finite = isinstance(row, np.ndarray) and math.isfinite(float(row.sum()))
        for name, shape in shapes.items():
            a = np.asarray(getattr(tp, name), dtype=float)
            if a.shape != shape:
                raise AllocatorError(f"table point field {name!r} has shape {a.shape}, expected {shape} for this layout")
            # one reduction per field: a NaN or inf anywhere makes the sum non-finite
            if not all_finite and name not in ("lbx", "ubx", "lbg", "ubg") and not math.isfinite(float(a.sum())):
                raise AllocatorError(f"table point field {name!r} is not finite")
            f[name] = a
        hxp = getattr(tp, "hess_lag_xp", None)
        hxp = np.zeros((nx, npar)) if hxp is None else np.asarray(hxp, dtype=float)
        if hxp.shape != (nx, npar):
            raise AllocatorError(f"table point field 'hess_lag_xp' has shape {hxp.shape}, expected {(nx, npar)} for this layout")
        if not math.isfinite(float(hxp.sum())):
            raise AllocatorError("table point field 'hess_lag_xp' is not finite")
        s = self.settings
        sx, sg = self.sx, self.sg
        g = sx * f["grad_f"]
        if hessian is not None and scale_by_hessian:  # the table's Hessian is not used at all
            Hn = np.asarray(hessian, dtype=float)
        else:
            H = self._sxx * f["hess_lag"]
            Hn = H = 0.5 * (H + H.T)
        cf = max(float(np.abs(Hn).max()), float(np.abs(g).max()), 1e-12)
        g /= cf
        if hessian is not None:
            H = np.asarray(hessian, dtype=float) / cf
            if H.shape != (nx, nx) or not math.isfinite(float(H.sum())):
                raise AllocatorError(f"prepare: hessian must be a finite ({nx}, {nx}) matrix, got shape {H.shape}")
        else:
            H /= cf
            Hr = H.copy()
            Hr.flat[::nx + 1] += s.regularization
            try:  # convex (the usual case: (7.24) is a sum of squares): H + reg I is all we need
                np.linalg.cholesky(Hr)
                H = Hr
            except np.linalg.LinAlgError:  # indefinite Lagrangian Hessian: floor the eigenvalues
                w, V = np.linalg.eigh(H)
                H = (V * np.maximum(w, s.regularization)) @ V.T
                H.flat[::nx + 1] += s.regularization
        self._H = 0.5 * (H + H.T)
        self._Hd = self._H + self._w_diag
        self._g = g
        self._cf = cf
        # the table's first-order model (Jacobians, value, cross derivative): built when a solve
        # needs it (_table_model); a real-time iteration with the exact Jacobian never does
        self._model_src = (f["jac_g_x"], f["jac_g_p"], f["g"], hxp)
        self._model_ready = False
        self._lbg = f["lbg"] / sg
        self._ubg = f["ubg"] / sg
        x0_new = f["x"].copy()
        if self._last_x is not None:  # warm start carried over to the new linearisation point
            self._last_z = (self._last_x - x0_new) / sx
        self._x0 = x0_new
        self._p0 = f["p"].copy()
        if self._active is None:  # the table's active-set hints start the exact solve
            hint = getattr(tp, "active", None)
            if isinstance(hint, dict) and all(k in hint for k in ("x_lower", "x_upper", "g_lower", "g_upper")):
                try:
                    self._active = ActiveSet(
                        (np.asarray(hint["g_upper"], dtype=np.int8) - np.asarray(hint["g_lower"], dtype=np.int8)).reshape(ng),
                        (np.asarray(hint["x_upper"], dtype=np.int8) - np.asarray(hint["x_lower"], dtype=np.int8)).reshape(nx))
                except ValueError:
                    self._active = None
        self._lbx = f["lbx"]
        self._ubx = f["ubx"]
        self._q_base = np.concatenate([g, np.full(2 * ng, s.slack_l1)])
        self._px_src = self._Hd
        if self._solver is None:
            self._table_model()
            self._setup()
        else:  # handed to OSQP with the next solve's vectors (if OSQP solves): one refactorisation
            self._pending.add("Px")
        self._prepared = True

    def _table_model(self) -> None:
        """The prepared table point's first-order model in the QP's units: the scaled Jacobians
        ``_J``, ``_Jp``, the value ``_g0``, the cross derivative ``_Hxp`` and OSQP's ``A`` values
        from ``_J`` (pending for the next solve); once per :meth:`prepare`."""
        if self._model_ready:
            return
        jx, jp, g0, hxp = self._model_src
        sg = self.sg
        self._Hxp = self.sx[:, None] * hxp / self._cf  # normalised, scaled x, physical p
        self._J = jx * self._sx_over_sg
        self._Jp = jp / sg[:, None]
        self._g0 = g0 / sg
        self._ax_src = self._J
        if self._solver is not None:
            self._pending.add("Ax")
        self._model_ready = True

    def _p_values(self, Hd: NDArray[np.float64]) -> NDArray[np.float64]:
        """OSQP's ``P`` values (upper triangle, column-major, then the slacks' diagonal) of the
        dense Hessian with the command weights ``Hd``."""
        vals = self._p_slack.copy()
        vals[:self._p_k] = Hd[self._p_rows_h, self._p_cols_h]
        return vals

    def _a_values(self, Js: NDArray[np.float64]) -> NDArray[np.float64]:
        """OSQP's ``A`` values with the scaled Jacobian ``Js`` in the model rows."""
        Ax = self._a_data.copy()
        Ax[self._a_jac_pos_arr] = Js.T.ravel()
        return Ax

    def _setup(self) -> None:
        s = self.settings
        P = sp.csc_matrix((self._p_values(self._px_src), self._p_rows, self._p_indptr), shape=(self.n, self.n))
        A = sp.csc_matrix((self._a_values(self._ax_src), self._a_rows, self._a_indptr), shape=(self.m, self.n))
        q = np.concatenate([self._g, np.full(2 * self.ng, s.slack_l1)])
        l = np.concatenate([self._lbg, -np.ones(self.nx), np.zeros(2 * self.ng)])
        u = np.concatenate([self._ubg, np.ones(self.nx), np.full(2 * self.ng, _INF)])
        self._solver = osqp.OSQP()
        self._solver.setup(P, q, A, np.maximum(l, -_INF), np.minimum(u, _INF), verbose=False, eps_abs=s.eps, eps_rel=s.eps,
                           max_iter=s.max_iter, polishing=False, warm_starting=True)

    # ------------------------------------------------------------------ feedback phase
    @property
    def x0(self) -> NDArray[np.float64]:
        """The interpolated primitive the QP is linearised around (physical, copy)."""
        return self._x0.copy()

    @property
    def p0(self) -> NDArray[np.float64]:
        """The parameters of the table point (physical, copy)."""
        return self._p0.copy()

    @property
    def hessian(self) -> NDArray[np.float64]:
        """The QP's Hessian of the Lagrangian in scaled variables, *not* normalised (``S_x H S_x``
        after convexification; the QP uses it divided by :attr:`objective_scale`), copy."""
        return self._H * self._cf

    @property
    def set_up(self) -> bool:
        """OSQP was set up (the first :meth:`prepare`); later ones only update values."""
        return self._solver is not None

    @property
    def objective_scale(self) -> float:
        """``c_f``, the normalisation of the QP's objective (module docstring)."""
        return float(self._cf)

    def set_hessian(self, H: NDArray[np.float64]) -> None:
        """Replace the QP's Hessian (scaled variables, not normalised: as :attr:`hessian`) by a
        symmetric positive definite ``H`` (a quasi-Newton update); OSQP refactorises."""
        H = np.asarray(H, dtype=float)
        if H.shape != (self.nx, self.nx) or not math.isfinite(float(H.sum())):
            raise AllocatorError(f"set_hessian: expected a finite ({self.nx}, {self.nx}) matrix, got shape {H.shape}")
        self._H = 0.5 * (H + H.T) / self._cf
        self._Hd = self._H + self._w_diag
        self._px_src = self._Hd
        self._pending.add("Px")

    @property
    def row_duals(self) -> NDArray[np.float64] | None:
        """Multipliers of the model rows of the last successful :meth:`solve_at`, in physical
        units of the objective (7.24) per unit of each row's physical residual; None after a
        refused solve."""
        if self._last_y is None:
            return None
        return self._last_y[:self.ng] * self._cf / self.sg

    @property
    def table_bounds(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The table's variable bounds at the point (physical)."""
        return self._lbx.copy(), self._ubx.copy()

    def solve(self, p: NDArray[np.float64], box: tuple[NDArray[np.float64], NDArray[np.float64]],
              lbg: NDArray[np.float64] | None = None, ubg: NDArray[np.float64] | None = None,
              x_ref: NDArray[np.float64] | None = None) -> Allocation:
        """One warm-started solve (the feedback phase).

        Parameters
        ----------
        p : ndarray (np,)
            Wanted parameters (speed, slope, cross slope, offsets ...); ``p - p0`` enters through
            the table's parameter Jacobian.
        box : (lo, hi)
            Physical bounds on ``x`` (non-empty; build them with :func:`merge_bounds`).
        lbg, ubg : ndarray (ng,), optional
            Physical constraint bounds replacing the table's (e.g. a torque row of an unpowered
            wheel, lbg = ubg = 0).
        x_ref : ndarray (nx,), optional
            Smoothness reference (the previous command): penalises ``w (z_c - z_ref,c)^2`` on the
            commanded variables; without it the same weight pulls toward the primitive.
        """
        if not self._prepared:
            raise AllocatorError("solve() before prepare(): load a table point first")
        s = self.settings
        sx = self.sx
        self._table_model()
        dp = np.asarray(p, dtype=float) - self._p0
        shift = self._g0 + self._Jp @ dp
        lg = (self._lbg if lbg is None else np.asarray(lbg, dtype=float) / self.sg) - shift
        ug = (self._ubg if ubg is None else np.asarray(ubg, dtype=float) / self.sg) - shift
        zlo = (np.asarray(box[0], dtype=float) - self._x0) / sx
        zhi = (np.asarray(box[1], dtype=float) - self._x0) / sx
        if not (math.isfinite(float(dp.sum())) and bool((zlo <= zhi).all()) and not (np.isnan(lg).any() or np.isnan(ug).any())):
            return self._refused("bad QP data (non-finite parameters or empty box)")
        q = self._q_base.copy()
        q[:self.nx] += self._Hxp @ dp  # d^2 L / dx dp: the gradient's move with the parameters
        if x_ref is not None:
            zr = _finite((np.asarray(x_ref, dtype=float) - self._x0) / sx)
            q[:self.nx] -= 2.0 * self._w * zr
        l = np.concatenate([lg, zlo, self._l_tail])
        u = np.concatenate([ug, zhi, self._u_tail])
        zw = None if self._last_z is None else np.clip(self._last_z, zlo, zhi)
        solved, status, it, zf, z, slack, obj = self._osqp(q, l, u, zlo, zhi, zw)
        if not solved:
            self._last_z = self._last_y = self._last_x = None
            return self._refused(f"OSQP: {status}", it)
        dx = z * sx
        x = self._x0 + dx
        self._last_z, self._last_y, self._last_x = zf[:self.nx].copy(), self._res_y, x.copy()
        ok = slack <= s.balance_tolerance
        return Allocation(x, dx, ok, status if ok else f"{status}; model-row slack {slack:.3g} > {s.balance_tolerance}", it,
                          slack, obj)

    def _osqp(self, q: NDArray[np.float64], l: NDArray[np.float64], u: NDArray[np.float64], zlo: NDArray[np.float64],
              zhi: NDArray[np.float64], z_warm: NDArray[np.float64] | None
              ) -> tuple[bool, str, int, NDArray[np.float64], NDArray[np.float64], float, float]:
        """One OSQP solve with the pending matrix values and these vectors (warm-started at
        ``z_warm`` and the last duals): ``(solved, status, iterations, raw answer, step clipped into
        the box, largest model-row slack, objective)``."""
        np.clip(l, -_INF, _INF, out=l)
        np.clip(u, -_INF, _INF, out=u)
        matrices = {}
        if "Px" in self._pending:
            matrices["Px"] = self._p_values(self._px_src)
        if "Ax" in self._pending:
            matrices["Ax"] = self._a_values(self._ax_src)
        self._solver.update(q=q, l=l, u=u, **matrices)  # one refactorisation for the tick's matrices
        self._pending = set()
        if z_warm is not None:
            self._solver.warm_start(x=np.concatenate([z_warm, np.zeros(2 * self.ng)]), y=self._last_y)
        self._q, self._l, self._u = q, l, u
        res = self._solver.solve(raise_error=False)
        self.last_solution = np.array(res.x, dtype=float) if res.x is not None else np.full(self.n, np.nan)
        status, it, zf = str(res.info.status), int(res.info.iter), res.x
        if res.info.status_val != osqp.SolverStatus.OSQP_SOLVED or zf is None or not np.all(np.isfinite(zf)):
            return False, status, it, self.last_solution, np.zeros(self.nx), math.inf, math.nan
        zf = np.asarray(zf, dtype=float)
        z = np.minimum(np.maximum(zf[:self.nx], zlo), zhi)
        sig = np.maximum(zf[self.nx:], 0.0)
        slack = float(np.max(sig[:self.ng] + sig[self.ng:])) if self.ng else 0.0
        self._res_y = np.asarray(res.y, dtype=float).copy()
        return True, status, it, zf, z, slack, float(res.info.obj_val)

    def solve_at(self, x_lin: NDArray[np.float64], g: NDArray[np.float64], grad_f: NDArray[np.float64],
                 jac_g_x: NDArray[np.float64] | None, box: tuple[NDArray[np.float64], NDArray[np.float64]],
                 lbg: NDArray[np.float64] | None = None, ubg: NDArray[np.float64] | None = None,
                 x_ref: NDArray[np.float64] | None = None) -> Allocation:
        """One real-time iteration of (7.25): the QP linearised at the iterate ``x_lin``.

        The residual ``g`` (every row, physical), the objective gradient ``grad_f`` and, if
        given, the rows' Jacobian ``jac_g_x`` are the exact ones at ``x_lin`` and the measured
        parameters (:class:`rtctl.physics.steady_state.SteadyStateResidual`); the Hessian is the
        prepared table point's (:meth:`prepare`), and so is the Jacobian where ``jac_g_x`` is
        None. The step ``z = (x - x_lin) / s_x`` solves

        .. math::

            \\min\\ \\tfrac12 z^T \\bar H z + \\bar g(x_{lin})^T z + \\text{slack penalties}
                + w\\,\\|z_c - z_{c,ref}\\|^2
            \\quad\\text{s.t.}\\quad l_g \\le \\frac{g(x_{lin}, p) + J\\, S_x z}{s_g} - \\sigma^+ + \\sigma^- \\le u_g,

        so its fixed point (``z = 0``, zero slack) is a KKT point of the NLP itself whenever the
        Jacobian is exact, wherever the table's grid is; the slack is zero only when the exact
        residual of the linearised step is met. Returns the new iterate ``x_lin + S_x z``.
        """
        if not self._prepared:
            raise AllocatorError("solve_at() before prepare(): load a table point first")
        s = self.settings
        sx, sg = self.sx, self.sg
        x_lin = np.asarray(x_lin, dtype=float)
        g = np.asarray(g, dtype=float)
        grad = np.asarray(grad_f, dtype=float)
        if x_lin.shape != (self.nx,) or g.shape != (self.ng,) or grad.shape != (self.nx,):
            raise AllocatorError(f"solve_at: x, g, grad_f of shapes {x_lin.shape}, {g.shape}, {grad.shape}; expected "
                                 f"({self.nx},), ({self.ng},), ({self.nx},)")
        zlo = (np.asarray(box[0], dtype=float) - x_lin) / sx
        zhi = (np.asarray(box[1], dtype=float) - x_lin) / sx
        lg = (self._lbg if lbg is None else np.asarray(lbg, dtype=float) / sg) - g / sg
        ug = (self._ubg if ubg is None else np.asarray(ubg, dtype=float) / sg) - g / sg
        finite = math.isfinite(float(x_lin.sum() + g.sum() + grad.sum()))
        if jac_g_x is not None:
            J = np.asarray(jac_g_x, dtype=float)
            finite = finite and J.shape == (self.ng, self.nx) and math.isfinite(float(J.sum()))
        if not (finite and bool((zlo <= zhi).all()) and not (np.isnan(lg).any() or np.isnan(ug).any())):
            return self._refused("bad QP data (non-finite iterate, residual or Jacobian, or empty box)")
        if jac_g_x is None:
            self._table_model()
        Js = self._J
        if jac_g_x is not None:
            Js = J * self._sx_over_sg
            self._ax_src = Js
            self._pending.add("Ax")
        q = self._q_base.copy()
        q[:self.nx] = sx * grad / self._cf
        if x_ref is not None:
            zr = _finite((np.asarray(x_ref, dtype=float) - x_lin) / sx)
            q[:self.nx] -= 2.0 * self._w * zr
        l = np.concatenate([lg, zlo, self._l_tail])
        u = np.concatenate([ug, zhi, self._u_tail])
        box_lo, box_hi = np.asarray(box[0], dtype=float), np.asarray(box[1], dtype=float)
        drop = _unreachable_rows(Js, lg, ug, zlo, zhi)
        exact = self._exact_step(Js, q, lg, ug, zlo, zhi, (box_lo, box_hi), drop) if s.active_set_iterations > 0 else None
        if exact is not None:
            z, it = exact
            slack, obj, status = 0.0, float(0.5 * z @ self._Hd @ z + q[:self.nx] @ z), "solved (active set)"
            self._q, self._l, self._u = q, l, u
        else:
            lo, hi = l, u
            if drop is not None:  # OSQP gets the row at the value it cannot leave (same minimiser)
                v = Js[drop] @ np.clip(np.zeros(self.nx), zlo, zhi)
                lo = np.clip(l, -_INF, _INF, out=l).copy()
                hi = np.clip(u, -_INF, _INF, out=u).copy()
                lo[:self.ng][drop] = np.minimum(lg[drop], v)
                hi[:self.ng][drop] = np.maximum(ug[drop], v)
            solved, status, it, zf, z, slack, obj = self._osqp(q, lo, hi, zlo, zhi, np.clip(np.zeros(self.nx), zlo, zhi))
            self._l, self._u = l, u
            if not solved:
                self._last_y = None
                self._active = None
                return Allocation(x_lin.copy(), np.zeros(self.nx), False, f"OSQP: {status}", it, math.inf, math.nan)
            self._active = self._active_from_osqp(zlo, zhi)
        if drop is not None:  # the dropped rows' slack, objective and multipliers (_unreachable_rows)
            slack, obj = self._dropped_rows_slack(drop, Js @ z, lg, ug, slack, obj)
        dx = z * sx
        x = x_lin + dx
        self._last_y = self._res_y
        ok = slack <= s.balance_tolerance
        return Allocation(x, dx, ok, status if ok else f"{status}; model-row slack {slack:.3g} > {s.balance_tolerance}", it,
                          slack, obj)

    def _exact_step(self, Js: NDArray[np.float64], q: NDArray[np.float64], lg: NDArray[np.float64],
                    ug: NDArray[np.float64], zlo: NDArray[np.float64], zhi: NDArray[np.float64],
                    box: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
                    drop: NDArray[np.bool_] | None = None) -> tuple[NDArray[np.float64], int] | None:
        """The QP of :meth:`solve_at` solved exactly on the last tick's active set
        (:func:`rtctl.active_set.solve_active_set`; when it does not settle within
        ``active_set_iterations``, again from the equality rows and fixed variables alone within
        ``active_set_restart_iterations``), with zero slack: valid when every KKT
        condition holds and every row multiplier is below the exact penalty ``slack_l1`` (then
        zero slack is optimal for the soft QP as well, so this is the same QP's minimiser).
        ``drop``: rows left out of the solve (:func:`_unreachable_rows`; their slack is the
        caller's). Returns ``(z, KKT systems solved)``, or None (OSQP solves the tick)."""
        s = self.settings
        guess = self._active
        last = self._last_box
        if guess is not None and box is not None and last is not None:
            # a variable bound that moved since the last tick (a rate limit around the last
            # command, the step limit around the iterate) is not guessed active again: its
            # activity was the last tick's; bounds that stayed (a cap, a table or actuator bound)
            # keep theirs
            moved = ((guess.box < 0) & (box[0] != last[0])) | ((guess.box > 0) & (box[1] != last[1]))
            if moved.any():
                guess = ActiveSet(guess.rows, np.where(moved, np.int8(0), guess.box).astype(np.int8))
        if box is not None:
            self._last_box = box
        keep = None if drop is None else ~drop
        if keep is not None:  # the solve sees the kept rows only
            Js, lg, ug = Js[keep], lg[keep], ug[keep]
            if guess is not None:
                guess = ActiveSet(guess.rows[keep], guess.box)
        r = solve_active_set(self._Hd, q[:self.nx], Js, lg, ug, zlo, zhi, guess, s.active_set_iterations)
        n = r.iterations
        if not r.ok and s.active_set_restart_iterations > 0:
            # the last tick's set did not settle (a cycle of the full update): once more from the
            # equality rows and the fixed variables alone; when that is where it started (the
            # same iterations would follow), on from where it stopped
            cold = guess is None or starts_alike(guess, None, lg, ug, zlo, zhi)
            r = solve_active_set(self._Hd, q[:self.nx], Js, lg, ug, zlo, zhi, r.active if cold else None,
                                 s.active_set_restart_iterations)
            n += r.iterations
        self.last_active_set_iterations = n
        if not r.ok or float(np.abs(r.y).max(initial=0.0)) >= s.slack_l1 * (1.0 - 1e-9):
            return None
        y, active = r.y, r.active
        if keep is not None:  # back to every row: a dropped row active on its violated side
            y = np.zeros(self.ng)
            y[keep] = r.y
            rows = np.zeros(self.ng, dtype=np.int8)
            rows[keep] = r.active.rows
            rows[~keep] = 1
            active = ActiveSet(rows, r.active.box)
        self._active = active
        z = np.minimum(np.maximum(r.z, zlo), zhi)  # np.clip's definition, without its Python-level dispatch
        ng = self.ng
        # OSQP's multipliers of the same point (warm start of a later fallback): rows, bounds, and
        # the slacks' lower bounds from the slack columns' stationarity at zero slack
        self._res_y = np.concatenate([y, r.nu, y - s.slack_l1, -s.slack_l1 - y])
        self.last_solution = np.concatenate([z, np.zeros(2 * ng)])
        self.last_solver = "active set"
        return z, n

    def _dropped_rows_slack(self, drop: NDArray[np.bool_], Jz: NDArray[np.float64], lg: NDArray[np.float64],
                            ug: NDArray[np.float64], slack: float, obj: float) -> tuple[float, float]:
        """Complete the answer of a solve without the rows ``drop`` (:func:`_unreachable_rows`) to
        the soft QP's: each such row's slack is its violation at the step (``Jz``, its value), which
        no step within the box changes, so it is optimal as it is; its multiplier is then the
        slack column's stationarity, ``+-(rho_1 + 2 rho_2 sigma)`` on the violated side, and the
        slack's bound is inactive. Updates :attr:`last_solution` and the multipliers in place;
        returns the largest slack of any row and the objective with the penalties of the dropped
        rows' slacks."""
        s = self.settings
        ng, nx = self.ng, self.nx
        sp_ = np.zeros(ng)
        sm_ = np.zeros(ng)
        sp_[drop] = np.maximum(Jz[drop] - ug[drop], 0.0)
        sm_[drop] = np.maximum(lg[drop] - Jz[drop], 0.0)
        sol = self.last_solution.copy()
        sol[nx:nx + ng][drop] = sp_[drop]
        sol[nx + ng:][drop] = sm_[drop]
        self.last_solution = sol
        if self._res_y is not None:
            y = self._res_y.copy()
            yr = np.where(sp_ > 0.0, s.slack_l1 + 2.0 * s.slack_l2 * sp_, -(s.slack_l1 + 2.0 * s.slack_l2 * sm_))
            y[:ng][drop] = yr[drop]
            y[ng + nx:ng + nx + ng][drop] = (yr - s.slack_l1 - 2.0 * s.slack_l2 * sp_)[drop]
            y[ng + nx + ng:][drop] = (-s.slack_l1 - 2.0 * s.slack_l2 * sm_ - yr)[drop]
            self._res_y = y
        sig = sp_ + sm_
        return (max(slack, float(sig.max(initial=0.0))),
                obj + float(s.slack_l1 * sig.sum() + s.slack_l2 * (sp_ @ sp_ + sm_ @ sm_)))

    def _active_from_osqp(self, zlo: NDArray[np.float64], zhi: NDArray[np.float64]) -> ActiveSet:
        """The active set of OSQP's answer (the next tick's guess): bounds and rows whose
        multiplier is not zero, on the side of its sign."""
        y = self._res_y if self._res_y is not None else np.zeros(self.m)
        tol = 1e-7
        rows = np.where(y[:self.ng] > tol, 1, np.where(y[:self.ng] < -tol, -1, 0)).astype(np.int8)
        yb = y[self.ng:self.ng + self.nx]
        box = np.where(yb > tol, 1, np.where(yb < -tol, -1, 0)).astype(np.int8)
        self.last_solver = "osqp"
        return ActiveSet(rows, box)

    def _refused(self, why: str, iterations: int = 0) -> Allocation:
        return Allocation(self._x0.copy(), np.zeros(self.nx), False, why, iterations, math.inf, math.nan)

    # ------------------------------------------------------------------ checks
    def snapshot(self) -> tuple[Any, ...]:
        """References to the data of the last :meth:`solve` and OSQP's raw answer (cheap: the
        arrays are replaced, never changed in place, by later calls); see :meth:`problem`."""
        return (self._px_src, self._ax_src, self._q, self._l, self._u, self.last_solution)

    def problem(self, snapshot: tuple[Any, ...] | None = None) -> QpProblem:
        """The QP of the last :meth:`solve` (or of a :meth:`snapshot`), for recording and
        cross-checks; OSQP's raw answer to it is :attr:`last_solution` (scaled step, slacks)."""
        Hd, Js, q, l, u = (snapshot or self.snapshot())[:5]
        P = sp.csc_matrix((self._p_values(Hd), self._p_rows, self._p_indptr), shape=(self.n, self.n))
        A = sp.csc_matrix((self._a_values(Js), self._a_rows, self._a_indptr), shape=(self.m, self.n))
        return QpProblem(P, q.copy(), A, l.copy(), u.copy())


def _unreachable_rows(Js: NDArray[np.float64], lg: NDArray[np.float64], ug: NDArray[np.float64],
                      zlo: NDArray[np.float64], zhi: NDArray[np.float64]) -> NDArray[np.bool_] | None:
    """The model rows no step within the box can move and whose value there lies outside their
    bounds: the scaled Jacobian ``Js`` vanishes on every free variable (``zlo < zhi``; at most
    ``_ZERO_ROW`` of the matrix's largest entry), so the row's value is ``Js[:, fixed] z_fixed``
    whatever the step, and that value violates ``[lg, ug]`` by more than the active set's
    tolerance (:func:`rtctl.active_set.solve_active_set`). None when there is none (the usual case).

    Why: such a row's slack in the soft QP (module docstring) is its violation, fixed by the
    box, and it enters no other row, so the QP without the row has the same minimiser in ``z``
    and the other slacks; the row's slack is then read off (:meth:`QpAllocator._dropped_rows_slack`).
    Kept, it makes the hard QP of the exact active-set solve infeasible (its dual regularisation
    answers with a multiplier of ``violation / delta``, 1e6-1e8, which the penalty test refuses),
    and it slows OSQP's ADMM. The case: the rigid skid-steer (no steerable wheel) at zero wheel
    slip angle, whose ``balance Fy`` row (7.13) no wheel speed, load or sinkage moves, and whose
    residual is the measured cross slope's lateral weight (noise of 0.2-1 mrad on the flat;
    measured over 1 m of ``tests/test_sim_any_rover.py``'s drive: 168 of 197 QPs, every one
    refused by the active set and solved by OSQP in 50-4000 iterations, median 475, against none
    refused and one KKT system each without the row). A row of zero Jacobian whose value lies
    within its bounds (a raised wheel's ``0 = 0`` zero-slip load row) stays: the active set's
    dual regularisation gives it a zero multiplier, as before."""
    if not Js.size:
        return None
    free = zhi > zlo
    scale = float(np.abs(Js).max())
    const = np.abs(Js[:, free]).max(axis=1, initial=0.0) <= _ZERO_ROW * scale
    if not const.any():
        return None
    v = Js[:, ~free] @ zlo[~free]
    tol = 1e-9
    out = const & ((v < lg - tol * (1.0 + np.abs(lg))) | (v > ug + tol * (1.0 + np.abs(ug))))
    return out if out.any() else None


def _finite(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.nan_to_num(v)`` (NaN to 0, +-inf to the largest finite values), the array itself
    when it is finite already (the usual case: np.nan_to_num costs tens of microseconds)."""
    return v if math.isfinite(float(v.sum())) else np.nan_to_num(v)


def solve_with_qpsolvers(problem: QpProblem, solver: str = "clarabel") -> NDArray[np.float64] | None:
    """Solve a recorded QP with another backend through ``qpsolvers.solve_qp`` (lazy import).

    The two-sided rows ``l <= A z <= u`` become equalities where ``l == u`` and inequalities
    ``A z <= u``, ``-A z <= -l`` where finite. Returns None when the backend fails.
    """
    import qpsolvers

    P = problem.P
    Pf = (P + sp.triu(P, 1).T).tocsc()  # full symmetric matrix from the upper triangle
    A = problem.A.tocsr()
    l, u = problem.l, problem.u
    eq = l == u
    up = (~eq) & (u < _INF / 2)
    lo = (~eq) & (l > -_INF / 2)
    G = sp.vstack([A[up], -A[lo]]).tocsc()
    h = np.concatenate([u[up], -l[lo]])
    Ae = A[eq].tocsc() if np.any(eq) else None
    be = u[eq] if np.any(eq) else None
    return qpsolvers.solve_qp(Pf, problem.q, G, h, Ae, be, solver=solver)

