"""The simulated mini rover: plant, actuators and sensors behind the controller's message types.

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
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rtctl.messages import Commands, FailureDeclaration, Measurements, Pose

from ..physics.params import ParameterSet, Rover
from ..physics.terramechanics import ModelOptions
from ..rover.scenario import Scenario
from .actuators import ActuatorConfig, Actuators
from .plant import GRAVITY, PlantModel, PlantSolution, SimulationError
from .sensors import PoseSource, SensorConfig
from .truth import Truth

__all__ = ["RoverSimulator", "TruthState", "plant_for", "declared_failures", "SimulationError"]


@functools.lru_cache(maxsize=8)
def plant_for(params: ParameterSet, rover: Rover, exit_angle: str = "classic", compiled: bool = True) -> PlantModel:
    """A cached :class:`PlantModel` (the soil enters per call, so one serves many truths)."""
    opts = ModelOptions(exit_angle=exit_angle, shear_direction_smoothing=1e-6)  # type: ignore[arg-type]
    return PlantModel(params, rover, opts, compiled=compiled)


def declared_failures(sc: Scenario) -> tuple[FailureDeclaration, ...]:
    """The failures of a scenario as the rover's fault management declares them."""
    out = []
    for k in ("FR", "FL", "RR", "RL"):
        f = sc.failure(k)
        if f.steer_stuck is not None:
            out.append(FailureDeclaration(k, "steer_stuck", f.steer_stuck))
        if math.isfinite(f.rim_speed_max):
            out.append(FailureDeclaration(k, "rim_speed_cap", f.rim_speed_max))
        if f.locked:
            out.append(FailureDeclaration(k, "locked"))
        if f.unpowered:
            out.append(FailureDeclaration(k, "unpowered"))
        if f.raised:
            out.append(FailureDeclaration(k, "raised"))
        if math.isfinite(f.torque_limit):
            out.append(FailureDeclaration(k, "torque_limit", f.torque_limit))
    return tuple(out)


@dataclass(frozen=True)
class TruthState:
    """What really happened at one instant (for recordings' truth channel and metrics)."""

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

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able values."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


