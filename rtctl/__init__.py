"""On-rover controller package (EKF on slip and heading + QP allocation at 5 Hz).

Light by contract: numpy, osqp, filterpy (and qpsolvers for cross-checks) only; never casadi
or :mod:`offline` (``tests/test_imports.py`` enforces it). Modules:

* :mod:`rtctl.layout`: the named layout of the steady-state NLP (7.25), shared with the table builder;
* :mod:`rtctl.messages`: measurements in, commands out;
* :mod:`rtctl.table`: lookup tables (load, hash/schema check, interpolation at an operating point).
"""

__all__ = ["layout", "messages", "table"]
