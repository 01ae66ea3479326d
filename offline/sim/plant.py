"""The rover plant: a planar rigid body on a slope carried by four terramechanics wheels.

State and unknowns
------------------
The rover moves in the plane of the terrain (world frame ``X`` along the initial heading,
``Y`` to its left). Its pose ``(X, Y, psi)`` is integrated from the body velocities
``(u, v, r)`` (forward, left, yaw rate). Each step solves 15 unknowns by Newton's method
with backtracking; each iteration evaluates the eight wheel states (the four wheels and their
zero-slip twins) in one call of a C-compiled casadi function (wrench and its exact 6 x 5
Jacobian per state) and assembles the residual and its Jacobian by the chain rule:

* ``u, v, r`` from the planar equations of motion of the rigid body, implicit Euler
  (``m (u - u_prev)/dt - m r v = sum F_x``, ``m (v - v_prev)/dt + m r u = sum F_y``,
  ``I_z (r - r_prev)/dt = sum M_z``). At 3 cm/s the soil's damping gives the body a time
  constant of a few milliseconds, so implicit Euler is the stable choice at any step (and
  ``dt = inf`` gives the quasi-static limit);
* ``log h`` of each wheel's sinkage from the rover's vertical, roll and two rocker-pitch
  balances (the passive pivot: each rocker balances its own pitch moment about the pivot,
  section 7.2.2): the wheel loads follow from the statics and the sinkage follows the load
  (5.34) in the same solve;
* ``log h0`` of each wheel's zero-slip sinkage under the same load (it fixes theta_m0 in
  skid, as in the optimizer);
* ``omega`` of each wheel: the servo's speed (speed mode: the motor supplies whatever torque
  that takes, ``T = J (omega - omega_prev)/dt - M_y + tau_d``) or, for a wheel in torque mode
  (unpowered: zero torque; torque-limited: the limit), from its spin dynamics, implicit Euler,
  ``J (omega - omega_prev)/dt = T + M_y - tau_d`` (``M_y`` the soil's moment on the wheel,
  ``tau_d`` a hub drag; ``J = 0`` or ``dt = inf``: the quasi-static axle balance). The wheel's
  angular momentum change is left out of the rocker pitch balances (``J omega_dot`` is below
  0.02 N m against rocker moments of several N m).
* a raised wheel (no ground contact, stuck suspension) carries no load and no soil wrench;
  the pivot is then locked, so the raised wheel's rocker takes the other rocker's angle and
  the two rocker pitch balances become the whole rover's pitch balance (as in
  :mod:`offline.rover.statics`); the raised wheel's sinkage unknowns are parked at the
  grouser height.

Per-wheel forces come from the full model of :func:`offline.physics.terramechanics.wrench_core`
(not the tables). Wheel radius per wheel and the soil parameters are *inputs* of the compiled
function, and slope, cross-slope, tether force, mass and yaw inertia enter the assembly, so
the discrepancy tool re-simulates with other truths (:data:`PARAM_NAMES`) without recompiling.

Statics derived here (not :class:`offline.rover.statics.FourWheelRocker`, whose sign
conventions are under revision): wheel ``i`` sits at ``(x_i, y_i) = (+-l_r/2, -+w_r/2)``
in the plan; a rocker pitched by ``phi = asin((h_rear - h_front) / l_r)`` (the wheel that
sinks more is lower, so the other end rises) puts the wheel centres at
``(+-l_r/2 cos phi + h_r sin phi, +-l_r/2 sin phi - h_r cos phi)`` from the pivot in the
rocker's x-z plane. Moments about the pivot are ``r x F``. The weight acts at the pivot
(the printed balances (7.15)-(7.17) carry no weight moment either).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..physics.backend import CASADI
from ..physics.params import ParameterSet, Rover
from ..physics.terramechanics import ModelOptions, PhysParams, WheelModel, wrench_core

__all__ = ["SimulationError", "PlantModel", "PlantSolution", "N_UNKNOWNS", "INPUT_NAMES", "PARAM_NAMES", "GRAVITY", "default_yaw_inertia",
           "DISTURBANCE_NAMES", "default_wheel_inertia", "WHEEL_MASS_ESTIMATE"]

GRAVITY = 9.81
"""m/s^2; converts the rover weight of Table 7.2 into a mass."""

N_UNKNOWNS = 15
WHEEL_POS_NAMES = ("FR", "FL", "RR", "RL")
INPUT_NAMES = (
    tuple(f"omega_cmd_{k}" for k in WHEEL_POS_NAMES) + tuple(f"speed_mode_{k}" for k in WHEEL_POS_NAMES)
    + tuple(f"torque_{k}" for k in WHEEL_POS_NAMES) + tuple(f"steer_{k}" for k in WHEEL_POS_NAMES)
    + ("u_prev", "v_prev", "r_prev", "heading", "inv_dt")
    + tuple(f"omega_prev_{k}" for k in WHEEL_POS_NAMES) + tuple(f"contact_{k}" for k in WHEEL_POS_NAMES)
)
"""Inputs of a plant step (SI): commanded wheel speeds, drive modes and torques, true steer
angles, the body velocities, heading and wheel speeds at the start of the step, ``1/dt`` (0:
quasi-static), and ground contact per wheel (1 on the ground, 0 raised)."""
PARAM_NAMES = (
    tuple(f"radius_{k}" for k in WHEEL_POS_NAMES)
    + ("k", "n0", "n1", "n2", "friction_angle", "unit_weight", "cohesion", "shear_modulus", "repose_angle")
    + ("slope", "cross_slope", "tether_force", "mass", "yaw_inertia", "wheel_inertia")
)
"""Truth parameters of a plant step (SI): per-wheel radius, soil, terrain, tether, body, and the
spin inertia of a wheel about its axle."""
DISTURBANCE_NAMES = (
    ("body_force_x", "body_force_y", "body_moment_z") + tuple(f"wheel_force_x_{k}" for k in WHEEL_POS_NAMES)
    + tuple(f"wheel_force_y_{k}" for k in WHEEL_POS_NAMES) + tuple(f"wheel_torque_{k}" for k in WHEEL_POS_NAMES)
)
"""External disturbance vector of :meth:`PlantModel.evaluate` (SI, rover body frame)."""
_SOIL_FIELDS = ("k", "n0", "n1", "n2", "phi", "rho", "c", "K", "repose")


class SimulationError(RuntimeError):
    """The plant could not be advanced (no equilibrium found); the message gives time and state,
    ``z`` (when set) the unknowns where Newton's method stopped."""

    z: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class PlantSolution:
    """The plant's answer for one step (SI; wheel order FR, FL, RR, RL)."""

    u: float
    v: float
    r: float
    omega: NDArray[np.float64]
    sinkage: NDArray[np.float64]
    sinkage_zero_slip: NDArray[np.float64]
    wrench: NDArray[np.float64]
    slip: NDArray[np.float64]
    slip_angle: NDArray[np.float64]
    iterations: int
    residual: float


