"""Concealed effects for the drive discrepancy tool, generated independently of its candidates.

The drive tool (:mod:`offline.discrepancy.drive.diagnosis`) names missing physics from the library
:data:`offline.discrepancy.drive.candidates.DRIVE_CANDIDATES`, whose terms are inputs of the plant
(:class:`offline.sim.truth.Truth` fields: ``slope``, ``cross_slope``, ``tether_force``,
``wheel_radius``, ``steer_offset``, soil ``k``). A test that conceals an effect through those
same inputs proves parameter recovery, not discovery. The effects here are produced by code
that shares nothing with the candidates' formulas: forces through the simulator's disturbance
hook (contract C5, :class:`offline.sim.simulator.DisturbanceForces`), the commands the actuators
really receive (:data:`offline.discrepancy.drive.synthetic.ActuatorPath`) and what the sensors really
report (:data:`offline.discrepancy.drive.synthetic.SensorPath`). Each has a different mechanism or
functional form from the candidate that should name it:

=========================  ===========================================  ======================  ===========
effect                     mechanism injected here                      candidate expected       independent
=========================  ===========================================  ======================  ===========
TerrainPlane               gravity projected on a plane given by its    terrain_slope            yes
                           normal (inclination + fall-line azimuth),
                           body force at the CoM; IMU tilt from the
                           normal and the true heading
TetherToAnchor             spring-reel cable from a rear attachment     tether (the mean         yes
                           point to a fixed world anchor: tension and   backward component)
                           direction vary with the pose, yaw moment
                           from the lever arm
SteeringEncoderMisaligned  the servo turns to commanded + offset; the   steer_offset_<W>         yes
                           encoder reports the commanded angle
WornWheel                  the plant's own per-wheel radius             wheel_radius_<W>         NO: parameter
                           (a smaller wheel changes contact geometry,                            recovery
                           not a force the hook can add)
LooserSoil                 another soil (n, k, c, phi, K all            soil_stiffness or        partly: the
                           different), not a k scaling                  recalibration            plant's soil law
HubDrag                    torque on one wheel's spin rising with its   none (out of library)    yes
                           sinkage (a hub seal in the soil)
SoftPatch                  a band of loose drift across the path:       none (out of library)    yes
                           resisting force on each wheel inside it
Undulation                 sinusoidal terrain height along world X:     none (out of library)    yes
                           gravity and IMU tilt from the local normal
GyroBiasStep               the gyro bias steps at a time of the drive   none (out of library)    yes
WheelSpeedServoShortfall   one wheel's speed servo reaches a fraction    speed_shortfall_<W>      NO: same law
                           of its command (actuator path)                (per-wheel actuator      (parameter
                                                                         library)                 recovery)
=========================  ===========================================  ======================  ===========

Every force effect keeps the mean of what it applied (``applied_mean``) so a test compares a
fitted tether with the pull the drive really felt. Not importable by ``offline`` (it lives in
``tests/``).

What the plant cannot take from a hook (documented approximations): the disturbance has no
vertical component, so a terrain plane's normal load stays the full weight (the plant's own
``cross_slope`` carries ``cos``: 0.19 % at 3.5 deg) and a body force acts at the CoM with no
roll or pitch moment (the plant's gravity also acts at the rocker pivot).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from offline.discrepancy.drive.synthetic import record_drive
from offline.physics.params import Soil
from offline.rover.scenario import Scenario
from offline.sim.truth import WHEELS, Truth
from rtctl.messages import Commands, Measurements

__all__ = ["TerrainPlane", "TetherToAnchor", "SteeringEncoderMisaligned", "WornWheel", "LooserSoil", "HubDrag",
           "SoftPatch", "Undulation", "GyroBiasStep", "WheelSpeedServoShortfall", "Effect", "Combined", "record_concealed", "LOOSE_SOIL",
           "terrain_frame", "gravity_and_tilt", "WHEEL_XY", "soil_pressure_check", "true_mean_sinkage",
           "soil_behaviour_check"]

G = 9.81

# wheel contact positions in the body frame (mini rover of Table 7.2: rocker 0.32 m, track 0.331 m)
WHEEL_XY = ((0.16, -0.1655), (0.16, 0.1655), (-0.16, -0.1655), (-0.16, 0.1655))
"""Body-frame (x forward, y left) contact positions FR, FL, RR, RL, m (wheelbase and track of Table 7.2)."""


def _forces(**kw: Any) -> Any:
    from offline.sim.simulator import DisturbanceForces  # contract C5 (branch sim13)

    return DisturbanceForces(**kw)


def terrain_frame(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthonormal terrain axes for a unit ``normal`` in a level frame (x0 = the start heading
    projected horizontally, y0 left, z up): ``e1`` = x0 projected on the plane, ``e2 = n x e1``, ``n``."""
    n = normal / np.linalg.norm(normal)
    x0 = np.array([1.0, 0.0, 0.0])
    e1 = x0 - (x0 @ n) * n
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1), n


