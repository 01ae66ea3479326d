"""The plant of any rover file: a planar rigid body on N terramechanics wheels, its suspension's statics.

:class:`SuspensionPlant` is :class:`offline.sim.plant.PlantModel` for a rover described by a
file (:mod:`rtctl.physics.rover_file`): the six-wheel rocker-bogie with its differential, the
rigid skid-steer frame, or the passive-pivot rocker. The mini rover keeps
:class:`~offline.sim.plant.PlantModel` (its simulations are bit for bit as before).

Same physics source as the optimizer
------------------------------------
* Wheels: :func:`offline.physics.terramechanics.wrench_core`, C-compiled as the mini rover's
  plant does (one casadi function mapped over the ``2 N`` wheel states: each wheel and its
  zero-slip twin), with its exact Jacobian in ``(v_x, v_y, omega, h, h0)``.
* Suspension: the rows of :class:`rtctl.physics.suspension.SuspensionStatics` (the rows the NLP
  is built from, :mod:`rtctl.physics.steady_state`), built once as a casadi function of the
  wheel-frame wrenches, steer angles and sinkages with its exact Jacobian. Each wheel's load in
  ``Fz`` ((7.23), (7.33)) is its soil ``F_z``, as the NLP's ``load`` rows make it at a primitive.

So at a primitive of a table (steady straight driving at the table's speed, slope and wheel
commands) the plant's root is the primitive itself; ``tests/test_sim_any_rover.py`` checks it.

Unknowns (``3 + 3 N``) and rows
-------------------------------
``z = (u, v, r, omega_1..N, log h_1..N, log h0_1..N)``: body velocities of O (forward, left,
yaw rate), wheel speeds, sinkages and zero-slip sinkages. Rows, in order:

* the suspension's balance rows (:attr:`SuspensionStatics.balance_names`, ``3 + N`` of them
  for each kind), with the dynamics added to the planar rows as in the mini rover's plant
  (implicit Euler; ``dt = inf``: the quasi-static limit):
  ``Fx - m ((u - u_prev)/dt - r v)``, ``Fy - m ((v - v_prev)/dt + r u)``,
  ``Mz - I_z (r - r_prev)/dt``. The inertial force is taken at O (its moment about O through
  a centre of mass away from O, of order ``m a c``, is left out: zero in a steady state and
  below 1e-4 of the soil's yaw moments at these speeds). Heading enters through the weight:
  the terrain's slope ``alpha`` and cross slope ``gamma`` seen from a rover heading ``psi`` are
  the effective ``alpha_e = asin(sin alpha cos psi - cos alpha sin gamma sin psi)`` and
  ``gamma_e = atan2(-g_y, W cos alpha cos gamma)`` of the rotated weight (the components the
  mini rover's plant uses, :meth:`PlantModel._context`);
* per wheel the axle balance (speed mode: the servo's speed; torque mode: ``M_y + T = 0``, with
  spin inertia ``J`` when set), as :class:`PlantModel`;
* per wheel the zero-slip twin's load, ``F_z(zero slip, h0) = F_z``.

Scales: forces by ``W``, moments by ``W L`` (``L`` the wheelbase), the rigid frame's height
compatibility rows by the shearing radius, the axle rows by ``W / N r_s`` and the nominal
wheel speed.

External forces of a disturbance hook (:class:`offline.sim.simulator.DisturbanceForces`) enter
as in the mini rover's plant: a body force and yaw moment in the planar rows, a body-frame force
per wheel added to that wheel's soil force (it acts wherever the soil force does: planar, roll,
rocker and bogie rows), a torque per wheel resisting its spin in the axle rows. They are held
over a step, so the Jacobian keeps its form (the suspension's rows evaluated at the loaded
wrenches).

Not modelled here (the mini rover's plant has them): raised wheels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtctl.physics.rover_file import RoverSpec
from rtctl.physics.suspension import SuspensionStatics

from ..physics.backend import CASADI
from ..physics.params import ParameterSet
from ..physics.terramechanics import ModelOptions, WheelModel
from .plant import (GRAVITY, WHEEL_MASS_ESTIMATE, PlantSolution, SimulationError, _DenseCall, _stiction, _twin_direction,
                    wheel_state_batch)

__all__ = ["SuspensionPlant", "param_names", "input_names", "suspension_yaw_inertia", "rover_gravity",
           "rover_file_wheel_inertia"]



def param_names(wheels: tuple[str, ...]) -> tuple[str, ...]:
    """Truth parameters of a step of :class:`SuspensionPlant` (SI): :data:`offline.sim.plant.PARAM_NAMES`
    with one radius per wheel of the rover file.

    Parameters
    ----------
    wheels : tuple of str
        Wheel names in the rover file's order.
    """
    return (tuple(f"radius_{k}" for k in wheels)
            + ("k", "n0", "n1", "n2", "friction_angle", "unit_weight", "cohesion", "shear_modulus", "repose_angle")
            + ("slope", "cross_slope", "tether_force", "mass", "yaw_inertia", "wheel_inertia"))


def input_names(wheels: tuple[str, ...]) -> tuple[str, ...]:
    """Inputs of a step of :class:`SuspensionPlant` (SI), as :data:`offline.sim.plant.INPUT_NAMES`
    per wheel of the rover file (every wheel on the ground: no contact entries).

    Parameters
    ----------
    wheels : tuple of str
        Wheel names in the rover file's order.
    """
    per = lambda s: tuple(f"{s}_{k}" for k in wheels)  # noqa: E731
    return (per("omega_cmd") + per("speed_mode") + per("torque") + per("steer")
            + ("u_prev", "v_prev", "r_prev", "heading", "inv_dt") + per("omega_prev"))


def suspension_yaw_inertia(spec: RoverSpec) -> float:
    """Yaw inertia of a uniform plate spanning the wheel centres' plan, kg m^2 (an estimate, as
    :func:`offline.sim.plant.default_yaw_inertia`: the soil's damping dominates at these speeds).

    Parameters
    ----------
    spec : RoverSpec
    """
    xs = [w.position[0] for w in spec.wheels]
    ys = [w.position[1] for w in spec.wheels]
    m = spec.weight / _gravity(spec)
    return m * ((max(xs) - min(xs)) ** 2 + (max(ys) - min(ys)) ** 2) / 12.0


def _gravity(spec: RoverSpec) -> float:
    """The rover's gravity, m/s^2: the rover file's ``[rover] gravity_m_s2`` when it gives one
    (the file's weight is ``mass_kg * gravity_m_s2``; the mass that enters the dynamics is the
    weight over this gravity), else :data:`offline.sim.plant.GRAVITY` (a file that gives
    ``weight_N``). :class:`RoverSpec` keeps only the weight, so the file is read again here."""
    import tomllib
    from pathlib import Path

    p = Path(spec.path) if spec.path else None
    if p is None or not p.is_file():
        return GRAVITY
    with p.open("rb") as fh:
        g = tomllib.load(fh).get("rover", {}).get("gravity_m_s2")
    return float(g) if isinstance(g, (int, float)) and g > 0 else GRAVITY


rover_gravity = _gravity


def rover_file_wheel_inertia(params: ParameterSet) -> float:
    """Spin inertia of a rover file's wheel, kg m^2: :data:`offline.sim.plant.WHEEL_MASS_ESTIMATE`
    scaled with the rim radius cubed from the mini rover's 0.1 kg ring (an estimate: a wheel's mass
    grows roughly with its volume; about 1.2 kg for a 13 cm wheel), as a thin ring ``m r^2``.

    Parameters
    ----------
    params : ParameterSet
        Its wheel's rim radius.
    """
    r = params.wheel.radius
    m = WHEEL_MASS_ESTIMATE * (r / 0.0575) ** 3
    return m * r * r


@dataclass(frozen=True)
class _Rows:
    """Indices of the balance rows by their role."""

    fx: int
    fy: int
    mz: int
    force: tuple[int, ...]  # scaled by W
    moment: tuple[int, ...]  # scaled by W L
    height: tuple[int, ...]  # scaled by r_s


class SuspensionPlant:
    """Compiled equations of one rover file's wheels and suspension (module docstring).

    The interface is :class:`offline.sim.plant.PlantModel`'s (``solve``, ``evaluate``,
    ``initial_guess``, ``param_vector``) with ``N`` wheels in the rover file's order.

    Parameters
    ----------
    params : ParameterSet
        Wheel width, grouser geometry and contact tuning (fixed); radius and soil per call.
    spec : RoverSpec
        The rover as the optimizer sees it (turned half round for a backward drive,
        :func:`rtctl.physics.rover_file.driving_backward`): wheel positions, links, suspension.
    options : ModelOptions, optional
        Terramechanics variant (the optimizer's by default).
    compiled : bool
        C-compile the wheel batch (cached on disk); ``False``: casadi's virtual machine.
    pitch_includes_wheel_torque : bool
        As the NLP's solver option of the same name (default True).
    """

    MAX_NEWTON = 40
    TOL = 1e-8
    rocker_jacobian = False
    """Unused (the balance Jacobian is exact here); kept for the simulator's interface."""

    def __init__(self, params: ParameterSet, spec: RoverSpec, options: ModelOptions | None = None, compiled: bool = True,
                 pitch_includes_wheel_torque: bool = True) -> None:
        import casadi as ca

        self.params, self.spec = params, spec
        self.wheels = spec.wheel_names
        n = self.n = len(self.wheels)
        self.n_unknowns = 3 + 3 * n
        self.options = options or ModelOptions(shear_direction_smoothing=1e-6)
        self._wheel_model = WheelModel(params.soil, params.wheel, params.tuning, self.options)
        f = self._build(True)
        # four wheels: the mini rover's plant's tags, so one compiled library serves both (same graph)
        tag = "sim_wheels" if n == 4 else f"sim_wheels_{2 * n}"
        self.function = self._wheel_model._compile(f, tag) if compiled else f
        so = self._wheel_model._so_paths.get(f.name()) if compiled else None
        self._call = _DenseCall(so, f) if so else None
        fr = self._build(False)
        self.residual_function = self._wheel_model._compile(fr, "sim_wheels_residual" if n == 4 else
                                                            f"sim_wheels_residual_{2 * n}") if compiled else fr
        so_r = self._wheel_model._so_paths.get(fr.name()) if compiled else None
        self._call_residual = _DenseCall(so_r, fr) if so_r else None
        self.rs_nominal = params.wheel.shearing_radius
        self.gravity = _gravity(spec)
        self.statics = SuspensionStatics(spec, None, pitch_includes_wheel_torque)
        names = self.statics.balance_names
        self.balance_names = names
        force = tuple(i for i, s in enumerate(names) if s in ("Fx", "Fy", "Fz"))
        height = tuple(i for i, s in enumerate(names) if s.startswith("height_compatibility"))
        moment = tuple(i for i in range(len(names)) if i not in force and i not in height)
        self._rows = _Rows(names.index("Fx"), names.index("Fy"), names.index("Mz"), force, moment, height)
        if len(names) != 3 + n:
            raise SimulationError(f"{spec.path or spec.name}: the {spec.suspension} suspension gives {len(names)} balance "
                                  f"rows for {n} wheels; the plant needs 3 + N = {3 + n} (one per sinkage and the "
                                  "three planar rows)")
        xs = np.array([w.position[0] for w in spec.wheels])
        ys = np.array([w.position[1] for w in spec.wheels])
        self._xs, self._ys = xs, ys
        self.wheelbase = float(xs.max() - xs.min())
        # the balance rows as one casadi function with its Jacobian in (wrench, h)
        Wsym = ca.SX.sym("w", 6, n)
        beta = ca.SX.sym("beta", n)
        h = ca.SX.sym("h", n)
        g = ca.SX.sym("g", 2)  # effective slope and cross slope, rad
        ext = ca.SX.sym("ext", 3)
        wr = {k: [Wsym[j, i] for j in range(6)] for i, k in enumerate(self.wheels)}
        bal = self.statics.balance(CASADI, wr, {k: beta[i] for i, k in enumerate(self.wheels)},
                                   {k: h[i] for i, k in enumerate(self.wheels)},
                                   {k: Wsym[2, i] for i, k in enumerate(self.wheels)}, g[0], 0.0, 0.0, g[1],
                                   None, (ext[0], ext[1], ext[2]))  # type: ignore[arg-type]  # SX, not float
        rows = ca.vertcat(*[bal[s] for s in names])
        wh = ca.vertcat(ca.vec(Wsym), h)
        self._balance = ca.Function("suspension_balance", [Wsym, beta, h, g, ext], [rows, ca.jacobian(rows, wh)])
        self._balance_residual = ca.Function("suspension_balance_residual", [Wsym, beta, h, g, ext], [rows])

    # ------------------------------------------------------------------ the wheel batch
    def _build(self, jacobian: bool) -> Any:
        """casadi function of the ``2 N`` wheel states, as :meth:`PlantModel._build` (mapped ``2 N``)."""
        return wheel_state_batch(self.params, self.options, 2 * self.n, jacobian)

    # ------------------------------------------------------------------ vectors
    def param_vector(self, radius: tuple[float, ...], soil: Any, slope: float, cross_slope: float, tether_force: float,
                     mass: float, yaw_inertia: float, wheel_inertia: float = 0.0) -> NDArray[np.float64]:
        """Pack :func:`param_names` from SI values (as :meth:`PlantModel.param_vector`, one radius per wheel).

        Parameters
        ----------
        radius : tuple of float
            Rim radius per wheel, m (N values).
        soil : offline.physics.params.Soil
        slope, cross_slope : float
            rad.
        tether_force, mass, yaw_inertia, wheel_inertia : float
            N, kg, kg m^2, kg m^2.
        """
        if len(radius) != self.n:
            raise SimulationError(f"{self.n} wheel radii expected ({', '.join(self.wheels)}), got {len(radius)}")
        return np.array([*radius, soil.k, soil.n0, soil.n1, soil.n2, soil.friction_angle, soil.unit_weight,
                         soil.cohesion, soil.shear_modulus, soil.repose_angle, slope, cross_slope, tether_force,
                         mass, yaw_inertia, wheel_inertia], dtype=float)

    def default_wheel_inertia(self) -> float:
        """Spin inertia of a wheel, kg m^2: :func:`rover_file_wheel_inertia` of the plant's wheel."""
        return rover_file_wheel_inertia(self.params)

    # ------------------------------------------------------------------ residual
    def _context(self, a: NDArray[np.float64], q: NDArray[np.float64]) -> dict[str, Any]:
        n = self.n
        hg = self.params.wheel.grouser_height
        soil0 = n
        mass, iz, jw = q[soil0 + 12], q[soil0 + 13], q[soil0 + 14]
        slope, cross, tether = q[soil0 + 9], q[soil0 + 10], q[soil0 + 11]
        weight = mass * self.gravity
        cmd, mode, torque, steer = a[0:n], a[n:2 * n], a[2 * n:3 * n], a[3 * n:4 * n]
        u0, v0, r0, psi, inv_dt = a[4 * n], a[4 * n + 1], a[4 * n + 2], a[4 * n + 3], a[4 * n + 4]
        omega0 = a[4 * n + 5:5 * n + 5] if len(a) > 4 * n + 5 else None
        rs = q[0:n] + hg
        c, s = np.cos(steer), np.sin(steer)
        P = np.empty((10, 2 * n))
        P[0, :n] = P[0, n:] = q[0:n]
        P[1:, :] = q[n:n + 9, None]
        xs, ys = self._xs, self._ys
        dv = np.zeros((n, 2, 3))
        dv[:, 0, 0], dv[:, 0, 1], dv[:, 0, 2] = c, s, -c * ys + s * xs
        dv[:, 1, 0], dv[:, 1, 1], dv[:, 1, 2] = -s, c, s * ys + c * xs
        gX, gY = -weight * math.sin(slope), -weight * math.cos(slope) * math.sin(cross)
        gx, gy = gX * math.cos(psi) + gY * math.sin(psi), -gX * math.sin(psi) + gY * math.cos(psi)
        normal = weight * math.cos(slope) * math.cos(cross)
        g_eff = np.array([math.asin(max(-1.0, min(1.0, -gx / weight))), math.atan2(-gy, normal)])
        spin = jw * inv_dt != 0.0
        return dict(n=n, hg=hg, mass=mass, iz=iz, jw=jw, weight=weight, tether=tether, cmd=cmd, mode=mode, torque=torque,
                    steer=steer, u0=u0, v0=v0, r0=r0, inv_dt=inv_dt, omega0=omega0, rs=rs, c=c, s=s, P=P, dv=dv,
                    g_eff=g_eff, om_scale=self.spec.travel_speed / rs if self.spec.travel_speed else 0.03 / rs,
                    t_scale=weight / n * rs, spin=spin, M=weight * self.wheelbase)

    def evaluate(self, z: NDArray[np.float64], a: NDArray[np.float64], q: NDArray[np.float64],
                 d: NDArray[np.float64] | None = None, jacobian: bool = True
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Residual ``(3 + 3N,)``, Jacobian, wrench ``(N, 6)`` (wheel frame), slip, slip angle at ``z``.

        Parameters
        ----------
        z : ndarray
            Unknowns (module docstring).
        a : ndarray
            Inputs (:func:`input_names`).
        q : ndarray
            Parameters (:func:`param_names`).
        d : ndarray or None
            External forces held over the step (a disturbance hook,
            :meth:`offline.sim.simulator.DisturbanceForces.vector` with ``N`` wheels), SI: ``(F_x,
            F_y, M_z)`` on the body (the planar rows, as the truth's tether), then per wheel in the
            rover file's order a body-frame force ``f_x`` (N values) and ``f_y`` (N values), added to
            that wheel's soil force where the suspension's rows take it (planar, roll and pitch
            rows, about the wheel's own position), and a torque resisting its spin (N values; the
            axle balance ``M_y + T - tau_d = 0``), as :meth:`offline.sim.plant.PlantModel.evaluate`.
            Only the first three entries: the body's alone. None: none (the undisturbed equations bit
            for bit).
        jacobian : bool
            False: the Jacobian is all NaN (residual only, a third of the cost).
        """
        return self._evaluate(z, self._context(a, q), d, jacobian)

    def _evaluate(self, z: NDArray[np.float64], ctx: dict[str, Any], d: NDArray[np.float64] | None, jacobian: bool
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        n, nz = self.n, self.n_unknowns
        c, s, rs, dv = ctx["c"], ctx["s"], ctx["rs"], ctx["dv"]
        u, v, r = z[0], z[1], z[2]
        omega = z[3:3 + n]
        h, h0 = np.exp(z[3 + n:3 + 2 * n]), np.exp(z[3 + 2 * n:3 + 3 * n])
        omega0 = ctx["omega0"] if ctx["omega0"] is not None else omega
        vxr, vyr = u - r * self._ys, v + r * self._xs
        vx, vy = c * vxr + s * vyr, -s * vxr + c * vyr
        speed = np.sqrt(vx * vx + vy * vy + 1e-18)
        roll = _twin_direction(vx)
        X = np.empty((5, 2 * n))
        X[0, :n] = X[0, n:] = vx
        X[1, :n] = X[1, n:] = vy
        X[2, :n] = omega
        X[2, n:] = roll * speed / rs
        X[3, :n] = h
        X[4, :n] = X[3, n:] = X[4, n:] = h0
        P = ctx["P"]
        if not jacobian:
            W, SL, BE = (self._call_residual(X, P) if self._call_residual is not None
                         else [np.asarray(o, dtype=float) for o in self.residual_function(X, P)])
            JW = None
        else:
            W, JW, SL, BE = (self._call(X, P) if self._call is not None
                             else [np.asarray(o, dtype=float) for o in self.function(X, P)])
            JW = JW.reshape(6, 2 * n, 5).transpose(1, 0, 2)
        _stiction(W, JW, X, rs)
        wheel = W[:, :n]  # (6, n) wheel frame
        ext = np.array([-ctx["tether"], 0.0, 0.0])
        loaded = wheel  # the wrenches the suspension carries: the soil's plus a hook's wheel forces
        if d is not None:
            d = np.asarray(d, dtype=float)
            if len(d) not in (3, 3 + 3 * n):
                raise SimulationError(f"the disturbance vector has {len(d)} entries; the plant of {self.spec.name} "
                                      f"takes 3 (body) or 3 + 3 N = {3 + 3 * n} (body, then per wheel f_x, f_y, torque)")
            ext = ext + d[:3]
        if d is not None and len(d) > 3:
            # a body-frame force at a wheel, turned into that wheel's frame (the inverse of
            # SuspensionStatics.to_rover_frame), added to the soil force it acts with
            fx, fy = d[3:3 + n], d[3 + n:3 + 2 * n]
            if np.any(fx) or np.any(fy):
                loaded = wheel.copy()
                loaded[0] += c * fx + s * fy
                loaded[1] += -s * fx + c * fy
        if jacobian:
            rows, Jb = (np.asarray(o, dtype=float) for o in self._balance(loaded, ctx["steer"], h, ctx["g_eff"], ext))
        else:
            rows, Jb = np.asarray(self._balance_residual(loaded, ctx["steer"], h, ctx["g_eff"], ext), dtype=float), None
        rows = rows.ravel()
        rw = self._rows
        mass, inv_dt, weight, M = ctx["mass"], ctx["inv_dt"], ctx["weight"], ctx["M"]
        nb = 3 + n
        res = np.empty(nz)
        res[:nb] = rows
        res[rw.fx] -= mass * ((u - ctx["u0"]) * inv_dt - r * v)
        res[rw.fy] -= mass * ((v - ctx["v0"]) * inv_dt + r * u)
        res[rw.mz] -= ctx["iz"] * (r - ctx["r0"]) * inv_dt
        scale = np.empty(nb)
        scale[list(rw.force)] = weight
        scale[list(rw.moment)] = M
        if rw.height:
            scale[list(rw.height)] = self.rs_nominal
        res[:nb] /= scale
        mode, t_scale, om_scale = ctx["mode"], ctx["t_scale"], ctx["om_scale"]
        one_m = 1 - mode
        res[nb:nb + n] = mode * (omega - ctx["cmd"]) / om_scale + one_m * (wheel[4] + ctx["torque"]) / t_scale
        if d is not None and len(d) > 3:  # a hook's torque resisting the spin: M_y + T - tau_d = 0 (the motor supplies it in speed mode)
            res[nb:nb + n] -= one_m * d[3 + 2 * n:3 + 3 * n] / t_scale
        inertia = one_m * ctx["jw"] * inv_dt
        if ctx["spin"]:
            res[nb:nb + n] -= inertia * (omega - omega0) / t_scale
        res[nb + n:] = (W[2, n:] - wheel[2]) / (weight / n)
        if JW is None or Jb is None:
            return res, np.full((nz, nz), math.nan), wheel.T.copy(), SL[0, :n].copy(), BE[0, :n].copy()
        # d state / d z of the wheels and their twins
        I = np.arange(n)
        ds = np.zeros((n, 5, nz))
        ds[:, 0:2, 0:3] = dv
        ds[I, 2, 3 + I] = 1.0
        ds[I, 3, 3 + n + I] = h
        ds[I, 4, 3 + 2 * n + I] = h0
        ds0 = np.zeros((n, 5, nz))
        ds0[:, 0:2, 0:3] = dv
        ds0[:, 2, 0:3] = roll[:, None] * (vx[:, None] * dv[:, 0] + vy[:, None] * dv[:, 1]) / (speed * rs)[:, None]
        ds0[I, 3, 3 + 2 * n + I] = h0
        ds0[I, 4, 3 + 2 * n + I] = h0
        dwheel = np.einsum("ikx,ixz->ikz", JW[:n], ds)  # (n, 6, nz)
        dzero = np.einsum("ikx,ixz->ikz", JW[n:], ds0)
        dh = np.zeros((n, nz))
        dh[I, 3 + n + I] = h
        J = np.zeros((nz, nz))
        # casadi's vec of the (6, n) wrench is column-major: index comp + 6 wheel, as dwheel.reshape
        J[:nb] = Jb[:, :6 * n] @ dwheel.reshape(6 * n, nz) + Jb[:, 6 * n:] @ dh
        J[rw.fx, 0] -= mass * inv_dt
        J[rw.fx, 1] += mass * r
        J[rw.fx, 2] += mass * v
        J[rw.fy, 1] -= mass * inv_dt
        J[rw.fy, 2] -= mass * u
        J[rw.fy, 0] -= mass * r
        J[rw.mz, 2] -= ctx["iz"] * inv_dt
        J[:nb] /= scale[:, None]
        J[nb:nb + n] = (one_m / t_scale)[:, None] * dwheel[:, 4]
        J[nb + I, 3 + I] += mode / om_scale
        if ctx["spin"]:
            J[nb + I, 3 + I] -= inertia / t_scale
        J[nb + n:] = (dzero[:, 2] - dwheel[:, 2]) / (weight / n)
        return res, J, wheel.T.copy(), SL[0, :n].copy(), BE[0, :n].copy()

    # ------------------------------------------------------------------ Newton
    def solve(self, z0: NDArray[np.float64], a: NDArray[np.float64], q: NDArray[np.float64],
              d: NDArray[np.float64] | None = None, trace: list[dict[str, Any]] | None = None
              ) -> tuple[NDArray[np.float64], PlantSolution]:
        """Newton's method with backtracking, as :meth:`offline.sim.plant.PlantModel.solve`.

        Parameters
        ----------
        z0 : ndarray
            Start.
        a, q, d : ndarray
            As :meth:`evaluate`.
        trace : list or None
            Receives one entry per iteration (``norm``, ``step``).

        Raises
        ------
        SimulationError
            No equilibrium within :attr:`MAX_NEWTON` iterations (the message gives the residual).
        """
        n = self.n
        z = np.array(z0, dtype=float)
        ctx = self._context(a, q)
        res, J, w, sl, be = self._evaluate(z, ctx, d, True)
        norm = float(np.max(np.abs(res)))
        it = 0
        while norm > self.TOL and it < self.MAX_NEWTON:
            it += 1
            try:
                dz = np.linalg.solve(J, -res)
            except np.linalg.LinAlgError:
                if not np.all(np.isfinite(J)):
                    break
                dz = np.linalg.lstsq(J, -res, rcond=None)[0]
            big = np.max(np.abs(dz[3 + n:]))
            lam = 1.0 if big < 1.0 else 1.0 / big
            for trial in range(30):
                zt = z + lam * dz
                rt, Jt, wt, slt, bet = self._evaluate(zt, ctx, d, trial == 0)
                nt = float(np.max(np.abs(rt)))
                if np.isfinite(nt) and (nt < (1 - 1e-4 * lam) * norm or nt <= self.TOL):
                    break
                lam *= 0.5
            else:
                break
            if trace is not None:
                trace.append({"norm": nt, "step": lam})
            if trial and nt > self.TOL:
                rt, Jt, wt, slt, bet = self._evaluate(zt, ctx, d, True)
            z, res, J, w, sl, be, norm = zt, rt, Jt, wt, slt, bet, nt
        if not (norm <= 1e-7 and np.all(np.isfinite(z))):
            err = SimulationError(
                f"no equilibrium of the rover found (max scaled residual {norm:.3g} after {it} Newton iterations; "
                f"body velocity u={z[0]:.4g} v={z[1]:.4g} r={z[2]:.4g}, sinkages {np.exp(z[3 + n:3 + 2 * n])}): the "
                "terrain or commands are outside what the wheels can carry; reduce the slope or the step size")
            err.z = z
            raise err
        sol = PlantSolution(float(z[0]), float(z[1]), float(z[2]), z[3:3 + n].copy(), np.exp(z[3 + n:3 + 2 * n]),
                            np.exp(z[3 + 2 * n:]), w, sl, be, it, norm)
        return z, sol

    def initial_guess(self, speed: float, q: NDArray[np.float64], contact: NDArray[np.float64] | None = None
                      ) -> NDArray[np.float64]:
        """Straight driving at ``speed``, equal loads, sinkages carried by them at zero slip.

        Parameters
        ----------
        speed : float
            m/s.
        q : ndarray
            Parameters (:func:`param_names`).
        contact : None
            Every wheel on the ground (raised wheels are not modelled here).
        """
        if contact is not None and np.any(np.asarray(contact) == 0.0):
            raise SimulationError(f"{self.spec.path or self.spec.name}: raised wheels are not modelled by the "
                                  "plant of a rover file (only the mini rover's)")
        n = self.n
        weight = q[n + 12] * self.gravity
        rs = self.rs_nominal
        sol = self._wheel_model.sinkage_from_load(np.full(n, weight / n), np.full(n, speed), np.zeros(n), np.full(n, speed / rs))
        h = np.where(sol.converged, sol.h, rs / 5)
        return np.concatenate([[speed, 0.0, 0.0], np.full(n, speed / rs), np.log(h), np.log(h)])
