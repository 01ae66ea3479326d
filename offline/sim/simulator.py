"""The simulated rover (the mini rover, or a rover file's): plant, actuators and sensors behind the controller's message types.

:class:`RoverSimulator` consumes :class:`rtctl.messages.Commands` and produces
:class:`rtctl.messages.Measurements`, so the same controller code drives it and the rover.
Fixed step (``dt``), seeded, deterministic bit for bit: the same seed, truth and command
sequence give the same run.

A tick of a closed loop::

    sim = RoverSimulator(scenario, truth, seed=1)
    sim.start(first_commands)
    while ...:
        m = sim.measure()
        cmd, _ = controller.step(m)
        sim.apply(cmd)
        sim.advance(0.2)

External forces (a disturbance hook, contract C5): ``RoverSimulator(..., disturbance=f)`` with
``f(t, truth_state) -> DisturbanceForces`` evaluated once at the start of every plant step
(and once at ``start``); the forces are held over the step. ``None`` (the default) runs the
undisturbed equations bit for bit.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from rtctl.messages import WHEELS, Commands, FailureDeclaration, Measurements, Pose

from rtctl.physics.rover_file import RoverSpec

from ..physics.params import ParameterSet, Rover
from ..physics.terramechanics import ModelOptions
from ..rover.scenario import Scenario
from .actuators import ActuatorConfig, Actuators
from .plant import DISTURBANCE_NAMES, GRAVITY, STICTION_SPEED, PlantModel, PlantSolution, SimulationError
from .sensors import GyroBias, PoseSource, SensorConfig
from .suspension_plant import SuspensionPlant, suspension_yaw_inertia
from .truth import Truth

__all__ = ["RoverSimulator", "TruthState", "plant_for", "suspension_plant_for", "rover_file_truth", "rover_file_actuators",
           "declared_failures", "SimulationError", "RoverStuck", "WheelLiftOff",
           "Disturbance",
           "DisturbanceForces", "DisturbanceError", "DISTURBANCE_NAMES"]


class RoverStuck(SimulationError):
    """The rover stalled and a wheel dug in below its axle: the simulation cannot go on (the wheel
    model holds to an entry angle of 90 deg). A drive ends here (:func:`offline.sim.experiments.run_drive`)."""


class WheelLiftOff(SimulationError):
    """A step failed with a wheel unloaded to its grouser height: the rover is about to lift the
    wheel off the ground, which the plant does not model (every wheel is in contact or declared
    raised). A drive ends here (:func:`offline.sim.experiments.run_drive`), said in its result."""


@functools.lru_cache(maxsize=8)
def plant_for(params: ParameterSet, rover: Rover, exit_angle: str = "classic", compiled: bool = True) -> PlantModel:
    """A cached :class:`PlantModel` (the soil enters per call, so one serves many truths)."""
    opts = ModelOptions(exit_angle=exit_angle, shear_direction_smoothing=1e-6)  # type: ignore[arg-type]
    return PlantModel(params, rover, opts, compiled=compiled)


@functools.lru_cache(maxsize=8)
def suspension_plant_for(params: ParameterSet, spec: RoverSpec, exit_angle: str = "classic", compiled: bool = True,
                         pitch_includes_wheel_torque: bool = True) -> SuspensionPlant:
    """A cached :class:`offline.sim.suspension_plant.SuspensionPlant` of a rover file (the soil
    enters per call)."""
    opts = ModelOptions(exit_angle=exit_angle, shear_direction_smoothing=1e-6)  # type: ignore[arg-type]
    return SuspensionPlant(params, spec, opts, compiled=compiled, pitch_includes_wheel_torque=pitch_includes_wheel_torque)


def rover_file_truth(sc: Scenario, plant: SuspensionPlant) -> Truth:
    """The world a rover file's tables believe in: the scenario's wheel on every wheel of the
    file, flat ground, no tether; mass the file's weight over its gravity, yaw inertia
    :func:`offline.sim.suspension_plant.suspension_yaw_inertia`, wheel spin inertia
    :meth:`SuspensionPlant.default_wheel_inertia` (estimates, stated there).

    Parameters
    ----------
    sc : Scenario
        A scenario with a rover file.
    plant : SuspensionPlant
    """
    spec = plant.spec
    n = len(spec.wheels)
    radius = tuple(sc.params.wheel.radius if sc.rim_radius(k) is None else float(sc.rim_radius(k) or 0.0)
                   for k in spec.wheel_names)
    offset = tuple(sc.offset(k) for k in spec.wheel_names)
    return Truth(params=sc.params, wheel_radius=radius, steer_offset=offset if any(offset) else (0.0,) * n,  # type: ignore[arg-type]
                 slope=sc.slope, cross_slope=sc.cross_slope, mass=spec.weight / plant.gravity,
                 yaw_inertia=suspension_yaw_inertia(spec), wheel_inertia=plant.default_wheel_inertia(),
                 source=f"nominal world of {spec.name} (rover file {spec.path or spec.name})")


def rover_file_actuators(spec: RoverSpec, rs: float) -> ActuatorConfig:
    """The servos of a rover file (its ``[actuators]`` section): drive torque limit, largest rim
    speed ``drive_speed_max * r_s``, steering rate and the widest steering range of its wheels;
    the wheel-speed lag is :class:`ActuatorConfig`'s default.

    Parameters
    ----------
    spec : RoverSpec
    rs : float
        Shearing radius of the wheels, m.
    """
    act = spec.actuators
    lim = max([max(abs(w.steer_min), abs(w.steer_max)) for w in spec.wheels if w.steerable] or [math.pi / 2])
    base = ActuatorConfig()
    return ActuatorConfig(steer_rate_max=act.steer_rate_max or base.steer_rate_max, steer_limit=lim,
                          torque_limit=act.drive_torque_max, max_rim_speed=act.drive_speed_max * rs)


def declared_failures(sc: Scenario) -> tuple[FailureDeclaration, ...]:
    """The failures of a scenario as the rover's fault management declares them: every failure
    kind the rover can declare (``ROVER_KIND``) with its declared value
    (:meth:`offline.rover.failures.FailureKind.declared_value`); a constraint that is part of the
    scenario's task (:func:`offline.rover.failures.with_task`) is not a failure."""
    from ..rover.failures import with_task

    out = []
    for k in sc.wheels:
        for kind in sc.failure(k).kinds():
            if kind.ROVER_KIND and not with_task(kind, k, sc.trench):
                out.append(FailureDeclaration(k, kind.ROVER_KIND, kind.declared_value()))
    return tuple(out)


