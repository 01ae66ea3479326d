"""The single-wheel product of the discrepancy tool: testbed trials against the wheel-soil model.

* :mod:`.recording`: :class:`~.recording.SingleWheelRecording`, the engine's adapter (one row per
  condition, repeat means and pooled noise, operating-point features);
* :mod:`.candidates`: the model (:class:`~.candidates.SingleWheelModel`) and the library of
  candidate terms (:data:`~.candidates.CANDIDATES`);
* :mod:`.face_pressure`: the bulldozing face-pressure study at large slip angles.

A diagnosis is :func:`offline.discrepancy.engine.diagnose` on a
:class:`~offline.fit.dataset.TrialSet`; its verdict is rendered by
:func:`offline.discrepancy.report.write_report`.
"""

__all__ = ["recording", "candidates", "face_pressure"]
from . import candidates, face_pressure, recording  # noqa: E402  (the modules __all__ lists)