def gravity_and_tilt(normal: np.ndarray, heading: float, weight: float) -> tuple[float, float, float, float]:
    """Gravity's in-plane component on the body (``Fx``, ``Fy``, N) and the IMU's ``roll``,
    ``pitch`` (rad; pitch nose up, roll left side up) for a rover on a plane of unit ``normal``
    (level frame) at ``heading`` in the plane's axes (:func:`terrain_frame`).

    Gravity ``-W z`` minus its normal part, projected on the body axes
    ``xb = cos(h) e1 + sin(h) e2``, ``yb = -sin(h) e1 + cos(h) e2``; an accelerometer at rest
    reads the up direction, so ``pitch = asin(z . xb)``, ``roll = asin(z . yb / cos(pitch))``.
    """
    e1, e2, n = terrain_frame(normal)
    c, s = math.cos(heading), math.sin(heading)
    xb, yb = c * e1 + s * e2, -s * e1 + c * e2
    up = np.array([0.0, 0.0, 1.0])
    g = -weight * up
    gt = g - (g @ n) * n
    pitch = math.asin(float(np.clip(up @ xb, -1, 1)))
    roll = math.asin(float(np.clip((up @ yb) / math.cos(pitch), -1, 1)))
    return float(gt @ xb), float(gt @ yb), roll, pitch


class Effect:
    """Base of a concealed effect: any of a disturbance, an actuator path and a sensor path.

    Attributes
    ----------
    name, physics : str
        Short name and what physics is injected.
    expect : dict
        Candidate key -> {parameter: value in the tool's reported units} that an honest tool
        should report (empty: out of the library, nothing should be named confidently).
    independent : bool
        The effect does not go through the plant inputs the candidates set.
    """

    name = "effect"
    physics = ""
    independent = True

    def truth(self, base: Truth) -> Truth:
        """The plant truth (the base world unless the effect is a plant parameter)."""
        return base

    def disturbance(self) -> Callable[[float, Any], Any] | None:
        """A fresh disturbance hook for one drive (``None``: no force)."""
        return None

    def actuator_path(self, c: Commands) -> Commands:
        """Commands the actuators really receive."""
        return c

    def sensor_path(self, m: Measurements, s: Any) -> Measurements:
        """Readings the rover really records."""
        return m

    def expect(self) -> dict[str, dict[str, float]]:
        """Expected names and parameters (after a drive: may depend on what it felt)."""
        return {}


class _Hooked(Effect):
    """An effect with a force hook; keeps the sum of the applied forces for :meth:`applied_mean`."""

    def __post_init__(self) -> None:
        self._sum = np.zeros(4)
        self._n = 0

    def forces(self, t: float, s: Any) -> Any:  # pragma: no cover - overridden
        raise NotImplementedError

    def disturbance(self) -> Callable[[float, Any], Any]:
        self._sum[:] = 0.0
        self._n = 0

        def hook(t: float, s: Any) -> Any:
            f = self.forces(t, s)
            self._sum += (f.body_force[0], f.body_force[1], f.body_moment_z, math.hypot(*f.body_force))
            self._n += 1
            return f

        return hook

    def applied_mean(self) -> tuple[float, float, float]:
        """Mean body force (x, y, N) and yaw moment (N m) over the hook's calls of the last drive."""
        return tuple(self._sum[:3] / max(self._n, 1))  # type: ignore[return-value]

    def mean_force(self) -> float:
        """Mean magnitude of the body force (N) over the hook's calls of the last drive."""
        return float(self._sum[3] / max(self._n, 1))


