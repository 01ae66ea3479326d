"""Rover statics for steady straight driving (dissertation section 7.2.2).

The 4-wheel rocker rover of Table 7.2: two rockers joined by a passive pivot, independent
steer and drive on every wheel. :class:`FourWheelRocker` implements the wheel kinematics
(7.6)-(7.7), rocker angles (7.10)-(7.11) and the balance equations (7.12)-(7.18) with the
load constraint (7.23), the steering offsets (7.26)-(7.27) and the slope (7.32)-(7.33),
backend-generic like the wheel physics (numpy for checking a solution, casadi for the NLP).

Another layout (a 6-wheel rocker-bogie) implements :class:`RoverStatics`: wheel names,
their velocities from the rover motion, and the balance residuals from wheel wrenches.

Frames: rover x forward, y left, z up (Fig. 7.2). A wheel steered by ``beta`` has its heading
rotated by ``beta`` about z (positive toward +y, i.e. left); for a rover driving straight the
steer angle equals the wheel's slip angle (5.1). The right rear wheel "pointed outwards" is
at a negative angle (Fig. 7.11: stuck at -50 deg).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, Sequence

from ..physics.backend import Backend
from ..physics.params import Rover

__all__ = ["WHEELS", "RoverStatics", "FourWheelRocker", "BALANCE_NAMES"]

WHEELS: tuple[str, ...] = ("FR", "FL", "RR", "RL")
BALANCE_NAMES: tuple[str, ...] = ("Fx", "Fy", "Fz", "Mx", "My_right", "My_left", "Mz")


class RoverStatics(Protocol):
    """What the steady-state optimizer needs from a rover layout."""

    wheels: tuple[str, ...]

    def wheel_velocity(self, ops: Backend, speed: Any, beta: Any) -> tuple[Any, Any]:
        """Wheel-frame velocity of a wheel steered by ``beta`` on a rover moving straight."""
        ...

    def balance(
        self, ops: Backend, wrench: dict[str, Sequence[Any]], beta: dict[str, Any], h: dict[str, Any],
        load: dict[str, Any], slope: Any, fy_offset: Any, mz_offset: Any,
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
        The rocker pitch balances (7.16)-(7.17) as printed omit the soil moments M_y about
        the wheel axles. Those act on the rocker-plus-wheel body (the motor torque is
        internal to it), so by default they are included; ``False`` reproduces the printed
        equations.
    """

    rover: Rover
    pitch_includes_wheel_torque: bool = True
    wheels: tuple[str, ...] = WHEELS

    def wheel_velocity(self, ops: Backend, speed: Any, beta: Any) -> tuple[Any, Any]:
        """Eqs. (7.6)-(7.7) with v_x,rover = speed, v_y,rover = 0."""
        return speed * ops.cos(beta), -speed * ops.sin(beta)

    def rocker_angles(self, ops: Backend, h: dict[str, Any]) -> tuple[Any, Any]:
        """Eqs. (7.10)-(7.11): phi_R, phi_L from the sinkage difference along each rocker."""
        lr = self.rover.rocker_length
        return ops.arcsin((h["RR"] - h["FR"]) / lr), ops.arcsin((h["RL"] - h["FL"]) / lr)

    @staticmethod
    def to_rover_frame(ops: Backend, w: Sequence[Any], beta: Any) -> tuple[Any, ...]:
        """Rotate a wheel wrench (Fx, Fy, Fz, Mx, My, Mz) by the steer angle about z."""
        c, s = ops.cos(beta), ops.sin(beta)
        fx, fy, fz, mx, my, mz = w
        return (c * fx - s * fy, s * fx + c * fy, fz, c * mx - s * my, s * mx + c * my, mz)

    def balance(
        self, ops: Backend, wrench: dict[str, Sequence[Any]], beta: dict[str, Any], h: dict[str, Any],
        load: dict[str, Any], slope: Any, fy_offset: Any, mz_offset: Any,
    ) -> dict[str, Any]:
        """Residuals of (7.12)/(7.32), (7.13)/(7.27), (7.23)/(7.33), (7.15)-(7.17), (7.18)/(7.26).

        ``wrench`` holds each wheel's soil wrench in its own wheel frame; it is rotated into the
        rover frame here.
        """
        lr, hr, wr = self.rover.rocker_length, self.rover.pivot_height, self.rover.track_width
        W = self.rover.weight
        F = {k: self.to_rover_frame(ops, wrench[k], beta[k]) for k in self.wheels}
        fx = {k: F[k][0] for k in F}
        fy = {k: F[k][1] for k in F}
        fz = {k: F[k][2] for k in F}
        mx = {k: F[k][3] for k in F}
        my = {k: F[k][4] for k in F}
        mz = {k: F[k][5] for k in F}
        phi_r, phi_l = self.rocker_angles(ops, h)
        cr, sr, cl, sl = ops.cos(phi_r), ops.sin(phi_r), ops.cos(phi_l), ops.sin(phi_l)
        res = {
            "Fx": fx["FR"] + fx["FL"] + fx["RR"] + fx["RL"] - W * ops.sin(slope),
            "Fy": fy["FR"] + fy["FL"] + fy["RR"] + fy["RL"] - fy_offset,
            "Fz": load["FR"] + load["FL"] + load["RR"] + load["RL"] - W * ops.cos(slope),
            "Mx": (mx["FR"] + mx["FL"] + mx["RR"] + mx["RL"]
                   + (fy["FR"] + fy["RR"]) * cr * hr + (fy["FR"] - fy["RR"]) * sr * lr / 2
                   + (fy["FL"] + fy["RL"]) * cl * hr + (fy["FL"] - fy["RL"]) * sl * lr / 2
                   + (-fz["FR"] + fz["FL"] - fz["RR"] + fz["RL"]) * wr / 2),
            "My_right": ((-fx["FR"] - fx["RR"]) * cr * hr + (-fx["FR"] + fx["RR"]) * sr * lr / 2
                         + (-fz["FR"] + fz["RR"]) * cr * lr / 2 + (fz["FR"] + fz["RR"]) * sr * hr),
            "My_left": ((-fx["FL"] - fx["RL"]) * cl * hr + (-fx["FL"] + fx["RL"]) * sl * lr / 2
                        + (-fz["FL"] + fz["RL"]) * cl * lr / 2 + (fz["FL"] + fz["RL"]) * sl * hr),
            "Mz": (mz["FR"] + mz["FL"] + mz["RR"] + mz["RL"]
                   + (fx["FR"] - fx["FL"] + fx["RR"] - fx["RL"]) * wr / 2
                   + (fy["FR"] - fy["RR"]) * lr / 2 * cr + (fy["FL"] - fy["RL"]) * lr / 2 * cl - mz_offset),
        }
        if self.pitch_includes_wheel_torque:
            res["My_right"] = res["My_right"] + my["FR"] + my["RR"]
            res["My_left"] = res["My_left"] + my["FL"] + my["RL"]
        return res

    @staticmethod
    def pivot_balance(res: dict[str, Any], pivot_locked: Any) -> tuple[Any, Any]:
        """The two pitch equations with the rocker pivot free (``pivot_locked = 0``): both
        rocker balances (7.16), (7.17); or locked (``1``, a stuck suspension): only the whole
        rover's pitch balance, the pivot carrying the difference. Returned as
        ``(My_right + My_left, (1 - locked) My_right)``, zero in both cases."""
        return res["My_right"] + res["My_left"], (1.0 - pivot_locked) * res["My_right"]
