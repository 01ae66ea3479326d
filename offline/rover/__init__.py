"""Rover layer: statics (ch. 7), scenarios and failure kinds, the steady-state optimizer (7.25).

Built on :mod:`offline.physics`; the table builder (:mod:`.table_builder`, :mod:`.table_verify`) and the
simulator build on this layer.
"""

__all__ = ["statics", "scenario", "primitives", "table_builder", "table_verify"]