@dataclass
class TerrainPlane(_Hooked):
    """A plane inclined by ``inclination`` (rad) whose fall line (downhill) points at
    ``fall_azimuth`` (rad, from the start heading, counter-clockwise). Gravity minus its normal
    part is applied at the CoM as a body force, and the IMU reads the up direction in the body
    axes (replacing the simulator's flat-ground tilt, its noise kept). Expected: terrain_slope
    with the along / across angles whose gravity components equal this plane's at heading 0."""

    inclination: float = math.radians(3.5)
    fall_azimuth: float = math.radians(-80.0)
    weight: float = 34.3
    name: str = "terrain_plane"
    physics: str = "gravity on a plane given by its normal (inclination, fall-line azimuth); IMU tilt from the normal"

    def __post_init__(self) -> None:
        super().__post_init__()
        a, z = self.inclination, self.fall_azimuth
        self.normal = np.array([math.sin(a) * math.cos(z), math.sin(a) * math.sin(z), math.cos(a)])

    def forces(self, t: float, s: Any) -> Any:
        fx, fy, _, _ = gravity_and_tilt(self.normal, s.heading, self.weight)
        return _forces(body_force=(fx, fy))

    def sensor_path(self, m: Measurements, s: Any) -> Measurements:
        _, _, roll, pitch = gravity_and_tilt(self.normal, s.heading, self.weight)
        return replace(m, roll=m.roll + roll, pitch=m.pitch + pitch)

    def expect(self) -> dict[str, dict[str, float]]:
        gx, gy, _, _ = gravity_and_tilt(self.normal, 0.0, self.weight)
        # the candidate's plant: gX = -W sin(slope), gY = -W cos(slope) sin(cross)
        slope = math.asin(-gx / self.weight)
        cross = math.asin(-gy / (self.weight * math.cos(slope)))
        # a component that is zero by construction is not scored relatively
        return {"terrain_slope": {k: math.degrees(a) for k, a in (("slope", slope), ("cross_slope", cross)) if abs(a) > 1e-9}}


@dataclass
class TetherToAnchor(_Hooked):
    """A cable paid out from a spring reel, attached at ``attach`` (body frame, m) and fixed to a
    world ``anchor`` (m, in the frame of the start pose). Tension ``T0 + stiffness (L - L0)``
    (``L0`` the length at the start, never below zero); the force points from the attachment
    to the anchor, so its body-frame direction turns with the heading and it has a yaw moment
    about the CoM. Expected: ``tether`` with the mean backward (-x) component the drive felt (a
    constant pull along -x; the lateral part is outside its form) or ``tether_anchor`` with the
    tension at the start."""

    anchor: tuple[float, float] = (-3.0, 0.0)
    attach: tuple[float, float] = (-0.2, 0.0)
    tension0: float = 2.0
    stiffness: float = 0.5
    name: str = "tether_to_anchor"
    physics: str = "spring-reel cable to a fixed world anchor (pose-dependent direction and tension, yaw moment)"

    def __post_init__(self) -> None:
        super().__post_init__()
        self.length0 = math.hypot(self.anchor[0] - self.attach[0], self.anchor[1] - self.attach[1])

    def forces(self, t: float, s: Any) -> Any:
        c, sn = math.cos(s.heading), math.sin(s.heading)
        ax = s.x + c * self.attach[0] - sn * self.attach[1]
        ay = s.y + sn * self.attach[0] + c * self.attach[1]
        dx, dy = self.anchor[0] - ax, self.anchor[1] - ay
        length = math.hypot(dx, dy)
        tension = max(0.0, self.tension0 + self.stiffness * (length - self.length0))
        fX, fY = tension * dx / length, tension * dy / length
        fx, fy = c * fX + sn * fY, -sn * fX + c * fY
        mz = self.attach[0] * fy - self.attach[1] * fx
        return _forces(body_force=(fx, fy), body_moment_z=mz)

    def expect(self) -> dict[str, dict[str, float]]:
        return {"tether|tether_anchor": {"force": -self.applied_mean()[0], "tension": self.tension0}}


