"""Out-of-library effects for the empirical terms of the drive tool (issue 24), generated
independently of :mod:`offline.discrepancy.drive.empirical`.

Each effect is produced by a mechanism of its own -- a rope to a dragged sled at a rear
attachment point, a current-limited servo clipping the commands it receives -- written here
with none of the empirical family's code (no :class:`~offline.discrepancy.drive.empirical.EmpiricalTerm`,
no weights, no hook of the tool). The generic term that should model each is a different
mechanism: a constant force at the centre of mass against the travel (no yaw moment, no speed
dependence) for the sled; a speed loss on the commands of the re-simulation for the servo.
``truth_localisation`` gives what the tool's localisation is judged against (time, position
or threshold) in SI.

Also used: :class:`concealed_effects.SoftPatch`, :class:`concealed_effects.GyroBiasStep`,
:class:`concealed_effects.HubDrag` (the issue's out-of-library drive cases).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from concealed_effects import Effect, _forces, _Hooked
from offline.sim.truth import WHEELS
from rtctl.messages import Commands

__all__ = ["SnaggedSled", "CurrentLimitedServo"]


@dataclass
class SnaggedSled(_Hooked):
    """OUT OF LIBRARY. From ``t_catch`` to ``t_release`` (s) the rover drags a sled caught on a rope
    at its rear attachment ``attach`` (body frame, m): the taut rope trails along the attachment
    point's path, so the force points against that point's velocity, with Coulomb friction
    ``friction`` (N, mu m g of the sled) plus ``viscous`` (N s/m) times its speed; off the
    centre of mass, it has a yaw moment. Generic model expected: a resisting force on the body,
    localised in time."""

    t_catch: float = 12.0
    t_release: float = 24.0
    friction: float = 1.2
    viscous: float = 10.0
    attach: tuple[float, float] = (-0.22, 0.05)
    name: str = "snagged_sled"
    physics: str = "a sled caught on a rope at a rear attachment for part of the drive (Coulomb + viscous, yaw moment)"

    def forces(self, t: float, s: Any) -> Any:
        if not (self.t_catch <= t < self.t_release):
            return _forces()
        ax, ay = self.attach
        vx, vy = s.u - s.yaw_rate * ay, s.v + s.yaw_rate * ax
        sp = math.hypot(vx, vy)
        if sp < 1e-6:
            return _forces()
        f = self.friction + self.viscous * sp
        fx, fy = -f * vx / sp, -f * vy / sp
        return _forces(body_force=(fx, fy), body_moment_z=ax * fy - ay * fx)

    def truth_localisation(self) -> dict[str, float]:
        """The interval the sled was dragged (s)."""
        return {"lo": self.t_catch, "hi": self.t_release}


@dataclass
class CurrentLimitedServo(Effect):
    """OUT OF LIBRARY. ``wheel``'s speed servo is current-limited: whatever it is commanded, its
    rim speed stays within ``v_max`` (m/s; sign kept), produced in the actuator path (the
    recording keeps the commanded speed). The default library has no per-wheel speed limit
    (the per-wheel actuator terms are not in it). Expected generic model: a speed loss of that
    wheel saturating above a commanded speed (its threshold judged against ``v_max``). The
    generic saturation with magnitude 1 has this law: the mechanism here is the recording
    simulator's actuator path, the law is not independent of the family."""

    wheel: str = "RL"
    v_max: float = 0.04
    name: str = "current_limited_servo"
    physics: str = "one wheel-speed servo current-limited at a rim speed"

    def actuator_path(self, c: Commands) -> Commands:
        i = WHEELS.index(self.wheel)
        rim = tuple(math.copysign(min(abs(v), self.v_max), v) if j == i else v for j, v in enumerate(c.rim_speed))
        return replace(c, rim_speed=rim)

    def truth_localisation(self) -> dict[str, float]:
        """The rim speed above which the servo stops following (m/s)."""
        return {"lo": self.v_max}
