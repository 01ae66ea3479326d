"""Fitting layer: single-wheel data, Bekker plate fit, calibration, validation and the discrepancy tool
(engine :mod:`.discrepancy` with :mod:`.observations`, :mod:`.candidates`, :mod:`.significance`)."""

__all__ = ["dataset", "bekker", "calibration", "validation", "observations", "candidates", "significance", "discrepancy"]
