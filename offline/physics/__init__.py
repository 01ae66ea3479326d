"""Physics layer: parameters, the numpy/casadi backend, soil flow (ch. 4) and 3D terramechanics (ch. 5).

Knows nothing of rovers, fitting or simulation (arrows point down only).
"""

__all__ = ["backend", "params", "soil_flow", "terramechanics", "plots_soil_flow"]
