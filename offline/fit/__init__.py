"""Fitting layer: single-wheel data, Bekker plate fit, calibration and validation of the
wheel-soil model (the discrepancy tool that starts from it is :mod:`offline.discrepancy`)."""

__all__ = ["dataset", "bekker", "calibration", "validation", "synthetic"]
