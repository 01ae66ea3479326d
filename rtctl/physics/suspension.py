"""Steady-state balance of any rover file's suspension, derived from its free bodies.

:class:`SuspensionStatics` builds the residual rows of the steady-state balance (the
generalisation of the dissertation's (7.12)-(7.18), (7.23), (7.26)-(7.27), (7.32)-(7.33)) from
the link tree of a :class:`~rtctl.physics.rover_file.RoverSpec`: the ``rocker`` of Table 7.2,
a ``rocker_bogie`` with a differential (MER, MSL) and a ``rigid`` skid-steer frame. Nothing is
written per rover: positions, angles and rows follow from the file's pivots and wheel centres.
Backend-generic like :mod:`rtctl.physics.statics` (numpy arrays, or casadi ``SX`` through the
ground side's backend). For the mini rover's file the rows equal
:class:`rtctl.physics.statics.FourWheelRocker`'s to rounding (``tests/test_suspension.py``).

Frames and inputs
-----------------
Terrain frame x forward (travel), y left, z along the terrain normal (Fig. 7.2). Each wheel's
wrench ``(F_x, F_y, F_z, M_x, M_y, M_z)`` is given in its own wheel frame about its centre (the
wheel model's output) and rotated into the terrain frame by its steer angle ``beta`` about z,
as :meth:`FourWheelRocker.to_rover_frame <rtctl.physics.statics.FourWheelRocker.to_rover_frame>`
does. A wheel's sinkage ``h`` puts its centre ``z_i = r_s,i - h_i`` above the terrain datum
(``r_s`` its shearing radius; when every wheel has the same ``r_s`` only differences matter and
``z_i = -h_i`` is used). Roll of the body is neglected, as in the dissertation (section 7.2.2):
every rotation is a pitch about the lateral axis.

Kinematics (from the sinkages to positions)
-------------------------------------------
A passive link (rocker or bogie) pitches about its pivot; it rests on exactly two supports,
each a wheel centre or a child link's pivot. With the supports' nominal offsets from the link's
pivot ``l_a``, ``l_b`` (``a`` the forward one), ``d = l_a - l_b``, ``L = |(d_x, d_z)|``,
``psi = atan2(d_z, d_x)``, a nose-up rotation by ``phi`` (``R_y(-phi)``) raises ``a`` over
``b`` by ``d_x sin(phi) + d_z cos(phi) = L sin(phi + psi)``, so

.. math::  \\phi = \\arcsin\\big((z_a - z_b) / L\\big) - \\psi,

which is (7.10)-(7.11) for the mini rover's rocker (``psi = 0``, ``L = l_r``). Links are solved
children first; a child's pivot height is ``z_b - (l_{b,x} \\sin\\phi + l_{b,z} \\cos\\phi)``.
The body pitches with the rocker it is fixed to (``rocker``), with the mean of the rocker
angles (``rocker_bogie``: an ideal differential of ratio 1), or with the least-squares plane
through the wheel centres, ``theta = asin(dz/dx)`` (``rigid``). Positions relative to the body
reference point O: a rocker's pivot ``R_y(-theta) p``, a child pivot and a wheel centre its
parent's pivot plus ``R_y(-phi)`` times the nominal offset; the centre of mass ``R_y(-theta) c``.

Free bodies (which body each row is about)
------------------------------------------
The links and wheels are massless: the whole weight acts at the body's centre of mass. A
wheel's soil moment ``M_y`` acts on the link carrying it (the motor torque is internal to
that free body); ``pitch_includes_wheel_torque=False`` drops it from the link rows as the
printed (7.16)-(7.17) do.

* ``Fx``, ``Fy``, ``Fz``, ``Mx``, ``Mz`` (and ``My`` except for ``rocker``): the whole rover.
  Net force of the wheel forces and the weight
  ``W (-sin alpha, -cos alpha sin gamma, -cos alpha cos gamma)`` (slope alpha, cross slope gamma;
  (7.32) and the cross slope of :mod:`rtctl.physics.statics`), with ``Fz`` from the loads,
  ``sum W_i - W cos alpha cos gamma`` ((7.23), (7.33)); net moment about O of the wheel
  wrenches and of the weight at the centre of mass. Offsets (7.26)-(7.27) and an external pull
  enter ``Fy``, ``Mz`` (and ``Fx``) as in :class:`~rtctl.physics.statics.FourWheelRocker`.
* Every passive link whose parent is a link (a bogie): the link and everything it carries, the
  moment about its pivot axis, ``My_<link>`` (the pivot transmits no moment about its axis).
* ``rocker``: the two rockers are joined by a passive pivot and the body is fixed to one of
  them, so the rows are each rocker's pitch about the common pivot axis, ``My_right`` (with the
  body's weight if the body is fixed to it) and ``My_left``: (7.16)-(7.17). Their sum is the
  whole rover's pitch about that axis, which therefore is not a separate row.
* ``rocker_bogie``: the differential makes the body pitch ``(phi_R + phi_L) / 2``. With the
  moments ``m_R``, ``m_L``, ``m_B`` it exerts on the rockers and the body, an ideal
  (massless, frictionless) differential does no work: ``m_R w_R + m_L w_L + m_B (w_R + w_L) / 2 = 0``
  for every ``w_R, w_L``, so ``m_R = m_L = -m_B / 2``. Each rocker (with its bogie) is balanced
  about its pivot axis by the differential alone, ``tau_side + m_side = 0``, hence the coupling
  row ``My_differential = tau_R - tau_L``, next to the whole rover's ``My``.
* ``rigid``: a rigid frame on ``N`` wheels is statically indeterminate in the normal loads
  (``N`` loads, three equations ``Fz``, ``Mx``, ``My``). Its wheel centres are points of one rigid
  body at one body height, so their heights lie on a plane, ``z_i = z_0 + g_x x_i + g_y y_i``.
  The ``N - 3`` rows ``height_compatibility_k = sum_i C_ki z_i`` (the rows of ``C`` an
  orthonormal basis of the left null space of ``[1, x_i, y_i]``) are zero exactly on such a
  plane; with the wheel model's load-sinkage law they close the loads.

What differs from the dissertation: the geometry of :mod:`rtctl.physics.statics` (signs of the
``sin(phi)`` terms, the lateral-force lever arm in the yaw row, the wheels' ``M_y`` in the pitch
rows, the cross slope), plus a centre of mass anywhere (not only at O), the bogie and
differential rows and the rigid frame's compatibility rows, none of which the dissertation has.
Raised wheels (``contact``) are implemented for the ``rocker`` kind only, as in
:class:`~rtctl.physics.statics.FourWheelRocker`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from .backend import Backend
from .rover_file import RoverSpec

__all__ = ["SuspensionStatics"]

Vec = tuple[Any, Any, Any]


def _rot(ops: Backend, phi: Any, v: Sequence[float]) -> Vec:
    """``R_y(-phi) v``: a nose-up pitch by ``phi`` (Fig. 7.2 frame)."""
    c, s = ops.cos(phi), ops.sin(phi)
    return c * v[0] - s * v[2], v[1], s * v[0] + c * v[2]


def _sub(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


def _cross(r: Sequence[Any], f: Sequence[Any]) -> Vec:
    return r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]


@dataclass(frozen=True)
class _Support:
    kind: str  # "wheel" or "link"
    name: str
    local: tuple[float, float, float]  # nominal offset from the link's pivot, m


@dataclass(frozen=True)
class _Link:
    name: str
    parent: str
    pivot: tuple[float, float, float]
    a: _Support  # the forward support
    b: _Support
    length: float  # L
    psi: float
    wheels: tuple[str, ...]  # wheels in its subtree, file order
    side: str  # "right" (pivot y < 0) or "left"


@dataclass(frozen=True)
class SuspensionStatics:
    """The balance rows of a rover file's suspension (module docstring derives them).

    Parameters
    ----------
    rover : RoverSpec
        A validated rover file (:func:`rtctl.physics.rover_file.load_rover_file`).
    shearing_radius : mapping of str to float or None
        Per wheel r_s = r + h_g, m (a wheel centre is ``r_s - h`` above the terrain datum).
        None: every wheel has the same r_s (only sinkage differences then matter).
    pitch_includes_wheel_torque : bool
        Include the wheels' soil moments ``M_y`` in the link pitch rows (default, as
        :class:`~rtctl.physics.statics.FourWheelRocker`).
    """

    rover: RoverSpec
    shearing_radius: Mapping[str, float] | None = None
    pitch_includes_wheel_torque: bool = True
    _links: tuple[_Link, ...] = field(init=False, repr=False, compare=False)
    _compat: np.ndarray = field(init=False, repr=False, compare=False)
    _slope_x: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        rv = self.rover
        if self.shearing_radius is not None:
            missing = sorted(set(rv.wheel_names) - set(self.shearing_radius))
            if missing:
                raise ValueError(f"SuspensionStatics: shearing_radius has no value for wheel(s) {missing}")
        by_name = {lk.name: lk for lk in rv.links}
        order: list[str] = []

        def visit(n: str) -> None:  # children first
            for ch in rv.links:
                if ch.parent == n:
                    visit(ch.name)
            if n != "body":
                order.append(n)

        visit("body")

        def subtree_wheels(n: str) -> list[str]:
            out = [w.name for w in rv.wheels if w.link == n]
            for ch in rv.links:
                if ch.parent == n:
                    out += subtree_wheels(ch.name)
            return out

        links = []
        for n in order:
            lk = by_name[n]
            sup = [_Support("wheel", w.name, _sub(w.position, lk.pivot)) for w in rv.wheels if w.link == n]
            sup += [_Support("link", ch.name, _sub(ch.pivot, lk.pivot)) for ch in rv.links if ch.parent == n]
            a, b = sorted(sup, key=lambda s_: -s_.local[0])  # a: forward (d_x >= 0)
            dx, dz = a.local[0] - b.local[0], a.local[2] - b.local[2]
            names = subtree_wheels(n)
            order_w = [w for w in rv.wheel_names if w in names]
            side = "right" if lk.pivot[1] < 0 else "left"
            links.append(_Link(n, lk.parent, lk.pivot, a, b, math.hypot(dx, dz), math.atan2(dz, dx), tuple(order_w), side))
        object.__setattr__(self, "_links", tuple(links))
        A = np.array([[1.0, w.position[0], w.position[1]] for w in rv.wheels])
        if rv.suspension == "rigid":
            u, _, _ = np.linalg.svd(A, full_matrices=True)
            object.__setattr__(self, "_compat", u[:, 3:].T.copy())
            object.__setattr__(self, "_slope_x", np.linalg.pinv(A)[1].copy())
        else:
            object.__setattr__(self, "_compat", np.zeros((0, len(rv.wheels))))
            object.__setattr__(self, "_slope_x", np.zeros(len(rv.wheels)))

    # ------------------------------------------------------------------ names
    @property
    def wheels(self) -> tuple[str, ...]:
        """Wheel names in the order of every per-wheel array (the rover file's order)."""
        return self.rover.wheel_names

    def _rocker(self, side: str) -> _Link:
        return next(lk for lk in self._links if lk.parent == "body" and lk.side == side)

    @property
    def balance_names(self) -> tuple[str, ...]:
        """Names of the rows :meth:`balance` returns, in order."""
        kind = self.rover.suspension
        if kind == "rocker":
            pitch = ["My_right", "My_left"]
        elif kind == "rocker_bogie":
            pitch = ["My", "My_differential", *(f"My_{lk.name}" for lk in self.rover.links if lk.parent != "body")]
        else:
            pitch = ["My"]
        compat = [f"height_compatibility_{k}" for k in range(self._compat.shape[0])]
        return ("Fx", "Fy", "Fz", "Mx", *pitch, "Mz", *compat)

    @property
    def contact_rows(self) -> bool:
        """Raised wheels (``contact``) and the locked pivot (:meth:`pivot_rows`) are modelled:
        the ``rocker`` kind only (module docstring)."""
        return self.rover.suspension == "rocker"

    # ------------------------------------------------------------------ kinematics
    def wheel_velocity(self, ops: Backend, speed: Any, beta: Any) -> tuple[Any, Any]:
        """Eqs. (7.6)-(7.7) with v_x,rover = speed, v_y,rover = 0 (no yaw rate: every wheel alike).

        Parameters
        ----------
        ops : Backend
        speed : float or array or SX
            Rover speed, m/s.
        beta : float or array or SX
            Steer angle, rad.
        """
        return speed * ops.cos(beta), -speed * ops.sin(beta)

    def _heights(self, h: Mapping[str, Any]) -> dict[str, Any]:
        if self.shearing_radius is None:
            return {w: -h[w] for w in self.wheels}
        return {w: self.shearing_radius[w] - h[w] for w in self.wheels}

    def link_angles(self, ops: Backend, h: Mapping[str, Any],
                    contact: Mapping[str, Any] | None = None) -> tuple[dict[str, Any], Any]:
        """Nose-up pitch of every link and of the body from the sinkages (module docstring).

        Parameters
        ----------
        ops : Backend
        h : mapping
            Per wheel sinkage, m.
        contact : mapping or None
            ``rocker`` only: 1 on the ground, 0 raised; a rocker with a raised wheel takes the
            other rocker's angle (the pivot is locked), as
            :meth:`~rtctl.physics.statics.FourWheelRocker.rocker_angles`.

        Returns
        -------
        angles : dict
            Link name to its absolute pitch angle, rad.
        body : scalar
            The body's pitch angle, rad.
        """
        kind = self.rover.suspension
        if contact is not None and kind != "rocker":
            raise ValueError(f"{self.rover.path or self.rover.name}: raised wheels (contact) are implemented for the "
                             f"'rocker' suspension only, not {kind!r}")
        z = self._heights(h)
        zp: dict[str, Any] = {}
        ang: dict[str, Any] = {}
        for lk in self._links:
            za = z[lk.a.name] if lk.a.kind == "wheel" else zp[lk.a.name]
            zb = z[lk.b.name] if lk.b.kind == "wheel" else zp[lk.b.name]
            phi = ops.arcsin((za - zb) / lk.length)
            if lk.psi != 0.0:
                phi = phi - lk.psi
            ang[lk.name] = phi
            zp[lk.name] = zb - (ops.sin(phi) * lk.b.local[0] + ops.cos(phi) * lk.b.local[2])
        if kind == "rigid":
            slope = sum(float(self._slope_x[i]) * z[w] for i, w in enumerate(self.wheels))
            return ang, ops.arcsin(slope)
        r, l_ = self._rocker("right"), self._rocker("left")
        if contact is not None:
            cr = contact[r.wheels[0]] * contact[r.wheels[1]]
            cl = contact[l_.wheels[0]] * contact[l_.wheels[1]]
            pr, pl = ang[r.name], ang[l_.name]
            ang[r.name], ang[l_.name] = cr * pr + (1 - cr) * pl, cl * pl + (1 - cl) * pr
        if kind == "rocker":
            return ang, ang[self.rover.body_fixed_to or ""]
        return ang, 0.5 * (ang[r.name] + ang[l_.name])

    def positions(self, ops: Backend, h: Mapping[str, Any], contact: Mapping[str, Any] | None = None
                  ) -> tuple[dict[str, Vec], dict[str, Vec], Vec, dict[str, Any]]:
        """Wheel centres, link pivots and the centre of mass relative to O (module docstring).

        Parameters
        ----------
        ops : Backend
        h : mapping
            Per wheel sinkage, m.
        contact : mapping or None
            As :meth:`link_angles`.

        Returns
        -------
        wheels, pivots : dict
            Name to ``(x, y, z)``, m.
        centre_of_mass : tuple
            ``(x, y, z)``, m.
        angles : dict
            Link name (and ``"body"``) to its pitch angle, rad.
        """
        ang, body = self.link_angles(ops, h, contact)
        spec = {lk.name: lk for lk in self.rover.links}
        piv: dict[str, Vec] = {}
        for lk in reversed(self._links):  # parents first
            if lk.parent == "body":
                piv[lk.name] = _rot(ops, body, lk.pivot)
            else:
                off = _rot(ops, ang[lk.parent], _sub(lk.pivot, spec[lk.parent].pivot))
                p = piv[lk.parent]
                piv[lk.name] = (p[0] + off[0], p[1] + off[1], p[2] + off[2])
        pos: dict[str, Vec] = {}
        for w in self.rover.wheels:
            if w.link == "body":
                pos[w.name] = _rot(ops, body, w.position)
            else:
                off = _rot(ops, ang[w.link], _sub(w.position, spec[w.link].pivot))
                p = piv[w.link]
                pos[w.name] = (p[0] + off[0], p[1] + off[1], p[2] + off[2])
        com = _rot(ops, body, self.rover.centre_of_mass)
        return pos, piv, com, {**ang, "body": body}

    @staticmethod
    def to_rover_frame(ops: Backend, w: Sequence[Any], beta: Any) -> tuple[Any, ...]:
        """Rotate a wheel wrench (Fx, Fy, Fz, Mx, My, Mz) by the steer angle about z.

        Parameters
        ----------
        ops : Backend
        w : sequence
            The wrench in the wheel frame, N and N m.
        beta : scalar
            Steer angle, rad.
        """
        c, s = ops.cos(beta), ops.sin(beta)
        fx, fy, fz, mx, my, mz = w
        return (c * fx - s * fy, s * fx + c * fy, fz, c * mx - s * my, s * mx + c * my, mz)

    # ------------------------------------------------------------------ balance
    def balance(
        self, ops: Backend, wrench: Mapping[str, Sequence[Any]], beta: Mapping[str, Any], h: Mapping[str, Any],
        load: Mapping[str, Any], slope: Any, fy_offset: Any, mz_offset: Any, cross_slope: Any = 0.0,
        contact: Mapping[str, Any] | None = None, external: tuple[float, float, float] | None = None,
    ) -> dict[str, Any]:
        """Residuals of the steady-state balance, rows :attr:`balance_names` (zero at a primitive).

        Parameters
        ----------
        ops : Backend
        wrench : mapping
            Per wheel ``(F_x, F_y, F_z, M_x, M_y, M_z)`` in its wheel frame about its centre.
        beta : mapping
            Per wheel steer angle, rad.
        h : mapping
            Per wheel sinkage, m.
        load : mapping
            Per wheel normal load W_i, N ((7.23): the ``Fz`` row).
        slope, cross_slope : scalar
            Terrain pitch alpha (uphill positive) and roll gamma (left side up), rad.
        fy_offset, mz_offset : scalar
            Steering offsets of (7.27) and (7.26), N and N m.
        contact : mapping or None
            ``rocker`` only (see :meth:`link_angles`).
        external : (F_x, F_y, M_z) or None
            Constant body-frame pull at O's height, N, N, N m about O.

        Returns
        -------
        dict
            Row name to residual (N or N m).
        """
        W = self.rover.weight
        kind = self.rover.suspension
        F = {k: self.to_rover_frame(ops, wrench[k], beta[k]) for k in self.wheels}
        pos, piv, com, ang = self.positions(ops, h, contact)
        res: dict[str, Any] = {
            "Fx": sum(F[k][0] for k in self.wheels) - W * ops.sin(slope),
            "Fy": sum(F[k][1] for k in self.wheels) - W * ops.cos(slope) * ops.sin(cross_slope) - fy_offset,
            "Fz": sum(load[k] for k in self.wheels) - W * ops.cos(slope) * ops.cos(cross_slope),
        }
        mx: Any = 0.0
        my: Any = 0.0
        mz: Any = -mz_offset
        for k in self.wheels:
            fx, fy, fz, wmx, wmy, wmz = F[k]
            rx, ry, rz = pos[k]
            mx = mx + wmx + ry * fz - rz * fy
            my = my + wmy + rz * fx - rx * fz
            mz = mz + wmz + rx * fy - ry * fx
        grav_y: dict[str, Any] = {}
        if any(c != 0.0 for c in self.rover.centre_of_mass):
            g = (-W * ops.sin(slope), -W * ops.cos(slope) * ops.sin(cross_slope),
                 -W * ops.cos(slope) * ops.cos(cross_slope))
            gm = _cross(com, g)
            mx, my, mz = mx + gm[0], my + gm[1], mz + gm[2]
            for lk in self._links:
                if lk.parent == "body":  # the weight's pitch moment about a rocker pivot
                    grav_y[lk.name] = _cross(_sub(com, piv[lk.name]), g)[1]
        tau: dict[str, Any] = {}
        for lk in self._links:
            t: Any = 0.0
            p = piv[lk.name]
            for k in lk.wheels:
                fx, _, fz, _, wmy, _ = F[k]
                r = pos[k]
                t = t + (r[2] - p[2]) * fx - (r[0] - p[0]) * fz + (wmy if self.pitch_includes_wheel_torque else 0.0)
            tau[lk.name] = t
        res["Mx"] = mx
        if kind == "rocker":
            for side in ("right", "left"):
                rk = self._rocker(side)
                row = tau[rk.name]
                if rk.name == self.rover.body_fixed_to and rk.name in grav_y:
                    row = row + grav_y[rk.name]
                res[f"My_{side}"] = row
        else:
            res["My"] = my
            if kind == "rocker_bogie":
                res["My_differential"] = tau[self._rocker("right").name] - tau[self._rocker("left").name]
                for spec in self.rover.links:
                    if spec.parent != "body":
                        res[f"My_{spec.name}"] = tau[spec.name]
        res["Mz"] = mz
        if kind == "rigid":
            z = self._heights(h)
            for i in range(self._compat.shape[0]):
                res[f"height_compatibility_{i}"] = sum(float(self._compat[i, j]) * z[w] for j, w in enumerate(self.wheels))
        if external is not None:
            res["Fx"] = res["Fx"] + external[0]
            res["Fy"] = res["Fy"] + external[1]
            res["Mz"] = res["Mz"] + external[2]
        return {n: res[n] for n in self.balance_names}

    @staticmethod
    def pivot_rows(res: Mapping[str, Any], pivot_locked: Any) -> tuple[Any, Any]:
        """``rocker`` only: the two pitch rows with the pivot free (0) or locked (1), as
        :meth:`rtctl.physics.statics.FourWheelRocker.pivot_rows`.

        Parameters
        ----------
        res : mapping
            Rows of :meth:`balance` (``My_right``, ``My_left``).
        pivot_locked : scalar
            0 free, 1 locked (smooth in between in a graph).
        """
        r, l_ = res["My_right"], res["My_left"]
        return r + pivot_locked * l_, (1.0 - pivot_locked) * l_
