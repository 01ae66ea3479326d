"""Closed-loop experiments of section 7.3: drive 1.5 m at 3 cm/s with a failure and a controller.

Controllers are pluggable: anything with ``step(m: Measurements) -> (Commands, diagnostics)``
(and optionally ``reset()``), the contract of :class:`rtctl.controller.Controller`. Built in:

``none``
    No compensation: the nominal primitive's wheel speeds and angles, whatever has failed.
``ff``
    Feed-forward only: the primitive of the failure scenario (7.25) with its constraints
    (7.28)-(7.31).
``fb``
    The nominal primitive plus PID on heading and cross-track error through the *default*
    steering controllers (section 7.2.4, computed around the nominal primitive).
``ff+fb``
    The failure primitive plus PID through the default steering controllers.
``ff+optfb``
    The failure primitive plus PID through the "optimal" steering controllers (re-solved
    with the offsets (7.26)-(7.27) around the failure primitive).
``rtctl``
    :class:`rtctl.controller.Controller` on the shipped tables (when available).

The PID acts, as on the mini rover, on the pose source (T265 at 5 Hz there): heading error
to a yaw-moment offset M_z, cross-track error to a lateral-force offset F_y, each scaled onto
the one-sided steering controllers ("Mz+" / "Mz-", "Fy+" / "Fy-") and added to the
primitive. The dissertation does not give its PID gains; ours are in :class:`PidGains`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.messages import Commands, Measurements, Task

from ..rover.primitives import PrimitiveResult, solve_primitive, steering_controllers
from ..rover.scenario import Scenario, load_scenario
from .simulator import RoverStuck, RoverSimulator, TruthState, WheelLiftOff

__all__ = [
    "ControllerLike", "PidGains", "PrimitiveController", "PidSteeringController", "DriveResult", "run_drive",
    "drive_metrics", "record_run", "build_controller", "BUILTIN_CONTROLLERS", "SECTION_7_3", "DISSERTATION_7_3", "plot_runs",
    "ExperimentError", "wheel_tuple", "scenario_by_name", "declared_task", "with_task", "trench_metrics",
]

WHEELS = ("FR", "FL", "RR", "RL")
BUILTIN_CONTROLLERS = ("none", "ff", "fb", "ff+fb", "ff+optfb")
"""Controllers built from the optimizer alone (``rtctl`` needs the tables and rtctl.controller)."""

SECTION_7_3 = {
    "rr_trench_clean": ("ff", "ff+fb", "ff+optfb"),
    "rr_speed_cap_half": ("none", "ff", "fb", "ff+fb", "ff+optfb"),
    "rr_steer_stuck_50": ("none", "ff", "fb", "ff+fb", "ff+optfb"),
}
"""The three scenarios of section 7.3 and the controllers the dissertation ran on each."""

DISSERTATION_7_3 = {
    "rr_trench_clean": "all of FF, FF+FB, FF+optFB: heading within 3 deg, y within 5 cm over 1.5 m (Fig. 7.6)",
    "rr_speed_cap_half": ("none: veers right off the track within 1 m; every compensation: heading within 6 deg and "
                          "y within 3 cm; FB only ~6 deg, with FF < 3 deg; travel 2.1-2.4 cm/s against 3 cm/s (Fig. 7.9)"),
    "rr_steer_stuck_50": ("none: 13 cm right and 3 deg over 1.6 m; FF: 4 cm and 15 deg; FB keeps heading; FF+FB yaw "
                          "like none; FF+optFB best (Fig. 7.11)"),
}
"""Hardware results of section 7.3 (text of sections 7.3.1-7.3.3)."""


class ExperimentError(ValueError):
    """An experiment cannot be set up (unknown controller, no primitive); the message says why."""


class ControllerLike(Protocol):
    """What the harness drives: the rtctl controller contract (C3)."""

    def step(self, m: Measurements) -> tuple[Commands, Any]:
        """Commands (and diagnostics) for one tick."""
        ...


def wheel_tuple(values: Mapping[str, float] | Sequence[float]) -> tuple[float, float, float, float]:
    """Four floats in wheel order FR, FL, RR, RL."""
    if isinstance(values, Mapping):
        return tuple(float(values[k]) for k in WHEELS)  # type: ignore[return-value]
    return tuple(float(v) for v in values)  # type: ignore[return-value]


@dataclass(frozen=True)
class PidGains:
    """PID on the pose errors (our choice; the dissertation does not give its gains).

    ``kp_yaw`` maps 0.1 rad of heading error to 0.2 N m (the Table 7.2 yaw offset);
    ``kp_y`` maps 5 cm of cross-track error to 1 N (the Table 7.2 lateral offset).
    Offsets are clipped to ``+-max_mz`` and ``+-max_fy``: the steering controllers are
    linear differences over +-0.2 N m and +-1 N and are not extrapolated far.
    """

    kp_yaw: float = 2.0
    ki_yaw: float = 0.1
    kd_yaw: float = 0.0
    kp_y: float = 20.0
    ki_y: float = 1.0
    kd_y: float = 0.0
    max_mz: float = 0.6
    max_fy: float = 3.0


class PrimitiveController:
    """Open loop: the same wheel speeds and angles every tick (a driving primitive).

    The commands are in the rover's body frame, wheels in the scenario's order: a rover file's
    wheel set; a backward drive's primitive (the rover file turned half round) has its rim
    speeds negated, as the rover's controller outputs them (:meth:`RoverSimulator.apply
    <offline.sim.simulator.RoverSimulator.apply>`)."""

    def __init__(self, primitive: PrimitiveResult, name: str = "ff") -> None:
        self.name = name
        sc = primitive.scenario
        self.rim: tuple[float, ...]
        self.steer: tuple[float, ...]
        if sc.rover_file is None:
            self.rim = wheel_tuple({k: w.rim_speed for k, w in primitive.wheels.items()})
            self.steer = wheel_tuple({k: w.steer for k, w in primitive.wheels.items()})
        else:
            sign = -1.0 if sc.rover_file.name.endswith(" (backward)") else 1.0
            self.rim = tuple(sign * float(primitive.wheels[k].rim_speed) for k in sc.wheels)
            self.steer = tuple(float(primitive.wheels[k].steer) for k in sc.wheels)

    def reset(self) -> None:
        """Nothing to reset (stateless)."""

    def step(self, m: Measurements) -> tuple[Commands, dict[str, Any]]:
        """The primitive's commands."""
        return Commands(m.t, m.seq, self.rim, self.steer), {"controller": self.name}


class PidSteeringController:
    """A primitive plus PID on the pose through the section 7.2.4 steering controllers.

    Parameters
    ----------
    primitive : PrimitiveResult
        Feed-forward (the nominal or the failure primitive).
    gains : dict
        :func:`offline.rover.primitives.steering_controllers` output: per offset direction,
        per wheel ``(d rim speed, d steer)`` per unit offset.
    pid : PidGains, optional
        PID gains on the pose errors (default :class:`PidGains()`).
    name : str
        Label of the controller in results and plots.
    """

    def __init__(self, primitive: PrimitiveResult, gains: Mapping[str, Mapping[str, tuple[float, float]]],
                 pid: PidGains | None = None, name: str = "ff+fb") -> None:
        # a side whose offset re-solve failed is taken as the mirror of the other side (a linear
        # controller, antisymmetric); the substitution is listed in ``self.mirrored``
        self.mirrored: list[str] = []
        self.gains: dict[str, NDArray[np.float64]] = {}
        for axis in ("Mz", "Fy"):
            plus, minus = gains.get(f"{axis}+"), gains.get(f"{axis}-")
            if plus and not minus:
                minus = {w: (-plus[w][0], -plus[w][1]) for w in WHEELS}
                self.mirrored.append(f"{axis}-")
            elif minus and not plus:
                plus = {w: (-minus[w][0], -minus[w][1]) for w in WHEELS}
                self.mirrored.append(f"{axis}+")
            if not plus or not minus:
                raise ExperimentError(f"steering controllers {axis}+ and {axis}- could not be computed (their offset "
                                      "re-solves failed); use a feed-forward-only controller for this scenario")
            self.gains[f"{axis}+"] = np.array([plus[w] for w in WHEELS])
            self.gains[f"{axis}-"] = np.array([minus[w] for w in WHEELS])
        self.base = PrimitiveController(primitive, name)
        self.pid = pid or PidGains()
        self.name = name
        self.reset()

    def reset(self) -> None:
        """Forget integrators and the last pose."""
        self._t = math.nan
        self._iyaw = self._iy = 0.0
        self._eyaw = self._ey = 0.0
        self._mz = self._fy = 0.0

    def step(self, m: Measurements) -> tuple[Commands, dict[str, Any]]:
        """Update the PID when a pose arrives, then primitive + scaled steering controllers."""
        g = self.pid
        if m.pose is not None and all(math.isfinite(v) for v in (m.pose.t, m.pose.x, m.pose.y, m.pose.heading)):
            eyaw = math.atan2(math.sin(m.pose.heading), math.cos(m.pose.heading))
            ey = m.pose.y
            first = not math.isfinite(self._t)
            dt = 0.0 if first else m.pose.t - self._t
            if first or dt > 0:  # a stale or repeated pose keeps the offsets
                if dt > 0:
                    self._iyaw += eyaw * dt
                    self._iy += ey * dt
                    dyaw, dy = (eyaw - self._eyaw) / dt, (ey - self._ey) / dt
                else:
                    dyaw = dy = 0.0
                self._t, self._eyaw, self._ey = m.pose.t, eyaw, ey
                self._mz = -float(np.clip(g.kp_yaw * eyaw + g.ki_yaw * self._iyaw + g.kd_yaw * dyaw, -g.max_mz, g.max_mz))
                self._fy = -float(np.clip(g.kp_y * ey + g.ki_y * self._iy + g.kd_y * dy, -g.max_fy, g.max_fy))
        d = (self.gains["Mz+"] if self._mz >= 0 else self.gains["Mz-"]) * abs(self._mz)
        d = d + (self.gains["Fy+"] if self._fy >= 0 else self.gains["Fy-"]) * abs(self._fy)
        rim = tuple(float(r + dr) for r, dr in zip(self.base.rim, d[:, 0]))
        steer = tuple(float(s + ds) for s, ds in zip(self.base.steer, d[:, 1]))
        return (Commands(m.t, m.seq, rim, steer),
                {"controller": self.name, "mz_offset": self._mz, "fy_offset": self._fy,
                 "heading_error": self._eyaw, "cross_track_error": self._ey})


def declared_task(sc: Scenario) -> Task | None:
    """The operator's task of a scenario as the rover declares it to rtctl: a trench goal gives
    ``Task("trench", wheel, depth)`` with its target depth, else its minimum depth (7.29); None
    without a trench goal. (The simulator's sensors do not produce it: a task is an operator's
    command, attached to each measurement by the drive loop, :func:`with_task`.)"""
    tr = sc.trench
    if tr is None:
        return None
    depth = tr.target_depth if tr.target_depth is not None else tr.min_depth
    return Task(type(tr).ROVER_KIND, tr.wheel, float(depth))


def with_task(m: Measurements, task: Task | None) -> Measurements:
    """The measurement with the operator's task attached (unchanged when there is none)."""
    from dataclasses import replace

    return m if task is None else replace(m, task=task)


def trench_metrics(truth: Sequence[TruthState], sc: Scenario, params: Any = None) -> dict[str, float]:
    """The trench the trenching wheel leaves, by the soil-flow model of ch. 4 (eqs. (4.1)-(4.18))
    from its *true* sinkage, slip angle and speed at each tick of the second half of the drive
    (post hoc: the plant's forces do not depend on the trench, as in the optimizer, whose
    trench rows (7.28)-(7.29) are constraints on the same quantities). Mean depth and rim-side
    pile height in mm, and the fraction of ticks whose trench is clean-sided (pile <= 0.5 mm,
    the goal's tolerance). Empty without a trench goal. ``params``: the truth's parameter set
    (default: the scenario's)."""
    from rtctl.physics.soil_flow import trench_profile

    tr = sc.trench
    if tr is None or not truth:
        return {}
    ps = params or sc.params
    i = WHEELS.index(tr.wheel)
    depth, pile = [], []
    for s in truth[len(truth) // 2:]:
        beta = float(s.slip_angle[i])
        vx = math.hypot(s.u, s.v) * math.cos(beta)
        try:
            tp = trench_profile(float(s.sinkage[i]), beta, float(s.omega[i]), max(vx, 1e-9), ps.wheel, ps.soil)
        except ValueError:
            continue
        depth.append(tp.d)
        pile.append(tp.h_R2)  # the pile the goal's check (TrenchGoal.check) requires to vanish
    if not depth:
        return {"trench_depth_mm": math.nan, "trench_pile_mm": math.nan, "trench_clean_fraction": math.nan}
    return {"trench_depth_mm": 1e3 * float(np.mean(depth)), "trench_pile_mm": 1e3 * float(np.mean(pile)),
            "trench_clean_fraction": float(np.mean(np.array(pile) <= 5e-4))}


def _nominal_of(sc: Scenario) -> Scenario:
    from dataclasses import replace

    return replace(sc, failures={}, trench=None, name=f"{sc.name} (nominal)")


def build_controller(kind: str, sc: Scenario, pid: PidGains | None = None,
                     rtctl_factory: Callable[[Scenario], ControllerLike] | None = None) -> ControllerLike:
    """One of :data:`BUILTIN_CONTROLLERS` (or ``rtctl`` through ``rtctl_factory``) for a scenario.

    Raises
    ------
    ExperimentError
        Unknown kind, or a primitive the optimizer did not find.
    """
    if kind == "rtctl":
        if rtctl_factory is None:
            raise ExperimentError("controller 'rtctl' needs the rtctl tables and controller (rtctl.controller, "
                                  "rtctl.table); they are not available in this installation")
        return rtctl_factory(sc)
    if kind not in BUILTIN_CONTROLLERS:
        raise ExperimentError(f"unknown controller {kind!r}; use one of {list(BUILTIN_CONTROLLERS) + ['rtctl']}")
    if sc.rover_file is not None and kind not in ("none", "ff"):
        raise ExperimentError(f"controller {kind!r}: the section 7.2.4 steering controllers are built for the mini "
                              f"rover's four wheels; for the rover file of {sc.rover_file.name} use rtctl, 'none' or 'ff'")
    nominal = _primitive(_nominal_of(sc))
    if kind in ("none", "fb"):
        prim = nominal
    else:
        prim = _primitive(sc)
    if kind in ("none", "ff"):
        return PrimitiveController(prim, kind)
    around = nominal if kind in ("fb", "ff+fb") else prim
    around_sc = _nominal_of(sc) if kind in ("fb", "ff+fb") else sc
    return PidSteeringController(prim, _controllers(around_sc, around), pid, kind)


_PRIM_CACHE: dict[Any, PrimitiveResult] = {}
_CTRL_CACHE: dict[Any, Any] = {}


def _key(sc: Scenario) -> Any:
    return (sc.params, sc.rover, sc.exit_angle, sc.speed, sc.slope, tuple(sorted(sc.failures.items())), sc.trench)


def _primitive(sc: Scenario) -> PrimitiveResult:
    k = _key(sc)
    if k not in _PRIM_CACHE:
        r = solve_primitive(sc)
        if not r.ok:
            raise ExperimentError(f"scenario {sc.name}: no driving primitive ({r.status}); "
                                  f"{r.evidence.get('closest', '')}")
        _PRIM_CACHE[k] = r
    return _PRIM_CACHE[k]


def _controllers(sc: Scenario, prim: PrimitiveResult) -> Any:
    k = _key(sc)
    if k not in _CTRL_CACHE:
        _CTRL_CACHE[k] = steering_controllers(sc, prim)
    return _CTRL_CACHE[k]


@dataclass
class DriveResult:
    """One closed-loop drive: the truth over time, the commands and the metrics."""

    scenario: str
    controller: str
    truth: list[TruthState] = field(default_factory=list)
    commands: list[Commands] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    wall_seconds: float = 0.0
    step_seconds: list[float] = field(default_factory=list)
    stuck: str = ""
    """Why the drive ended early because the rover got stuck (:class:`offline.sim.simulator.RoverStuck`;
    "" when it did not): the metrics then cover the drive up to that step and hold ``stuck_at_s``."""
    ended: str = ""
    """Why the drive ended before its distance or time: the rover got stuck (as ``stuck``) or a wheel
    began to lift off, which the plant does not model (:class:`offline.sim.simulator.WheelLiftOff`);
    "" when it did not. The metrics then cover the drive up to that step and hold ``ended_at_s``."""

    def series(self, name: str) -> NDArray[np.float64]:
        """A truth field over time as an array."""
        return np.array([getattr(s, name) for s in self.truth])


def drive_metrics(truth: Sequence[TruthState], target_speed: float) -> dict[str, float]:
    """Final and maximum heading error (deg) and cross-track error (cm), mean travel speed (cm/s)
    along the path (world X), and its error relative to the target (%)."""
    hd = np.degrees([math.atan2(math.sin(s.heading), math.cos(s.heading)) for s in truth])
    y = 100 * np.array([s.y for s in truth])
    t, x = truth[-1].t - truth[0].t, truth[-1].x - truth[0].x
    speed = 100 * x / t if t > 0 else math.nan
    return {"final_heading_deg": float(hd[-1]), "max_abs_heading_deg": float(np.max(np.abs(hd))),
            "final_cross_track_cm": float(y[-1]), "max_abs_cross_track_cm": float(np.max(np.abs(y))),
            "mean_speed_cm_s": float(speed), "speed_error_pct": float(100 * (speed / (100 * target_speed) - 1)),
            "distance_m": float(x), "time_s": float(t)}


def run_drive(sim: RoverSimulator, controller: ControllerLike, distance: float = 1.5, max_time: float | None = None,
              period: float = 0.2, recorder: Any = None, name: str = "") -> DriveResult:
    """Drive until the rover has advanced ``distance`` along the path (world X) or ``max_time``
    (default three times the nominal duration) has passed, at the control ``period``.

    ``recorder`` (an :class:`rtctl.recording.Recorder`) receives every measurement, command,
    diagnostic, step time and the truth.
    """
    sc = sim.scenario
    task = declared_task(sc)
    if max_time is None:
        max_time = 3.0 * distance / sc.speed
    if hasattr(controller, "reset"):
        controller.reset()
    res = DriveResult(sc.name, name or getattr(controller, "name", type(controller).__name__))
    t0 = time.perf_counter()
    # settle on the controller's first answer: the rover drove it before the run (section 7.3)
    c0, _ = controller.step(_first_measurement(sim))
    if hasattr(controller, "reset"):
        controller.reset()
    sim.start(c0)
    while True:
        m = with_task(sim.measure(), task)
        ts = time.perf_counter()
        cmd, diag = controller.step(m)
        step = time.perf_counter() - ts
        sim.apply(cmd)
        truth = sim.truth_state()
        res.truth.append(truth)
        res.commands.append(cmd)
        res.step_seconds.append(step)
        if recorder is not None:
            recorder.measurements(m)
            recorder.commands(cmd)
            recorder.diagnostics(m.t, diag)
            recorder.timing(m.t, m.seq, step, period)
            if "truth" in getattr(recorder, "_channels", {}):
                recorder.truth(m.t, truth)
        if truth.x - res.truth[0].x >= distance or sim.t >= max_time:
            break
        try:
            sim.advance(period)
        except RoverStuck as exc:  # the physical end of this drive (a wheel dug in), said in the result
            res.stuck = res.ended = str(exc)
            break
        except WheelLiftOff as exc:  # the end of what the plant models, said in the result
            res.ended = str(exc)
            break
    res.wall_seconds = time.perf_counter() - t0
    res.metrics = drive_metrics(res.truth, sc.speed)
    res.metrics.update(trench_metrics(res.truth, sc, sim.truth.params))
    if res.stuck:
        res.metrics["stuck_at_s"] = float(sim.t)
    if res.ended:
        res.metrics["ended_at_s"] = float(sim.t)
    return res


def record_run(path: str | Path, sim: RoverSimulator, controller: ControllerLike, distance: float,
               metadata: Mapping[str, Any] | None = None, max_time: float | None = None, name: str = "") -> DriveResult:
    """:func:`run_drive` written to an MCAP recording (:class:`rtctl.recording.Recorder`, the truth
    channel included; a rover file's recording carries its wheel set), as ``offnominal drive`` records.

    Parameters
    ----------
    path : str or Path
        The recording to write.
    sim, controller, distance, max_time, name
        As :func:`run_drive`.
    metadata : mapping, optional
        The recording's metadata (scenario, seed, ...; never the truth's parameters when the
        recording is to be diagnosed).
    """
    from rtctl.recording import Recorder, provenance

    wheels = sim.wheels if sim.rover_file is not None else None  # the mini rover's: as every recording before
    with Recorder(path, dict(metadata or {}), truth=True, provenance=provenance(controller), wheels=wheels) as rec:
        return run_drive(sim, controller, distance=distance, max_time=max_time, recorder=rec, name=name)


def _first_measurement(sim: RoverSimulator) -> Measurements:
    """A noise-free measurement of the rover at rest on its commanded path (to ask the
    controller for its first command before the plant has a state)."""
    from rtctl.messages import Pose

    wheels = getattr(sim, "wheels", WHEELS)
    steer = []
    for k in wheels:
        f = sim.scenario.failure(k)
        steer.append(f.steer_stuck if f.steer_stuck is not None else 0.0)
    om = sim.scenario.speed / sim.scenario.params.wheel.shearing_radius
    heading = 0.0
    if getattr(sim, "backward", False):  # the body frame of a rover driving backward (RoverSimulator.measure)
        om, heading = -om, math.pi
    return Measurements(t=-1.0, seq=-1, wheel_speed=(om,) * len(wheels), steer_angle=tuple(steer),
                        yaw_rate=0.0, pose=Pose(-1.0, 0.0, 0.0, heading), failures=sim.failures,
                        task=declared_task(sim.scenario))


def plot_runs(runs: Sequence[DriveResult], path: str | Path, title: str = "") -> Path:
    """Heading (yaw) and cross-track (y) error against distance, one line per controller
    (like Figs. 7.6, 7.9, 7.11). Written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..files import atomic_path

    fig, ax = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for r in runs:
        x = r.series("x")
        ax[0].plot(x, np.degrees(r.series("heading")), label=r.controller)
        ax[1].plot(x, 100 * r.series("y"), label=r.controller)
    ax[0].set_ylabel("yaw error [deg]")
    ax[1].set_ylabel("y error [cm]")
    ax[1].set_xlabel("distance along the path [m]")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.axhline(0, color="k", lw=0.5)
    ax[0].legend(loc="best", fontsize=8)
    if title:
        ax[0].set_title(title)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    return Path(path)


def scenario_by_name(name: str) -> Scenario:
    """A shipped scenario (``offline/scenarios/<name>.toml``) or a path."""
    from ..rover.scenario import example_scenarios

    p = Path(name)
    if not p.exists():
        shipped = {q.stem: q for q in example_scenarios()}
        if name not in shipped:
            raise ExperimentError(f"no scenario {name!r}: give a TOML path or one of {sorted(shipped)}")
        p = shipped[name]
    return load_scenario(p)

