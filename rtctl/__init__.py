"""On-rover controller package (EKF on slip and heading + QP allocation at 5 Hz).

Light by contract: numpy, osqp, filterpy (and qpsolvers for cross-checks) only; never casadi
or :mod:`offline` (``tests/test_imports.py`` enforces it). Modules:

* :mod:`rtctl.layout`: the named layout of the steady-state NLP (7.25), shared with the table builder;
* :mod:`rtctl.messages`: measurements in, commands out;
* :mod:`rtctl.inputs`: the input boundary (every field converted once; time stamps and sequence numbers judged);
* :mod:`rtctl.table`: lookup tables (load, hash/schema check, interpolation at an operating point);
* :mod:`rtctl.wheel_set`: the wheel set a table is for (its header) and whether this rtctl drives it;
* :mod:`rtctl.config`: the controller's TOML configuration (actuator limits, noise, gains, QP settings);
* :mod:`rtctl.estimator`: EKF on heading, position, slip, crab angle and gyro bias (filterpy);
* :mod:`rtctl.allocator`: the QP of one SQP step of (7.25) (OSQP, set up once per table);
* :mod:`rtctl.rti`: one table's real-time iteration (exact linearisation at the carried iterate, the QP);
* :mod:`rtctl.mirror`: the left-right mirror of a table (a rear-right table serves rear-left);
* :mod:`rtctl.physics`: the wheel-soil physics both sides share (numpy here, for the exact residual);
* :mod:`rtctl.controller`: ``Controller(tables, config).step(measurements) -> (commands, diagnostics)``;
* :mod:`rtctl.runner`: the 5 Hz clock, step timing against the 200 ms deadline, overrun count;
* :mod:`rtctl.codegen`: optional tool (not on the 5 Hz path): the QP as C code (OSQP's code generation) for a flight build.
"""

__all__ = ["layout", "messages", "inputs", "table", "wheel_set", "config", "estimator", "allocator", "rti", "mirror", "physics",
           "controller", "runner", "codegen"]