class PlantModel:
    """Compiled equations of one rover layout with one wheel geometry and model options.

    Parameters
    ----------
    params : ParameterSet
        Wheel width, grouser geometry and contact tuning are fixed here; radius and soil
        enter per call (:data:`PARAM_NAMES`).
    rover : Rover
        Rocker length, pivot height, track width (fixed); weight enters as ``mass`` per call.
    options : ModelOptions, optional
        Terramechanics variant (the optimizer's by default: classic exit angle).
    compiled : bool
        C-compile the function (cached on disk by :class:`WheelModel`); ``False`` uses the
        casadi virtual machine (slower, same numbers to rounding).
    """

    def __init__(self, params: ParameterSet, rover: Rover, options: ModelOptions | None = None, compiled: bool = True) -> None:
        self.params, self.rover = params, rover
        self.options = options or ModelOptions(shear_direction_smoothing=1e-6)
        self._wheel_model = WheelModel(params.soil, params.wheel, params.tuning, self.options)
        f = self._build()
        self.function = self._wheel_model._compile(f, "sim_wheels") if compiled else f
        so = self._wheel_model._so_paths.get(f.name()) if compiled else None
        self._call = _DenseCall(so, f) if so else None
        # the same wheel batch without its Jacobian: the trial points of the line search need only
        # the residual (same graph, same operations: the wrench is bit-for-bit that of ``function``)
        fr = self._build(jacobian=False)
        self.residual_function = self._wheel_model._compile(fr, "sim_wheels_residual") if compiled else fr
        so_r = self._wheel_model._so_paths.get(fr.name()) if compiled else None
        self._call_residual = _DenseCall(so_r, fr) if so_r else None
        self._no_jacobian: NDArray[np.float64] = np.zeros((6, 40))
        self.rs_nominal = params.wheel.shearing_radius

    def _build(self, jacobian: bool = True) -> Any:
        """casadi function of 8 wheel states (the four wheels and their zero-slip twins):
        ``(x[5, 8], p[10, 8]) -> (wrench[6, 8], d wrench / d x [6, 40], slip[1, 8], beta[1, 8])``,
        ``p = (r, k, n0, n1, n2, phi, rho, c, K, repose)`` per state; ``jacobian=False`` leaves
        the Jacobian out: ``(x, p) -> (wrench, slip, beta)`` (for the line search's trial points)."""
        return wheel_state_batch(self.params, self.options, 8, jacobian)

    def evaluate(self, z: NDArray[np.float64], a: NDArray[np.float64], q: NDArray[np.float64],
                 d: NDArray[np.float64] | None = None, jacobian: bool = True
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Residual (15,), Jacobian (15, 15), wrench (4, 6), slip (4,), slip angle (4,) at unknowns ``z``.

        ``jacobian=False`` evaluates the wheels without their Jacobian (:attr:`residual_function`,
        about a third of the cost); the residual, wrench, slip and slip angle are bit-for-bit those
        of ``jacobian=True``, and the returned Jacobian is all NaN (it must not be used).

        ``d`` (optional, :data:`DISTURBANCE_NAMES`, SI) holds external forces constant over the
        step: a body force at the centre of mass (enters the planar balances like the tether),
        a yaw moment, a body-frame force per wheel (added to that wheel's soil force, so it
        enters the yaw, roll and rocker balances where the soil force does) and a torque per
        wheel resisting its spin (axle balance ``M_y + T - tau_d = 0``). ``None`` skips these
        terms altogether (bit-for-bit the undisturbed equations).

        The Jacobian is exact except for the rocker angle's dependence on the sinkages (a
        term of order ``h_r / l_r`` times the sinkage difference), so Newton converges to
        the exact root a little slower than quadratically.

        What depends on the inputs ``a`` and parameters ``q`` alone (steer rotations, gravity
        components, scales) is computed once per Newton solve (:meth:`_context`); the
        operations and their order are those of computing it at every evaluation, so the
        numbers are bit for bit the same.
        """
        return self._evaluate(z, self._context(a, q), d, jacobian)

    def _context(self, a: NDArray[np.float64], q: NDArray[np.float64]) -> tuple[Any, ...]:
        """The part of :meth:`evaluate` that does not depend on the unknowns (one Newton solve)."""
        ro = self.rover
        lr, hr, wr = ro.rocker_length, ro.pivot_height, ro.track_width
        hg = self.params.wheel.grouser_height
        mass, iz = q[16], q[17]
        jw = q[18] if len(q) > 18 else 0.0
        weight = mass * GRAVITY
        slope, cross, tether = q[13], q[14], q[15]
        cmd, mode, torque, steer = a[0:4], a[4:8], a[8:12], a[12:16]
        u0, v0, r0, psi, inv_dt = a[16], a[17], a[18], a[19], a[20]
        omega0 = a[21:25] if len(a) > 21 else None
        raised = [i for i in range(4) if len(a) > 25 and a[25 + i] == 0.0]
        rs = q[0:4] + hg
        c, s = np.cos(steer), np.sin(steer)
        xs, ys = _XS(lr), _YS(wr)
        P = np.empty((10, 8))
        P[0, :4] = P[0, 4:] = q[0:4]
        P[1:, :] = q[4:13, None]
        # d(vx, vy)/d(u, v, r) per wheel
        dv = np.zeros((4, 2, 3))
        dv[:, 0, 0], dv[:, 0, 1], dv[:, 0, 2] = c, s, -c * _YS(wr) + s * _XS(lr)
        dv[:, 1, 0], dv[:, 1, 1], dv[:, 1, 2] = -s, c, s * _YS(wr) + c * _XS(lr)
        # d state / d z for the driven states and the zero-slip twins, (4, 5, 15): the parts
        # that do not depend on the unknowns
        ds = np.zeros((4, 5, N_UNKNOWNS))
        ds0 = np.zeros((4, 5, N_UNKNOWNS))
        ds[:, 0:2, 0:3] = dv
        ds0[:, 0:2, 0:3] = dv
        ds[_I4, 2, 3 + _I4] = 1.0
        # rotate into the rover frame (wrench and its derivative; steer is an input)
        R = np.zeros((4, 6, 6))
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = c, -s, s, c
        R[:, 2, 2] = R[:, 5, 5] = 1.0
        R[:, 3, 3], R[:, 3, 4], R[:, 4, 3], R[:, 4, 4] = c, -s, s, c
        gX, gY = -weight * math.sin(slope), -weight * math.cos(slope) * math.sin(cross)
        gx, gy = gX * math.cos(psi) + gY * math.sin(psi), -gX * math.sin(psi) + gY * math.cos(psi)
        normal = weight * math.cos(slope) * math.cos(cross)
        M = weight * lr
        om_scale = ro.travel_speed / rs
        t_scale = weight / 4 * rs
        one_m = 1 - mode
        spin = jw * inv_dt != 0.0
        return (lr, hr, wr, hg, mass, iz, jw, weight, tether, cmd, mode, torque, u0, v0, r0, inv_dt, omega0, raised,
                rs, c, s, -s, xs, ys, P, dv, ds, ds0, R, gx, gy, normal, M, om_scale, t_scale, one_m, one_m / t_scale,
                mode / om_scale, one_m * jw * inv_dt, spin)

    def _evaluate(self, z: NDArray[np.float64], ctx: tuple[Any, ...], d: NDArray[np.float64] | None, jacobian: bool
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """:meth:`evaluate` with its :meth:`_context`."""
        (lr, hr, wr, hg, mass, iz, jw, weight, tether, cmd, mode, torque, u0, v0, r0, inv_dt, omega0, raised,
         rs, c, s, ms, xs, ys, P, dv, ds_t, ds0_t, R, gx, gy, normal, M, om_scale, t_scale, one_m, one_m_t, mode_om, inertia,
         spin) = ctx
        u, v, r = z[0], z[1], z[2]
        omega = z[3:7]
        h, h0 = np.exp(z[7:11]), np.exp(z[11:15])
        if omega0 is None:
            omega0 = omega
        if raised:  # park the raised wheel's sinkages (the wheel model must stay finite; its wrench is dropped)
            h, h0 = h.copy(), h0.copy()
            h[raised] = h0[raised] = hg
        vxr, vyr = u - r * ys, v + r * xs
        vx, vy = c * vxr + s * vyr, ms * vxr + c * vyr
        speed = np.sqrt(vx * vx + vy * vy + 1e-18)
        X = np.empty((5, 8))
        X[0, :4] = X[0, 4:] = vx
        X[1, :4] = X[1, 4:] = vy
        X[2, :4] = omega
        X[3, :4] = h
        X[4, :4] = X[3, 4:] = X[4, 4:] = h0
        roll = _twin_direction(vx)  # the twin rolls the way the wheel travels (zero slip backward too)
        X[2, 4:] = roll * speed / rs
        if not jacobian:
            if self._call_residual is not None:
                W, SL, BE = self._call_residual(X, P)
            else:
                W, SL, BE = (np.asarray(o, dtype=float) for o in self.residual_function(X, P))
            JW = None
        elif self._call is not None:
            W, JW, SL, BE = self._call(X, P)
        else:
            W, JW, SL, BE = (np.asarray(o, dtype=float) for o in self.function(X, P))
        if JW is not None:
            JW = JW.reshape(6, 8, 5).transpose(1, 0, 2)  # (state, wrench comp, x)
        _stiction(W, JW, X, rs)
        if raised:  # no ground contact: no soil wrench, slip undefined
            idx = raised + [4 + i for i in raised]
            W[:, idx] = 0.0
            if JW is not None:
                JW[idx] = 0.0
            SL[0, raised] = BE[0, raised] = math.nan
        wheel = W[:, :4].T  # (4, 6) wheel frame
        if JW is not None:
            ds, ds0 = ds_t.copy(), ds0_t.copy()
            ds[_DS_H] = h
            ds[_DS_H0] = h0
            ds0[:, 2, 0:3] = roll[:, None] * (vx[:, None] * dv[:, 0] + vy[:, None] * dv[:, 1]) / (speed * rs)[:, None]
            ds0[_DS0_H0] = h0
            ds0[_DS_H0] = h0
            dwheel = np.einsum("ikx,ixz->ikz", JW[:4], ds)  # (4, 6, 15)
            dzero = np.einsum("ikx,ixz->ikz", JW[4:], ds0)
        F = np.einsum("ijk,ik->ij", R, wheel)
        if JW is not None:
            dF = np.einsum("ijk,ikz->ijz", R, dwheel)
        if d is not None:
            F[:, 0] += d[3:7]
            F[:, 1] += d[7:11]
        # rocker geometry (x, z of wheel centres from the pivot)
        px, pz = np.empty(4), np.empty(4)
        sps = [(h[2] - h[0]) / lr, (h[3] - h[1]) / lr]
        if raised:  # pivot locked: the rocker of the raised wheel takes the other rocker's angle
            side = raised[0] % 2
            sps[side] = sps[1 - side]
        for fr, re in ((0, 2), (1, 3)):
            sp = sps[fr]
            cp = math.sqrt(max(1.0 - sp * sp, 0.0))
            px[fr], pz[fr] = lr / 2 * cp + hr * sp, lr / 2 * sp - hr * cp
            px[re], pz[re] = -lr / 2 * cp + hr * sp, -lr / 2 * sp - hr * cp
        res = np.empty(N_UNKNOWNS)
        res[0] = (_add_reduce(F[:, 0]) + gx - tether - mass * ((u - u0) * inv_dt - r * v)) / weight
        if d is not None:
            res[0] += d[0] / weight
        res[1] = (_add_reduce(F[:, 1]) + gy - mass * ((v - v0) * inv_dt + r * u)) / weight
        if d is not None:
            res[1] += d[1] / weight
        res[2] = (_add_reduce(F[:, 5] + xs * F[:, 1] - ys * F[:, 0]) - iz * (r - r0) * inv_dt) / M
        if d is not None:
            res[2] += d[2] / M
        res[3] = (_add_reduce(F[:, 2]) - normal) / weight
        res[4] = _add_reduce(F[:, 3] + ys * F[:, 2] - pz * F[:, 1]) / M
        # the rockers: wheels 0 and 2 (right), 1 and 3 (left)
        res[5] = _add_reduce(F[0::2, 4] + pz[0::2] * F[0::2, 0] - px[0::2] * F[0::2, 2]) / M
        res[6] = _add_reduce(F[1::2, 4] + pz[1::2] * F[1::2, 0] - px[1::2] * F[1::2, 2]) / M
        res[7:11] = mode * (omega - cmd) / om_scale + one_m * (wheel[:, 4] + torque) / t_scale
        if d is not None:
            res[7:11] -= one_m * d[11:15] / t_scale
        if spin:  # spin inertia of a wheel in torque mode: J (omega - omega_prev) / dt
            res[7:11] -= inertia * (omega - omega0) / t_scale
        res[11:15] = (W[2, 4:] - wheel[:, 2]) / (weight / 4)
        if not jacobian:
            J = np.full((N_UNKNOWNS, N_UNKNOWNS), math.nan)
            if raised:
                i = raised[0]
                res[5] = res[5] + res[6]
                res[6] = z[7 + i] - math.log(hg)
                res[11 + i] = z[11 + i] - math.log(hg)
                if mode[i] == 0.0 and not spin:  # free spinning without inertia: keep its speed
                    res[7 + i] = (omega[i] - omega0[i]) / om_scale[i]
            return res, J, wheel, SL[0, :4].copy(), BE[0, :4].copy()
        J = np.zeros((N_UNKNOWNS, N_UNKNOWNS))
        J[0] = _add_reduce(dF[:, 0], 0) / weight
        J[0, 0] -= mass * inv_dt / weight
        J[0, 1] += mass * r / weight
        J[0, 2] += mass * v / weight
        J[1] = _add_reduce(dF[:, 1], 0) / weight
        J[1, 1] -= mass * inv_dt / weight
        J[1, 2] -= mass * u / weight
        J[1, 0] -= mass * r / weight
        J[2] = _add_reduce(dF[:, 5] + xs[:, None] * dF[:, 1] - ys[:, None] * dF[:, 0], 0) / M
        J[2, 2] -= iz * inv_dt / M
        J[3] = _add_reduce(dF[:, 2], 0) / weight
        J[4] = _add_reduce(dF[:, 3] + ys[:, None] * dF[:, 2] - pz[:, None] * dF[:, 1], 0) / M
        J[5] = _add_reduce(dF[0::2, 4] + pz[0::2, None] * dF[0::2, 0] - px[0::2, None] * dF[0::2, 2], 0) / M
        J[6] = _add_reduce(dF[1::2, 4] + pz[1::2, None] * dF[1::2, 0] - px[1::2, None] * dF[1::2, 2], 0) / M
        if self.rocker_jacobian:  # the rocker angles' dependence on the sinkages (left out by default)
            for side, (fr, re) in enumerate(((0, 2), (1, 3))):
                src = 1 - side if raised and raised[0] % 2 == side else side
                sf, sr = (0, 2) if src == 0 else (1, 3)
                sp = sps[side]
                cp = math.sqrt(max(1.0 - sp * sp, 1e-12))
                dsp = np.zeros(N_UNKNOWNS)
                dsp[7 + sr], dsp[7 + sf] = h[sr] / lr, -h[sf] / lr
                dpx = {fr: -lr / 2 * sp / cp + hr, re: lr / 2 * sp / cp + hr}
                dpz = {fr: lr / 2 + hr * sp / cp, re: -lr / 2 + hr * sp / cp}
                for i in (fr, re):
                    J[4] -= F[i, 1] * dpz[i] * dsp / M
                    J[5 + side] += (F[i, 0] * dpz[i] - F[i, 2] * dpx[i]) * dsp / M
        J[7:11] = one_m_t[:, None] * dwheel[:, 4]
        J[_J_OMEGA] += mode_om
        if spin:
            J[_J_OMEGA] -= inertia / t_scale
        J[11:15] = (dzero[:, 2] - dwheel[:, 2]) / (weight / 4)
        if raised:
            i = raised[0]
            # one rigid frame (pivot locked): the whole rover's pitch balance, and the raised
            # wheel's sinkages pinned at the parked value
            res[5], J[5] = res[5] + res[6], J[5] + J[6]
            res[6], J[6] = z[7 + i] - math.log(hg), 0.0
            J[6, 7 + i] = 1.0
            res[11 + i], J[11 + i] = z[11 + i] - math.log(hg), 0.0
            J[11 + i, 11 + i] = 1.0
            if mode[i] == 0.0 and not spin:  # free spinning without inertia: keep its speed
                res[7 + i], J[7 + i] = (omega[i] - omega0[i]) / om_scale[i], 0.0
                J[7 + i, 3 + i] = 1.0 / om_scale[i]
        return res, J, wheel, SL[0, :4].copy(), BE[0, :4].copy()

    rocker_jacobian = False
    """Include the rocker angles' dependence on the sinkages in the Jacobian (exact Newton).
    Off by default (the documented approximation, kept so that every simulation that converges
    without it stays bit for bit as it was); the simulator turns it on for a step whose Newton
    solve failed (:meth:`offline.sim.simulator.RoverSimulator.step`)."""

    MAX_NEWTON = 40
    TOL = 1e-8

    def solve(self, z0: NDArray[np.float64], a: NDArray[np.float64], q: NDArray[np.float64],
              d: NDArray[np.float64] | None = None, trace: list[dict[str, Any]] | None = None
              ) -> tuple[NDArray[np.float64], PlantSolution]:
        """Newton's method with backtracking on ``||res||`` from ``z0`` (``d``: see :meth:`evaluate`).

        The line search halves the step from the full Newton step (or the one that moves a
        log-sinkage by 1) at most 30 times, accepting the first trial point that lowers the max
        norm (Armijo, 1e-4); shortened trial points are evaluated residual only, and the Jacobian
        once at the accepted point when another iteration follows, so the iterates are bit for bit
        those of evaluating every trial with its Jacobian. ``trace`` (a list, optional) receives
        the start (``trials`` 0) and one entry per iteration: ``norm`` (max scaled residual after
        it), ``step`` (the accepted step length; 0 where the line search failed, the iterate then
        unchanged), ``trials`` (trial points evaluated), ``z`` and ``slip`` at the iterate; the
        solve is the same with or without it.

        Raises
        ------
        SimulationError
            No equilibrium within :attr:`MAX_NEWTON` iterations (the message gives the residual).
        """
        z = np.array(z0, dtype=float)
        ctx = self._context(a, q)
        res, J, w, sl, be = self._evaluate(z, ctx, d, True)
        res = res.ravel()
        norm = float(np.max(np.abs(res)))
        if trace is not None:
            trace.append({"norm": norm, "step": 0.0, "trials": 0, "z": z.copy(), "slip": np.ravel(sl).copy()})
        it = 0
        while norm > self.TOL and it < self.MAX_NEWTON:
            it += 1
            try:
                dz = np.linalg.solve(J, -res)
            except np.linalg.LinAlgError:
                if not np.all(np.isfinite(J)):  # a non-finite Jacobian: no Newton step from here
                    break
                try:
                    dz = np.linalg.lstsq(J, -res, rcond=None)[0]
                except np.linalg.LinAlgError:
                    break
            # keep log-sinkage steps modest (the wrench is smooth but strongly nonlinear in h)
            big = np.max(np.abs(dz[7:]))
            lam = 1.0 if big < 1.0 else 1.0 / big
            for trial in range(30):
                zt = z + lam * dz
                # the full step with its Jacobian (usually taken, and needed unless this is the last
                # iteration); a shortened step residual only
                rt, Jt, wt, slt, bet = self._evaluate(zt, ctx, d, trial == 0 and it < self.MAX_NEWTON)
                rt = rt.ravel()
                nt = float(np.max(np.abs(rt)))
                if np.isfinite(nt) and (nt < (1 - 1e-4 * lam) * norm or nt <= self.TOL):
                    break
                lam *= 0.5
            else:
                if trace is not None:
                    trace.append({"norm": norm, "step": 0.0, "trials": 30, "z": z.copy(), "slip": np.ravel(sl).copy()})
                break
            if trace is not None:
                trace.append({"norm": nt, "step": lam, "trials": trial + 1, "z": zt.copy(), "slip": np.ravel(slt).copy()})
            if trial and nt > self.TOL and it < self.MAX_NEWTON:
                # a shortened step accepted and another iteration to come: its Jacobian (the
                # residual, wrench, slip and slip angle are the same, bit for bit)
                rt, Jt, wt, slt, bet = self._evaluate(zt, ctx, d, True)
                rt = rt.ravel()
            z, res, J, w, sl, be, norm = zt, rt, Jt, wt, slt, bet, nt
        if not (norm <= 1e-7 and np.all(np.isfinite(z))):
            err = SimulationError(
                f"no equilibrium of the rover found (max scaled residual {norm:.3g} after {it} Newton iterations; "
                f"body velocity u={z[0]:.4g} v={z[1]:.4g} r={z[2]:.4g}, sinkages {np.exp(z[7:11])}): the terrain or "
                "commands are outside what the wheels can carry; reduce the slope or the step size")
            err.z = z
            raise err
        contact = np.asarray(a[25:29]) if len(a) > 25 else np.ones(4)
        sol = PlantSolution(float(z[0]), float(z[1]), float(z[2]), z[3:7].copy(), np.exp(z[7:11]) * contact,
                            np.exp(z[11:15]) * contact, w.reshape(4, 6), sl.ravel(), be.ravel(), it, norm)
        return z, sol

    def initial_guess(self, speed: float, q: NDArray[np.float64], contact: NDArray[np.float64] | None = None
                      ) -> NDArray[np.float64]:
        """Straight driving at ``speed``, equal loads on the wheels in contact, sinkages carried
        by those loads at zero slip (a raised wheel's sinkage parked at the grouser height)."""
        weight = q[16] * GRAVITY
        rs = self.rs_nominal
        on = np.ones(4) if contact is None else np.asarray(contact, dtype=float)
        sol = self._wheel_model.sinkage_from_load(np.full(4, weight / on.sum()), np.full(4, speed), np.zeros(4),
                                                  np.full(4, speed / rs))
        h = np.where(sol.converged, sol.h, rs / 5)
        h = np.where(on == 0.0, self.params.wheel.grouser_height, h)
        return np.concatenate([[speed, 0.0, 0.0], np.full(4, speed / rs), np.log(h), np.log(h)])

    @staticmethod
    def param_vector(radius: tuple[float, float, float, float], soil: Any, slope: float, cross_slope: float,
                     tether_force: float, mass: float, yaw_inertia: float, wheel_inertia: float = 0.0) -> NDArray[np.float64]:
        """Pack :data:`PARAM_NAMES` from SI values (``soil`` is a :class:`offline.physics.params.Soil`;
        ``wheel_inertia`` 0: the wheels have no spin inertia, the quasi-static axle balance)."""
        return np.array([*radius, soil.k, soil.n0, soil.n1, soil.n2, soil.friction_angle, soil.unit_weight,
                         soil.cohesion, soil.shear_modulus, soil.repose_angle, slope, cross_slope, tether_force,
                         mass, yaw_inertia, wheel_inertia], dtype=float)



def wheel_state_batch(params: ParameterSet, options: ModelOptions, n_states: int, jacobian: bool = True) -> Any:
    """casadi function of ``n_states`` wheel states mapped over one wheel's wrench (5.x, the
    :func:`~offline.physics.terramechanics.wrench_core` source the optimizer uses):
    ``(x[5, n], p[10, n]) -> (wrench[6, n], d wrench / d x [6, 5 n], slip[1, n], beta[1, n])`` with
    ``p = (r, k, n0, n1, n2, phi, rho, c, K, repose)`` per state; ``jacobian=False`` leaves the
    Jacobian out. Shared by the mini rover's plant (8 states) and a rover file's (``2 N``)."""
    import casadi as ca

    x = ca.SX.sym("x", 5)
    pw = ca.SX.sym("p", 10)
    base = PhysParams.from_sets(params.soil, params.wheel, params.tuning)
    p = base._replace(r=pw[0], **dict(zip(_SOIL_FIELDS, [pw[1 + i] for i in range(9)])))
    w6, diag = wrench_core(CASADI, x[0], x[1], x[2], x[3], x[4], p, options)
    w = ca.vertcat(*w6)
    if not jacobian:
        return ca.Function("wheel_state_residual", [x, pw], [w, diag["slip"], diag["beta"]]).map(n_states)
    one = ca.Function("wheel_state", [x, pw], [w, ca.jacobian(w, x), diag["slip"], diag["beta"]])
    return one.map(n_states)

class _DenseCall:
    """Call the C-compiled wheel batch through ctypes with preallocated buffers (the casadi
    Python call costs about as much as the 8 wheel evaluations themselves).

    Generated-code interface: ``int f(const double** arg, double** res, casadi_int* iw,
    double* w, int mem)`` and ``int f_work(...)``; inputs and outputs are column-major
    nonzeros, scattered here into dense arrays.
    """

    def __init__(self, so: Any, ref: Any) -> None:
        import ctypes

        lib = ctypes.CDLL(str(so))
        name = ref.name()
        self._fn = getattr(lib, name)
        ci = ctypes.c_longlong
        sz = [ci(0) for _ in range(4)]
        getattr(lib, f"{name}_work")(*[ctypes.byref(v) for v in sz])
        n_arg, n_res, n_iw, n_w = (int(v.value) for v in sz)
        dp = ctypes.POINTER(ctypes.c_double)
        self._in = [np.zeros(ref.sparsity_in(i).nnz()) for i in range(ref.n_in())]
        # dense inputs: a column-major view of the buffer with the input's shape
        self._in_views = [b.reshape(ref.sparsity_in(i).shape, order="F") if ref.sparsity_in(i).is_dense() else None
                          for i, b in enumerate(self._in)]
        self._out = [np.zeros(ref.sparsity_out(i).nnz()) for i in range(ref.n_out())]
        self._shapes = [ref.sparsity_out(i).shape for i in range(ref.n_out())]
        self._trip = []
        for i in range(ref.n_out()):
            sp = ref.sparsity_out(i)
            r, c = sp.get_triplet()
            self._trip.append(None if sp.is_dense() else (np.asarray(r, dtype=int), np.asarray(c, dtype=int)))
        self._arg = (dp * max(n_arg, len(self._in)))()
        self._res = (dp * max(n_res, len(self._out)))()
        for i, b in enumerate(self._in):
            self._arg[i] = b.ctypes.data_as(dp)
        for i, b in enumerate(self._out):
            self._res[i] = b.ctypes.data_as(dp)
        self._iw = (ci * max(n_iw, 1))()
        self._w = (ctypes.c_double * max(n_w, 1))()
        self._fn.argtypes = [ctypes.POINTER(dp), ctypes.POINTER(dp), ctypes.POINTER(ci), ctypes.POINTER(ctypes.c_double),
                             ctypes.c_int]
        self._fn.restype = ctypes.c_int

    def __call__(self, *args: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        for b, a, view in zip(self._in, args, self._in_views):
            if view is not None and isinstance(a, np.ndarray) and a.shape == view.shape:
                view[...] = a  # column-major into the buffer, one copy
            else:
                b[:] = np.asarray(a, dtype=float).ravel(order="F")
        if self._fn(self._arg, self._res, self._iw, self._w, 0) != 0:
            raise SimulationError("the compiled wheel batch returned an error")
        out = []
        for b, shape, trip in zip(self._out, self._shapes, self._trip):
            if trip is None:
                out.append(b.reshape(shape, order="F").copy())
            else:
                d = np.zeros(shape)
                d[trip[0], trip[1]] = b
                out.append(d)
        return out


_I4 = np.arange(4)
_add_reduce = np.add.reduce  # what ndarray.sum calls, without its Python-level wrapper (the same sums)
_DS_H = (_I4, 3, 7 + _I4)  # d h / d log h of each wheel in the driven states' d state / d z
_DS_H0 = (_I4, 4, 11 + _I4)  # d h0 / d log h0 (driven states and zero-slip twins)
_DS0_H0 = (_I4, 3, 11 + _I4)  # the twin's sinkage is h0
_J_OMEGA = (7 + _I4, 3 + _I4)  # each axle balance's own wheel speed

def _twin_direction(vx: NDArray[np.float64]) -> NDArray[np.float64]:
    """+1 or -1 per wheel: the sign of the zero-slip twin's spin, that of the wheel's travel
    ``v_x`` (the wheel model mirrors travel toward -x, so a twin at ``+speed / r_s`` on a
    reversing wheel was at slip -2, not 0, and its zero-slip sinkage meaningless)."""
    return np.where(vx < 0, -1.0, 1.0)


STICTION_SPEED = 1e-4
"""m/s: the stiction tolerance of a wheel at rest on the soil (see :func:`_stiction`)."""
_STICTION_CUTOFF = 20.0
"""``tanh(x)`` rounds to exactly 1.0 for ``x > 19.1``: above ``20 * STICTION_SPEED`` a factor is
not applied at all, so every drive whose wheels move is bit-for-bit the unregularised plant."""
_LONGITUDINAL = np.array([0, 4])  # F_x, M_y: shear along the rim (needs the rim or the wheel to move)
_LATERAL = np.array([1, 3, 5])  # F_y, M_x, M_z: lateral shear and sidewall bulldozing (need the wheel to move)


def _stiction(W: NDArray[np.float64], JW: NDArray[np.float64] | None, X: NDArray[np.float64],
              rs: NDArray[np.float64]) -> None:
    """Regularised static friction of a wheel at rest on the soil (in place).

    The wheel model's forces are rate-independent: a locked wheel (``omega = 0``) develops its
    full skid resistance at any travel speed ``v > 0`` and the opposite one at ``v < 0``, and
    the sidewall bulldozing of any wheel follows the direction of travel, however slow. At rest
    these forces are set-valued (static friction anywhere in between). A rover that cannot drag
    a locked wheel is at rest with that wheel's force inside the set, and Newton's method on
    the discontinuous force finds no root (issue 21: "no equilibrium of the rover found",
    u = 3e-4 m/s, three driven wheels at slip 0.99 pulling 10.1 N against the locked wheel's
    10.1 N).

    As rigid-body simulators do with Coulomb friction (a "stiction tolerance", e.g. Drake's
    ``v_s``), the forces that need the wheel to move are scaled by ``tanh(speed / v_s)``
    (:data:`STICTION_SPEED`), continuous through rest, so a stall is a creep at a fraction of a
    millimetre per second with the resting wheel's force wherever the balance needs it, up to
    its sliding value:

    * ``F_x, M_y`` (shear along the rim) by ``tanh(q / v_s)``,
      ``q = sqrt(v_x^2 + v_y^2 + (r_s omega)^2)``: a wheel spinning in place on a stalled
      rover slides under its rim at centimetres per second and keeps its full (slip 1) thrust;
    * ``F_y, M_x, M_z`` (lateral shear and sidewall bulldozing, which follow the direction of
      travel) by ``tanh(v / v_s)``, ``v = sqrt(v_x^2 + v_y^2)``.

    ``F_z`` is not scaled (the wheel still carries its load and sinks). Only the wheel states
    ``W[:, :n]`` (``n = len(rs)``, four for the mini rover) are touched (not the zero-slip twins, whose ``F_z`` alone is used), and only
    below ``20 v_s`` (2 mm/s), where ``tanh`` differs from 1 in double precision: a drive whose
    wheels all travel faster is bit for bit the unregularised plant. Not modelled: the sinkage
    growth of a wheel spinning in place (digging); the plant is quasi-static in sinkage.

    Parameters
    ----------
    W : ndarray (6, 2 n)
        Wrenches of the ``2 n`` wheel states (the wheels, then their twins; wheel frame), scaled in place.
    JW : ndarray (2 n, 6, 5) or None
        Their derivatives with respect to the states ``(v_x, v_y, omega, h, h0)``, in place
        (None: a residual-only evaluation).
    X : ndarray (5, 2 n)
        The states.
    rs : ndarray (n,)
        Shearing radius of each wheel, m.
    """
    n = len(rs)  # wheels (the zero-slip twins follow them)
    floor2 = (1e-3 * STICTION_SPEED) ** 2
    cut = _STICTION_CUTOFF * STICTION_SPEED
    # the usual case, every wheel travelling, decided on Python floats (the same IEEE operations as
    # the array expression below, so the same decision; NaN goes to the array path)
    if all(math.sqrt(a * a + b * b + floor2) >= cut for a, b in zip(X[0, :n].tolist(), X[1, :n].tolist())):
        return
    vx, vy, om = X[0, :n], X[1, :n], X[2, :n]
    v = np.sqrt(vx * vx + vy * vy + floor2)
    slow = np.flatnonzero(v < cut)
    if not slow.size:  # every wheel travels: nothing to scale (q >= v)
        return
    q = np.sqrt(vx * vx + vy * vy + (rs * om) ** 2 + floor2)
    for i in slow:
        groups = [(_LATERAL, v[i], np.array([vx[i], vy[i], 0.0, 0.0, 0.0]) / v[i])]
        if q[i] < cut:
            groups.append((_LONGITUDINAL, q[i], np.array([vx[i], vy[i], rs[i] ** 2 * om[i], 0.0, 0.0]) / q[i]))
        for rows, speed, dspeed in groups:
            f = math.tanh(speed / STICTION_SPEED)
            dfdx = (1.0 - f * f) / STICTION_SPEED * dspeed
            w = W[rows, i].copy()
            if JW is not None:
                JW[i, rows] = f * JW[i, rows] + np.outer(w, dfdx)
            W[rows, i] = f * w


def _XS(lr: float) -> NDArray[np.float64]:
    return np.array([lr / 2, lr / 2, -lr / 2, -lr / 2])


def _YS(wr: float) -> NDArray[np.float64]:
    return np.array([-wr / 2, wr / 2, -wr / 2, wr / 2])


WHEEL_MASS_ESTIMATE = 0.1
"""kg: our estimate of one wheel's rotating mass (rim, grousers, hub). The dissertation gives
neither the wheel's mass nor the drive motor's (Dynamixel XM-430) rotor inertia."""


def default_wheel_inertia(params: ParameterSet) -> float:
    """Spin inertia of a wheel about its axle, kg m^2: :data:`WHEEL_MASS_ESTIMATE` as a thin ring
    at the rim radius, ``m r^2`` (about 3.3e-4 kg m^2 for the 57.5 mm wheel). An estimate: the
    gear-reflected rotor inertia of the drive motor is unknown and not included (set
    ``wheel_inertia_kg_m2`` in a truth file to study it)."""
    return WHEEL_MASS_ESTIMATE * params.wheel.radius**2


def default_yaw_inertia(rover: Rover) -> float:
    """Yaw inertia of a uniform plate spanning the wheelbase and track, kg m^2 (an estimate:
    the dissertation gives none; at 3 cm/s it hardly matters, the soil damping dominates)."""
    m = rover.weight / GRAVITY
    return m * (rover.rocker_length**2 + rover.track_width**2) / 12.0

