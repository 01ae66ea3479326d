"""The drive product of the discrepancy tool: rover recordings (MCAP) against the simulator.

* :mod:`.diagnosis`: the drive adapter (:class:`~.diagnosis.DriveRecording`, time segments),
  the re-simulating model (:class:`~.diagnosis.DriveModel`) and :func:`~.diagnosis.diagnose_drives`;
* :mod:`.candidates`: the drive library (terrain, tether, soil, wheels, steering, actuators) and
  the truth files the simulator reads;
* :mod:`.empirical`: generic empirical terms for what the library lacks;
* :mod:`.synthetic`: recorded drives from the simulator (calibration drive, concealed truths);
* :mod:`.report`: the report folder a drive verdict is rendered to (plots, truth file).
"""

__all__ = ["diagnosis", "candidates", "empirical", "synthetic", "report"]
from . import candidates, diagnosis, empirical, report, synthetic  # noqa: E402  (the modules __all__ lists)
