"""Fitting layer: single-wheel data, Bekker plate fit, calibration, validation and the discrepancy tool."""

__all__ = ["dataset", "bekker", "calibration", "validation", "discrepancy"]