@dataclass
class SteeringEncoderMisaligned(Effect):
    """The steering encoder of ``wheel`` is mounted ``offset`` rad off: the servo, closing its
    loop on that encoder, turns the wheel to commanded + ``offset`` while the encoder reads the
    commanded angle. Produced in the actuator path (the commands the servo receives; rate limits
    and clipping apply to the true angle) and the sensor path (the encoder reading), not through
    the plant's steer offset. Expected: steer_offset_<wheel> = offset."""

    wheel: str = "FL"
    offset: float = math.radians(3.0)
    name: str = "steering_encoder_misaligned"
    physics: str = "servo turns to commanded + offset, encoder reports the commanded angle"

    def _add(self, a: tuple[float, ...], sign: float) -> tuple[float, ...]:
        i = WHEELS.index(self.wheel)
        return tuple(v + sign * self.offset if j == i else v for j, v in enumerate(a))

    def actuator_path(self, c: Commands) -> Commands:
        return replace(c, steer_angle=self._add(c.steer_angle, +1.0))

    def sensor_path(self, m: Measurements, s: Any) -> Measurements:
        return replace(m, steer_angle=self._add(m.steer_angle, -1.0))

    def expect(self) -> dict[str, dict[str, float]]:
        return {f"steer_offset_{self.wheel}": {"offset": math.degrees(self.offset)}}


@dataclass
class WornWheel(Effect):
    """``wheel``'s rim radius ``change`` (relative) smaller, through the plant's own per-wheel
    radius: a smaller wheel changes the contact geometry and the travel per revolution, which no
    external force reproduces. This case is PARAMETER RECOVERY (the candidate sets the same
    input), kept for the issue's case list and marked ``independent = False``."""

    wheel: str = "RR"
    change: float = -0.07
    name: str = "worn_wheel"
    physics: str = "per-wheel radius of the plant (parameter recovery, not independent)"
    independent = False

    def truth(self, base: Truth) -> Truth:
        i = WHEELS.index(self.wheel)
        r = tuple(v * (1 + self.change) if j == i else v for j, v in enumerate(base.wheel_radius))
        return replace(base, wheel_radius=r)  # type: ignore[arg-type]

    def expect(self) -> dict[str, dict[str, float]]:
        return {f"wheel_radius_{self.wheel}": {"radius_change": 100 * self.change}}


LOOSE_SOIL = Soil(k=1.0e6, n0=1.1, n1=0.01, n2=0.74, friction_angle=math.radians(26.0), unit_weight=12.5e3,
                  cohesion=0.4e3, shear_modulus=0.028, repose_angle=math.radians(27.0), name="loose_sand_generated",
                  source="tests/concealed_effects.py: a looser soil than Table 5.3 (n, k, c, phi, K, rho all changed)")
"""A looser soil than the believed Table 5.3 soil: lower sinkage exponent with a modulus that gives
about 30 % less pressure at the nominal 9 mm sinkage, lower friction angle and cohesion, larger shear modulus."""


@dataclass
class LooserSoil(Effect):
    """The ground is another soil (:data:`LOOSE_SOIL`): every Bekker / shear parameter differs,
    so it is not the k scaling of the soil_stiffness candidate. It still goes through the plant's
    soil law (the same eqs. 5.5-5.10 the believed model uses): the soil's functional form is the
    model's, its parameters are not. Expected: "parameters off" (soil_stiffness or the
    recalibration); the check is what the accepted soil does to the wheels at the drive's true
    states (:func:`soil_behaviour_check`: sinkage and wheel torque)."""

    soil: Soil = LOOSE_SOIL
    name: str = "looser_soil"
    physics: str = "a different soil (n, k, c, phi, K, rho), not a k scaling"
    independent = False

    def truth(self, base: Truth) -> Truth:
        return replace(base, params=replace(base.params, soil=self.soil))

    def expect(self) -> dict[str, dict[str, float]]:
        return {"soil_stiffness|recalibration": {}}


