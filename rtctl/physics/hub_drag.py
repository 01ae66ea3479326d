"""Hub contact: a face that bulldozes soil once a wheel sinks beyond a clearance (issue 14).

A wheel whose sinkage ``h`` exceeds a clearance ``h_c`` pushes a vertical face of width ``b``
(hub, axle housing or body) through the soil to the depth ``e = h - h_c``. The face meets
Rankine passive earth pressure ``p(z) = gamma K_p z + 2 c sqrt(K_p)``,
``K_p = tan^2(45 deg + phi / 2)`` (soil unit weight ``gamma``, cohesion ``c``, friction angle
``phi``), so the drag is

.. math::
    F = b \\left(\\frac{\\gamma K_p e^2}{2} + 2 c \\sqrt{K_p}\\, e\\right)

acting against the wheel's travel, with a torque ``F arm`` resisting the wheel's spin (the
lever ``arm`` about the axle; 0 when the face does not turn with the wheel). This is not in
the dissertation; it is the discrepancy tool's ``hub_contact`` candidate
(:class:`offline.discrepancy.drive.candidates.HubContact`, the simulator's disturbance hook), and
:func:`hub_wrench` is the same term for the steady-state NLP and the table builder.

Smoothing (only in :func:`hub_wrench`, for IPOPT and exact Jacobians)
--------------------------------------------------------------------
* the submerged depth ``e = max(h - h_c, 0)`` is the smooth maximum
  ``(d + sqrt(d^2 + eps^2)) / 2`` with ``eps = 0.1 mm`` (:data:`EXCESS_SMOOTHING`): at most
  0.05 mm above the exact depth at ``d = 0``, and ``eps^2 / (4 |d|)`` below it (2.5e-7 m at
  ``d = -10 mm``, a drag of order 1e-10 N for a 40 mm face);
* the travel direction ``v / sqrt(|v|^2 + (1 mm/s)^2)`` and the spin sign
  ``omega / sqrt(omega^2 + (0.01 rad/s)^2)``: the simulator hook's own smoothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from .backend import Backend
from .parameters import ParameterError, SoilLike as Soil

__all__ = ["HubFace", "HUB_KEYS", "passive_force", "hub_wrench", "EXCESS_SMOOTHING", "SPEED_SMOOTHING",
           "SPIN_SMOOTHING"]

EXCESS_SMOOTHING = 1e-4
"""``eps`` of the smooth submerged depth ``(d + sqrt(d^2 + eps^2)) / 2``, m (0.1 mm)."""
SPEED_SMOOTHING = 1e-3
"""Speed below which the drag direction is smoothed, m/s (the simulator hook's 1 mm/s)."""
SPIN_SMOOTHING = 1e-2
"""Spin rate below which the torque's sign is smoothed, rad/s (the simulator hook's 0.01 rad/s)."""

HUB_KEYS: dict[str, tuple[str, float, float, float]] = {
    "clearance_mm": ("clearance", 1e-3, 0.0, 500.0),
    "face_width_mm": ("face_width", 1e-3, 0.0, 2000.0),
    "arm_mm": ("arm", 1e-3, 0.0, 500.0),
}
"""Keys of a ``[hub_contact]`` section (truth and scenario files): ``{key: (field of
:class:`HubFace`, factor to SI, lowest, highest in file units)}``; ``clearance_mm`` is required."""


@dataclass(frozen=True)
class HubFace:
    """The geometry of a bulldozing face, the same on every wheel (SI).

    Parameters
    ----------
    clearance : float
        Sinkage at which the face touches the soil, m.
    face_width : float
        Width of the face, m.
    arm : float
        Lever of the drag about the wheel axle, m (0: no torque on the wheel's spin).

    Raises
    ------
    ParameterError
        A value that is not finite or negative.
    """

    clearance: float
    face_width: float = 0.0
    arm: float = 0.0

    def __post_init__(self) -> None:
        for name in ("clearance", "face_width", "arm"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0.0):
                raise ParameterError(f"HubFace.{name} must be a finite number >= 0 (m), got {v!r}")


def passive_force(ops: Backend, e: Any, width: float, soil: Soil) -> Any:
    """Rankine passive force on a vertical face of ``width`` (m) submerged to depth ``e`` (m), N.

    ``F = b (gamma K_p e^2 / 2 + 2 c sqrt(K_p) e)``, ``K_p = tan^2(pi / 4 + phi / 2)`` with the
    soil's unit weight, cohesion and friction angle (module notes). ``e`` must be >= 0 (the
    caller clips or smooths it).
    """
    kp = math.tan(math.pi / 4 + soil.friction_angle / 2) ** 2
    return width * (0.5 * soil.unit_weight * kp * e * e + 2.0 * soil.cohesion * math.sqrt(kp) * e)


def hub_wrench(ops: Backend, face: HubFace, soil: Soil, vx: Any, vy: Any, omega: Any, h: Any) -> tuple[Any, Any, Any]:
    """The hub drag on one wheel in the wheel frame (Fig. 5.1), about the wheel centre.

    Parameters
    ----------
    ops : Backend
        :data:`~offline.physics.backend.NUMPY` or :data:`~offline.physics.backend.CASADI`.
    face : HubFace
    soil : Soil
        The soil the face pushes (unit weight, cohesion, friction angle).
    vx, vy : array_like or casadi
        Wheel-centre velocity in the wheel frame, m/s (the wheel's travel).
    omega : array_like or casadi
        Wheel spin rate, rad/s (positive driving forward).
    h : array_like or casadi
        Wheel sinkage, m.

    Returns
    -------
    (F_x, F_y, M_y) : tuple
        Force against the travel, ``-F (v_x, v_y) / |v|``, N, and the moment about the axle
        ``-F arm sgn(omega)``, N m (the soil-moment convention: motor torque ``= -M_y``, so the
        motor works harder). ``F`` of :func:`passive_force` at the smooth depth (module notes).
    """
    d = h - face.clearance
    e = 0.5 * (d + ops.sqrt(d * d + EXCESS_SMOOTHING ** 2))
    f = passive_force(ops, e, face.face_width, soil)
    speed = ops.sqrt(vx * vx + vy * vy + SPEED_SMOOTHING ** 2)
    spin = omega / ops.sqrt(omega * omega + SPIN_SMOOTHING ** 2)
    return -f * vx / speed, -f * vy / speed, -f * face.arm * spin
