"""Simulation layer: the rover plant, actuators and sensors, closed-loop experiments (ch. 7.3).

:mod:`.plant` (planar rigid body, terramechanics wheels, rocker statics), :mod:`.actuators`,
:mod:`.sensors`, :mod:`.truth` (the simulated world's parameter file), :mod:`.simulator`
(measurements out, commands in), :mod:`.experiments` (section 7.3 harness and its controllers),
:mod:`.rtctl_bridge` (rtctl as a controller of the harness).
"""

from .simulator import Disturbance, DisturbanceForces, TruthState

__all__ = ["plant", "actuators", "sensors", "truth", "simulator", "experiments", "rtctl_bridge", "Disturbance",
           "DisturbanceForces", "TruthState"]
