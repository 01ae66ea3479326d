"""The wheel-soil physics in one home, imported by both sides (ARCHITECTURE.md, design point 1).

numpy only at import: the rover evaluates each tick's exact residual of (7.25) with it
(:mod:`rtctl.physics.steady_state`), and the ground side builds its casadi graphs from the
same functions (``offline.physics.backend.CASADI``).
"""
