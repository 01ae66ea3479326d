"""A synthetic 'linear rover' table for the controller's tests and benchmarks (no NLP needed).

Written with the real table writer (:func:`rtctl.table.table_bytes`) and read with the real
loader, so the controller sees exactly what it sees with a built table, but its fields come
from a linear model whose signs follow the dissertation's conventions:

* traction F_x,i = k (omega_i - omega0) (a faster wheel pushes harder), lateral force
  F_y,i = c beta_i (a wheel steered left pushes the rover left);
* balance rows (7.12)-(7.18) with the offsets of (7.26)-(7.27) (``g = sum - offset``) and the
  slope of (7.32)-(7.33); load rows F_z(h) - W; a wheel-torque row proportional to the traction;
* objective (7.24): sum of squared torques (Lagrangian Hessian on omega), zero gradient at the
  primitive, which is therefore the optimum.

So a positive yaw-moment offset must speed up the right wheels and slow the left ones, and a
positive lateral-force offset must steer every wheel left, as the steering controllers of
section 7.2.4 do.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from rtctl.layout import WHEELS, NlpLayout
from rtctl.table import CONTROLLER_NAMES, SCHEMA, SCHEMA_VERSION, field_shapes, load_table, table_bytes

RS = 0.063  # shearing radius r + h_g of the mini rover's wheel, m
TRACK, ROCKER, WEIGHT = 0.331, 0.32, 34.3
K_TRACTION = 15.0  # N per rad/s (about dF_x/d omega of a mini-rover wheel: W/4 per unit slip)
C_LATERAL = 6.0  # N per rad
K_SINK = 2000.0  # N per m
K_TORQUE = 2.0  # N m per rad/s
SLIP0 = 0.1
SCALES = {"omega": 0.5, "beta": 0.3, "W": WEIGHT / 4, "h": RS / 4, "h0": RS / 4}
CSCALES = {"force": WEIGHT, "moment": WEIGHT * ROCKER, "load": WEIGHT / 4, "torque": 0.5}
TRUST = {"speed": 0.01, "slope": 0.1, "cross_slope": 0.1, "fy_offset": 1.0, "mz_offset": 0.2}
SIDE = {"FR": -1.0, "FL": 1.0, "RR": -1.0, "RL": 1.0}
FRONT = {"FR": 1.0, "FL": 1.0, "RR": -1.0, "RL": -1.0}


def point_fields(lay: NlpLayout, speed: float, slope: float, stuck: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """All contract-C2 fields of the linear rover at one operating point (physical units)."""
    nx, npar, ng = lay.nx, lay.np_, lay.ng
    om0 = speed / (RS * (1 - SLIP0))
    x = np.zeros(nx)
    w_load = WEIGHT * math.cos(slope) / 4
    for w in WHEELS:
        x[lay.var("omega", w)] = om0
        x[lay.var("beta", w)] = (stuck or {}).get(w, 0.0)
        x[lay.var("W", w)] = w_load
        x[lay.var("h", w)] = 0.01 + w_load / K_SINK
        x[lay.var("h0", w)] = 0.01 + w_load / K_SINK
    if stuck and "RR" in stuck:  # the primitive balances F_y and M_z of a stuck RR with RL opposite
        x[lay.var("beta", "RL")] = -stuck["RR"]
    p = np.zeros(npar)
    p[lay.index("speed")], p[lay.index("slope")] = speed, slope
    for w in WHEELS:
        p[lay.index(f"contact {w}")] = 1.0
    J = np.zeros((ng, nx))
    Jp = np.zeros((ng, npar))
    r = {n: lay.index(f"balance {n}") for n in ("Fx", "Fy", "Fz", "Mx", "My_right", "My_left", "Mz")}
    for w in WHEELS:
        io, ib, iW, ih, ih0 = (lay.var(v, w) for v in ("omega", "beta", "W", "h", "h0"))
        J[r["Fx"], io] = K_TRACTION
        J[r["Fy"], ib] = C_LATERAL
        J[r["Fz"], iW] = 1.0
        J[r["Mx"], iW] = SIDE[w] * TRACK / 2
        J[r["Mz"], io] = -SIDE[w] * K_TRACTION * TRACK / 2  # right wheel (y < 0) faster: turn left
        J[r["Mz"], ib] = FRONT[w] * C_LATERAL * ROCKER / 2
        rocker = "My_right" if SIDE[w] < 0 else "My_left"
        J[r[rocker], iW] = -FRONT[w] * ROCKER / 2
        J[lay.index(f"load {w}"), ih] = K_SINK
        J[lay.index(f"load {w}"), iW] = -1.0
        J[lay.index(f"zero-slip load {w}"), ih0] = K_SINK
        J[lay.index(f"zero-slip load {w}"), iW] = -1.0
        J[lay.index(f"wheel torque {w}"), io] = K_TORQUE
    Jp[r["Fx"], lay.index("slope")] = -WEIGHT * math.cos(slope)
    Jp[r["Fz"], lay.index("slope")] = WEIGHT * math.sin(slope)
    Jp[r["Fy"], lay.index("fy_offset")] = -1.0
    Jp[r["Mz"], lay.index("mz_offset")] = -1.0
    Jp[r["Fx"], lay.index("speed")] = -K_TRACTION / (RS * (1 - SLIP0)) * 4  # more speed, same omega: less traction
    H = np.zeros((nx, nx))
    for w in WHEELS:
        io = lay.var("omega", w)
        H[io, io] = 2 * K_TORQUE ** 2
    lbx = np.zeros(nx)
    ubx = np.zeros(nx)
    for w in WHEELS:
        lbx[lay.wheel_slice(w)] = [0.0, -math.pi / 2, 0.0, 0.005, 0.005]
        ubx[lay.wheel_slice(w)] = [12 * speed / RS, math.pi / 2, WEIGHT / 2, 1.5 * 0.058 + 0.005, 1.5 * 0.058 + 0.005]
        if stuck and w in stuck:
            lbx[lay.var("beta", w)] = ubx[lay.var("beta", w)] = stuck[w]
    lbg = np.zeros(ng)
    ubg = np.zeros(ng)
    for w in WHEELS:
        j = lay.index(f"wheel torque {w}")
        lbg[j], ubg[j] = -1e30, 1e30  # the builder writes BIG = 1e30 for "unbounded"
    # sensitivity d x*/d p from the KKT system of this linear-quadratic problem
    eq = [i for i in range(ng) if lbg[i] == ubg[i]]
    Hr = H + 1e-6 * np.diag(1 / lay.variable_scale ** 2)
    K = np.block([[Hr, J[eq].T], [J[eq], np.zeros((len(eq), len(eq)))]])
    sol = np.linalg.lstsq(K, np.vstack([np.zeros((nx, npar)), -Jp[eq]]), rcond=None)[0]
    dxdp = sol[:nx]
    wrench = np.zeros((4, 6))
    wj = np.zeros((4, 6, 5))
    for i, w in enumerate(WHEELS):
        wrench[i, 2] = w_load
        wj[i, 1, 1] = -50.0  # lateral resistance: F_y opposes a lateral wheel velocity
        wj[i, 0, 0] = -K_TRACTION / (RS * om0)
    ctrl = np.zeros((len(CONTROLLER_NAMES), 4, 2))
    io_idx = [lay.var("omega", w) for w in WHEELS]
    ib_idx = [lay.var("beta", w) for w in WHEELS]
    for n, name in enumerate(CONTROLLER_NAMES):
        j = lay.index("mz_offset" if name.startswith("Mz") else "fy_offset")
        ctrl[n, :, 0] = dxdp[io_idx, j] * RS
        ctrl[n, :, 1] = dxdp[ib_idx, j]
    trust = np.zeros(npar)
    for name, r in TRUST.items():
        trust[lay.index(name)] = r
    return {"trust_radius": trust, "x": x, "p": p, "g": np.zeros(ng), "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg, "lam_x": np.zeros(nx),
            "lam_g": np.zeros(ng), "jac_g_x": J, "jac_g_p": Jp, "grad_f": np.zeros(nx), "hess_lag": H, "dx_dp": dxdp,
            "wrench": wrench, "wrench_jac": wj, "slip": np.full(4, SLIP0), "slip_angle": x[ib_idx],
            "torque": np.zeros(4), "power": np.zeros(4), "controllers": ctrl, "objective": np.array(0.0)}


def write_table(folder: Path, name: str = "linear_nominal", stuck_wheel: str | None = None) -> Path:
    """Write a synthetic table (optionally a stuck-steering family over the angle axis)."""
    lay = NlpLayout.build(SCALES, CSCALES)
    axes = {"slope": np.radians([0.0, 10.0, 20.0]), "speed": np.array([0.02, 0.03, 0.04])}
    if stuck_wheel:
        axes["steer_stuck"] = np.radians([-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0])
    grid = [dict(zip(axes, v)) for v in np.stack(np.meshgrid(*axes.values(), indexing="ij"), -1).reshape(-1, len(axes))]
    shape = tuple(len(v) for v in axes.values())
    shapes = field_shapes(lay.nx, lay.np_, lay.ng)
    arrays = {k: np.zeros(shape + s) for k, s in shapes.items()}
    for flat, op in enumerate(grid):
        idx = np.unravel_index(flat, shape)
        stuck = {stuck_wheel: float(op["steer_stuck"])} if stuck_wheel else None
        for k, v in point_fields(lay, float(op["speed"]), float(op["slope"]), stuck).items():
            arrays[k][idx] = v
    arrays["status"] = np.zeros(shape, dtype=np.int8)
    arrays["active_x"] = np.zeros(shape + (lay.nx,), dtype=np.int8)
    arrays["active_g"] = np.zeros(shape + (lay.ng,), dtype=np.int8)
    from offline.rover.failures import KINDS, StuckSteering

    failures = {}
    family = None
    records = []
    if stuck_wheel:
        failures = {stuck_wheel: {"__class__": "WheelFailure", "steer_stuck": 0.0, "rim_speed_max": None}}
        family = {"axis": "steer_stuck", "wheel": stuck_wheel, "kind": "stuck steering angle",
                  "declares": {"kind": "steer_stuck", "per_speed": False}}
        records = [StuckSteering(0.0).rover_record(stuck_wheel)]
    header = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "name": name,
              "rover": {"name": "mini_rover", "weight": WEIGHT, "rocker_length": ROCKER, "pivot_height": 0.112,
                        "track_width": TRACK},
              "params": {"wheel": {"radius": 0.058, "grouser_height": 0.005}},
              "scenario": {"failures": failures}, "family": family,
              "failure_kinds": {c.ROVER_KIND: c.rover_description() for c in KINDS}, "failures": records,
              "axis_order": list(axes), "axes": {k: {"values": v.tolist(), "unit": "SI"} for k, v in axes.items()},
              "layout": json.loads(lay.to_json()),
              "trust_radius": dict(TRUST),
              "evidence": {}}
    path = Path(folder) / f"{name}.npz"
    path.write_bytes(table_bytes(header, arrays))
    return path


def synthetic_tables(folder: Path) -> dict:
    """{name: Table} for a nominal table and a rear-right stuck-steering family."""
    return {"linear_nominal": load_table(write_table(folder)),
            "linear_rr_stuck": load_table(write_table(folder, "linear_rr_stuck", "RR"))}
