"""Rover statics for steady straight driving (dissertation section 7.2.2), derived from the geometry.

The 4-wheel rocker rover of Table 7.2: two rockers joined by a passive pivot, independent
steer and drive on every wheel. :class:`FourWheelRocker` implements the wheel kinematics
(7.6)-(7.7), the rocker angles (7.10)-(7.11) and the balance (7.12)-(7.18) with the load
constraint (7.23), the steering offsets (7.26)-(7.27), the slope (7.32)-(7.33) and a cross
slope, backend-generic like the wheel physics (numpy for checking a solution, casadi for the
NLP). ``offline.rover.statics.free_body_residuals`` computes the same balance independently (numpy,
explicit 3-D positions and rotation matrices, cross products); the optimizer's independent
check uses it. This module is shared: the NLP graph (casadi) and the rover's exact residual
(numpy, :mod:`rtctl.physics.steady_state`) are built from it.

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

from .backend import Backend
from .parameters import RoverLike

__all__ = ["WHEELS", "RoverStatics", "FourWheelRocker", "BALANCE_NAMES"]

WHEELS: tuple[str, ...] = ("FR", "FL", "RR", "RL")
"""Wheel order (front right, front left, rear right, rear left); same as :data:`rtctl.layout.WHEELS`."""
BALANCE_NAMES: tuple[str, ...] = ("Fx", "Fy", "Fz", "Mx", "My_right", "My_left", "Mz")
"""Balance rows; same as :data:`rtctl.layout.BALANCE_ROWS`."""
_SIDE = {"FR": "R", "RR": "R", "FL": "L", "RL": "L"}
_FRONT = {"FR": True, "FL": True, "RR": False, "RL": False}


class RoverStatics(Protocol):
    """What the steady-state optimizer needs from a rover layout."""

    wheels: tuple[str, ...]

    def wheel_velocity(self, ops: Backend, speed: Any, beta: Any) -> tuple[Any, Any]:
        """Wheel-frame velocity of a wheel steered by ``beta`` on a rover moving straight."""
        ...

    def balance(
        self, ops: Backend, wrench: Mapping[str, Sequence[Any]], beta: dict[str, Any], h: dict[str, Any],
        load: dict[str, Any], slope: Any, fy_offset: Any, mz_offset: Any, cross_slope: Any = 0.0,
        contact: Mapping[str, Any] | None = None, external: tuple[float, float, float] | None = None,
    ) -> dict[str, Any]:
        """Residuals of the steady-state balance (zero at a driving primitive)."""
        ...


@dataclass(frozen=True)
class FourWheelRocker:
    """The mini rover of Table 7.2 and any rover of that layout.

    Parameters
    ----------
    rover : Rover
        Rocker length l_r, pivot height h_r above the wheel centres, track width w_r,
        weight, nominal speed.
    pitch_includes_wheel_torque : bool
        Include the soil moments M_y about the wheel axles in the rocker pitch balances
        (default; ``False`` reproduces the printed (7.16)-(7.17) in this respect).
    wheels : tuple of str
        Wheel names in the order of every per-wheel array (FR, FL, RR, RL).
    """

    rover: RoverLike
    pitch_includes_wheel_torque: bool = True
    wheels: tuple[str, ...] = WHEELS

    @property
    def balance_names(self) -> tuple[str, ...]:
        """Names of the rows :meth:`balance` returns (:data:`BALANCE_NAMES`), as
        :attr:`rtctl.physics.suspension.SuspensionStatics.balance_names`."""
        return BALANCE_NAMES

    @property
    def contact_rows(self) -> bool:
        """Raised wheels (``contact``) and the locked pivot (:meth:`pivot_rows`) are modelled."""
        return True

    def wheel_velocity(self, ops: Backend, speed: Any, beta: Any) -> tuple[Any, Any]:
        """Eqs. (7.6)-(7.7) with v_x,rover = speed, v_y,rover = 0."""
        return speed * ops.cos(beta), -speed * ops.sin(beta)

    def rocker_angles(self, ops: Backend, h: Mapping[str, Any], contact: Mapping[str, Any] | None = None) -> tuple[Any, Any]:
        """Eqs. (7.10)-(7.11): nose-up angles phi_R, phi_L from the sinkage difference along each rocker.

        ``contact`` (1 on the ground, 0 raised; smooth in the casadi graph): a rocker with a
        raised wheel takes the other rocker's angle (pivot locked, module docstring).
        """
        lr = self.rover.rocker_length
        pr = ops.arcsin((h["RR"] - h["FR"]) / lr)
        pl = ops.arcsin((h["RL"] - h["FL"]) / lr)
        if contact is None:
            return pr, pl
        cr = contact["FR"] * contact["RR"]
        cl = contact["FL"] * contact["RL"]
        return cr * pr + (1 - cr) * pl, cl * pl + (1 - cl) * pr

    def wheel_centre(self, ops: Backend, wheel: str, phi: Any) -> tuple[Any, Any, Any]:
        """Wheel centre relative to the reference point O for a nose-up rocker angle ``phi``
        (module docstring)."""
        return self._centre(wheel, ops.cos(phi), ops.sin(phi))

    def _centre(self, wheel: str, c: Any, s: Any) -> tuple[Any, Any, Any]:
        """:meth:`wheel_centre` from ``cos(phi)``, ``sin(phi)`` (shared by a rocker's two wheels)."""
        lr, hr, wr = self.rover.rocker_length, self.rover.pivot_height, self.rover.track_width
        half = (lr if _FRONT[wheel] else -lr) / 2  # sx lr / 2: sign and halving are exact, so
        y = -wr / 2 if _SIDE[wheel] == "R" else wr / 2  # c * half is sx c lr / 2 bit for bit
        return c * half + s * hr, y, s * half - c * hr

    @staticmethod
    def to_rover_frame(ops: Backend, w: Sequence[Any], beta: Any) -> tuple[Any, ...]:
        """Rotate a wheel wrench (Fx, Fy, Fz, Mx, My, Mz) by the steer angle about z."""
        c, s = ops.cos(beta), ops.sin(beta)
        fx, fy, fz, mx, my, mz = w
        return (c * fx - s * fy, s * fx + c * fy, fz, c * mx - s * my, s * mx + c * my, mz)

    def balance(
        self, ops: Backend, wrench: Mapping[str, Sequence[Any]], beta: dict[str, Any], h: dict[str, Any],
        load: dict[str, Any], slope: Any, fy_offset: Any, mz_offset: Any, cross_slope: Any = 0.0,
        contact: Mapping[str, Any] | None = None, external: tuple[float, float, float] | None = None,
    ) -> dict[str, Any]:
        """Residuals of (7.12)/(7.32), (7.13)/(7.27), (7.23)/(7.33), (7.15)-(7.17), (7.18)/(7.26),
        derived from the geometry (module docstring lists where they depart from print).

        ``external``: a constant body-frame pull ``(F_x, F_y, M_z about O)`` (N, N, N m) added to
        the x, y and yaw rows; None builds exactly the balance without it.

        ``wrench`` holds each wheel's soil wrench in its own wheel frame (about the wheel
        centre); it is rotated into the rover frame here. ``My_right`` / ``My_left`` are the
        pitch moments of each rocker about its pivot axis.
        """
        W = self.rover.weight
        F = {k: self.to_rover_frame(ops, wrench[k], beta[k]) for k in self.wheels}
        phi_r, phi_l = self.rocker_angles(ops, h, contact)
        trig = {"R": (ops.cos(phi_r), ops.sin(phi_r)), "L": (ops.cos(phi_l), ops.sin(phi_l))}
        res: dict[str, Any] = {
            "Fx": sum(F[k][0] for k in self.wheels) - W * ops.sin(slope),
            "Fy": sum(F[k][1] for k in self.wheels) - W * ops.cos(slope) * ops.sin(cross_slope) - fy_offset,
            "Fz": sum(load[k] for k in self.wheels) - W * ops.cos(slope) * ops.cos(cross_slope),
        }
        mx = my_r = my_l = 0.0
        mz = -mz_offset
        for k in self.wheels:
            fx, fy, fz, wmx, wmy, wmz = F[k]
            rx, ry, rz = self._centre(k, *trig[_SIDE[k]])
            mx = mx + wmx + ry * fz - rz * fy
            pitch = rz * fx - rx * fz + (wmy if self.pitch_includes_wheel_torque else 0.0)
            if _SIDE[k] == "R":
                my_r = my_r + pitch
            else:
                my_l = my_l + pitch
            mz = mz + wmz + rx * fy - ry * fx
        res.update(Mx=mx, My_right=my_r, My_left=my_l, Mz=mz)
        if external is not None:
            res["Fx"] = res["Fx"] + external[0]
            res["Fy"] = res["Fy"] + external[1]
            res["Mz"] = res["Mz"] + external[2]
        return {n: res[n] for n in BALANCE_NAMES}

    @staticmethod
    def pivot_rows(res: Mapping[str, Any], pivot_locked: Any) -> tuple[Any, Any]:
        """The two pitch rows of the NLP. Pivot free (``pivot_locked = 0``): each rocker's
        balance (7.16), (7.17). Locked (``1``, a stuck suspension): the whole rover's pitch
        balance in the first row (the pivot carries the difference) and 0 in the second."""
        r, l_ = res["My_right"], res["My_left"]
        return r + pivot_locked * l_, (1.0 - pivot_locked) * l_
