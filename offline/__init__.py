"""Offline (ground-side) half of the off-nominal rover driving library.

Physics (soil flow, ch. 4; terramechanics, ch. 5), calibration against single-wheel data,
validation, the discrepancy tool, rover statics and the steady-state driving-primitive
optimizer (ch. 7). Heavy dependencies (casadi, scipy, matplotlib) are allowed here and never
in :mod:`rtctl`. Modules are imported on demand: ``from offline.terramechanics import WheelModel``.
"""

__all__ = [
    "backend",
    "params",
    "soil_flow",
    "terramechanics",
    "dataset",
    "bekker",
    "calibration",
    "validation",
    "discrepancy",
    "rover",
    "scenario",
    "primitives",
    "cli",
]
