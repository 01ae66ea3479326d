"""Offline (ground-side) half of the off-nominal rover driving library.

Physics (soil flow, ch. 4; terramechanics, ch. 5), calibration against single-wheel data,
and the tools built on them. Heavy dependencies (casadi, scipy, matplotlib) are allowed
here and never in :mod:`rtctl`.
"""

__all__ = ["backend", "params"]
