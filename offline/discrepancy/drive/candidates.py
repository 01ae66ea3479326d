"""Rover-level candidate physics for the discrepancy engine (issue 14), with physical parameters and bounds.

The engine (:func:`offline.discrepancy.engine.diagnose`) fits :class:`~offline.discrepancy.wheel.candidates.Candidate`
objects whose ``build(theta, params)`` returns an extension the model takes; the drive model's
extension type is :class:`RoverExtension` (the engine starts from ``model.empty_extension()``):
soil changes in ``RoverExtension.soil`` (the fields of :class:`~offline.physics.params.Soil`, SI)
and the rover terms in ``RoverExtension.terms`` over :data:`ROVER_KEYS`, checked when the
extension is made (unknown key or non-finite value: :class:`DriveCandidateError`). Two candidates
merge with :meth:`RoverExtension.merge`; the single-wheel model's
:class:`~offline.discrepancy.wheel.candidates.Extension` is not taken by the drive model, nor the reverse.

Each term maps onto an input the simulator already takes, so an accepted term *is* a truth
file (:func:`truth_from_terms`, :func:`write_truth_toml`) that
:func:`offline.sim.truth.load_truth` reads and the table builder takes
(``offnominal tables build SCENARIO --world accepted_truth.toml``,
:func:`offline.rover.scenario.scenario_with_world`):

===================  ===================================================  =========================
candidate            physics                                              simulator input
===================  ===================================================  =========================
terrain_slope        terrain inclined (along and across the pose frame)   ``slope``, ``cross_slope``
imu_tilt             IMU mounted tilted (readings only, no force)         sensor ``tilt_offset``
wheel_radius_<W>     one wheel worn / mis-measured                        ``wheels.<W>.radius_mm``
steer_offset_<W>     one wheel points elsewhere than its encoder says     ``wheels.<W>.steer_offset_deg``
tether               tether / drawbar pull along the rover's -x           ``tether_force_N``
tether_anchor        a cable to a fixed anchor (start frame) at a tension     ``[tether_anchor]``;
                     whose pull turns with the rover's pose                   disturbance hook (C5):
                                                                              :class:`AnchoredTether`
servo_lag            wheel-speed servo slower than believed               actuator ``wheel_lag``
torque_saturation    drive torque saturates lower than believed           actuator ``torque_limit``
gyro_scale           gyro scale-factor error (readings only)              (measurement chain)
speed_saturation_<W> one wheel's speed servo capped at a rim speed         commands the servo follows
speed_shortfall_<W>  one wheel's speed servo reaches a fraction of its     (:func:`actuator_commands`;
                     command                                               per-wheel actuator terms,
servo_lag_<W>        one wheel's speed servo lags more (extra 1st order)   screened: fitted only on the
speed_rate_limit_<W> one wheel's speed servo ramps at a bounded            wheels the data implicate)
                     acceleration (a slew-rate limit)
steer_saturation_<W> one wheel's steering servo capped at an angle
soil_stiffness       soil stiffer / softer than believed (k)              ``soil_stiffness_scale``
wheel_radius_all     every wheel's radius off (a parameter the model has) ``wheels.*.radius_mm``
recalibration        k, n0, c, phi, K refitted ("parameters off")         ``params`` file

hub_contact          hub / body face bulldozes soil once a wheel sinks     ``[hub_contact]``;
                     beyond a clearance (Rankine passive pressure on a     disturbance hook (C5):
                     face, a drag force against the wheel's travel and a   :class:`HubContact`
                     torque against its spin)
===================  ===================================================  =========================

Which of them the table builder takes (:data:`TABLE_BUILDER_TAKES`; ``--world`` applies the
truth file to the scenario): ``terrain_slope`` (added to the scenario's slope / cross slope; the
table's axes span the inclination), ``soil_stiffness`` and ``recalibration`` (the soil),
``wheel_radius_all`` and ``wheel_radius_<W>`` (a rim radius per wheel in the NLP, the table
header's ``world`` record, rtctl's per-wheel rim-speed conversion), ``steer_offset_<W>`` (steering
failures in encoder terms move by the offset, the header records it, rtctl commands
``beta - offset``), ``tether`` and ``tether_anchor`` (a constant body-frame force in the balance
(7.12), (7.13), (7.18): in steady straight driving the anchored cable's bearing is constant; its
anchor distance and spring rate, which make the pull vary along a drive, are not in the steady
state), ``torque_saturation`` (a ``torque_limit_Nm`` failure on every wheel) and ``hub_contact``
(``[hub_contact]``: the same Rankine drag, :func:`rtctl.physics.hub_drag.hub_wrench`, added to
each wheel's wrench in the NLP at the wheel's sinkage -- against its travel, with the torque
``F arm`` against its spin -- and in the tables' stored wheel wrenches and Jacobians; the
submerged depth is smoothed over 0.1 mm for IPOPT). Not taken: ``servo_lag`` (a dynamic effect
the steady-state tables have no place for). ``imu_tilt`` and ``gyro_scale`` act on the readings
only and change no table.

Hub contact and the anchored tether travel as :class:`~offline.sim.simulator.DisturbanceForces`
hooks (:func:`disturbance_from_terms`), which :class:`~offline.sim.simulator.RoverSimulator` takes;
``accepted_truth.toml`` carries their parameters in the truth format's ``[tether_anchor]`` and
``[hub_contact]`` sections, which ``offnominal drive --truth`` applies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence, cast

import numpy as np
from numpy.typing import NDArray

from ...files import write_text
from ...physics.backend import NUMPY
from rtctl.physics.hub_drag import SPEED_SMOOTHING, SPIN_SMOOTHING, HubFace, passive_force
from ...physics.params import ParameterError, ParameterSet, Soil
from ...sim.simulator import DisturbanceForces, TruthState
from ...sim.truth import WHEELS, Truth
from ..wheel.candidates import Candidate

__all__ = ["ROVER_KEYS", "DRIVE_CANDIDATES", "ACTUATOR_CANDIDATES", "DRIVE_CANDIDATES_WITH_ACTUATORS",
           "BASE_DRIVE_CANDIDATES",
           "PER_WHEEL_ACTUATOR_KEYS", "NEUTRAL_VALUES", "actuator_commands", "RoverTerms", "rover_terms", "recalibration_candidate",
           "truth_from_terms", "write_truth_toml", "DriveCandidateError", "HubContact", "disturbance_from_terms",
           "disturbance_from_truth",
           "AnchoredTether", "Hooks", "PosePath", "wheel_plan_positions", "backward_rover_file",
           "TABLE_BUILDER_TAKES", "RoverExtension", "MEASUREMENT_KEYS"]

ROVER_KEYS = (
    "slope", "cross_slope", "imu_roll", "imu_pitch", "tether", "wheel_lag", "torque_limit", "gyro_scale",
    "radius_scale_all", *(f"radius_scale.{w}" for w in WHEELS), *(f"steer_offset.{w}" for w in WHEELS),
    "hub_clearance", "hub_face_width", "hub_arm", "wheel_drag", "anchor_tension", "anchor_bearing", "anchor_inverse_distance",
    "anchor_attach_x", "anchor_spring_rate",
    *(f"rim_speed_max.{w}" for w in WHEELS), *(f"speed_fraction.{w}" for w in WHEELS), *(f"wheel_lag.{w}" for w in WHEELS),
    *(f"steer_max.{w}" for w in WHEELS), *(f"rim_accel_max.{w}" for w in WHEELS),
)
"""Rover terms of :attr:`RoverExtension.terms` (SI: rad, N, s, N m, m, relative)."""

PER_WHEEL_ACTUATOR_KEYS = (*(f"rim_speed_max.{w}" for w in WHEELS), *(f"speed_fraction.{w}" for w in WHEELS),
                           *(f"wheel_lag.{w}" for w in WHEELS), *(f"steer_max.{w}" for w in WHEELS),
                           *(f"rim_accel_max.{w}" for w in WHEELS))
"""Per-wheel actuator terms (applied to the commands a wheel's servos receive, :func:`actuator_commands`)."""

PER_WHEEL_TERMS = ("radius_scale", "steer_offset", "rim_speed_max", "speed_fraction", "wheel_lag", "steer_max",
                   "rim_accel_max")
"""Rover terms of one wheel, ``<term>.<wheel>``: :data:`ROVER_KEYS` names the mini rover's wheels; a
rover file's wheels (issue 23) take the same terms under their own names (:func:`is_rover_key`)."""


def is_rover_key(key: str) -> bool:
    """Whether ``key`` is a rover term: one of :data:`ROVER_KEYS`, or a per-wheel term
    (:data:`PER_WHEEL_TERMS`) of any wheel name (a rover file's wheels, issue 23)."""
    term, dot, wheel = key.partition(".")
    return key in ROVER_KEYS or (bool(dot) and term in PER_WHEEL_TERMS and bool(wheel))


def neutral_value(key: str) -> float:
    """The value of a rover term that changes nothing (:data:`NEUTRAL_VALUES`, whatever the wheel's
    name); NaN when it has none."""
    term, dot, wheel = key.partition(".")
    if key in NEUTRAL_VALUES or not dot:
        return NEUTRAL_VALUES.get(key, math.nan)
    return NEUTRAL_VALUES.get(f"{term}.FR", math.nan)


__all__ += ["PER_WHEEL_TERMS", "is_rover_key", "neutral_value"]  # issue 23: any rover's wheels

MEASUREMENT_KEYS = ("imu_roll", "imu_pitch", "gyro_scale")
"""Terms acting on the readings only (no re-simulation needed)."""

NEUTRAL_VALUES: dict[str, float] = {
    "slope": 0.0, "cross_slope": 0.0, "tether": 0.0, "wheel_drag": 0.0, "radius_scale_all": 1.0,
    **{f"radius_scale.{w}": 1.0 for w in WHEELS}, **{f"steer_offset.{w}": 0.0 for w in WHEELS},
    **{f"speed_fraction.{w}": 1.0 for w in WHEELS}, **{f"wheel_lag.{w}": 0.0 for w in WHEELS},
}
"""Rover terms whose value changes nothing (:func:`truth_from_terms` and :func:`actuator_commands`
multiply by 1 or add 0): :meth:`RoverTerms.physics_key` leaves them out, so the drive model's
cache serves them with the believed model's simulation. Terms with absolute values
(``wheel_lag``, ``torque_limit``, the caps, the hooks' parameters) have no neutral value here."""


class DriveCandidateError(ValueError):
    """An extension carries an unknown rover term or a value the simulator cannot take."""


class RoverTerms(dict[str, float]):
    """Rover terms of one extension: ``{key: value}`` over :data:`ROVER_KEYS` (absent = no change)."""

    def physics_key(self) -> tuple[tuple[str, float], ...]:
        """The terms that need a re-simulation (all but :data:`MEASUREMENT_KEYS`), sorted; a term
        at its :data:`NEUTRAL_VALUES` value is left out (it multiplies by 1 or adds 0, so the
        re-simulation is bit for bit the one without it, and a fit's start at the believed model
        is the believed model's simulation)."""
        return tuple(sorted((k, float(v)) for k, v in self.items()
                            if k not in MEASUREMENT_KEYS and neutral_value(k) != v))


@dataclass(frozen=True)
class RoverExtension:
    """What a rover-level candidate changes in the believed drive model. Defaults change nothing.

    Attributes
    ----------
    soil : dict
        Field replacements (SI) of the believed :class:`~offline.physics.params.Soil`.
    terms : dict
        Rover terms over :data:`ROVER_KEYS` (module table), SI.

    Raises
    ------
    DriveCandidateError
        An unknown term or a non-finite value.
    """

    soil: Mapping[str, float] = field(default_factory=dict)
    terms: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for k, v in self.terms.items():
            if not is_rover_key(k):
                raise DriveCandidateError(f"unknown rover term {k!r}; known: {list(ROVER_KEYS)} (per-wheel terms "
                                          f"{list(PER_WHEEL_TERMS)} also for a rover file's wheels: <term>.<wheel>)")
            if not math.isfinite(float(v)):
                raise DriveCandidateError(f"rover term {k} = {v!r} is not finite")
        for k, v in self.soil.items():
            if not math.isfinite(float(v)):
                raise DriveCandidateError(f"soil field {k} = {v!r} is not finite")
        object.__setattr__(self, "terms", {k: float(v) for k, v in self.terms.items()})
        object.__setattr__(self, "soil", dict(self.soil))

    def merge(self, other: "RoverExtension") -> "RoverExtension":
        """Both extensions at once (the other's entries win)."""
        return RoverExtension({**self.soil, **other.soil}, {**self.terms, **other.terms})


def rover_terms(ext: RoverExtension | None) -> RoverTerms:
    """The rover terms of an extension (empty for None).

    Raises
    ------
    DriveCandidateError
        ``ext`` is not a :class:`RoverExtension` (e.g. the single-wheel model's extension).
    """
    if ext is None:
        return RoverTerms()
    if not isinstance(ext, RoverExtension):
        raise DriveCandidateError(f"the drive model takes a RoverExtension, got {type(ext).__name__}; rover terms are "
                                  f"{list(ROVER_KEYS)} and soil fields")
    return RoverTerms(ext.terms)


def _opt(**kw: float) -> RoverExtension:
    return RoverExtension(terms={k.replace("__", "."): float(v) for k, v in kw.items()})


_D = math.pi / 180.0


def wheel_plan_positions(rover: Any) -> NDArray[np.float64]:
    """Plan positions ``(x forward, y left)`` of the wheel centres in the body frame, m, one row per
    wheel: the mini rover's (:class:`~offline.physics.params.Rover`: ``(+-l/2, -+w/2)``, order FR,
    FL, RR, RL) or a rover file's (:class:`rtctl.physics.rover_file.RoverSpec`: its wheels in file
    order; a backward drive's spec is already turned into the travel frame,
    :func:`rtctl.physics.rover_file.driving_backward`)."""
    wheels = getattr(rover, "wheels", None)
    if wheels is not None:
        return np.array([[float(w.position[0]), float(w.position[1])] for w in wheels])
    lr, wr = rover.rocker_length / 2, rover.track_width / 2
    return np.array([[lr, -wr], [lr, wr], [-lr, -wr], [-lr, wr]])


def _wheel_count(rover: Any) -> int:
    wheels = getattr(rover, "wheels", None)
    return len(WHEELS) if wheels is None else len(wheels)


def backward_rover_file(rover: Any) -> bool:
    """Whether ``rover`` is a rover file turned for a backward drive (the simulator's own test,
    :attr:`offline.sim.simulator.RoverSimulator.backward`)."""
    return bool(getattr(rover, "wheels", None) is not None and str(getattr(rover, "name", "")).endswith(" (backward)"))


@dataclass(frozen=True)
class HubContact:
    """Hub or body contact with the soil: a face that bulldozes soil once a wheel sinks beyond a clearance.

    For each wheel with sinkage ``h`` above the clearance ``h_c`` the submerged depth
    ``e = h - h_c`` of a vertical face of width ``b`` meets Rankine passive earth pressure,
    ``F = b (gamma K_p e^2 / 2 + 2 c sqrt(K_p) e)``, ``K_p = tan^2(45 deg + phi / 2)`` (soil unit
    weight ``gamma``, cohesion ``c``, friction angle ``phi`` of the believed soil). ``F`` acts at
    the wheel against the wheel's travel direction in the body frame (the contact moves with the
    wheel), and, with lever ``arm`` about the axle, resists the wheel's spin (``T = F arm``, sign
    of omega). Direction and sign are smoothed over 1 mm/s and 0.01 rad/s so the plant's Newton
    solve stays smooth at rest. Evaluated once per plant step by the simulator's disturbance
    hook (contract C5) with the sinkage of the last step.

    Parameters
    ----------
    clearance, face_width, arm : float
        The face's geometry, m: as :class:`rtctl.physics.hub_drag.HubFace` (the NLP's and the
        tables' term, :func:`rtctl.physics.hub_drag.hub_wrench`, with the same drag force).
    soil : Soil
    rover : Rover or RoverSpec
        Wheel positions: the mini rover's (rocker length, track width; order FR, FL, RR, RL) or a
        rover file's (:class:`rtctl.physics.rover_file.RoverSpec`: its wheels' plan positions in
        its order, the body frame of the plant -- the travel frame of a backward drive, issue 23).
    """

    clearance: float
    face_width: float
    arm: float
    soil: Soil
    rover: Any

    def __post_init__(self) -> None:
        try:
            HubFace(self.clearance, self.face_width, self.arm)  # the one check of the face's geometry
        except ParameterError as exc:
            raise DriveCandidateError(str(exc).replace("HubFace.", "HubContact.")) from None

    def force(self, sinkage: NDArray[np.float64]) -> NDArray[np.float64]:
        """Drag magnitude per wheel (N) at the sinkages (m)."""
        e = np.maximum(np.asarray(sinkage, dtype=float) - self.clearance, 0.0)
        return np.asarray(passive_force(NUMPY, e, self.face_width, self.soil), dtype=float)

    def __call__(self, t: float, s: TruthState) -> DisturbanceForces:
        """The forces over the next step (contract C5), one per wheel of :attr:`rover`."""
        f = self.force(np.array(s.sinkage))
        xy = wheel_plan_positions(self.rover)
        if len(f) != len(xy):
            raise DriveCandidateError(f"hub contact on {getattr(self.rover, 'name', 'the rover')}: the state has {len(f)} "
                                      f"wheels, the rover {len(xy)}")
        xs, ys = xy[:, 0], xy[:, 1]
        vx, vy = s.u - s.yaw_rate * ys, s.v + s.yaw_rate * xs
        norm = np.sqrt(vx * vx + vy * vy + SPEED_SMOOTHING ** 2)
        om = np.array(s.omega)
        torque = f * self.arm * om / np.sqrt(om * om + SPIN_SMOOTHING ** 2)
        return DisturbanceForces(wheel_force=tuple((float(-fi * a / n), float(-fi * b / n)) for fi, a, b, n in zip(f, vx, vy, norm)),
                                 wheel_torque=tuple(float(x) for x in torque))


@dataclass(frozen=True)
class WheelDrag:
    """The same resisting force at every wheel's contact, against that contact's travel (a
    look-alike probe of the identifiability rule, :data:`WRENCH_LOOKALIKES`: per-wheel drags the
    soil model lacks -- hub faces, rolling resistance -- whose sum on a straight drive is the body
    wrench of a pull at the body). Direction smoothed over 1 mm/s as :class:`HubContact`'s; no
    torque on the wheels' spin.

    Parameters
    ----------
    force : float
        Drag per wheel, N (positive: against the travel).
    rover : Rover or RoverSpec
        Wheel positions (:func:`wheel_plan_positions`).
    """

    force: float
    rover: Any

    def __call__(self, t: float, s: TruthState) -> DisturbanceForces:
        """The forces over the next step (contract C5), one per wheel of :attr:`rover`."""
        xy = wheel_plan_positions(self.rover)
        xs, ys = xy[:, 0], xy[:, 1]
        vx, vy = s.u - s.yaw_rate * ys, s.v + s.yaw_rate * xs
        norm = np.sqrt(vx * vx + vy * vy + SPEED_SMOOTHING ** 2)
        f = self.force
        return DisturbanceForces(wheel_force=tuple((float(-f * a / n), float(-f * b / n)) for a, b, n in zip(vx, vy, norm)),
                                 wheel_torque=(0.0,) * len(xs))


PosePath = Any
"""``pose_at(t) -> (x, y, heading)`` in the frame of the drive's start pose (m, rad): where the
rover was at time ``t`` (the recorded pose for a re-simulated drive)."""


@dataclass(frozen=True)
class AnchoredTether:
    """A cable from the rover to a fixed anchor: its pull turns with the rover's pose.

    The cable leaves the rover at ``(attach_x, 0)`` (body frame, m) and runs straight to an
    anchor fixed in the terrain at bearing ``bearing`` (rad, counter-clockwise from the drive's
    start heading) and distance ``1 / inverse_distance`` (m) from the start position, at the
    constant ``tension`` (N). With ``a`` the attachment's position in the start frame and
    ``u = (cos bearing, sin bearing)``, the pull points along ``u - q a`` (``q`` the inverse
    distance: 0 is an anchor far away, a pull of fixed direction in the terrain). The tension is
    that of a spring reel, ``tension + spring_rate (L - L0)`` (never below zero), ``L - L0 =
    (|u - q a| - |u - q a0|) / q`` the cable paid out since the start (``a0`` the attachment
    there; ``-u . (a - a0)`` at ``q = 0``); in the body
    frame it is turned by ``-heading`` and has a yaw moment ``attach_x * F_y`` about the centre
    of mass. The inverse distance keeps the force smooth in its parameters up to an anchor at
    infinity. The rover's pose comes from ``pose_at`` (the recorded pose in a re-simulation, so
    the direction does not drift with a dead-reckoning error), or from the simulator's truth
    state when None. Evaluated once per plant step by the simulator's disturbance hook
    (contract C5).

    Parameters
    ----------
    tension : float
        Cable tension, N (>= 0).
    bearing : float
        Direction of the anchor from the start position, rad from the start heading.
    inverse_distance : float
        1 / distance of the anchor from the start position, 1/m (>= 0).
    attach_x : float
        Attachment point on the body's x axis, m (negative: behind the centre of mass).
    spring_rate : float
        Tension gained per metre of cable paid out, N/m (0: a constant-tension reel).
    pose_at : callable, optional
        :data:`PosePath`.
    """

    tension: float
    bearing: float
    inverse_distance: float
    attach_x: float = 0.0
    spring_rate: float = 0.0
    pose_at: PosePath = None

    def _direction(self, x: float, y: float, h: float) -> tuple[float, float, float]:
        q = self.inverse_distance
        dx = math.cos(self.bearing) - q * (x + math.cos(h) * self.attach_x)
        dy = math.sin(self.bearing) - q * (y + math.sin(h) * self.attach_x)
        return dx, dy, math.hypot(dx, dy)

    def __post_init__(self) -> None:
        for name in ("tension", "bearing", "inverse_distance", "attach_x", "spring_rate"):
            v = getattr(self, name)
            if not math.isfinite(v):
                raise DriveCandidateError(f"AnchoredTether.{name} must be finite, got {v!r}")
        if self.tension < 0.0 or self.inverse_distance < 0.0:
            raise DriveCandidateError(f"AnchoredTether tension (N) and inverse_distance (1/m) must be >= 0 (a cable only "
                                      f"pulls), got {self.tension!r}, {self.inverse_distance!r}")

    def __call__(self, t: float, s: TruthState) -> DisturbanceForces:
        """The force over the next step (contract C5)."""
        x, y, h = self.pose_at(t) if self.pose_at is not None else (s.x, s.y, s.heading)
        c, sn = math.cos(h), math.sin(h)
        dx, dy, d = self._direction(x, y, h)
        if d < 1e-9:
            return DisturbanceForces()
        q = self.inverse_distance
        if q > 1e-9:
            paid = (d - self._direction(0.0, 0.0, 0.0)[2]) / q
        else:
            paid = -(math.cos(self.bearing) * (x + (c - 1.0) * self.attach_x) + math.sin(self.bearing) * (y + sn * self.attach_x))
        ten = max(0.0, self.tension + self.spring_rate * paid)
        fx = ten * (c * dx + sn * dy) / d
        fy = ten * (-sn * dx + c * dy) / d
        return DisturbanceForces(body_force=(fx, fy), body_moment_z=self.attach_x * fy)


@dataclass(frozen=True)
class Hooks:
    """Several disturbance hooks acting together on a rover of ``wheels`` wheels (their forces add)."""

    hooks: tuple[Any, ...]
    wheels: int = 4

    def __call__(self, t: float, s: TruthState) -> DisturbanceForces:
        """The summed forces over the next step (contract C5)."""
        n = self.wheels
        v = sum(h(t, s).vector(n) for h in self.hooks)
        return DisturbanceForces(body_force=(v[0], v[1]), body_moment_z=v[2], wheel_force=tuple(zip(v[3:3 + n], v[3 + n:3 + 2 * n])),
                                 wheel_torque=tuple(v[3 + 2 * n:3 + 3 * n]))


def _travel_pose(pose_at: PosePath) -> PosePath:
    """A recorded (body-frame) pose path in the travel frame of a backward drive: heading + pi."""
    def turned(t: float) -> tuple[float, float, float]:
        x, y, h = pose_at(t)
        return x, y, h + math.pi
    return turned


def disturbance_from_terms(ext: RoverExtension | None, params: ParameterSet, rover: Any,
                           pose_at: PosePath = None) -> Any:
    """The simulator disturbance hook of an extension's hub-contact and anchored-tether terms (None
    without them; :class:`Hooks` with both).

    Parameters
    ----------
    ext : RoverExtension or None
    params : ParameterSet
        The believed set (the hub contact's soil, with ``ext``'s soil changes).
    rover : Rover or RoverSpec
        The mini rover or a rover file (a scenario's ``rover_file``, issue 23): the hub contact acts
        at its wheels (:func:`wheel_plan_positions`). A backward drive's file (turned half round,
        :func:`rtctl.physics.rover_file.driving_backward`) puts the plant in the travel frame: the
        anchored tether's attachment ``attach_x`` (body frame of the rover as built) becomes
        ``-attach_x`` there and a recorded ``pose_at`` heading (the body's) gains pi, so the cable
        pulls the same way in the world.
    pose_at : callable, optional
        :class:`AnchoredTether`.
    """
    t = rover_terms(ext)
    hooks: list[Any] = []
    if "hub_clearance" in t:
        soil = replace(params.soil, **dict[str, Any](ext.soil)) if ext is not None and ext.soil else params.soil
        hooks.append(HubContact(t["hub_clearance"], t.get("hub_face_width", 0.0), t.get("hub_arm", 0.0), soil, rover))
    if t.get("wheel_drag", 0.0) != 0.0:
        hooks.append(WheelDrag(t["wheel_drag"], rover))
    if "anchor_tension" in t:
        back = backward_rover_file(rover)
        hooks.append(AnchoredTether(t["anchor_tension"], t.get("anchor_bearing", math.pi), t.get("anchor_inverse_distance", 0.0),
                                    -t.get("anchor_attach_x", 0.0) if back else t.get("anchor_attach_x", 0.0),
                                    t.get("anchor_spring_rate", 0.0),
                                    _travel_pose(pose_at) if back and pose_at is not None else pose_at))
    if not hooks:
        return None
    return hooks[0] if len(hooks) == 1 else Hooks(tuple(hooks), _wheel_count(rover))


def disturbance_from_truth(truth: Truth, rover: Any) -> Any:
    """The simulator's disturbance hook of a truth file's hook sections: ``[tether_anchor]``,
    ``[hub_contact]`` and ``[[empirical_force]]`` (:class:`~offline.discrepancy.drive.empirical.EmpiricalTerms`
    localised by the simulator's own time and pose); None without any.

    Raises
    ------
    ValueError
        An ``[[empirical_force]]`` combination the empirical family does not have.
    """
    terms = {f"anchor_{k}": v for k, v in (truth.anchor or {}).items()}
    terms.update({f"hub_{k}": v for k, v in (truth.hub or {}).items()})
    hook = disturbance_from_terms(RoverExtension(terms=terms), truth.params, rover) if terms else None
    if not truth.empirical:
        return hook
    from .empirical import EmpiricalTerms, terms_from_truth, wheel_names

    more = EmpiricalTerms(terms_from_truth(truth.empirical, wheel_names(rover)), rover).hook()
    return more if hook is None else Hooks((hook, more), _wheel_count(rover))


def _term_build(key: str, base: float) -> Callable[[NDArray[np.float64], ParameterSet], RoverExtension]:
    """The build of a one-parameter rover term: ``{key: base + theta}``."""
    def build(t: NDArray[np.float64], p: ParameterSet) -> RoverExtension:
        return RoverExtension(terms={key: base + float(t[0])})
    return build


def actuator_commands(terms: Mapping[str, float], rim_cmd: NDArray[np.float64], steer_cmd: NDArray[np.float64],
                      period: float, wheels: Sequence[str] = WHEELS) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The commands each wheel's servos really follow under the per-wheel actuator terms.

    ``speed_fraction.<W>``: the wheel-speed servo reaches only this fraction of its command
    (``rim -> fraction rim``); ``rim_speed_max.<W>`` (m/s): the wheel-speed servo saturates,
    ``|rim| <= max`` (sign kept; after the fraction); ``rim_accel_max.<W>`` (m/s^2): the
    wheel-speed servo's reference ramps toward that (capped) command by at most ``a period``
    per command period, ``y_k = y_(k-1) + clip(u_k - y_(k-1), -a period, a period)``, started
    at the first command (a slew-rate limit: a motor controller's acceleration ramp);
    ``wheel_lag.<W>`` (s): an extra first-order lag of that wheel's speed servo, applied to its
    rim-speed command at the command period (the lagged reference at the end of each period,
    exact exponential per period: ``y_k = u_k + (y_(k-1) - u_k) exp(-period / tau)``, in series with the
    believed servo lag of every wheel; a staircase at the tick resolution, snapped to the
    command once within 1e-9 m/s so steady stretches stay steady); ``steer_max.<W>`` (rad): the
    steering servo saturates, ``|steer| <= max``. Other keys are ignored.

    Parameters
    ----------
    terms : mapping
        Rover terms (:data:`ROVER_KEYS`).
    rim_cmd, steer_cmd : ndarray, shape (n, 4)
        Recorded per-tick commands (m/s, rad), wheel order :data:`~offline.sim.truth.WHEELS`.
    period : float
        Command period, s.
    wheels : sequence of str
        The columns' wheel names (default the mini rover's; a rover file's, issue 23).

    Returns
    -------
    rim, steer : ndarray, shape (n, 4)
        Copies with the terms applied.
    """
    rim, steer = np.array(rim_cmd, dtype=float), np.array(steer_cmd, dtype=float)
    for i, w in enumerate(wheels):
        tau = terms.get(f"wheel_lag.{w}", 0.0)
        if tau > 0.0:
            a = math.exp(-period / tau)
            u = rim[:, i].copy()
            for k in range(1, u.size):  # the lagged reference at the end of command period k
                y = u[k] + (rim[k - 1, i] - u[k]) * a
                rim[k, i] = u[k] if abs(y - u[k]) < 1e-9 else y
        rim[:, i] *= terms.get(f"speed_fraction.{w}", 1.0)
        cap = terms.get(f"rim_speed_max.{w}", math.inf)
        if math.isfinite(cap):
            rim[:, i] = np.clip(rim[:, i], -cap, cap)
        acc = terms.get(f"rim_accel_max.{w}", math.inf)
        if math.isfinite(acc):
            step = acc * period
            for k in range(1, rim.shape[0]):  # the ramped reference: rim[k - 1] is already y_(k-1)
                rim[k, i] = rim[k - 1, i] + min(max(rim[k, i] - rim[k - 1, i], -step), step)
        lim = terms.get(f"steer_max.{w}", math.inf)
        if math.isfinite(lim):
            steer[:, i] = np.clip(steer[:, i], -lim, lim)
    return rim, steer


def _actuator_candidates() -> list[Candidate]:
    out = []
    for w in WHEELS:
        ch = (f"omega_{w}", f"torque_{w}", "yaw_rate", "dheading", "dx_body", "dy_body")
        out.append(Candidate(
            f"speed_saturation_{w}", f"the {w} wheel-speed servo saturates: its rim speed cannot exceed a limit "
            "(a weak or overheating motor, a current limit on that wheel only)",
            (("rim_speed_max", "mm/s", 5.0, 150.0, 40.0, 1e-3),),
            _term_build(f"rim_speed_max.{w}", 0.0), ch, starts=((20.0,), (35.0,), (60.0,)), threshold=True,
            family=f"speed_{w}"))
        out.append(Candidate(
            f"speed_shortfall_{w}", f"the {w} wheel-speed servo reaches only a fraction of its command (a speed loop "
            "that saturates in proportion: a weak motor, a low supply voltage or gain on that wheel)",
            (("fraction", "-", 0.3, 1.2, 1.0, 1.0),),
            _term_build(f"speed_fraction.{w}", 0.0), ch, family=f"speed_{w}", null=(1.0,)))
        out.append(Candidate(
            f"servo_lag_{w}", f"the {w} wheel-speed servo lags more than the others (an extra first-order time constant; "
            "at most 0.6 s: the quasi-static plant finds no equilibrium for one wheel reversing much slower than the others)",
            (("time_constant", "s", 0.0, 0.6, 0.2, 1.0),),
            _term_build(f"wheel_lag.{w}", 0.0), ch, starts=((0.5,),), family=f"speed_{w}", null=(0.0,)))
        out.append(Candidate(
            f"speed_rate_limit_{w}", f"the {w} wheel-speed servo ramps at a bounded acceleration: its rim speed moves "
            "toward its command by at most a limit rate (an acceleration ramp or current limit in that wheel's motor "
            "controller); a family of its own, so it can join the wheel's speed cap or shortfall",
            (("accel_max", "m/s^2", 0.02, 1.0, 0.1, 1.0),),
            _term_build(f"rim_accel_max.{w}", 0.0), ch, starts=((0.05,), (0.2,), (0.5,)), threshold=True,
            family=f"slew_{w}"))
        out.append(Candidate(
            f"steer_saturation_{w}", f"the {w} steering servo saturates: the wheel cannot steer beyond a limit angle",
            (("steer_max", "deg", 1.0, 60.0, 20.0, _D),),
            _term_build(f"steer_max.{w}", 0.0), (f"torque_{w}", "yaw_rate", "dheading", "dy_body"),
            starts=((5.0,), (15.0,), (30.0,)), threshold=True, family=f"steer_{w}"))
    return [replace(c, screened=True) for c in out]


ACTUATOR_CANDIDATES: tuple[Candidate, ...] = tuple(_actuator_candidates())
"""Per-wheel actuator terms (issue 24): wheel-speed saturation (an absolute cap, and a shortfall
in proportion to the command), extra servo lag, a slew-rate limit (bounded acceleration) and
steering saturation of each wheel; part of :data:`DRIVE_CANDIDATES`, *screened*
(``Candidate.screened``): twenty more fits on every drive would cost each diagnosis about as much
again, so a term is fitted only on a wheel the data implicate -- a located region on that wheel's
own channels, or a free score on its own encoders (the wheel-speed encoder's segment rows for the
speed terms and the slew, the steering encoder's ticks for the steering cap) that reaches half of
what an accepted term must gain (:meth:`offline.discrepancy.drive.diagnosis.DriveRecording.screen`).
The family (``speed_<W>``, ``slew_<W>``, ``steer_<W>``) names the wheel and which encoder screens
it; the slew is a family of its own (it joins a wheel's cap in the forward step, as a rate limiter
in series with a saturation does) and is screened on top of its wheel's best speed term."""


def _wheel_candidates() -> list[Candidate]:
    out = []
    for w in WHEELS:
        out.append(Candidate(
            f"wheel_radius_{w}", f"the {w} wheel's radius differs from the believed one (wear, a flat, mis-measured)",
            (("radius_change", "%", -20.0, 20.0, 0.0, 1e-2),),
            _term_build(f"radius_scale.{w}", 1.0),
            (f"torque_{w}", "yaw_rate", "dheading", "dx_body", "dy_body"), family=f"radius_{w}", null=(0.0,)))
    for w in WHEELS:
        out.append(Candidate(
            f"steer_offset_{w}", f"the {w} wheel points elsewhere than its steering encoder says (true = encoder + offset)",
            (("offset", "deg", -10.0, 10.0, 0.0, _D),),
            _term_build(f"steer_offset.{w}", 0.0),
            (f"torque_{w}", "yaw_rate", "dheading", "dy_body"), family=f"steer_{w}", null=(0.0,)))
    return out


DRIVE_CANDIDATES: tuple[Candidate, ...] = (
    Candidate("terrain_slope", "the terrain is inclined: slope along and across the pose frame's x axis "
              "(gravity pulls the rover and tilts the IMU; the tilt turns with the heading)",
              (("slope", "deg", -15.0, 15.0, 0.0, _D), ("cross_slope", "deg", -15.0, 15.0, 0.0, _D)),
              lambda t, p: _opt(slope=t[0], cross_slope=t[1]),
              ("roll", "pitch", "torque_FR", "torque_FL", "torque_RR", "torque_RL", "dy_body"), family="slope", null=(0.0, 0.0)),
    Candidate("imu_tilt", "the IMU is mounted tilted: roll and pitch readings offset, no force on the rover",
              (("roll", "deg", -15.0, 15.0, 0.0, _D), ("pitch", "deg", -15.0, 15.0, 0.0, _D)),
              lambda t, p: _opt(imu_roll=t[0], imu_pitch=t[1]), ("roll", "pitch"), family="imu", null=(0.0, 0.0)),
    *_wheel_candidates(),
    Candidate("tether", "a tether or drawbar pulls the rover backward along its own -x axis (positive: pulls back)",
              (("force", "N", -10.0, 10.0, 0.0, 1.0),),
              lambda t, p: _opt(tether=t[0]), ("torque_FR", "torque_FL", "torque_RR", "torque_RL", "dx_body"), family="tether",
              null=(0.0,)),
    Candidate("tether_anchor", "a tether to a fixed anchor: a cable from a spring reel, from a point on the rover's x "
              "axis to an anchor fixed in the terrain (bearing from the start heading, 1 / distance from the start, "
              "at least 1 m away), so its pull turns with the rover's pose and grows with the cable paid out",
              (("tension", "N", 0.0, 10.0, 1.0, 1.0), ("bearing", "deg", 0.0, 360.0, 180.0, _D),
               ("inverse_distance", "1/m", 0.0, 1.0, 0.3, 1.0), ("attach_x", "m", -0.3, 0.3, 0.0, 1.0),
               ("spring_rate", "N/m", 0.0, 5.0, 0.0, 1.0)),
              lambda t, p: _opt(anchor_tension=t[0], anchor_bearing=t[1], anchor_inverse_distance=t[2],
                                anchor_attach_x=t[3], anchor_spring_rate=t[4]),
              ("torque_FR", "torque_FL", "torque_RR", "torque_RL", "dx_body", "dy_body", "yaw_rate", "dheading"),
              family="tether", null=(0.0, math.nan, math.nan, math.nan, math.nan), nuisance=("inverse_distance",)),
    Candidate("servo_lag", "the wheel-speed servos lag more than believed (first-order time constant)",
              (("time_constant", "s", 0.0, 2.0, 0.3, 1.0),),
              lambda t, p: _opt(wheel_lag=t[0]), ("omega_FR", "omega_FL", "omega_RR", "omega_RL"),
              starts=((1.0,),)),
    Candidate("torque_saturation", "the drive motors saturate at a lower torque than believed (the wheel slows)",
              (("torque_limit", "N m", 0.02, 1.5, 0.5, 1.0),),
              lambda t, p: _opt(torque_limit=t[0]), ("omega_FR", "omega_FL", "omega_RR", "omega_RL"),
              starts=((0.1,), (0.2,)), threshold=True),
    Candidate("hub_contact", "hub or body contact: once a wheel sinks beyond a clearance, a face bulldozes soil "
              "(Rankine passive pressure): a drag against the wheel's travel and a torque against its spin",
              (("clearance", "mm", 0.0, 60.0, 4.0, 1e-3), ("face_width", "mm", 0.0, 150.0, 40.0, 1e-3),
               ("arm", "mm", 0.0, 60.0, 20.0, 1e-3)),
              lambda t, p: _opt(hub_clearance=t[0], hub_face_width=t[1], hub_arm=t[2]),
              ("torque_FR", "torque_FL", "torque_RR", "torque_RL", "dx_body"),
              starts=((10.0, 40.0, 20.0),), threshold=True),
    Candidate("gyro_scale", "gyro scale-factor error: the yaw rate reads (1 + g) times the true rate",
              (("scale_error", "%", -30.0, 30.0, 0.0, 1e-2),),
              lambda t, p: _opt(gyro_scale=t[0]), ("yaw_rate",), null=(0.0,)),
    # --- parameters the believed model already has ("parameters off")
    Candidate("soil_stiffness", "the soil is stiffer or softer than believed: Bekker modulus k (eq. 5.6) scaled",
              (("k_scale", "-", 0.2, 5.0, 1.0, 1.0),),
              lambda t, p: RoverExtension(soil={"k": p.soil.k * float(t[0])}),
              ("torque_FR", "torque_FL", "torque_RR", "torque_RL", "dx_body"), kind="parameters", family="soil", null=(1.0,)),
    Candidate("wheel_radius_all", "every wheel's radius is off by the same fraction (the believed wheel radius)",
              (("radius_change", "%", -20.0, 20.0, 0.0, 1e-2),),
              lambda t, p: _opt(radius_scale_all=1.0 + float(t[0])), kind="parameters", family="radius_all", null=(0.0,)),
)
"""The rover-level library (module table)."""

BASE_DRIVE_CANDIDATES: tuple[Candidate, ...] = DRIVE_CANDIDATES
"""The rover-level library without the per-wheel actuator terms (the default library before issue 24)."""

DRIVE_CANDIDATES = BASE_DRIVE_CANDIDATES + ACTUATOR_CANDIDATES
"""The rover-level library (module table): the base terms, always fitted, and the per-wheel
actuator terms, fitted on the wheels the screen admits (:data:`ACTUATOR_CANDIDATES`)."""

DRIVE_CANDIDATES_WITH_ACTUATORS: tuple[Candidate, ...] = BASE_DRIVE_CANDIDATES + tuple(
    replace(c, screened=False) for c in ACTUATOR_CANDIDATES)
"""The rover-level library with every per-wheel actuator term fitted on every drive, unscreened
(``offnominal discrepancy --recording ... --per-wheel-actuators``: slower; what the screen is
checked against on the benchmark)."""


WHEEL_DRAG = Candidate(
    "wheel_drag", "the same resisting force at every wheel's contact against its travel (hub or body faces, a rolling "
    "resistance the soil model lacks)",
    (("force", "N", -3.0, 3.0, 0.0, 1.0),), lambda t, p: _opt(wheel_drag=t[0]),
    ("torque_FR", "torque_FL", "torque_RR", "torque_RL", "dx_body"), family="wheel_drag", null=(0.0,), starts=((0.5,),))
"""A look-alike probe of the identifiability rule (:data:`WRENCH_LOOKALIKES`), not part of the library:
:class:`WheelDrag`, one parameter (N per wheel)."""

WRENCH_LOOKALIKES: dict[str, str] = {
    "tether": "a pull at the body", "tether_anchor": "a pull at the body",
    "hub_contact": "drags at the wheels", "wheel_drag": "drags at the wheels",
    "soil_stiffness": "a softer or stiffer soil", "recalibration": "a softer or stiffer soil",
}
"""Candidates that can give the same body wrench on a drive -- a resisting force along the travel,
paid for by every wheel's slip and torque -- keyed to what each claims (issue 24, "never a confident
wrong name"): on a straight drive a pull at the body, per-wheel drags summing to the same force and
a softer soil are look-alikes; a turn, a reverse leg or a change of slope separates them
(:data:`SEPARATING_MANOEUVRES`). The engine's identifiability rule
(:func:`offline.discrepancy.engine.diagnose`, step 6) refits one probe per other claim
(:data:`LOOKALIKE_PROBES`) in place of an accepted term of this table."""

LOOKALIKE_PROBES: tuple[str, ...] = ("tether", "wheel_drag", "soil_stiffness")
"""One one-parameter probe per claim of :data:`WRENCH_LOOKALIKES`: a constant pull at the body along
its -x axis, the same drag at every wheel's contact (:data:`WHEEL_DRAG`), the soil's Bekker k scaled."""

SEPARATING_MANOEUVRES: dict[frozenset[str], str] = {
    frozenset({"a pull at the body", "drags at the wheels"}): (
        "a drive in the other direction (a pull keeps its direction on the rover or in the terrain and helps a reverse "
        "leg; drags turn with each wheel's travel) or a turn (drags at the wheels resist the yaw, a pull at the centre "
        "does not)"),
    frozenset({"a pull at the body", "a softer or stiffer soil"}): (
        "a drive in the other direction (a pull helps a reverse leg, a softer soil resists both ways) or a change of "
        "slope (the wheel loads: a soil's resistance grows with the sinkage, a pull does not)"),
    frozenset({"drags at the wheels", "a softer or stiffer soil"}): (
        "a change of slope or of the load per wheel (a soil's resistance grows with the sinkage, a constant drag "
        "does not) or a point turn (the soil's lateral resistance changes with the slip angle)"),
}
"""What separates each pair of claims of :data:`WRENCH_LOOKALIKES` (the manoeuvres named in an
'ambiguous' verdict; the recording's own advice says which of them it lacks)."""


def lookalike_probes(scenario: Any) -> tuple[Candidate, ...]:
    """The probes of :data:`LOOKALIKE_PROBES` for the rover of ``scenario`` (force bounds scaled to
    a rover file's weight as the library's are, :func:`offline.discrepancy.drive.wheel_set.library_for`)."""
    from .wheel_set import _rescaled, rover_scales

    lib = {c.key: c for c in (*BASE_DRIVE_CANDIDATES, WHEEL_DRAG)}
    force, length = rover_scales(scenario)
    out = []
    for key in LOOKALIKE_PROBES:
        c = lib[key]
        c = _rescaled(c, force, length) if (force, length) != (1.0, 1.0) else c
        if getattr(scenario, "rover_file", None) is not None:
            from .wheel_set import _channels

            c = replace(c, channels=_channels(c.channels, tuple(scenario.wheels)))
        out.append(c)
    return tuple(out)


__all__ += ["WHEEL_DRAG", "WheelDrag", "WRENCH_LOOKALIKES", "LOOKALIKE_PROBES", "SEPARATING_MANOEUVRES", "lookalike_probes"]


TABLE_BUILDER_TAKES: dict[str, str] = {
    "terrain_slope": "yes: the slope / cross_slope axes of the table",
    "soil_stiffness": "yes: the parameter file's soil k",
    "recalibration": "yes: the parameter file's soil (recalibrated.toml)",
    "wheel_radius_all": "yes: the parameter file's wheel radius",
    "torque_saturation": "yes: a torque_limit_Nm failure on every wheel in the scenario file",
    **{f"speed_saturation_{w}": f"partly: a rim_speed_max failure on {w} in the scenario file caps its forward rim speed"
       for w in WHEELS},
    **{f"servo_lag_{w}": "no: a dynamic effect the steady-state tables have no place for" for w in WHEELS},
    **{f"speed_rate_limit_{w}": "no: a dynamic effect the steady-state tables have no place for" for w in WHEELS},
    **{f"speed_shortfall_{w}": "no: the tables assume the commanded rim speed is reached" for w in WHEELS},
    **{f"steer_saturation_{w}": "no: the tables assume the full steering range (a steer_stuck failure is the nearest)"
       for w in WHEELS},
    **{f"wheel_radius_{w}": "yes: [wheels.<W>] radius_mm (--world): that wheel's radius in the NLP, the table header "
                            "and rtctl's odometry (rim-speed commands keep the command radius)" for w in WHEELS},
    **{f"steer_offset_{w}": "yes: [wheels.<W>] steer_offset_deg (--world): steering limits and stuck angles in encoder "
                            "terms, the table header and rtctl's commands (beta - offset)" for w in WHEELS},
    "tether": "yes: tether_force_N (--world): a constant pull along -x in the balance (7.12)",
    "hub_contact": "yes: [hub_contact] (--world): a Rankine drag per wheel against its travel and a torque F arm against "
                   "its spin in the NLP (rtctl.physics.hub_drag; depth smoothed over 0.1 mm), in the stored wheel "
                   "wrenches and Jacobians and the table header",
    "tether_anchor": "yes: [tether_anchor] (--world): tension at its bearing from the attachment, a constant body-frame "
                     "force and yaw moment in the steady state (anchor distance and spring rate not used)",
    "servo_lag": "no: a dynamic effect; steady-state tables have no place for it",
    "imu_tilt": "not applicable: acts on the readings only",
    "gyro_scale": "not applicable: acts on the readings only",
}
"""Whether the table builder takes each candidate's fitted parameters (module notes)."""


def recalibration_candidate(params: ParameterSet) -> Candidate:
    """The soil recalibration: k (as a scale), n0, c, phi and K refitted together, starting at the
    believed values ("parameters off" when it explains the drive as well as any term)."""
    s = params.soil
    specs = (("k_scale", "-", 0.2, 5.0, 1.0, 1.0), ("n0", "-", 0.3, 2.0, float(np.clip(s.n0, 0.3, 2.0)), 1.0),
             ("c", "kPa", 0.0, 10.0, float(np.clip(s.cohesion / 1e3, 0.0, 10.0)), 1e3),
             ("phi", "deg", 15.0, 50.0, float(np.clip(math.degrees(s.friction_angle), 15.0, 50.0)), _D),
             ("K", "mm", 1.0, 100.0, float(np.clip(s.shear_modulus * 1e3, 1.0, 100.0)), 1e-3))

    def build(t: NDArray[np.float64], p: ParameterSet) -> RoverExtension:
        return RoverExtension(soil={"k": p.soil.k * float(t[0]), "n0": float(t[1]), "cohesion": float(t[2]),
                               "friction_angle": float(t[3]), "shear_modulus": float(t[4])})

    return Candidate("recalibration", "the believed soil parameters are off: k, n0, c, phi, K refitted "
                     "(eqs. 5.6, 5.10)", specs, build,
                     ("torque_FR", "torque_FL", "torque_RR", "torque_RL", "dx_body", "dy_body"),
                     kind="parameters", family="recalibration")


def truth_from_terms(params: ParameterSet, base: Truth, ext: RoverExtension, wheels: Sequence[str] = WHEELS
                     ) -> tuple[Truth, dict[str, float] | None, dict[str, float]]:
    """The simulator's view of an extension: a truth, actuator overrides and measurement terms.

    Parameters
    ----------
    params : ParameterSet
        The believed parameter set (soil changes of ``ext`` are applied to it).
    base : Truth
        The believed world (flat, nominal wheels) the terms are added to.
    ext : RoverExtension
    wheels : sequence of str
        The wheel names of ``base``'s per-wheel tuples (default the mini rover's; a rover file's
        wheels for its rover, issue 23).

    Returns
    -------
    truth : Truth
    actuator_changes : dict or None
        ``{"wheel_lag": s, "torque_limit": N m}`` entries to replace in the believed
        :class:`~offline.sim.actuators.ActuatorConfig` (None when unchanged).
    measurement : dict
        ``imu_roll``, ``imu_pitch`` (rad), ``gyro_scale`` (relative).
    """
    t = rover_terms(ext)
    if len(wheels) != len(base.wheel_radius):
        raise DriveCandidateError(f"the believed world has {len(base.wheel_radius)} wheel radii, the wheel set "
                                  f"{list(wheels)} has {len(wheels)} wheels: pass the rover's wheels")
    ps = params if not ext.soil else replace(params, soil=replace(params.soil, **dict[str, Any](ext.soil)))
    r_all = t.get("radius_scale_all", 1.0)
    radius = cast(tuple[float, float, float, float],
                  tuple(base.wheel_radius[i] * r_all * t.get(f"radius_scale.{w}", 1.0) for i, w in enumerate(wheels)))
    offset = cast(tuple[float, float, float, float],
                  tuple(base.steer_offset[i] + t.get(f"steer_offset.{w}", 0.0) for i, w in enumerate(wheels)))
    if min(radius) <= ps.wheel.grouser_height:
        raise DriveCandidateError(f"wheel radii {radius} m do not exceed the grouser height")
    truth = replace(base, params=ps, wheel_radius=radius, steer_offset=offset,
                    slope=base.slope + t.get("slope", 0.0), cross_slope=base.cross_slope + t.get("cross_slope", 0.0),
                    tether_force=base.tether_force + t.get("tether", 0.0))
    act = {k: t[k] for k in ("wheel_lag", "torque_limit") if k in t}
    meas = {"imu_roll": t.get("imu_roll", 0.0), "imu_pitch": t.get("imu_pitch", 0.0),
            "gyro_scale": t.get("gyro_scale", 0.0)}
    return truth, (act or None), meas


_HOOK_KEYS = {"tether_anchor": {"anchor_tension_N": ("tension_N", 1.0), "anchor_bearing_rad": ("bearing_deg", 180 / math.pi),
                                "anchor_inverse_distance_per_m": ("inverse_distance_per_m", 1.0),
                                "anchor_attach_x_m": ("attach_x_m", 1.0),
                                "anchor_spring_rate_N_per_m": ("spring_rate_N_per_m", 1.0)},
              "hub_contact": {"hub_clearance_m": ("clearance_mm", 1e3), "hub_face_width_m": ("face_width_mm", 1e3),
                              "hub_arm_m": ("arm_mm", 1e3)}}


def write_truth_toml(path: str | Path, params_file: str, truth: Truth, believed: Truth, measurement: Mapping[str, float],
                     actuator: Mapping[str, float] | None, header: Mapping[str, Any],
                     disturbance: Mapping[str, float] | None = None,
                     empirical: Sequence[Mapping[str, Any]] = (), wheels: Sequence[str] = WHEELS) -> Path:
    """Write the accepted terms as a truth file :func:`offline.sim.truth.load_truth` reads.

    Only what differs from the believed world is written. Terms the truth format has no key
    for (IMU tilt, gyro scale, servo lag, torque limit) go to a ``[sensors_and_actuators]``
    comment block with their values, since they belong to the sensor and actuator
    configuration, not to the world; ``disturbance`` (hub contact, anchored tether: their
    parameters, SI, keys ``anchor_tension_N`` ... ``hub_arm_m``) goes to the truth format's
    ``[tether_anchor]`` and ``[hub_contact]`` sections; ``empirical`` (the ``[[empirical_force]]``
    tables of :func:`offline.discrepancy.drive.empirical.truth_entries`) goes to that array of tables.
    ``header`` lines become comments (fitted values, standard errors, held-out improvement).
    ``wheels``: the names of the truths' per-wheel tuples (a rover file's wheels, issue 23).
    """
    lines = ["# written by offline.discrepancy.drive.report: the accepted discrepancy terms as a truth file",
             "# (offline.sim.truth.load_truth reads it; the simulator and the table builder take it)"]
    lines += [f"# {k}: {v}" for k, v in header.items()]
    lines += ["", "[truth]", f'params = "{params_file}"']
    kb, kt = believed.params.soil.k, truth.params.soil.k
    if abs(kt / kb - 1.0) > 1e-12:
        lines.append(f"soil_stiffness_scale = {kt / kb:.6g}")
    for key, a, b in (("slope_deg", truth.slope, believed.slope), ("cross_slope_deg", truth.cross_slope, believed.cross_slope)):
        if a != b:
            lines.append(f"{key} = {math.degrees(a):.6g}")
    if truth.tether_force != believed.tether_force:
        lines.append(f"tether_force_N = {truth.tether_force:.6g}")
    other = {f: (getattr(truth.params.soil, f), getattr(believed.params.soil, f))
             for f in ("n0", "cohesion", "friction_angle", "shear_modulus") if getattr(truth.params.soil, f) != getattr(believed.params.soil, f)}
    if other:
        lines.append("# soil fields refitted (not keys of the truth format; put them in the parameter file's [soil]):")
        lines += [f"#   {f} = {a:.6g} (believed {b:.6g}, SI)" for f, (a, b) in other.items()]
    for i, w in enumerate(wheels):
        wl = []
        if truth.wheel_radius[i] != believed.wheel_radius[i]:
            wl.append(f"radius_mm = {1e3 * truth.wheel_radius[i]:.6g}")
        if truth.steer_offset[i] != believed.steer_offset[i]:
            wl.append(f"steer_offset_deg = {math.degrees(truth.steer_offset[i]):.6g}")
        if wl:
            lines += ["", f"[wheels.{w}]", *wl]
    hub = {k: v for k, v in (disturbance or {}).items()}
    for section, keys in _HOOK_KEYS.items():  # real sections of the truth format (load_truth reads them)
        got = [(dst, hub.pop(src) * f) for src, (dst, f) in keys.items() if src in hub]
        if got:
            lines += ["", f"[{section}]", *(f"{k} = {v:.6g}" for k, v in got)]
    if hub:
        lines += ["", "# disturbance parameters the truth format has no key for, SI:"]
        lines += [f"#   {k} = {v:.6g}" for k, v in hub.items()]
    for e in empirical:
        lines += ["", "[[empirical_force]]"]
        lines += [f'{k} = "{v}"' if isinstance(v, str) else f"{k} = {float(v)!r}" for k, v in e.items()]
    extra = {k: v for k, v in measurement.items() if v}
    extra.update(actuator or {})
    if extra:
        lines += ["", "# sensors and actuators (SensorConfig / ActuatorConfig, SI), not part of the truth format:"]
        lines += [f"#   {k} = {v:.6g}" for k, v in extra.items()]
    return write_text(path, "\n".join(lines) + "\n")
