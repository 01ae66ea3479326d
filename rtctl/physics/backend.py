"""Array backends that let one physics implementation serve two uses.

The wheel-soil physics (:mod:`rtctl.physics.soil_flow`, :mod:`rtctl.physics.terramechanics`,
:mod:`rtctl.physics.statics`, :mod:`rtctl.physics.steady_state`) is written once against the
small namespace defined here. With :data:`NUMPY` it evaluates numerically, batched over arrays
of wheel states (offline, and on the rover for each tick's exact residual); with the casadi
backend (``offline.physics.backend.CASADI``, built on the ground side only: rtctl never imports
casadi) the very same code builds a casadi ``SX`` expression graph with exact derivatives
(ARCHITECTURE.md, design point 1).

Shape convention
----------------
*Numpy*: every per-state quantity has shape ``(B, 1)`` (a column of ``B`` wheel states);
quadrature nodes have shape ``(1, n)`` so that integrands broadcast to ``(B, n)``;
:meth:`Backend.cat` joins node blocks along the last axis.
:meth:`Backend.qsum` sums over the node axis and keeps it, returning ``(B, 1)``.

*casadi*: every per-state quantity is a scalar ``SX``; quadrature nodes are an ``(n, 1)``
``DM`` column, integrands are ``(n, 1)`` ``SX`` columns and :meth:`Backend.qsum` is
``casadi.sum1``.

Only element-wise operations, ``where`` (select) and ``qsum`` are used by the physics, so
the two backends give the same numbers to rounding.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

__all__ = ["Backend", "NUMPY", "gauss_legendre", "smooth_max", "smooth_min", "smooth_abs"]


@dataclass(frozen=True)
class Backend:
    """A namespace of element-wise operations for one array library.

    Attributes
    ----------
    name : str
        ``"numpy"`` or ``"casadi"``.
    """

    name: str
    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    tan: Callable[[Any], Any]
    arcsin: Callable[[Any], Any]
    arccos: Callable[[Any], Any]
    arctan: Callable[[Any], Any]
    arctan2: Callable[[Any, Any], Any]
    sqrt: Callable[[Any], Any]
    exp: Callable[[Any], Any]
    log: Callable[[Any], Any]
    fabs: Callable[[Any], Any]
    fmax: Callable[[Any, Any], Any]
    fmin: Callable[[Any, Any], Any]
    where: Callable[[Any, Any, Any], Any]
    qsum: Callable[[Any], Any]
    nodes: Callable[[np.ndarray], Any]
    cat: Callable[[list[Any]], Any]

    def clip(self, x: Any, lo: Any, hi: Any) -> Any:
        """Clip ``x`` to ``[lo, hi]`` (kinks at the bounds)."""
        return self.fmin(self.fmax(x, lo), hi)

    def segment_nodes(self, lo: Any, hi: Any, breaks: list[Any], x: np.ndarray, w: np.ndarray) -> tuple[Any, Any]:
        """Quadrature nodes and weights on the segments between ``lo``, the ``breaks`` clamped
        into ``[lo, hi]`` and sorted, and ``hi``: on each segment ``[a, b]`` the nodes
        ``(a + b) / 2 + (b - a) / 2 x`` and weights ``(b - a) / 2 w`` (``x``, ``w``: a rule on
        ``[-1, 1]``), joined by :meth:`cat`.

        The sort is a network (bubble) of :attr:`fmin` / :attr:`fmax`, continuous and
        differentiable almost everywhere, as the casadi graph needs. With numpy the same
        numbers come from one clamp and one ``np.sort`` of the stacked breaks and whole-array
        arithmetic on the segment ends (a sort and the network select the same values, and
        every node is the same expression of its segment's ends), in a few array operations
        instead of some eighty: the cost of the rover's numpy physics is in the operation count.
        """
        xs, ws_ = np.asarray(x, dtype=float).reshape(-1), np.asarray(w, dtype=float).reshape(-1)
        if self.name == "numpy":
            nb = len(breaks)
            parts = [lo, *breaks, hi]
            if len({np.shape(q) for q in parts}) > 1:  # states of mixed shapes: broadcast them first
                parts = list(np.broadcast_arrays(*parts))
            ends = np.concatenate(parts, axis=-1)
            mid_ = ends[..., 1:nb + 1]
            np.maximum(mid_, lo, out=mid_)
            np.minimum(mid_, hi, out=mid_)
            mid_.sort(axis=-1)
            a, b = ends[..., :-1, None], ends[..., 1:, None]
            half = 0.5 * (b - a)
            shape = half.shape[:-2] + (-1,)
            return (0.5 * (b + a) + half * xs).reshape(shape), (half * ws_).reshape(shape)
        bs = [self.fmin(self.fmax(b_, lo), hi) for b_ in breaks]
        for i in range(len(bs)):
            for j in range(len(bs) - 1 - i):
                bs[j], bs[j + 1] = self.fmin(bs[j], bs[j + 1]), self.fmax(bs[j], bs[j + 1])
        xn, wn = self.nodes(xs), self.nodes(ws_)
        thetas, weights = [], []
        edges = [lo, *bs, hi]
        for a_, b_ in zip(edges[:-1], edges[1:]):
            half_ = 0.5 * (b_ - a_)
            thetas.append(0.5 * (b_ + a_) + half_ * xn)
            weights.append(half_ * wn)
        return self.cat(thetas), self.cat(weights)


def _np_where(c: Any, a: Any, b: Any) -> Any:
    return np.where(c, a, b)


def _np_qsum(x: Any, _add: Any = np.add.reduce) -> Any:
    return _add(x, axis=-1, keepdims=True)  # np.sum's own reduction, without its Python-level dispatch


def _np_nodes(x: np.ndarray) -> Any:
    return np.asarray(x, dtype=float).reshape(1, -1)


def _np_cat(xs: list[Any]) -> Any:
    return np.concatenate(xs, axis=-1)


NUMPY = Backend(
    name="numpy",
    sin=np.sin,
    cos=np.cos,
    tan=np.tan,
    arcsin=np.arcsin,
    arccos=np.arccos,
    arctan=np.arctan,
    arctan2=np.arctan2,
    sqrt=np.sqrt,
    exp=np.exp,
    log=np.log,
    fabs=np.abs,
    fmax=np.maximum,
    fmin=np.minimum,
    where=_np_where,
    qsum=_np_qsum,
    nodes=_np_nodes,
    cat=_np_cat,
)


def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on ``[-1, 1]``.

    Parameters
    ----------
    n : int
        Number of nodes (exact for polynomials of degree ``2 n - 1``).

    Returns
    -------
    nodes, weights : ndarray
    """
    if n < 1:
        raise ValueError(f"quadrature node count must be >= 1, got {n}")
    x, w = np.polynomial.legendre.leggauss(n)
    return x, w


def smooth_max(ops: Backend, a: Any, b: Any, eps: float) -> Any:
    """Smooth maximum ``(a + b + sqrt((a - b)^2 + eps^2)) / 2``.

    Differs from ``max(a, b)`` by at most ``eps / 2`` (at ``a == b``) and is infinitely
    differentiable. Used only where a documented, narrow smoothing helps a solver.
    """
    return 0.5 * (a + b + ops.sqrt((a - b) ** 2 + eps * eps))


def smooth_min(ops: Backend, a: Any, b: Any, eps: float) -> Any:
    """Smooth minimum, the mirror of :func:`smooth_max` (error at most ``eps / 2``)."""
    return 0.5 * (a + b - ops.sqrt((a - b) ** 2 + eps * eps))


def smooth_abs(ops: Backend, x: Any, eps: float) -> Any:
    """``sqrt(x^2 + eps^2)``: differs from ``|x|`` by at most ``eps``."""
    return ops.sqrt(x * x + eps * eps)