@dataclass
class HubDrag(_Hooked):
    """OUT OF LIBRARY. A hub seal of ``wheel`` dragging in the soil: a torque resisting the
    wheel's spin, ``coulomb + per_sinkage * h`` (N m, ``h`` its true sinkage), which the motor
    supplies on top of the soil's moment."""

    wheel: str = "RR"
    coulomb: float = 0.005
    per_sinkage: float = 3.0
    name: str = "hub_drag"
    physics: str = "drag torque on one wheel's spin rising with its sinkage"

    def forces(self, t: float, s: Any) -> Any:
        i = WHEELS.index(self.wheel)
        tq = [0.0] * 4
        tq[i] = math.copysign(self.coulomb + self.per_sinkage * s.sinkage[i], s.omega[i])
        return _forces(wheel_torque=tuple(tq))


@dataclass
class SoftPatch(_Hooked):
    """OUT OF LIBRARY. A band of loose drift across the path, ``x_from <= X < x_to`` (m, frame of
    the start pose): each wheel inside it meets a resisting force ``force`` (N) against its
    contact point's velocity (bulldozing), applied at that wheel's contact."""

    x_from: float = 0.12
    x_to: float = 0.30
    force: float = 0.8
    name: str = "soft_patch"
    physics: str = "a band of loose soil for part of the drive: resisting force on each wheel inside it"

    def forces(self, t: float, s: Any) -> Any:
        c, sn = math.cos(s.heading), math.sin(s.heading)
        wf = []
        for x, y in WHEEL_XY:
            X = s.x + c * x - sn * y
            vx, vy = s.u - s.yaw_rate * y, s.v + s.yaw_rate * x
            sp = math.hypot(vx, vy)
            if self.x_from <= X < self.x_to and sp > 1e-6:
                wf.append((-self.force * vx / sp, -self.force * vy / sp))
            else:
                wf.append((0.0, 0.0))
        return _forces(wheel_force=tuple(wf))


@dataclass
class Undulation(_Hooked):
    """OUT OF LIBRARY. Terrain height ``amplitude sin(2 pi X / wavelength)`` along the start
    heading's axis X: the local normal tilts with X, so gravity's in-plane pull and the IMU
    pitch/roll oscillate along the path (mean slope near zero over a few wavelengths)."""

    amplitude: float = 0.003
    wavelength: float = 0.3
    weight: float = 34.3
    name: str = "undulation"
    physics: str = "sinusoidal terrain undulation along X (gravity and IMU tilt from the local normal)"

    def _normal(self, X: float) -> np.ndarray:
        dz = self.amplitude * 2 * math.pi / self.wavelength * math.cos(2 * math.pi * X / self.wavelength)
        return np.array([-dz, 0.0, 1.0]) / math.sqrt(1 + dz * dz)

    def forces(self, t: float, s: Any) -> Any:
        fx, fy, _, _ = gravity_and_tilt(self._normal(s.x), s.heading, self.weight)
        return _forces(body_force=(fx, fy))

    def sensor_path(self, m: Measurements, s: Any) -> Measurements:
        _, _, roll, pitch = gravity_and_tilt(self._normal(s.x), s.heading, self.weight)
        return replace(m, roll=m.roll + roll, pitch=m.pitch + pitch)


@dataclass
class GyroBiasStep(Effect):
    """OUT OF LIBRARY. The gyro's bias steps by ``bias`` (rad/s) at time ``t_step`` (s) and stays
    (a thermal shift); the readings before it are untouched."""

    t_step: float = 10.0
    bias: float = 0.006
    name: str = "gyro_bias_step"
    physics: str = "gyro bias step at a time of the drive"

    def sensor_path(self, m: Measurements, s: Any) -> Measurements:
        return replace(m, yaw_rate=m.yaw_rate + (self.bias if m.t >= self.t_step else 0.0))


