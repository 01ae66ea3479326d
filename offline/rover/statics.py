"""Rover statics for steady straight driving (dissertation section 7.2.2): the independent check.

The balance the NLP and the rover evaluate is :class:`rtctl.physics.statics.FourWheelRocker`
(re-exported here; its module docstring derives the geometry and lists where it departs from
the printed equations). :func:`free_body_residuals` computes the same balance independently
(numpy, explicit 3-D positions and rotation matrices, cross products); the optimizer's
independent check uses it, so the two are never the same code.
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