class DisturbanceError(ValueError):
    """A disturbance hook returned something the simulator cannot apply (wrong type, shape,
    or a non-finite value); the message names the field and the time."""


def _floats(name: str, v: Any, n: int | None) -> Any:
    """``v`` as a float (``n is None``) or a tuple of ``n`` floats, finite, else DisturbanceError."""
    try:
        vals: tuple[float, ...] = (float(v),) if n is None else tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise DisturbanceError(f"DisturbanceForces.{name} must be {'a number' if n is None else f'{n} numbers'}, "
                               f"got {v!r}") from None
    out: Any = vals[0] if n is None else vals
    if n is not None and len(vals) != n:
        raise DisturbanceError(f"DisturbanceForces.{name} must have {n} entries, got {len(vals)}: {v!r}")
    if not all(math.isfinite(x) for x in vals):
        raise DisturbanceError(f"DisturbanceForces.{name} must be finite (N, N m), got {v!r}")
    return out


@dataclass(frozen=True)
class DisturbanceForces:
    """External forces on the rover over one plant step (SI; rover body frame: x forward, y left).

    Attributes
    ----------
    body_force : (float, float)
        Force at the centre of mass, N (enters the planar balances like the truth's tether;
        ``(-k, 0)`` is a drawbar pull ``k`` backwards).
    body_moment_z : float
        Yaw moment about the centre of mass, N m (positive turns left).
    wheel_force : N x (fx, fy)
        Extra force at each wheel, N, in the simulator's wheel order (the mini rover's FR, FL, RR,
        RL; a rover file's wheels in its order, :attr:`RoverSimulator.wheels`). It adds to that
        wheel's soil force: it acts at the wheel's plan position (a yaw moment about the centre of
        mass) and enters the roll and pitch (rocker, bogie) balances where the soil force does; it
        exerts no torque on the wheel's spin (use ``wheel_torque`` for that).
    wheel_torque : N float
        Extra torque resisting each wheel's spin, N m (hub drag; positive opposes positive
        omega): a speed-servoed wheel's motor supplies it, a torque-mode wheel
        (unpowered or at its torque limit) is slowed by it.

    The defaults are four zeros (the mini rover's wheels); all-zero per-wheel entries fit a rover
    of any wheel count (a body-only hook such as an anchored tether serves every rover), while
    non-zero ones must have one entry per wheel of the simulated rover (:meth:`vector`).
    """

    body_force: tuple[float, float] = (0.0, 0.0)
    body_moment_z: float = 0.0
    wheel_force: tuple[tuple[float, float], ...] = ((0.0, 0.0),) * 4
    wheel_torque: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "body_force", _floats("body_force", self.body_force, 2))
        object.__setattr__(self, "body_moment_z", _floats("body_moment_z", self.body_moment_z, None))
        wf = self.wheel_force
        if isinstance(wf, (str, bytes)) or not hasattr(wf, "__len__") or len(wf) < 1:
            raise DisturbanceError(f"DisturbanceForces.wheel_force must be one pair (fx, fy) per wheel (the mini rover: "
                                   f"4, in the order FR, FL, RR, RL), got {wf!r}")
        object.__setattr__(self, "wheel_force", tuple(_floats(f"wheel_force[{i}]", w, 2) for i, w in enumerate(wf)))
        wt = self.wheel_torque
        if isinstance(wt, (str, bytes)) or not hasattr(wt, "__len__") or len(wt) < 1:
            raise DisturbanceError(f"DisturbanceForces.wheel_torque must be one number per wheel (the mini rover: 4, in "
                                   f"the order FR, FL, RR, RL), got {wt!r}")
        object.__setattr__(self, "wheel_torque", _floats("wheel_torque", wt, len(wt)))

    def vector(self, wheels: int = 4) -> NDArray[np.float64]:
        """The plant's disturbance vector for a rover of ``wheels`` wheels: ``(F_x, F_y, M_z,
        fx per wheel, fy per wheel, torque per wheel)`` (the mini rover's:
        :data:`offline.sim.plant.DISTURBANCE_NAMES`; a rover file's plant takes the same layout
        with its ``N``, :meth:`offline.sim.suspension_plant.SuspensionPlant.evaluate`).

        Raises
        ------
        DisturbanceError
            A per-wheel entry with non-zero values has another length than ``wheels``.
        """
        fx = self._per_wheel("wheel_force", tuple(f[0] for f in self.wheel_force), wheels)
        fy = self._per_wheel("wheel_force", tuple(f[1] for f in self.wheel_force), wheels)
        tq = self._per_wheel("wheel_torque", self.wheel_torque, wheels)
        return np.array([*self.body_force, self.body_moment_z, *fx, *fy, *tq], dtype=float)

    def _per_wheel(self, name: str, v: tuple[float, ...], wheels: int) -> tuple[float, ...]:
        if len(v) == wheels:
            return v
        if not any(v):
            return (0.0,) * wheels
        raise DisturbanceError(f"DisturbanceForces.{name} has {len(v)} entries; the simulated rover has {wheels} wheels "
                               f"(one entry per wheel, in the simulator's wheel order)")


