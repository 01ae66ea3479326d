"""Physics layer, ground side: parameters, the casadi backend and the validated wheel model (ch. 5).

The physics itself (soil flow of ch. 4, the terramechanics of ch. 5, the statics of ch. 7) lives
in :mod:`rtctl.physics`, which the rover imports too; this layer builds on it.

Knows nothing of rovers, fitting or simulation (arrows point down only).
"""

__all__ = ["backend", "params", "terramechanics", "plots_soil_flow"]
