"""Rover statics for steady straight driving (dissertation section 7.2.2), derived from the geometry.

The 4-wheel rocker rover of Table 7.2: two rockers joined by a passive pivot, independent
steer and drive on every wheel. :class:`FourWheelRocker` implements the wheel kinematics
(7.6)-(7.7), the rocker angles (7.10)-(7.11) and the balance (7.12)-(7.18) with the load
constraint (7.23), the steering offsets (7.26)-(7.27), the slope (7.32)-(7.33) and a cross
slope, backend-generic like the wheel physics (numpy for checking a solution, casadi for the
NLP). :func:`free_body_residuals` computes the same balance independently (numpy, explicit
3-D positions and rotation matrices, cross products); the optimizer's independent check
uses it.

Frames: terrain frame x forward (travel direction), y left, z along the terrain normal
(Fig. 7.2); the wheel forces and moments are expressed in it (the wheel model sees flat
ground), each wheel's wrench about its wheel centre. A wheel steered by ``beta`` has its
heading rotated by ``beta`` about z (positive toward +y, i.e. left); for a rover driving
straight the steer angle equals the wheel's slip angle (5.1). The right rear wheel
"pointed outwards" is at a negative angle (Fig. 7.11: stuck at -50 deg).

Geometry (derived here; where it departs from the printed equations)
--------------------------------------------------------------------
Each rocker carries its front and rear wheel centres at ``+-l_r/2`` along the rocker and
``h_r`` below its pivot; the pivots sit at ``y = -+w_r/2`` of the reference point O (the
body at pivot height, where the weight acts: the rover's centre of mass is taken at O, as
the printed moment equations imply by having no weight terms). The rocker angle ``phi``
is the nose-up angle of (7.10)-(7.11): ``phi_R = asin((h_RR - h_FR) / l_r)`` is positive
when the rear wheel sinks deeper (its centre ``r - h`` is lower). A nose-up angle is a
rotation by ``-phi`` about +y, so the wheel centres relative to O are::

    front: ( cos(phi) l_r/2 + sin(phi) h_r,  -+w_r/2,  sin(phi) l_r/2 - cos(phi) h_r)
    rear:  (-cos(phi) l_r/2 + sin(phi) h_r,  -+w_r/2, -sin(phi) l_r/2 - cos(phi) h_r)

and the balance is ``sum(r x F + M) = 0`` about O (pitch of each rocker: about its pivot
axis). Compared with the printed equations:

* (7.15)-(7.17): the ``sin(phi)`` terms have the opposite sign. The printed signs put the
  front axle lower for a positive angle (nose down), which contradicts (7.10)-(7.11)
  (nose up when the rear sinks more). Here the signs follow the geometry.
* (7.18): the yaw balance gains ``(F_y,F + F_y,R) h_r sin(phi)`` per rocker, the lever arm
  of the lateral forces along x that a tilted rocker gives its wheel centres (omitted in
  the printed equation).
* (7.16)-(7.17): the soil moments ``M_y`` about the wheel axles act on the rocker-plus-wheel
  body (the motor torque is internal) and are included (``pitch_includes_wheel_torque``).
* Cross slope ``gamma`` (not in the dissertation): gravity in the terrain frame is
  ``W (-sin(alpha), -cos(alpha) sin(gamma), -cos(alpha) cos(gamma))`` (pitch alpha about y,
  then roll gamma about x, left side up positive), so (7.13) gains ``- W cos(alpha) sin(gamma)``
  and (7.33) becomes ``sum W_i = W cos(alpha) cos(gamma)``. With the centre of mass at O the
  weight has no moment about O.
* External pull (not in the dissertation; a tether, drawbar or anchored cable): a constant
  body-frame force ``(F_x, F_y)`` at the height of O with yaw moment ``M_z`` about O adds to
  (7.12), (7.13) and (7.18); attached at O's height and parallel to the terrain it has no
  roll or pitch moment. Only built into the graph when given (``external``).
* Roll of the body is neglected, as in the dissertation (section 7.2.2).
* A raised wheel (stuck suspension, pivot locked): its rocker is held at the other
  rocker's angle (the locked body is one rigid frame), so its placeholder sinkage does not
  enter any angle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.physics.statics import BALANCE_NAMES, WHEELS, FourWheelRocker, RoverStatics

from ..physics.params import Rover

__all__ = ["WHEELS", "RoverStatics", "FourWheelRocker", "BALANCE_NAMES", "free_body_residuals", "rotation_x",
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
