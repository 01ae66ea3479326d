"""Rover statics for steady straight driving (dissertation section 7.2.2): the independent check.

The balance the NLP and the rover evaluate is :class:`rtctl.physics.statics.FourWheelRocker`
(re-exported here; its module docstring derives the geometry and lists where it departs from
the printed equations). :func:`free_body_residuals` computes the same balance independently
(numpy, explicit 3-D positions and rotation matrices, cross products); the optimizer's
independent check uses it, so the two are never the same code.

For a rover described by a file (:mod:`rtctl.physics.rover_file`) the NLP's balance is
:class:`rtctl.physics.suspension.SuspensionStatics` (closed-form link angles from its link
tree); :class:`FreeBodyBalance` is its independent check: every link angle found by root
finding on the rotated support positions, positions by explicit rotation matrices, moments
projected on each pivot axis (the computation of ``tests/test_suspension.py``'s free body).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.physics.rover_file import RoverSpec
from rtctl.physics.statics import BALANCE_NAMES, WHEELS, FourWheelRocker, RoverStatics

from ..physics.params import Rover

__all__ = ["WHEELS", "RoverStatics", "FourWheelRocker", "BALANCE_NAMES", "free_body_residuals", "FreeBodyBalance", "rotation_x",
           "rotation_y", "rotation_z"]

_SIDE = {"FR": "R", "RR": "R", "FL": "L", "RL": "L"}
_FRONT = {"FR": True, "FL": True, "RR": False, "RL": False}


def rotation_x(a: float) -> NDArray[np.float64]:
    """Rotation matrix about x by ``a`` (right-handed)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rotation_y(a: float) -> NDArray[np.float64]:
    """Rotation matrix about y by ``a`` (right-handed; positive tips +x toward -z)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotation_z(a: float) -> NDArray[np.float64]:
    """Rotation matrix about z by ``a`` (right-handed)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def free_body_residuals(rover: Rover, wrench: Mapping[str, Sequence[float]], beta: Mapping[str, float],
                        h: Mapping[str, float], load: Mapping[str, float], slope: float, cross_slope: float = 0.0,
                        fy_offset: float = 0.0, mz_offset: float = 0.0, contact: Mapping[str, float] | None = None,
                        include_wheel_torque: bool = True,
                        external: tuple[float, float, float] | None = None) -> dict[str, float]:
    """Independent free-body balance of the rover (numpy, 3-D vectors, rotation matrices).

    Each wheel's wrench (about its centre, wheel frame) is rotated into the terrain frame by
    ``R_z(beta)``; each wheel centre is placed by rotating its position in the rocker frame,
    ``(+-l_r/2, 0, -h_r)``, by ``R_y(-phi)`` (``phi`` the nose-up rocker angle of
    (7.10)-(7.11); a rocker with a raised wheel takes the other rocker's angle) and shifting
    it to its pivot at ``y = -+w_r/2``; gravity ``R_x(gamma)^T R_y(-alpha)^T (0, 0, -W)`` acts at
    the reference point O. Returns the same rows as :meth:`FourWheelRocker.balance`:
    net force (with ``Fz`` from the loads, (7.23)), net moment about O, and each rocker's
    moment about its pivot axis (the y axis through O). ``external``: a body-frame pull
    ``(F_x, F_y, M_z)`` (N, N, N m about O) at the height of O, added to the net force and
    moment (module notes).
    """
    lr, hr, wr, W = rover.rocker_length, rover.pivot_height, rover.track_width, rover.weight
    contact = contact or {k: 1.0 for k in WHEELS}
    measured: dict[str, float | None] = {}
    for side, (f, r) in (("R", ("FR", "RR")), ("L", ("FL", "RL"))):
        measured[side] = float(np.arcsin((h[r] - h[f]) / lr)) if contact[f] and contact[r] else None
    # a side with a raised wheel takes the other side's rocker angle; neither side: level
    ang = {side: next((a for a in (measured[side], measured[other]) if a is not None), 0.0)
           for side, other in (("R", "L"), ("L", "R"))}
    gravity = rotation_x(cross_slope).T @ rotation_y(-slope).T @ np.array([0.0, 0.0, -W])
    force = gravity.copy()
    force[2] = 0.0
    moment = np.zeros(3)
    pitch = {"R": 0.0, "L": 0.0}
    for k in WHEELS:
        side = "R" if k in ("FR", "RR") else "L"
        local = np.array([lr / 2 if k in ("FR", "FL") else -lr / 2, 0.0, -hr])
        pos = rotation_y(-ang[side]) @ local + np.array([0.0, -wr / 2 if side == "R" else wr / 2, 0.0])
        Rz = rotation_z(beta[k])
        f = Rz @ np.asarray(wrench[k][:3], dtype=float)
        m = Rz @ np.asarray(wrench[k][3:], dtype=float)
        force[:2] += f[:2]
        mk = np.cross(pos, f) + m
        moment += mk
        pitch[side] += mk[1] if include_wheel_torque else mk[1] - m[1]
    force[2] = sum(load[k] for k in WHEELS) + gravity[2]
    if external is not None:
        force[:2] += np.asarray(external[:2], dtype=float)
        moment[2] += float(external[2])
    return {"Fx": float(force[0]), "Fy": float(force[1] - fy_offset), "Fz": float(force[2]), "Mx": float(moment[0]),
            "My_right": float(pitch["R"]), "My_left": float(pitch["L"]), "Mz": float(moment[2] - mz_offset)}


