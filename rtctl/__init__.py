"""On-rover controller package (EKF on slip and heading + QP allocation at 5 Hz).

Not implemented yet: this package currently holds nothing but its import-cleanliness
contract (it must never import casadi, scipy.optimize or :mod:`offline`), which
``tests/test_imports.py`` enforces.
"""

__all__: list[str] = []