class RoverSimulator:
    """The mini rover of Table 7.2 driving on a slope, with failures, actuators and sensors.

    Parameters
    ----------
    scenario : Scenario
        Failures to inject (``[wheels.*]`` of the scenario file) and the believed parameter
        set (its wheel's shearing radius converts rim-speed commands to wheel speeds).
    truth : Truth, optional
        The simulated world (default: the scenario's parameters, flat, no tether).
    actuators, sensors : configs
    dt : float
        Fixed plant step, s (the 5 Hz control period should be a multiple).
    seed : int
        Seeds every noise source.
    """

    def __init__(self, scenario: Scenario, truth: Truth | None = None, actuators: ActuatorConfig | None = None,
                 sensors: SensorConfig | None = None, dt: float = 0.1, seed: int = 0, compiled: bool = True) -> None:
        if not (math.isfinite(dt) and 1e-4 <= dt <= 1.0):
            raise ValueError(f"dt must be in [1e-4, 1] s, got {dt!r}")
        self.scenario = scenario
        self.truth = truth or Truth.nominal(scenario.params, scenario.rover)
        self.plant = plant_for(self.truth.params, scenario.rover, scenario.exit_angle, compiled)
        self.q = self.truth.vector()
        self.rs_true = np.asarray(self.truth.wheel_radius) + self.truth.params.wheel.grouser_height
        self.act = Actuators(actuators or ActuatorConfig(), dict(scenario.failures), scenario.params.wheel.shearing_radius)
        self.sensors = sensors or SensorConfig()
        self.dt = dt
        self.rng = np.random.default_rng(seed)
        self.pose_source = PoseSource(self.sensors, self.rng)
        self.failures = declared_failures(scenario)
        self.t = 0.0
        self.seq = 0
        self.steps = 0
        self.x = self.y = self.heading = 0.0
        self.travelled = 0.0
        self.z = np.zeros(15)
        self.sol: PlantSolution | None = None
        self.mode = np.ones(4)
        self.torque = np.zeros(4)
        self.newton_iterations = 0

    # ------------------------------------------------------------------ plant
    def _inputs(self, inv_dt: float) -> NDArray[np.float64]:
        steer = self.act.steer + np.asarray(self.truth.steer_offset)
        return np.concatenate([self.act.omega_servo, self.mode, self.torque, steer,
                               self.z[:3], [self.heading, inv_dt]])

    def _solve(self, inv_dt: float) -> None:
        base_mode, base_torque = self.act.drive_modes()
        self.mode, self.torque = base_mode.copy(), base_torque.copy()
        for _ in range(6):  # active set of the torque limits
            z, sol = self.plant.solve(self.z, self._inputs(inv_dt), self.q)
            self.newton_iterations += sol.iterations
            motor = -sol.wrench[:, 4]
            changed = False
            for i in range(4):
                lim = self.act.torque_limit(i)
                if base_mode[i] == 0:
                    continue
                if self.mode[i] == 1 and abs(motor[i]) > lim * (1 + 1e-9):
                    self.mode[i], self.torque[i] = 0.0, math.copysign(lim, motor[i])
                    changed = True
                elif self.mode[i] == 0 and abs(sol.omega[i]) > abs(self.act.omega_servo[i]) + 1e-12:
                    self.mode[i], self.torque[i] = 1.0, 0.0  # the servo can hold its speed again
                    changed = True
            if not changed:
                break
        self.z, self.sol = z, sol
        # a wheel held at its torque limit turns at the speed the soil allows; the servo tracks it
        held = (self.mode == 0) & (base_mode == 1)
        self.act.omega_servo = np.where(held, sol.omega, self.act.omega_servo)

    def start(self, commands: Commands) -> None:
        """Begin at the steady state of the first commands (the rover already driving them, as
        in section 7.3 where it drove 5 s before each run), at the origin, heading 0."""
        self.act.reset(commands.rim_speed, commands.steer_angle)
        self.z = self.plant.initial_guess(self.scenario.speed, self.q)
        # quasi-static steady state, reached by continuation from straight driving (Newton from a
        # straight guess need not converge for a strongly steered primitive such as the trench)
        om_t, st_t = self.act.omega_servo.copy(), self.act.steer.copy()
        om_0 = np.full(4, self.scenario.speed / (self.scenario.params.wheel.shearing_radius * 0.92))
        lam, step, solved = 0.0, 1.0, False
        while True:
            trial = min(1.0, lam + step)
            self.act.omega_servo, self.act.steer = om_0 + trial * (om_t - om_0), trial * st_t
            z_keep = self.z.copy()
            try:
                self._solve(0.0)
                solved, lam = True, trial
                step *= 2.0
            except SimulationError:
                self.z = z_keep
                step *= 0.5
                if step < 1.0 / 256:
                    raise
            if solved and lam >= 1.0:
                break
        self.pose_source.take(self.t, self.x, self.y, self.heading, self.travelled)

    def apply(self, commands: Commands) -> None:
        """Latch commands (clipped to actuator limits by the servos; NaN ignored)."""
        self.act.command(commands.rim_speed, commands.steer_angle)

    def step(self) -> None:
        """Advance one fixed step ``dt``."""
        if self.sol is None:
            raise SimulationError("call start(first_commands) before stepping the simulator")
        self.act.advance(self.dt)
        self._solve(1.0 / self.dt)
        u, v, r = self.z[0], self.z[1], self.z[2]
        hm = self.heading + 0.5 * r * self.dt
        self.x += self.dt * (u * math.cos(hm) - v * math.sin(hm))
        self.y += self.dt * (u * math.sin(hm) + v * math.cos(hm))
        self.heading += r * self.dt
        self.travelled += self.dt * math.hypot(u, v)
        self.steps += 1
        self.t = self.steps * self.dt
        self.pose_source.take(self.t, self.x, self.y, self.heading, self.travelled)

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
        """Sensor readings at the current time (noise drawn in a fixed order)."""
        if self.sol is None:
            raise SimulationError("call start(first_commands) before measuring")
        c = self.sensors
        n = self.rng.standard_normal(4 + 4 + 1 + 2 + 4)
        omega = self.sol.omega + c.wheel_speed_noise * n[0:4]
        steer = self.act.steer + c.steer_noise * n[4:8]
        gyro = self.z[2] + c.gyro_bias + c.gyro_noise * n[8]
        roll, pitch = self._tilt()
        roll += c.tilt_offset[0] + c.tilt_noise * n[9]
        pitch += c.tilt_offset[1] + c.tilt_noise * n[10]
        torque = None
        if math.isfinite(c.torque_noise):
            torque = tuple(float(x) for x in (-self.sol.wrench[:, 4] + c.torque_noise * n[11:15]))
        fix = self.pose_source.deliver(self.t)
        pose = Pose(*fix) if fix is not None else None
        m = Measurements(t=self.t, seq=self.seq, wheel_speed=tuple(float(x) for x in omega),  # type: ignore[arg-type]
                         steer_angle=tuple(float(x) for x in steer), yaw_rate=float(gyro),  # type: ignore[arg-type]
                         roll=float(roll), pitch=float(pitch), motor_torque=torque, pose=pose,  # type: ignore[arg-type]
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
                          tup(s.wrench[:, 2]), tup(s.slip), tup(s.slip_angle), tup(-s.wrench[:, 4]), self.travelled)

    @property
    def mass(self) -> float:
        """Rover mass of the truth, kg."""
        return float(self.truth.mass)

    @property
    def weight(self) -> float:
        """Rover weight of the truth, N."""
        return float(self.truth.mass * GRAVITY)
