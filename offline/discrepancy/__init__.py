"""The discrepancy tool: when simulation and recordings differ, locate the mismatch, say what
physics was left out (or that the model's own parameters are off), model it, and show the fit
improve on held-out data.

A layer above :mod:`offline.fit` (the calibrated wheel-soil model it starts from) and
:mod:`offline.sim` (the simulator a drive is re-simulated with); nothing below imports it.

* :mod:`.engine`: the generic engine (:func:`~.engine.diagnose`, :class:`~.engine.Verdict`),
  over any :class:`~.observations.Observations` and model; :mod:`.significance` its statistics;
* :mod:`.parallel`: the independent re-simulations of a diagnosis over worker processes, with
  the verdict of one process bit for bit (``workers=``);
* :mod:`.report`: renders a verdict to a report folder (the diagnosis itself writes nothing);
* :mod:`.wheel`: the single-wheel product (testbed trials, its candidate library);
* :mod:`.drive`: the drive product (MCAP recordings, its library, empirical terms, drive report).

Import the module you need: ``from offline.discrepancy.drive.diagnosis import diagnose_drives``.
"""

__all__ = ["engine", "observations", "significance", "parallel", "report", "wheel", "drive"]


def __getattr__(name: str) -> object:
    """Submodules on first use (``import offline.discrepancy`` stays light)."""
    if name in __all__:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