class Disturbance(Protocol):
    """A disturbance hook: called once at the start of each plant step with the time and the
    true state then, it returns the forces held over the step. It must be deterministic (it may
    keep its own seeded random generator)."""

    def __call__(self, t: float, s: "TruthState") -> DisturbanceForces:
        """Forces to apply over the step that starts at ``t`` in state ``s``."""
        ...


@dataclass(frozen=True)
class TruthState:
    """What really happened at one instant (for recordings' truth channel and metrics).

    ``disturbance`` holds the external forces applied over the step that ended at ``t``
    (``None`` without a hook); ``gyro_bias`` is the gyro's true yaw-rate bias now, rad/s.
    """

    t: float
    x: float
    y: float
    heading: float
    u: float
    v: float
    yaw_rate: float
    omega: tuple[float, ...]
    steer: tuple[float, ...]
    sinkage: tuple[float, ...]
    load: tuple[float, ...]
    slip: tuple[float, ...]
    slip_angle: tuple[float, ...]
    motor_torque: tuple[float, ...]
    travelled: float
    disturbance: DisturbanceForces | None = None
    gyro_bias: float = 0.0

    @property
    def v_x(self) -> float:
        """Forward body velocity, m/s (same as ``u``)."""
        return self.u

    @property
    def v_y(self) -> float:
        """Leftward body velocity, m/s (same as ``v``)."""
        return self.v

    @property
    def h(self) -> tuple[float, ...]:
        """Per-wheel sinkage, m (same as ``sinkage``)."""
        return self.sinkage

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able values (the disturbance as a nested mapping, or ``None``)."""
        out: dict[str, Any] = {}
        for k, v in self.__dict__.items():
            if isinstance(v, DisturbanceForces):
                v = {"body_force": list(v.body_force), "body_moment_z": v.body_moment_z,
                     "wheel_force": [list(f) for f in v.wheel_force], "wheel_torque": list(v.wheel_torque)}
            out[k] = list(v) if isinstance(v, tuple) else v
        return out


class RoverSimulator:
    """A rover driving on a slope, with failures, actuators and sensors: the mini rover of
    Table 7.2, or the rover of a scenario's rover file (issue 23).

    A rover-file scenario (six-wheel rocker-bogie, rigid skid-steer, ...) runs on its own plant,
    :class:`offline.sim.suspension_plant.SuspensionPlant` (the optimizer's wheel model and
    suspension rows), with the file's wheels in its order in every per-wheel vector of the
    measurements, commands and truth (:attr:`wheels`). A backward drive (the scenario's rover
    file turned half round, :func:`rtctl.physics.rover_file.driving_backward`) is simulated in
    the travel frame; its sensors and commands are in the rover's body frame, as the rover's
    would be (:meth:`measure`, :meth:`apply`); a disturbance hook sees the true state and
    gives its forces in that travel frame (the plant's). Not for rover files in this version:
    raised wheels.

    Parameters
    ----------
    scenario : Scenario
        Failures to inject (``[wheels.*]`` of the scenario file) and the believed parameter
        set (its wheel's shearing radius converts rim-speed commands to wheel speeds).
    truth : Truth, optional
        The simulated world (default: the scenario's parameters, flat, no tether; for a rover
        file :func:`rover_file_truth`, one radius per wheel of the file).
    actuators, sensors : ActuatorConfig, SensorConfig, optional
        Servo limits and dynamics; sensor noise and rates (defaults: the classes' defaults; for a
        rover file the servos of its ``[actuators]``, :func:`rover_file_actuators`).
    dt : float
        Fixed plant step, s (the 5 Hz control period should be a multiple).
    seed : int
        Seeds every noise source.
    compiled : bool
        C-compile the wheel forces (cached on disk); ``False`` uses casadi's virtual
        machine (slower, the same numbers to rounding).
    disturbance : Disturbance, optional
        External forces (contract C5): called once at the start of each step, held over it;
        ``None`` runs the undisturbed equations bit for bit.

    Notes
    -----
    The yaw inertia of the truth is our own estimate (:func:`offline.sim.plant.default_yaw_inertia`;
    the dissertation gives none).
    """

    def __init__(self, scenario: Scenario, truth: Truth | None = None, actuators: ActuatorConfig | None = None,
                 sensors: SensorConfig | None = None, dt: float = 0.1, seed: int = 0, compiled: bool = True,
                 disturbance: Disturbance | None = None) -> None:
        if not (math.isfinite(dt) and 1e-4 <= dt <= 1.0):
            raise ValueError(f"dt must be in [1e-4, 1] s, got {dt!r}")
        rf = getattr(scenario, "rover_file", None)
        self.rover_file: RoverSpec | None = rf
        self.wheels: tuple[str, ...] = tuple(scenario.wheels)
        n = self.n = len(self.wheels)
        # a backward drive's rover file is turned half round (the table builder's rule, wheel_set_header)
        self.backward = bool(rf is not None and rf.name.endswith(" (backward)"))
        self.scenario = scenario
        if rf is None:
            self.truth = truth or Truth.nominal(scenario.params, scenario.rover)
            self.plant: PlantModel | SuspensionPlant = plant_for(self.truth.params, scenario.rover, scenario.exit_angle,
                                                                 compiled)
        else:  # a rover file: its suspension's plant (the optimizer's statics), in the travel frame
            params = truth.params if truth is not None else scenario.params
            self.plant = suspension_plant_for(params, rf, scenario.exit_angle, compiled)
            self.truth = truth or rover_file_truth(scenario, self.plant)
            if len(self.truth.wheel_radius) != n:
                raise SimulationError(f"scenario {scenario.name}: the truth gives {len(self.truth.wheel_radius)} wheel "
                                      f"radii; the rover file of {rf.name} has {n} wheels ({', '.join(self.wheels)})")
            if actuators is None:
                actuators = rover_file_actuators(rf, scenario.params.wheel.shearing_radius)
        self.q = self.truth.vector()
        self.rs_true = np.asarray(self.truth.wheel_radius) + self.truth.params.wheel.grouser_height
        self.act = Actuators(actuators or ActuatorConfig(), dict(scenario.failures), scenario.params.wheel.shearing_radius,
                             wheels=self.wheels)
        self.sensors = sensors or SensorConfig()
        self.dt = dt
        self.rng = np.random.default_rng(seed)
        self.pose_source = PoseSource(self.sensors, self.rng)
        self.gyro_bias = GyroBias(self.sensors, seed)
        self.failures = declared_failures(scenario)
        self.t = 0.0
        self.seq = 0
        self.steps = 0
        self.x = self.y = self.heading = 0.0
        self.travelled = 0.0
        self.z = np.zeros(3 + 3 * n)
        self.sol: PlantSolution | None = None
        self.mode = np.ones(n)
        self.torque = np.zeros(n)
        self.newton_iterations = 0
        self.substepped = 0  # steps that needed sub-steps (see :meth:`step`)
        self.contact = self.act.contact()
        self.motor = np.zeros(n)
        if disturbance is not None and not callable(disturbance):
            raise DisturbanceError(f"disturbance must be a callable (t, TruthState) -> DisturbanceForces, got {disturbance!r}")
        self.disturbance = disturbance
        self.applied: DisturbanceForces | None = None  # forces held over the current (last) step
        self._d: NDArray[np.float64] | None = None

    # ------------------------------------------------------------------ plant
    def _inputs(self, inv_dt: float) -> NDArray[np.float64]:
        steer = self.act.steer + np.asarray(self.truth.steer_offset)
        if self.rover_file is not None:  # every wheel on the ground (no contact inputs)
            return np.concatenate([self.act.omega_servo, self.mode, self.torque, steer,
                                   self.z[:3], [self.heading, inv_dt], self.z[3:3 + self.n]])
        return np.concatenate([self.act.omega_servo, self.mode, self.torque, steer,
                               self.z[:3], [self.heading, inv_dt], self.z[3:7], self.contact])

    def _solve(self, inv_dt: float) -> None:
        base_mode, base_torque = self.act.drive_modes()
        self.mode, self.torque = base_mode.copy(), base_torque.copy()
        z_last: NDArray[np.float64] | None = None
        for _ in range(6):  # active set of the torque limits
            try:
                z, sol = self.plant.solve(self.z, self._inputs(inv_dt), self.q, self._d)
            except SimulationError:
                if z_last is None:
                    raise
                # the drive modes changed: start from the last active set's root instead, and
                # failing that with the wheels now held at their torque limit nearly stalled (a
                # motor at its limit against a wheel at slip 1 on a rover at rest turns it at the
                # speed where the resting soil's moment drops to the limit, see plant._stiction)
                try:
                    z, sol = self.plant.solve(z_last, self._inputs(inv_dt), self.q, self._d)
                except SimulationError:
                    zs = z_last.copy()
                    held = (self.mode == 0) & (base_mode == 1)
                    zs[3:3 + self.n] = np.where(held, 1e-3 * zs[3:3 + self.n], zs[3:3 + self.n])
                    z, sol = self.plant.solve(zs, self._inputs(inv_dt), self.q, self._d)
            z_last = z
            self.newton_iterations += sol.iterations
            motor = self._motor(sol, inv_dt)
            changed = False
            for i in range(self.n):
                lim = self.act.torque_limit(i)
                if base_mode[i] == 0:
                    continue
                if self.mode[i] == 1 and abs(motor[i]) > lim * (1 + 1e-9):
                    self.mode[i], self.torque[i] = 0.0, math.copysign(lim, motor[i])
                    changed = True
                elif self.mode[i] == 0 and math.copysign(1.0, self.torque[i]) * (sol.omega[i] - self.act.omega_servo[i]) > 1e-12:
                    self.mode[i], self.torque[i] = 1.0, 0.0  # the limit torque would overshoot: the servo holds its speed again
                    changed = True
            if not changed:
                break
        self.z, self.sol, self.motor = z, sol, motor
        # a wheel held at its torque limit turns at the speed the soil allows; the servo tracks it
        held = (self.mode == 0) & (base_mode == 1)
        self.act.omega_servo = np.where(held, sol.omega, self.act.omega_servo)

    def _motor(self, sol: PlantSolution, inv_dt: float) -> NDArray[np.float64]:
        """Motor torque per wheel over the step just solved: it balances the soil's axle moment,
        any hub drag and the wheel's spin inertia, ``T = J (omega - omega_prev)/dt - M_y + tau_d``
        (``self.z`` still holds the previous step's unknowns)."""
        motor = -sol.wrench[:, 4]
        if self._d is not None:
            motor = motor + self._d[3 + 2 * self.n:3 + 3 * self.n]
        jw = self.truth.wheel_inertia
        if jw * inv_dt != 0.0:
            motor = motor + jw * inv_dt * (sol.omega - self.z[3:3 + self.n])
        return motor

    def _disturb(self) -> NDArray[np.float64] | None:
        """Evaluate the disturbance hook at the current time and state (held over the next step)."""
        if self.disturbance is None:
            return None
        f = self.disturbance(self.t, self.truth_state())
        if not isinstance(f, DisturbanceForces):
            raise DisturbanceError(f"t={self.t:.6g} s: the disturbance hook returned {type(f).__name__}, "
                                   "expected DisturbanceForces")
        self.applied, self._d = f, f.vector(self.n)
        return self._d

    def start(self, commands: Commands) -> None:
        """Begin at the steady state of the first commands (the rover already driving them, as
        in section 7.3 where it drove 5 s before each run), at the origin, heading 0."""
        rim = tuple(-float(v) for v in commands.rim_speed) if self.backward else commands.rim_speed  # see apply
        self.act.reset(rim, commands.steer_angle)
        self.z = self.plant.initial_guess(self.scenario.speed, self.q, self.contact)
        # quasi-static steady state, reached by continuation from straight driving (Newton from a
        # straight guess need not converge for a strongly steered primitive such as the trench)
        om_t, st_t = self.act.omega_servo.copy(), self.act.steer.copy()
        om_0 = np.full(self.n, self.scenario.speed / (self.scenario.params.wheel.shearing_radius * 0.92))
        lam, step, solved = 0.0, 1.0, False
        while True:
            trial = min(1.0, lam + step)
            self.act.omega_servo, self.act.steer = om_0 + trial * (om_t - om_0), trial * st_t
            z_keep = self.z.copy()
            try:
                try:
                    self._solve(0.0)
                except SimulationError:
                    self._solve_exact_or_from_rest(0.0, z_keep)  # the fallbacks of a failed step (see step)
                solved, lam = True, trial
                step *= 2.0
            except SimulationError:
                self.z = z_keep
                step *= 0.5
                if step < 1.0 / 256:
                    raise
            if solved and lam >= 1.0:
                break
        if self.disturbance is not None:
            self._start_disturbed()
        self.pose_source.take(self.t, self.x, self.y, self.heading, self.travelled)

    def _start_disturbed(self) -> None:
        """The quasi-static state under the disturbance at t = 0, by continuation in its size
        from the undisturbed steady state."""
        full = self._disturb()
        if full is None:
            return
        lam, step = 0.0, 1.0
        while lam < 1.0:
            trial = min(1.0, lam + step)
            self._d = trial * full
            z_keep, om_keep = self.z.copy(), self.act.omega_servo.copy()
            try:
                self._solve(0.0)
                lam = trial
                step *= 2.0
            except SimulationError:
                self.z, self.act.omega_servo = z_keep, om_keep
                step *= 0.5
                if step < 1.0 / 256:
                    raise SimulationError(f"no steady state under the disturbance at t=0 ({self.applied}); "
                                          f"reached {lam:.3g} of it") from None
        self._d = full

    def apply(self, commands: Commands) -> None:
        """Latch commands (clipped to actuator limits by the servos; NaN ignored).

        A backward drive's commands are in the rover's body frame (the controller's boundary,
        :meth:`rtctl.controller.Controller.feedback`); the plant is in the travel frame (the rover
        file turned half round), where a rim speed changes sign and a steering angle does not.
        """
        rim = commands.rim_speed
        if self.backward:
            rim = tuple(-float(v) for v in rim)
        self.act.command(rim, commands.steer_angle)

    def step(self) -> None:
        """Advance one fixed step ``dt``."""
        if self.sol is None:
            raise SimulationError("call start(first_commands) before stepping the simulator")
        self._disturb()
        self.gyro_bias.advance(self.dt)
        om_prev, steer_prev = self.act.omega_servo.copy(), self.act.steer.copy()
        self.act.advance(self.dt)
        om_new, steer_new = self.act.omega_servo.copy(), self.act.steer.copy()
        keep = (self.z.copy(), self.sol, self.motor.copy(), self.act.omega_servo.copy(), self.mode.copy(),
                self.torque.copy())
        try:
            self._solve(1.0 / self.dt)
            self._integrate(self.dt)
        except SimulationError as first:
            # Newton from the last state found no root over the whole step (the body's velocity
            # changes too much in one step, e.g. when a rover stalls on a locked wheel): the
            # same implicit-Euler step in n equal sub-steps, each a continuation from the last,
            # with the servos' speeds and angles moving linearly from the last step's to this
            # step's over them (the servos reach this step's values at its end, as in one
            # step). Steps that converge never come here (bit for bit).
            # Last, one step from the rover at rest (a creep of STICTION_SPEED / 10): a rover that
            # stalls within the step (e.g. its driven wheels reach slip 1 against a locked wheel)
            # has its root there, far from the moving state Newton started from.
            self.plant.rocker_jacobian = True  # exact Newton from here on, for this step only
            attempts = [(n, False) for n in (1, *self.SUBSTEPS)] + [(1, True)]
            for n, from_rest in attempts:
                (self.z, self.sol, m, om, self.mode, self.torque) = (keep[0].copy(), keep[1], keep[2].copy(),
                                                                     keep[3].copy(), keep[4].copy(), keep[5].copy())
                self.motor, self.act.omega_servo = m, om
                if from_rest:
                    self.z[0:3] = (0.1 * STICTION_SPEED, 0.0, 0.0)
                pose = (self.x, self.y, self.heading, self.travelled)
                try:
                    for k in range(1, n + 1):
                        self.act.omega_servo = om_prev + k / n * (om_new - om_prev)
                        self.act.steer = steer_prev + k / n * (steer_new - steer_prev)
                        self._solve(n / self.dt)
                        self._integrate(self.dt / n)
                except SimulationError:
                    self.x, self.y, self.heading, self.travelled = pose
                    continue
                self.substepped += 1
                break
            else:
                self.plant.rocker_jacobian = False
                (self.z, self.sol, self.motor, self.act.omega_servo, self.mode, self.torque) = keep  # as before the step
                self._raise_if_dug_in(keep[0], first)
                raise SimulationError(f"t={self.t + self.dt:.6g} s: {first} (also with the exact Jacobian, in "
                                      f"{self.SUBSTEPS[-1]} sub-steps and from rest)") from None
            self.plant.rocker_jacobian = False
        self.steps += 1
        self.t = self.steps * self.dt
        self.pose_source.take(self.t, self.x, self.y, self.heading, self.travelled)

    def _raise_if_dug_in(self, z: NDArray[np.float64], err: SimulationError) -> None:
        """Raise :class:`RoverStuck` when a step failed with a wheel on the ground sunk deeper than
        its shearing radius (the wheel model's domain ends at an entry angle of 90 deg), at the
        step's start ``z`` or where the first failed Newton solve stopped (``err.z``), and
        :class:`WheelLiftOff` when instead a wheel in contact is unloaded to its grouser height."""
        n = self.n
        hs = slice(3 + n, 3 + 2 * n)
        h = np.exp(z[hs]) * self.contact
        if err.z is not None and np.all(np.isfinite(err.z[hs])):
            h = np.maximum(h, np.exp(err.z[hs]) * self.contact)
        deep = [i for i in range(n) if h[i] > self.rs_true[i]]
        if not deep:
            hg = self.truth.params.wheel.grouser_height
            zz = err.z if err.z is not None and np.all(np.isfinite(err.z[hs])) else z
            light = [i for i in range(n) if self.contact[i] and np.exp(zz[3 + n + i]) < 1.1 * hg]
            if light:
                what = ", ".join(f"{self.wheels[i]} {1e3 * np.exp(zz[3 + n + i]):.1f} mm" for i in light)
                raise WheelLiftOff(f"t={self.t + self.dt:.6g} s: a wheel is unloading ({what}: sinkage at the "
                                      f"{1e3 * hg:.0f} mm grouser height, almost no load); the plant does not model a "
                                      f"wheel lifting off the ground ({err})") from None
            return
        slip = self.sol.slip if self.sol is not None else np.full(n, math.nan)
        what = ", ".join(f"{self.wheels[i]} {1e3 * h[i]:.1f} mm at slip {slip[i]:.2f}" for i in deep)
        raise RoverStuck(f"t={self.t + self.dt:.6g} s: the rover is stuck, dug in: {what}, deeper than the wheel's "
                         f"{1e3 * float(self.rs_true[deep[0]]):.0f} mm shearing radius, where the wheel model ends "
                         f"(x = {self.x:.3f} m; {err})")

    def _solve_exact_or_from_rest(self, inv_dt: float, z0: NDArray[np.float64]) -> None:
        """Solve from ``z0`` with the exact Jacobian, then from the rover at rest with the same
        sinkages (a creep of ``STICTION_SPEED / 10``); raise the last failure."""
        self.plant.rocker_jacobian = True
        try:
            for from_rest in (False, True):
                self.z = z0.copy()
                if from_rest:
                    self.z[0:3] = (0.1 * STICTION_SPEED, 0.0, 0.0)
                try:
                    self._solve(inv_dt)
                    return
                except SimulationError:
                    if from_rest:
                        self.z = z0.copy()
                        raise
        finally:
            self.plant.rocker_jacobian = False

    SUBSTEPS = (2, 4, 8, 16)
    """Sub-step counts tried, in order, for a step whose Newton solve fails (see :meth:`step`)."""

    def _integrate(self, dt: float) -> None:
        """Advance the pose over ``dt`` at the body velocities just solved (midpoint heading)."""
        u, v, r = self.z[0], self.z[1], self.z[2]
        hm = self.heading + 0.5 * r * dt
        self.x += dt * (u * math.cos(hm) - v * math.sin(hm))
        self.y += dt * (u * math.sin(hm) + v * math.cos(hm))
        self.heading += r * dt
        self.travelled += dt * math.hypot(u, v)

    def advance(self, duration: float) -> None:
        """Advance ``round(duration / dt)`` steps."""
        for _ in range(int(round(duration / self.dt))):
            self.step()

    # ------------------------------------------------------------------ sensors
    def _tilt(self) -> tuple[float, float]:
        tr = self.truth
        gX, gY = -math.sin(tr.slope), -math.cos(tr.slope) * math.sin(tr.cross_slope)
        gx = gX * math.cos(self.heading) + gY * math.sin(self.heading)
        gy = -gX * math.sin(self.heading) + gY * math.cos(self.heading)
        pitch = math.asin(max(-1.0, min(1.0, -gx)))
        roll = math.asin(max(-1.0, min(1.0, -gy / max(math.cos(pitch), 1e-9))))
        return roll, pitch

    def measure(self) -> Measurements:
        """Sensor readings at the current time (noise drawn in a fixed order).

        A backward drive's readings are in the body frame: wheel speeds and motor torques
        change sign, roll and pitch change sign, a pose's heading gains pi (the inverse of the
        controller's turn, :meth:`rtctl.controller.Controller.feedback`); steering, yaw rate and
        position are the same in both frames."""
        if self.sol is None:
            raise SimulationError("call start(first_commands) before measuring")
        c = self.sensors
        k = self.n  # the mini rover: 4 + 4 + 1 + 2 + 4 draws, in this order
        n = self.rng.standard_normal(k + k + 1 + 2 + k)
        omega = self.sol.omega + c.wheel_speed_noise * n[0:k]
        steer = self.act.steer + c.steer_noise * n[k:2 * k]
        gyro = self.z[2] + self.gyro_bias.value + c.gyro_noise * n[2 * k]
        roll, pitch = self._tilt()
        roll += c.tilt_offset[0] + c.tilt_noise * n[2 * k + 1]
        pitch += c.tilt_offset[1] + c.tilt_noise * n[2 * k + 2]
        torque = None
        if math.isfinite(c.torque_noise):
            torque = tuple(float(x) for x in (self.motor + c.torque_noise * n[2 * k + 3:3 * k + 3]))
        fix = self.pose_source.deliver(self.t)
        pose = Pose(*fix) if fix is not None else None
        if self.backward:  # the body frame of a rover driving backward (see apply)
            omega, torque = -omega, None if torque is None else tuple(-x for x in torque)
            roll, pitch = -roll, -pitch
            if pose is not None:
                pose = Pose(pose.t, pose.x, pose.y, math.atan2(math.sin(pose.heading + math.pi),
                                                               math.cos(pose.heading + math.pi)))
        m = Measurements(t=self.t, seq=self.seq, wheel_speed=tuple(float(x) for x in omega),
                         steer_angle=tuple(float(x) for x in steer), yaw_rate=float(gyro),
                         roll=float(roll), pitch=float(pitch), motor_torque=torque, pose=pose,
                         failures=self.failures)
        self.seq += 1
        return m

    def truth_state(self) -> TruthState:
        """The true state now."""
        if self.sol is None:
            raise SimulationError("call start(first_commands) first")
        s = self.sol
        tup = lambda a: tuple(float(x) for x in a)  # noqa: E731
        return TruthState(self.t, self.x, self.y, self.heading, float(self.z[0]), float(self.z[1]), float(self.z[2]),
                          tup(s.omega), tup(self.act.steer + np.asarray(self.truth.steer_offset)), tup(s.sinkage),
                          tup(s.wrench[:, 2]), tup(s.slip), tup(s.slip_angle), tup(self.motor), self.travelled,
                          self.applied, self.gyro_bias.value)

    @property
    def mass(self) -> float:
        """Rover mass of the truth, kg."""
        return float(self.truth.mass)

    @property
    def weight(self) -> float:
        """Rover weight of the truth, N."""
        return float(self.truth.mass * (GRAVITY if self.rover_file is None else getattr(self.plant, "gravity", GRAVITY)))