@dataclass
class WheelSpeedServoShortfall(Effect):
    """A wheel-speed servo that reaches only ``fraction`` of its command once the command's
    magnitude passes ``above`` (m/s rim speed): issue 24's concealed case (the rear-left servo at
    80 % of its command). Produced in the actuator path (the servo receives the reduced command;
    the recording keeps the commanded one). The per-wheel ``speed_shortfall_<W>`` candidate has
    the same law (a constant fraction), so naming it is PARAMETER RECOVERY, not discovery
    (``independent = False``); without the per-wheel actuator terms in the library no candidate
    has it. (A smooth saturation ``rim / (1 + |rim| / knee)`` was tried first: the truth
    simulator's quasi-static plant finds no equilibrium for it in the calibration drive's crab.)"""

    wheel: str = "RL"
    fraction: float = 0.8
    above: float = 0.005
    name: str = "wheel_speed_servo_shortfall"
    physics: str = "one wheel-speed servo reaches only a fraction of its command"
    independent = False

    def actuator_path(self, c: Commands) -> Commands:
        i = WHEELS.index(self.wheel)
        rim = tuple(v * self.fraction if j == i and abs(v) > self.above else v for j, v in enumerate(c.rim_speed))
        return replace(c, rim_speed=rim)

    def expect(self) -> dict[str, dict[str, float]]:
        return {f"speed_shortfall_{self.wheel}": {"fraction": self.fraction}}


@dataclass
class Combined(Effect):
    """Two effects at once (forces add; actuator and sensor paths compose in order)."""

    first: Effect = field(default_factory=Effect)
    second: Effect = field(default_factory=Effect)

    def __post_init__(self) -> None:
        self.name = f"{self.first.name}+{self.second.name}"
        self.physics = f"{self.first.physics}; {self.second.physics}"
        self.independent = self.first.independent and self.second.independent

    def truth(self, base: Truth) -> Truth:
        return self.second.truth(self.first.truth(base))

    def disturbance(self) -> Callable[[float, Any], Any] | None:
        hooks = [h for h in (self.first.disturbance(), self.second.disturbance()) if h is not None]
        if not hooks:
            return None
        if len(hooks) == 1:
            return hooks[0]

        def hook(t: float, s: Any) -> Any:
            a, b = hooks[0](t, s), hooks[1](t, s)
            return _forces(body_force=(a.body_force[0] + b.body_force[0], a.body_force[1] + b.body_force[1]),
                           body_moment_z=a.body_moment_z + b.body_moment_z,
                           wheel_force=tuple((p[0] + q[0], p[1] + q[1]) for p, q in zip(a.wheel_force, b.wheel_force)),
                           wheel_torque=tuple(p + q for p, q in zip(a.wheel_torque, b.wheel_torque)))

        return hook

    def actuator_path(self, c: Commands) -> Commands:
        return self.second.actuator_path(self.first.actuator_path(c))

    def sensor_path(self, m: Measurements, s: Any) -> Measurements:
        return self.second.sensor_path(self.first.sensor_path(m, s), s)

    def expect(self) -> dict[str, dict[str, float]]:
        return {**self.first.expect(), **self.second.expect()}


def record_concealed(path: str | Path, scenario: Scenario, effect: Effect, seed: int, duration: float,
                     base: Truth | None = None, **kw: Any) -> Path:
    """Record a calibration drive (:func:`offline.discrepancy.drive.synthetic.record_drive`) with ``effect``
    concealed: its plant truth, disturbance hook, actuator path and sensor path."""
    b = base or Truth.nominal(scenario.params, scenario.rover)
    plain = type(effect).actuator_path is Effect.actuator_path and not isinstance(effect, Combined)
    quiet = type(effect).sensor_path is Effect.sensor_path and not isinstance(effect, Combined)
    return record_drive(path, scenario, effect.truth(b), seed=seed, duration=duration, disturbance=effect.disturbance(),
                        actuator_path=None if plain else effect.actuator_path,
                        sensor_path=None if quiet else effect.sensor_path, **kw)


def true_mean_sinkage(path: str | Path) -> float:
    """Mean true sinkage over the wheels and ticks of a recording (its ``/sim/truth`` channel), m."""
    from rtctl.recording import read_recording

    h = [x for d in read_recording(path).truth for x in d["sinkage"]]
    return float(np.mean(h))


