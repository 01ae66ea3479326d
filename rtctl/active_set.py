"""A small dense QP solved exactly by a warm-started primal-dual active-set method.

The allocation QP of one real-time iteration (:mod:`rtctl.allocator`) has 20 variables and
19-22 rows. Between ticks its active set (which bounds and inequality rows hold with
equality) almost never changes, so the QP is one linear system of at most 41 unknowns: the
KKT system of the equality-constrained QP on the guessed active set. This module solves

.. math::

    \\min_z\\ \\tfrac12 z^T H z + q^T z \\quad\\text{s.t.}\\quad
    l_g \\le J z \\le u_g,\\qquad z_{lo} \\le z \\le z_{hi}

with ``H`` symmetric positive definite, by the primal-dual active-set iteration of
Hintermüller, Ito & Kunisch (SIAM J. Optim. 13(3), 2003): solve the KKT system on the guessed
set, then add every violated constraint and drop every active one whose multiplier has the
wrong sign, until nothing changes (then every KKT condition of the convex QP holds, so the
answer is its unique minimiser to rounding) or the iteration budget is spent (then the caller
solves the QP another way: :class:`rtctl.allocator.QpAllocator` falls back to OSQP).

Multipliers follow OSQP's convention: stationarity ``H z + q + J^T y + nu = 0``, with ``y_i``,
``nu_i`` >= 0 at an upper bound, <= 0 at a lower one, free on an equality row (``l = u``), 0
when inactive. Rows with two infinite bounds are never active.

The equality rows' block carries a dual regularisation ``-delta I`` (``delta = 1e-12`` of the
matrix's scale): a row whose Jacobian vanishes (a wheel out of contact makes its zero-slip load
row ``0 = 0``) leaves the system solvable, with a zero multiplier when its residual is zero and
a huge one (which the caller's penalty test refuses) when it is not.

Everything is deterministic dense numpy (``numpy.linalg.solve``); the budget is in iterations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["ActiveSet", "ActiveSetResult", "solve_active_set", "starts_alike"]

_BIG = 1e20  # a bound at or beyond this magnitude is absent


@dataclass
class ActiveSet:
    """Which constraints hold with equality: ``-1`` at the lower bound, ``+1`` at the upper,
    ``0`` inactive, for the rows (``rows``, ng) and the variable bounds (``box``, nx). Equality
    rows are always active whatever their entry says."""

    rows: NDArray[np.int8]
    box: NDArray[np.int8]

    @classmethod
    def empty(cls, nx: int, ng: int) -> "ActiveSet":
        return cls(np.zeros(ng, dtype=np.int8), np.zeros(nx, dtype=np.int8))

    def copy(self) -> "ActiveSet":
        return ActiveSet(self.rows.copy(), self.box.copy())


@dataclass(frozen=True)
class ActiveSetResult:
    """Answer of :func:`solve_active_set`.

    Attributes
    ----------
    ok : bool
        Every KKT condition holds (within ``tol``) on the final active set.
    z : ndarray (nx,)
        The minimiser (meaningful only when ``ok``).
    y : ndarray (ng,)
        Row multipliers (OSQP's sign convention, module docstring).
    nu : ndarray (nx,)
        Bound multipliers.
    active : ActiveSet
        The final active set (the next tick's guess).
    iterations : int
        KKT systems solved.
    why : str
        Empty when ``ok``; else why not (budget spent, singular system, ...).
    """

    ok: bool
    z: NDArray[np.float64]
    y: NDArray[np.float64]
    nu: NDArray[np.float64]
    active: ActiveSet
    iterations: int
    why: str


def solve_active_set(H: NDArray[np.float64], q: NDArray[np.float64], J: NDArray[np.float64],
                     lg: NDArray[np.float64], ug: NDArray[np.float64], zlo: NDArray[np.float64],
                     zhi: NDArray[np.float64], guess: ActiveSet | None = None, max_iter: int = 8,
                     tol: float = 1e-9) -> ActiveSetResult:
    """Solve the QP of the module docstring from the active-set ``guess``.

    Parameters
    ----------
    H : ndarray (nx, nx)
        Symmetric positive definite Hessian.
    q : ndarray (nx,)
    J : ndarray (ng, nx)
    lg, ug : ndarray (ng,)
        Row bounds (``|bound| >= 1e20``: none); ``lg = ug`` is an equality row.
    zlo, zhi : ndarray (nx,)
        Variable bounds, ``zlo <= zhi`` (``zlo = zhi`` fixes the variable).
    guess : ActiveSet, optional
        Start (the last tick's final set); None starts from the equality rows and the variables
        fixed by their bounds.
    max_iter : int
        Budget of KKT systems.
    tol : float
        Feasibility and sign tolerance, relative to ``1 + |bound|``.

    Returns
    -------
    ActiveSetResult
    """
    nx, ng = H.shape[0], J.shape[0]
    has_lo_g, has_hi_g = lg > -_BIG, ug < _BIG
    act, eq, fixed_var = _start(guess, lg, ug, zlo, zhi, tol, has_lo_g, has_hi_g)
    scale = max(float(np.abs(H).max()), float(np.abs(J).max()) if J.size else 0.0, 1e-300)
    delta = 1e-12 * scale
    z = np.zeros(nx)
    y = np.zeros(ng)
    nu = np.zeros(nx)
    seen = {act.rows.tobytes() + act.box.tobytes()}
    ineq = ~eq
    tl, tu = tol * (1.0 + np.abs(lg)), tol * (1.0 + np.abs(ug))
    bl, bu = tol * (1.0 + np.abs(zlo)), tol * (1.0 + np.abs(zhi))
    # loop-invariant parts of the update's conditions (evaluated once, not per KKT system)
    lo_rows, hi_rows, free_var = ineq & has_lo_g, ineq & has_hi_g, ~fixed_var
    lg_t, ug_t, zlo_t, zhi_t = lg - tl, ug + tu, zlo - bl, zhi + bu
    for it in range(1, max_iter + 1):
        # one KKT system over (z, y_E, nu_B): H z + J_E' y_E + S_B' nu_B = -q, J_E z = b_E, z_B = bound
        E = act.rows != 0
        B = act.box != 0
        iB = np.flatnonzero(B)
        JE = J[E]
        nE, nB = JE.shape[0], iB.size
        n = nx + nE + nB
        K = np.zeros((n, n))
        K[:nx, :nx] = H
        K[:nx, nx:nx + nE] = JE.T
        K[nx:nx + nE, :nx] = JE
        K[nx:nx + nE, nx:nx + nE].flat[::nE + 1] = -delta
        kb = nx + nE + np.arange(nB)
        K[kb, iB] = 1.0
        K[iB, kb] = 1.0
        rhs = np.concatenate([-q, np.where(act.rows[E] < 0, lg[E], ug[E]), np.where(act.box[B] < 0, zlo[B], zhi[B])])
        try:
            sol = np.linalg.solve(K, rhs)
        except np.linalg.LinAlgError:
            return ActiveSetResult(False, z, y, nu, act, it, "singular KKT system")
        if not np.isfinite(sol).all():
            return ActiveSetResult(False, z, y, nu, act, it, "non-finite KKT solution")
        z = sol[:nx]
        y = np.zeros(ng)
        y[E] = sol[nx:nx + nE]
        nu = np.zeros(nx)
        nu[iB] = sol[nx + nE:]
        F = ~B
        # ---- the new guess: add what is violated, drop what pulls the wrong way
        Jz = J @ z
        new = act.copy()
        r0 = act.rows == 0
        new.rows[lo_rows & r0 & (Jz < lg_t)] = -1
        new.rows[hi_rows & r0 & (Jz > ug_t)] = 1
        new.rows[ineq & (act.rows < 0) & (y > tol)] = 0
        new.rows[ineq & (act.rows > 0) & (y < -tol)] = 0
        new.box[F & (z < zlo_t)] = -1
        new.box[F & (z > zhi_t)] = 1
        new.box[free_var & (act.box < 0) & (nu > tol)] = 0
        new.box[free_var & (act.box > 0) & (nu < -tol)] = 0
        if np.array_equal(new.rows, act.rows) and np.array_equal(new.box, act.box):
            # every KKT condition: stationarity (by construction), primal feasibility of the
            # inactive rows and free variables, signs of the active multipliers
            return ActiveSetResult(True, z, y, nu, act, it, "")
        key = new.rows.tobytes() + new.box.tobytes()
        if key in seen:  # a cycle of the full update: change only the worst-violated condition
            new = _single_change(act, z, y, nu, Jz, lg, ug, zlo, zhi, eq, fixed_var, has_lo_g, has_hi_g, tol)
            key = new.rows.tobytes() + new.box.tobytes()
        seen.add(key)
        act = new
    return ActiveSetResult(False, z, y, nu, act, max_iter, f"active set still changing after {max_iter} KKT systems")


def _start(guess: ActiveSet | None, lg: NDArray[np.float64], ug: NDArray[np.float64], zlo: NDArray[np.float64],
           zhi: NDArray[np.float64], tol: float, has_lo_g: NDArray[np.bool_], has_hi_g: NDArray[np.bool_]
           ) -> tuple[ActiveSet, NDArray[np.bool_], NDArray[np.bool_]]:
    """The set :func:`solve_active_set` starts from (``guess`` with every equality row active,
    every fixed variable at its bound, no row active on a side without a bound), the equality
    rows and the fixed variables."""
    eq = has_lo_g & has_hi_g & (ug - lg <= tol * (1.0 + np.abs(lg)))
    fixed_var = zhi - zlo <= tol * (1.0 + np.abs(zlo))
    act = ActiveSet.empty(zlo.size, lg.size) if guess is None else guess.copy()
    act.rows = np.where(eq, np.int8(1), act.rows).astype(np.int8)
    act.rows[(act.rows < 0) & ~has_lo_g] = 0
    act.rows[(act.rows > 0) & ~has_hi_g] = 0
    act.box = np.where(fixed_var, np.int8(-1), act.box).astype(np.int8)
    return act, eq, fixed_var


def starts_alike(a: ActiveSet | None, b: ActiveSet | None, lg: NDArray[np.float64], ug: NDArray[np.float64],
                 zlo: NDArray[np.float64], zhi: NDArray[np.float64], tol: float = 1e-9) -> bool:
    """Whether :func:`solve_active_set` starts from the same set for the guesses ``a`` and
    ``b`` on this QP's bounds (then the same iterations follow)."""
    has_lo_g, has_hi_g = lg > -_BIG, ug < _BIG
    sa = _start(a, lg, ug, zlo, zhi, tol, has_lo_g, has_hi_g)[0]
    sb = _start(b, lg, ug, zlo, zhi, tol, has_lo_g, has_hi_g)[0]
    return bool(np.array_equal(sa.rows, sb.rows) and np.array_equal(sa.box, sb.box))


def _single_change(act: ActiveSet, z: NDArray[np.float64], y: NDArray[np.float64], nu: NDArray[np.float64],
                   Jz: NDArray[np.float64], lg: NDArray[np.float64], ug: NDArray[np.float64],
                   zlo: NDArray[np.float64], zhi: NDArray[np.float64], eq: NDArray[np.bool_],
                   fixed_var: NDArray[np.bool_], has_lo_g: NDArray[np.bool_], has_hi_g: NDArray[np.bool_],
                   tol: float) -> ActiveSet:
    """The set with only its worst violation changed (the safeguard against the full update's
    cycles, as in Hintermüller-Ito-Kunisch's remark on non-M-matrix problems): the most violated
    constraint is added, or else the active one with the most wrong-signed multiplier dropped."""
    cand: list[tuple[float, str, int, int]] = []
    ineq = ~eq
    viol_lo = np.where(ineq & (act.rows == 0) & has_lo_g, lg - Jz, -np.inf)
    viol_hi = np.where(ineq & (act.rows == 0) & has_hi_g, Jz - ug, -np.inf)
    free = act.box == 0
    vz_lo = np.where(free, zlo - z, -np.inf)
    vz_hi = np.where(free, z - zhi, -np.inf)
    for arr, kind, side in ((viol_lo, "row", -1), (viol_hi, "row", 1), (vz_lo, "box", -1), (vz_hi, "box", 1)):
        if arr.size:
            i = int(np.argmax(arr))
            if arr[i] > tol:
                cand.append((float(arr[i]), kind, i, side))
    if not cand:
        wrong_r = np.where(ineq & (act.rows < 0), y, np.where(ineq & (act.rows > 0), -y, -np.inf))
        wrong_b = np.where(~fixed_var & (act.box < 0), nu, np.where(~fixed_var & (act.box > 0), -nu, -np.inf))
        for arr, kind in ((wrong_r, "row"), (wrong_b, "box")):
            if arr.size:
                i = int(np.argmax(arr))
                if arr[i] > tol:
                    cand.append((float(arr[i]), kind, i, 0))
    new = act.copy()
    if cand:
        _, kind, i, side = max(cand)
        (new.rows if kind == "row" else new.box)[i] = side
    return new
