"""Offline (ground-side) half of the off-nominal rover driving library.

Subpackages by layer (arrows point down only; none imports a layer above it):

* :mod:`offline.physics`: parameters, backend, soil flow (ch. 4), terramechanics (ch. 5);
* :mod:`offline.rover`: rover statics, scenarios and failure kinds, steady-state optimizer (ch. 7);
* :mod:`offline.fit`: single-wheel data, Bekker fit, calibration, validation;
* :mod:`offline.sim`: the rover simulator and closed-loop experiments;
* :mod:`offline.discrepancy`: the discrepancy tool on single-wheel trials and drive recordings
  (engine, report writer, the single-wheel and the drive products);
* :mod:`offline.files`: atomic output files that never replace an input;
* :mod:`offline.cli`: the ``offnominal`` command (thin: parse, call the library, print).

Heavy dependencies (casadi, scipy, matplotlib) are allowed here and never in :mod:`rtctl`.
Modules are imported on demand: ``from offline.physics.terramechanics import WheelModel``.
"""

__all__ = ["physics", "rover", "fit", "sim", "discrepancy", "files", "cli"]