def soil_pressure_check(v: Any, effect: Effect, base: Truth, path: str | Path) -> dict[str, float]:
    """Bekker pressure ``k z^n0`` (eq. 5.5, kPa) at the true mean sinkage of the drive: the
    soil the tool accepted (the believed soil with its fitted changes) against the true soil.
    Different soils give the same drive when their pressure-sinkage curves cross near the
    operating sinkage, so this, not k or n alone, is what a drive can identify."""
    from offline.discrepancy.drive.diagnosis import accepted_extension

    z = true_mean_sinkage(path)
    fitted = replace(base.params.soil, **accepted_extension(v).soil)
    true = effect.truth(base).params.soil
    pf, pt = fitted.k * z**fitted.n0 / 1e3, true.k * z**true.n0 / 1e3
    return {"fitted": pf, "truth": pt, "rel_error": abs(pf - pt) / pt, "sinkage_mm": 1e3 * z}


def soil_behaviour_check(v: Any, effect: Effect, base: Truth, path: str | Path, every: int = 2) -> dict[str, dict[str, float]]:
    """What the accepted soil does to a wheel, against what the true soil does, at the states
    the drive went through: for every ``every``-th tick and every wheel of the recording's
    ``/sim/truth`` channel (its true load, slip and slip angle; reverse and |slip| >= 1 ticks
    left out), the sinkage carrying the load (eq. 5.34) and the wheel torque M_y
    (eqs. 5.5-5.10, quasi-static, so the travel speed does not enter) under each soil.

    A drive cannot pin a Bekker pair (k, n) down (no sinkage sensor; one load level), so two
    soils with very different k agree on everything the rover feels; this compares that, not
    the parameters. Returns two checks, each ``fitted`` / ``truth`` / ``rel_error`` and the
    believed soil's error ``believed_rel_error`` for scale:

    - ``sinkage at the drive's true states``: mean sinkage (mm); error = mean |h_fit - h_true| / h_true;
    - ``wheel torque at the drive's true states``: RMS M_y (mN m); error = RMS(M_fit - M_true) / RMS(M_true).
    """
    from offline.discrepancy.drive.diagnosis import accepted_extension
    from offline.physics.terramechanics import WheelModel, state_from_slip
    from rtctl.recording import read_recording

    rec = read_recording(path).truth[::every]
    load = np.array([x for d in rec for x in d["load"]], dtype=float)
    slip = np.array([x for d in rec for x in d["slip"]], dtype=float)
    beta = np.array([x for d in rec for x in d["slip_angle"]], dtype=float)
    ok = np.isfinite(load) & np.isfinite(slip) & np.isfinite(beta) & (load > 0) & (np.abs(slip) < 0.95) & (np.abs(beta) < 0.5 * math.pi)
    ps = base.params
    vx, vy, om = state_from_slip(slip[ok], beta[ok], 0.03, ps.wheel)
    soils = {"fitted": replace(ps.soil, **accepted_extension(v).soil), "truth": effect.truth(base).params.soil,
             "believed": ps.soil}
    h, my = {}, {}
    for name, soil in soils.items():
        m = WheelModel(soil, ps.wheel, ps.tuning)
        r = m.sinkage_from_load(load[ok], vx, vy, om)
        h[name] = np.asarray(r.h, dtype=float)
        my[name] = np.asarray(m.wrench(vx, vy, om, r.h, r.h_zero_slip).My, dtype=float)
    good = np.all([np.isfinite(h[k]) & np.isfinite(my[k]) for k in soils], axis=0)

    def sink_err(k: str) -> float:
        return float(np.mean(np.abs(h[k][good] - h["truth"][good]) / h["truth"][good]))

    def torque_err(k: str) -> float:
        return float(np.sqrt(np.mean((my[k][good] - my["truth"][good]) ** 2) / np.mean(my["truth"][good] ** 2)))

    rms = lambda a: float(np.sqrt(np.mean(a[good] ** 2)))  # noqa: E731
    return {"sinkage at the drive's true states": {"fitted": 1e3 * float(np.mean(h["fitted"][good])),
                                                   "truth": 1e3 * float(np.mean(h["truth"][good])),
                                                   "rel_error": sink_err("fitted"), "believed_rel_error": sink_err("believed"),
                                                   "states": int(good.sum())},
            "wheel torque at the drive's true states": {"fitted": 1e3 * rms(my["fitted"]), "truth": 1e3 * rms(my["truth"]),
                                                        "rel_error": torque_err("fitted"),
                                                        "believed_rel_error": torque_err("believed"), "states": int(good.sum())}}
