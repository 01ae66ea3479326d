"""The casadi backend of the one physics implementation (ground side only).

The physics is written once against :class:`rtctl.physics.backend.Backend` (its module
docstring has the shape conventions). :data:`CASADI` builds casadi ``SX`` graphs with exact
derivatives from that same code; it lives here because rtctl, the rover side, never imports
casadi. The numpy backend and the helpers are re-exported from :mod:`rtctl.physics.backend`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rtctl.physics.backend import NUMPY, Backend, gauss_legendre, smooth_abs, smooth_max, smooth_min

__all__ = ["Backend", "NUMPY", "CASADI", "gauss_legendre", "smooth_max", "smooth_min", "smooth_abs"]


def _make_casadi() -> Backend:
    import casadi as ca  # heavy import kept local: offline only, never rtctl

    def where(c: Any, a: Any, b: Any) -> Any:
        return ca.if_else(c, a, b)

    def nodes(x: np.ndarray) -> Any:
        return ca.DM(np.asarray(x, dtype=float).reshape(-1, 1))

    return Backend(
        name="casadi",
        sin=ca.sin,
        cos=ca.cos,
        tan=ca.tan,
        arcsin=ca.asin,
        arccos=ca.acos,
        arctan=ca.atan,
        arctan2=ca.atan2,
        sqrt=ca.sqrt,
        exp=ca.exp,
        log=ca.log,
        fabs=ca.fabs,
        fmax=ca.fmax,
        fmin=ca.fmin,
        where=where,
        qsum=ca.sum1,
        nodes=nodes,
        cat=lambda xs: ca.vertcat(*xs),
    )


class _LazyCasadi:
    """Defers ``import casadi`` until the casadi backend is first used."""

    _backend: Backend | None = None

    def __getattr__(self, item: str) -> Any:
        if _LazyCasadi._backend is None:
            _LazyCasadi._backend = _make_casadi()
        return getattr(_LazyCasadi._backend, item)


CASADI: Backend = _LazyCasadi()  # type: ignore[assignment]