class FreeBodyBalance:
    """Independent free-body balance of a rover file's suspension (numpy, 3-D vectors).

    Written without :class:`rtctl.physics.suspension.SuspensionStatics` (the NLP's rows): each
    passive link's nose-up angle ``phi`` is the root (``scipy.optimize.brentq``) of
    ``(R_y(-phi) (p_a - p_b))_z = z_a - z_b`` for its two supports (wheel centres at
    ``z = -h``, or child pivots, solved children first); the body pitches with the rocker it is
    fixed to (``rocker``), with the mean rocker angle (``rocker_bogie``) or with the
    least-squares plane through the wheel centres (``rigid``). Each wheel's wrench is rotated
    by ``R_z(beta)``; net force (``Fz`` from the loads, (7.23)/(7.33)), net moment about O with
    the weight ``R_x(gamma)^T R_y(-alpha)^T (0, 0, -W)`` at the centre of mass, and each link's
    subtree moment about its pivot axis give the rows of
    :attr:`~rtctl.physics.suspension.SuspensionStatics.balance_names`.

    Parameters
    ----------
    rover : RoverSpec
        A validated rover file.
    include_wheel_torque : bool
        Include the wheels' soil moments ``M_y`` in the link pitch rows.
    """

    def __init__(self, rover: RoverSpec, include_wheel_torque: bool = True) -> None:
        self.rover = rover
        self.include_wheel_torque = include_wheel_torque
        self._links = {lk.name: lk for lk in rover.links}
        self._wheels = {w.name: w for w in rover.wheels}

    def _side(self, link: str) -> str:
        return "right" if self._links[link].pivot[1] < 0 else "left"

    def _rockers(self) -> dict[str, str]:
        return {self._side(n): n for n, lk in self._links.items() if lk.parent == "body"}

    def _subtree(self, link: str) -> list[str]:
        out = [w for w, s in self._wheels.items() if s.link == link]
        for n, lk in self._links.items():
            if lk.parent == link:
                out += self._subtree(n)
        return out

    def angles(self, h: Mapping[str, float], contact: Mapping[str, float] | None = None) -> tuple[dict[str, float], float]:
        """Absolute nose-up angle of every link (root finding) and of the body, rad.

        Parameters
        ----------
        h : mapping
            Per wheel sinkage, m.
        contact : mapping or None
            ``rocker`` only: a rocker with a raised wheel (0) takes the other rocker's angle
            (the pivot is locked); both raised: level.
        """
        from scipy.optimize import brentq

        z = {w: -float(h[w]) for w in self._wheels}
        ang: dict[str, float] = {}
        pivot_z: dict[str, float] = {}

        def solve(link: str) -> None:
            lk = self._links[link]
            sup = [(np.array(s.position), z[n]) for n, s in self._wheels.items() if s.link == link]
            for n, ch in self._links.items():
                if ch.parent == link:
                    solve(n)
                    sup.append((np.array(ch.pivot), pivot_z[n]))
            (pa, za), (pb, zb) = sup

            def f(phi: float) -> float:
                return float((rotation_y(-phi) @ (pa - pb))[2] - (za - zb))

            phi = float(brentq(f, -1.2, 1.2, xtol=1e-16, rtol=4 * np.finfo(float).eps))
            ang[link] = phi
            pivot_z[link] = za - float((rotation_y(-phi) @ (pa - np.array(lk.pivot)))[2])

        for n, lk in self._links.items():
            if lk.parent == "body":
                solve(n)
        kind = self.rover.suspension
        if contact is not None and kind == "rocker":
            r = self._rockers()
            up = {side: all(contact[w] != 0.0 for w in self._subtree(n)) for side, n in r.items()}
            measured = {side: ang[n] for side, n in r.items()}
            for side, other in (("right", "left"), ("left", "right")):
                ang[r[side]] = measured[side] if up[side] else (measured[other] if up[other] else 0.0)
        if kind == "rocker":
            body = ang[self.rover.body_fixed_to or ""]
        elif kind == "rocker_bogie":
            r = self._rockers()
            body = 0.5 * (ang[r["right"]] + ang[r["left"]])
        else:
            A = np.array([[1.0, s.position[0], s.position[1]] for s in self._wheels.values()])
            coef = np.linalg.lstsq(A, np.array([z[w] for w in self._wheels]), rcond=None)[0]
            body = math.asin(float(coef[1]))
        return ang, body

    def place(self, ang: Mapping[str, float], body: float
              ) -> tuple[dict[str, NDArray[np.float64]], dict[str, NDArray[np.float64]], NDArray[np.float64]]:
        """Pivot points, wheel centres and the centre of mass relative to O, m.

        Parameters
        ----------
        ang : mapping
            Link angles, rad (:meth:`angles`).
        body : float
            Body pitch, rad.
        """
        P: dict[str, NDArray[np.float64]] = {}

        def pivot(link: str) -> NDArray[np.float64]:
            if link not in P:
                lk = self._links[link]
                if lk.parent == "body":
                    P[link] = rotation_y(-body) @ np.array(lk.pivot)
                else:
                    par = self._links[lk.parent]
                    P[link] = pivot(lk.parent) + rotation_y(-ang[lk.parent]) @ (np.array(lk.pivot) - np.array(par.pivot))
            return P[link]

        pos: dict[str, NDArray[np.float64]] = {}
        for n, s in self._wheels.items():
            if s.link == "body":
                pos[n] = rotation_y(-body) @ np.array(s.position)
            else:
                lk = self._links[s.link]
                pos[n] = pivot(s.link) + rotation_y(-ang[s.link]) @ (np.array(s.position) - np.array(lk.pivot))
        for n in self._links:
            pivot(n)
        return P, pos, rotation_y(-body) @ np.array(self.rover.centre_of_mass)

    def residuals(self, wrench: Mapping[str, Sequence[float]], beta: Mapping[str, float], h: Mapping[str, float],
                  load: Mapping[str, float], slope: float, cross_slope: float = 0.0, fy_offset: float = 0.0,
                  mz_offset: float = 0.0, contact: Mapping[str, float] | None = None,
                  external: tuple[float, float, float] | None = None) -> dict[str, float]:
        """The balance rows (N, N m; ``height_plane``: m), zero at a steady state.

        Parameters
        ----------
        wrench : mapping
            Per wheel ``(F_x, F_y, F_z, M_x, M_y, M_z)``, wheel frame, about its centre.
        beta, h, load : mapping
            Per wheel steer angle (rad), sinkage (m), normal load (N).
        slope, cross_slope : float
            Terrain pitch (uphill +) and roll (left side up +), rad.
        fy_offset, mz_offset : float
            (7.27), (7.26): N, N m.
        contact : mapping or None
            ``rocker`` only: 1 on the ground, 0 raised (see :meth:`angles`).
        external : (F_x, F_y, M_z) or None
            Constant body-frame pull at O's height, N, N, N m.

        Returns
        -------
        dict
            Rows ``Fx, Fy, Fz, Mx`` (``My_right, My_left`` for ``rocker``; ``My``,
            ``My_differential`` and ``My_<bogie>`` for ``rocker_bogie``; ``My`` for ``rigid``),
            ``Mz``, and for ``rigid`` one row ``height_plane``: the largest distance of a wheel
            centre from the least-squares plane of the centres, m (zero for one rigid frame;
            the NLP's ``height_compatibility_k`` rows are zero exactly then).
        """
        ang, body = self.angles(h, contact if self.rover.suspension == "rocker" else None)
        P, pos, com = self.place(ang, body)
        W = self.rover.weight
        g = rotation_x(cross_slope).T @ rotation_y(-slope).T @ np.array([0.0, 0.0, -W])
        f = {k: rotation_z(beta[k]) @ np.asarray(wrench[k][:3], dtype=float) for k in self._wheels}
        m = {k: rotation_z(beta[k]) @ np.asarray(wrench[k][3:], dtype=float) for k in self._wheels}
        force = np.sum([f[k] for k in self._wheels], axis=0) + g
        moment = np.sum([np.cross(pos[k], f[k]) + m[k] for k in self._wheels], axis=0) + np.cross(com, g)
        if external is not None:
            force[:2] += np.asarray(external[:2], dtype=float)
            moment[2] += float(external[2])
        ey = np.array([0.0, 1.0, 0.0])

        def tau(link: str) -> float:
            return float(sum(ey @ (np.cross(pos[k] - P[link], f[k]) + (m[k] if self.include_wheel_torque else 0.0))
                             for k in self._subtree(link)))

        out = {"Fx": float(force[0]), "Fy": float(force[1] - fy_offset), "Fz": float(sum(load.values()) + g[2]),
               "Mx": float(moment[0])}
        kind = self.rover.suspension
        if kind == "rocker":
            for side, n in self._rockers().items():
                out[f"My_{side}"] = tau(n) + (float(ey @ np.cross(com - P[n], g)) if n == self.rover.body_fixed_to else 0.0)
        else:
            out["My"] = float(moment[1])
        if kind == "rocker_bogie":
            r = self._rockers()
            out["My_differential"] = tau(r["right"]) - tau(r["left"])
            for n, lk in self._links.items():
                if lk.parent != "body":
                    out[f"My_{n}"] = tau(n)
        out["Mz"] = float(moment[2] - mz_offset)
        if kind == "rigid":
            z = np.array([-float(h[w]) for w in self._wheels])
            A = np.array([[1.0, s.position[0], s.position[1]] for s in self._wheels.values()])
            out["height_plane"] = float(np.max(np.abs(z - A @ np.linalg.lstsq(A, z, rcond=None)[0])))
        return out
