"""The wheel-soil physics in one home, imported by both sides (ARCHITECTURE.md, design point 1).

numpy only at import: the rover evaluates each tick's exact residual of (7.25) with it
(:mod:`rtctl.physics.steady_state`), and the ground side builds its casadi graphs from the
same functions (``offline.physics.backend.CASADI``). Modules:

* :mod:`rtctl.physics.backend`: the array backend the physics is written against (numpy here);
* :mod:`rtctl.physics.parameters`: what the physics reads of a parameter set (protocols, records);
* :mod:`rtctl.physics.terramechanics`: the 3D wheel-soil wrench, eqs. (5.1)-(5.33);
* :mod:`rtctl.physics.soil_flow`: the soil-flow trench model of ch. 4;
* :mod:`rtctl.physics.hub_drag`: hub / body face drag below the clearance;
* :mod:`rtctl.physics.statics`: the rocker rover's balance (7.12)-(7.18);
* :mod:`rtctl.physics.rover_file`: a rover described by a TOML file (wheels, suspension, limits);
* :mod:`rtctl.physics.suspension`: the balance of any rover file's suspension, from its free bodies;
* :mod:`rtctl.physics.steady_state`: the rows and objective of (7.25), and the rover's exact residual.

Submodules load on first use (``rtctl.physics.soil_flow`` only where a trench row needs it).
"""

import importlib
from typing import Any

__all__ = ["backend", "parameters", "terramechanics", "soil_flow", "hub_drag", "statics", "steady_state", "rover_file", "suspension"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
