"""Driving scenarios as data: failure modes, trenching goals and operating point (TOML).

A scenario names the model (a parameter file or preset), the rover, the travel speed, the
slope, the steering offsets (7.26)-(7.27), failures on any wheels and an optional trenching
goal. Every failure is a set of constraints on one wheel, so adding a failure mode is
writing a file (ARCHITECTURE.md, design point 2).

File format
-----------
.. code-block:: toml

    [scenario]
    name = "rr_speed_cap"
    params = "dissertation-ch7"      # preset (PARAM_PRESETS, PARAM_FILE_PRESETS: "calibrated-sand",
                                     # ...), or a parameter TOML path (relative to this file)
    drive_direction = "forward"      # or "backward" (a rover file only: the rover turned half
                                     # round, rtctl.physics.rover_file.driving_backward)
    rover = "mini-rover-t72"         # preset, or a TOML path with a [rover] section; or a rover
                                     # file (rtctl.physics.rover_file): a shipped one by name
                                     # ("mer_class_rocker_bogie", "skid_steer_4w", "mini_rover_t72")
                                     # or a path to a file with a [suspension] section
    exit_angle = "classic"           # default; "soil_flow" takes theta_r from the trench model
    speed_m_s = 0.03
    slope_deg = 0.0                  # pitch of the terrain along the travel direction (uphill +)
    cross_slope_deg = 0.0            # roll of the terrain, left side up positive (hillside traverse)
    yaw_moment_offset_Nm = 0.0       # (7.26)
    lateral_force_offset_N = 0.0     # (7.27)
    grouser_volume_fraction = 1.0    # optional override of zeta (the dissertation trenches with 1)
    grouser_area_ratio = 0.5         # optional override of mu (Table 5.2: 0.5; published code: 0.1)
    tether_force_N = 0.0             # constant pull along the rover's -x at the centre of mass O

    [tether]                         # optional: a cable to an anchor (constant bearing in steady
    tension_N = 2.0                  # straight driving, so a constant body-frame force)
    bearing_deg = 180.0              # direction of the pull from the rover's +x, CCW (180: straight back)
    attach_x_m = -0.1                # attachment on the body's x axis (negative: behind O)

    [hub_contact]                    # optional: a face that bulldozes soil once a wheel sinks
    clearance_mm = 4.0               # beyond the clearance (required in this section), of this
    face_width_mm = 40.0             # width (default 0), with this lever about the axle against
    arm_mm = 20.0                    # the spin (default 0); the same on every wheel

    [wheels.RR]                      # any of FR, FL, RR, RL (a rover file: its wheel names);
                                     # any combination of keys
    rim_speed_max_m_s = 0.015        # (7.30)
    steer_stuck_deg = -50.0          # (7.31)
    locked = true                    # omega = 0
    unpowered = true                 # free rolling: wheel torque M_y = 0
    raised = true                    # no ground contact: W = 0 (stuck suspension: the rocker
                                     # pivot is locked, so only the whole-rover pitch balances)
    torque_limit_Nm = 0.2            # |M_y| <= limit
    steer_min_deg = -90.0            # steering range of this wheel (default +-90)
    steer_max_deg = 0.0
    radius_mm = 54.0                 # this wheel's rim radius (default: the parameter set's)
    steer_offset_deg = 2.0           # true steer angle = encoder angle + offset; every steering
                                     # key above (range, stuck angle) is in encoder terms

    [trench]
    wheel = "RR"
    clean_side = true                # (7.28): no pile on the side the wheel is turned toward
    min_depth_m = 0.025              # (7.29); or min_depth = "half_width" for b / 2
    min_flat_width_m = 0.0
    target_depth_m = 0.03            # optional equality instead of a minimum

Recipe: add a failure mode
--------------------------
A failure kind is ONE object in :mod:`offline.rover.failures`:

1. Write a class deriving :class:`~offline.rover.failures.FailureKind` with its
   ``TOML_KEYS`` and ``from_toml`` (keys and their plausible ranges), ``apply`` (its
   constraints: bounds on the wheel's omega, beta, W, h, h0, its torque row, its contact),
   ``mirror``, ``check`` and ``evidence``; optionally ``start`` (start-point hints).
   For the rover: ``ROVER_KIND`` (the name fault management declares), ``ROVER_VALUE`` (the
   declared value's unit and range), ``RULES`` (what ``apply`` imposes, in the rover's
   vocabulary of :mod:`rtctl.failures`), ``ODOMETRY``, ``from_declared`` and
   ``declared_value``. Every table header then carries the description; rtctl reads it and
   needs no change (``tests/test_failure_descriptions.py`` checks ``RULES`` against ``apply``
   for every kind, and drives a kind defined in the test module).
2. List it in :data:`offline.rover.failures.KINDS`. The scenario loader, the NLP bounds,
   the continuation (which moves every bound from the nominal primitive), the independent
   check, the evidence, the mirror image and the rover then use it; nothing else changes.
3. Add an example file to ``offline/scenarios/`` and a case to the catalog benchmark
   (``tests/bench/bench_primitives.py``) and to ``tests/test_failures.py``.

World terms (external pull, per-wheel radius, steering offset, hub contact)
--------------------------------------------------------------------------
An external pull is a constant force in the body frame (:class:`ExternalForce`): the tether
``tether_force_N`` pulls along -x at O; the anchored cable of ``[tether]`` pulls with its tension
along ``bearing_deg`` from the attachment ``(attach_x_m, 0)`` on the body's x axis, so it adds
``F_x = T cos(bearing)``, ``F_y = T sin(bearing)`` and a yaw moment ``attach_x F_y`` about O.
Assumption: the cable is parallel to the terrain and attached at the height of O (where the
body and its weight act), so it has no roll or pitch moment (the simulator's planar balances
make the same assumption). Hub contact (``[hub_contact]``, :class:`~rtctl.physics.hub_drag.HubFace`):
each wheel sunk beyond the clearance meets a Rankine passive drag against its travel and a
torque against its spin (:func:`rtctl.physics.hub_drag.hub_wrench`, added to the wheel's
wrench in the NLP, the independent check and the tables' stored wrenches and Jacobians). The
defaults (no pull, the parameter set's radius on every wheel, zero offsets, no hub contact)
leave the scenario, its NLP and its table files exactly as before.
A truth file (:mod:`offline.sim.truth`, e.g. the discrepancy tool's ``accepted_truth.toml``)
applies to a scenario with :func:`scenario_with_world` (``offnominal tables build --world``).

Any rover from a file (issue 23)
-------------------------------
With ``rover`` naming a rover file (:mod:`rtctl.physics.rover_file`), the scenario's wheels are
the file's (``[wheels.<name>]`` takes its names, in file order), and :attr:`Scenario.rover_file`
holds the file; the NLP then takes its variables and balance rows from the file's suspension
(:mod:`offline.rover.primitives`). Without a ``params`` key the wheels' parameter set is the
rover file's (one parameter set shared by every wheel in this version; a file whose wheels name
different sets is refused); with one, the scenario's set is used on every wheel.
:attr:`Scenario.rover` then holds a :class:`~offline.physics.params.Rover` with the file's
weight and nominal speed and, for scales only, its wheelbase, track and pivot height
(``source`` says so): the four-wheel geometry it describes is not the rover's. Raised wheels
need the ``rocker`` suspension; a stuck steering angle needs a steerable wheel within the
file's steering range. Without a ``rover`` key the scenario is the mini rover, exactly as
before.

Units are checked where a value is implausible for its unit: ``speed_m_s = 3.0`` is refused
with a hint that it looks like cm/s; slopes beyond 60 deg are refused (degrees expected).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, Sequence

from rtctl.physics.hub_drag import HUB_KEYS, HubFace
from rtctl.physics.parameters import read_toml
from rtctl.physics.rover_file import SHIPPED_ROVERS, RoverFileError, RoverSpec, driving_backward, load_rover_file
from ..physics.params import (
    ROVER_MINI_T72,
    SOIL_DISSERTATION_T53_GROUSERED,
    TUNING_T72_LINEAR,
    WHEEL_GROUSERED_PUBLISHED_CODE,
    ParameterError,
    ParameterSet,
    Rover,
    load_toml,
)
from .failures import (
    KINDS,
    FailureKind,
    FailureSpecError,
    Locked,
    Raised,
    RimSpeedCap,
    SteerRange,
    StuckSteering,
    TorqueLimit,
    TrenchGoal,
    Unpowered,
)
from .statics import WHEELS

__all__ = ["ScenarioError", "ExternalForce", "WheelFailure", "TrenchGoal", "Scenario", "load_scenario", "PARAM_PRESETS",
           "PARAM_FILE_PRESETS", "param_preset_file",
           "ROVER_PRESETS", "example_scenarios", "rover_scale_record", "scenario_with_world", "section_table", "MAX_SPEED", "MAX_SLOPE_DEG", "wheel_tables"]


def wheel_tables(path: Path, data: Mapping[str, Any], known: Iterable[str],
                 error: Callable[[str], Exception], wheels: Sequence[str] = WHEELS) -> Iterator[tuple[str, dict[str, Any]]]:
    """The ``[wheels.FR]`` ... tables of a parsed TOML file (scenario or truth), checked.

    Yields ``(wheel name, table)`` in file order. Raises ``error(message)`` naming ``path``
    when ``[wheels]`` is not a table of tables, a wheel name is not one of ``wheels`` (default
    FR, FL, RR, RL; a rover file's wheel names), or a key is not in ``known``.
    """
    names = tuple(wheels)
    known = sorted(known)
    tables = data.get("wheels", {})
    if not isinstance(tables, dict):
        raise error(f"{path}: [wheels] must hold tables [wheels.{names[0]}] ...")
    for name, tab in tables.items():
        if name not in names:
            raise error(f"{path}: [wheels.{name}] unknown wheel; use one of {list(names)}")
        if not isinstance(tab, dict):
            raise error(f"{path}: [wheels.{name}] must be a table")
        bad = sorted(set(tab) - set(known))
        if bad:
            raise error(f"{path}: [wheels.{name}] unknown key(s) {bad}; known: {known}")
        yield name, tab


class ScenarioError(ValueError):
    """A scenario file is malformed or physically impossible; the message names file and key."""


PARAM_PRESETS: dict[str, ParameterSet] = {
    "dissertation-ch7": ParameterSet(
        SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, TUNING_T72_LINEAR,
        notes="chapter 7: Table 5.3 soil, Table 7.2 wheel and linear a(beta)",
    ),
}
ROVER_PRESETS: dict[str, Rover] = {"mini-rover-t72": ROVER_MINI_T72}
PARAM_FILE_PRESETS: dict[str, str] = {
    "calibrated-sand": "calibrated_grousered.toml",
    "calibrated-sand-soil-flow": "calibrated_grousered_soil_flow.toml",
    "dissertation-t54-grousered": "dissertation_grousered_t54.toml",
    "dissertation-t54-smooth": "dissertation_smooth_t54.toml",
}
"""Parameter files shipped in ``offline/data``, by name (``params = "calibrated-sand"`` in a
scenario works from any folder): the sand calibrated against the 189 single-wheel trials
(``offnominal calibrate``, classic exit angle; the parameter file of every shipped table) and its
soil-flow variant, and the dissertation's Table 5.2 wheels with Table 5.3 soil and Table 5.4's
per-angle contact tuning. ``dissertation-ch7`` (:data:`PARAM_PRESETS`) is chapter 7's set."""


def param_preset_file(ref: str) -> Path | None:
    """The shipped parameter file a preset name stands for (:data:`PARAM_FILE_PRESETS`), else None."""
    name = PARAM_FILE_PRESETS.get(ref)
    return None if name is None else Path(str(resources.files("offline").joinpath("data", name)))


@dataclass(frozen=True)
class WheelFailure:
    """The failure kinds on one wheel (all optional; defaults mean nominal).

    The keyword fields are shorthands for the built-in kinds of :mod:`offline.rover.failures`;
    :meth:`kinds` returns the kind objects that carry the constraints, checks and evidence.
    A kind without a shorthand goes into ``extra``.
    """

    rim_speed_max: float = math.inf
    steer_stuck: float | None = None
    locked: bool = False
    unpowered: bool = False
    raised: bool = False
    torque_limit: float = math.inf
    steer_min: float = -math.pi / 2
    steer_max: float = math.pi / 2
    extra: tuple[FailureKind, ...] = ()

    @property
    def nominal(self) -> bool:
        """True when no failure kind applies."""
        return not self.kinds()

    def kinds(self) -> tuple[FailureKind, ...]:
        """The failure-kind objects, in :data:`offline.rover.failures.KINDS` order."""
        out: list[FailureKind] = []
        if self.steer_min > -math.pi / 2 or self.steer_max < math.pi / 2:
            out.append(SteerRange(self.steer_min, self.steer_max))
        if self.steer_stuck is not None:
            out.append(StuckSteering(self.steer_stuck))
        if math.isfinite(self.rim_speed_max):
            out.append(RimSpeedCap(self.rim_speed_max))
        if self.locked:
            out.append(Locked())
        if self.unpowered:
            out.append(Unpowered())
        if self.raised:
            out.append(Raised())
        if math.isfinite(self.torque_limit):
            out.append(TorqueLimit(self.torque_limit))
        return (*out, *self.extra)

    @classmethod
    def from_kinds(cls, kinds: "list[FailureKind] | tuple[FailureKind, ...]") -> "WheelFailure":
        """Gather kind objects into one wheel's record (built-in kinds into their fields)."""
        kw: dict[str, Any] = {}
        extra: list[FailureKind] = []
        for k in kinds:
            if isinstance(k, SteerRange):
                kw.update(steer_min=k.steer_min, steer_max=k.steer_max)
            elif isinstance(k, StuckSteering):
                kw["steer_stuck"] = k.angle
            elif isinstance(k, RimSpeedCap):
                kw["rim_speed_max"] = k.cap
            elif isinstance(k, Locked):
                kw["locked"] = True
            elif isinstance(k, Unpowered):
                kw["unpowered"] = True
            elif isinstance(k, Raised):
                kw["raised"] = True
            elif isinstance(k, TorqueLimit):
                kw["torque_limit"] = k.limit
            else:
                extra.append(k)
        return cls(**kw, extra=tuple(extra))

    def mirror(self) -> "WheelFailure":
        """The failures of the mirror-image wheel (every kind mirrored)."""
        return WheelFailure.from_kinds([k.mirror() for k in self.kinds()])


@dataclass(frozen=True)
class ExternalForce:
    """A constant external force on the rover in its body frame (tether, drawbar, anchored cable).

    Attributes
    ----------
    fx, fy : float
        Force on the rover along its x (forward) and y (left) axes, N (a pull from behind:
        ``fx < 0``).
    mz : float
        Its yaw moment about the reference point O, N m (``attach_x * fy`` for a cable attached
        at ``(attach_x, 0)``).
    """

    fx: float = 0.0
    fy: float = 0.0
    mz: float = 0.0

    @property
    def zero(self) -> bool:
        """True when the force and moment are all zero."""
        return self.fx == 0.0 and self.fy == 0.0 and self.mz == 0.0

    def mirror(self) -> "ExternalForce":
        """The left-right mirror image (lateral force and yaw moment negated)."""
        return ExternalForce(self.fx, -self.fy, -self.mz)

    def __add__(self, other: "ExternalForce") -> "ExternalForce":
        """Both forces acting together."""
        return ExternalForce(self.fx + other.fx, self.fy + other.fy, self.mz + other.mz)

    @classmethod
    def tether(cls, force: float) -> "ExternalForce":
        """A pull of ``force`` N along the rover's -x at O (the simulator's ``tether_force``)."""
        return cls(-float(force), 0.0, 0.0) if force else cls()

    @classmethod
    def cable(cls, tension: float, bearing: float, attach_x: float) -> "ExternalForce":
        """A cable at ``tension`` N pulling along ``bearing`` rad (from the rover's +x, CCW) from
        ``(attach_x, 0)`` m on the body's x axis."""
        fy = tension * math.sin(bearing)
        return cls(tension * math.cos(bearing), fy, attach_x * fy)


_OMIT = {"omit_default": True}  # table encoding leaves the field out at its default (old files unchanged)


@dataclass(frozen=True)
class Scenario:
    """A steady straight-driving problem, SI units."""

    name: str
    params: ParameterSet
    rover: Rover
    exit_angle: str = "classic"
    speed: float = 0.03
    slope: float = 0.0
    mz_offset: float = 0.0
    fy_offset: float = 0.0
    failures: Mapping[str, WheelFailure] = field(default_factory=dict)
    trench: TrenchGoal | None = None
    description: str = ""
    source: str = ""
    cross_slope: float = 0.0
    """Roll of the terrain about the travel direction, rad, left side up positive."""
    external: ExternalForce | None = field(default=None, metadata=_OMIT)
    """Constant external pull in the body frame (None: none)."""
    wheel_radius: tuple[float, ...] | None = field(default=None, metadata=_OMIT)
    """Rim radius per wheel (FR, FL, RR, RL), m (None: the parameter set's on every wheel)."""
    steer_offset: tuple[float, ...] | None = field(default=None, metadata=_OMIT)
    """True minus encoder steer angle per wheel, rad (None: zero); steering failures are in encoder terms."""
    hub_contact: HubFace | None = field(default=None, metadata=_OMIT)
    """Hub contact on every wheel (None: none; :mod:`rtctl.physics.hub_drag`)."""
    rover_file: RoverSpec | None = field(default=None, metadata=_OMIT)
    """The rover file the scenario names (None: the mini rover of :attr:`rover`, Table 7.2)."""

    @property
    def wheels(self) -> tuple[str, ...]:
        """Wheel names in layout order: the rover file's, else FR, FL, RR, RL."""
        return WHEELS if self.rover_file is None else self.rover_file.wheel_names

    def failure(self, wheel: str) -> WheelFailure:
        """The wheel's failures (nominal when none), steering angles in encoder terms."""
        return self.failures.get(wheel, WheelFailure())

    def offset(self, wheel: str) -> float:
        """The wheel's steering offset (true minus encoder angle), rad."""
        return 0.0 if self.steer_offset is None else float(self.steer_offset[self.wheels.index(wheel)])

    def physical_failure(self, wheel: str) -> WheelFailure:
        """The wheel's failures with steering angles in physical terms (encoder + offset).

        Without an offset the same object as :meth:`failure`. With one, the steering range
        (the encoder's +-90 deg by default) and a stuck angle move by the offset.
        """
        f = self.failure(wheel)
        d = self.offset(wheel)
        if d == 0.0:
            return f
        stuck = None if f.steer_stuck is None else f.steer_stuck + d
        return replace(f, steer_min=f.steer_min + d, steer_max=f.steer_max + d, steer_stuck=stuck)

    def rim_radius(self, wheel: str) -> float | None:
        """The wheel's rim radius, m (None: the parameter set's)."""
        return None if self.wheel_radius is None else float(self.wheel_radius[self.wheels.index(wheel)])

    def with_(self, **kw: Any) -> "Scenario":
        """A copy with fields replaced (e.g. ``slope=...``)."""
        return replace(self, **kw)


_SCENARIO_KEYS = {"name": str, "description": str, "params": str, "rover": str, "exit_angle": str, "speed_m_s": float,
                  "slope_deg": float, "cross_slope_deg": float, "yaw_moment_offset_Nm": float, "lateral_force_offset_N": float,
                  "grouser_volume_fraction": float, "grouser_area_ratio": float, "tether_force_N": float,
                  "drive_direction": str}
_WORLD_WHEEL_KEYS = ("radius_mm", "steer_offset_deg")
_WHEEL_KEYS: tuple[str, ...] = tuple(k for kind in KINDS for k in kind.TOML_KEYS) + _WORLD_WHEEL_KEYS
_TETHER_KEYS = {"tension_N": float, "bearing_deg": float, "attach_x_m": float}
MAX_TETHER_N = 1000.0
"""Largest |tether force| accepted, N (beyond it: not a tether on a small rover, or wrong units)."""
MAX_SPEED = 0.5
"""Largest plausible travel speed, m/s (planetary rovers drive at cm/s; 3.0 is a unit slip)."""
MAX_SLOPE_DEG = 60.0
"""Largest |slope| and |cross slope| accepted, deg (beyond it: degrees expected, or not a slope)."""
_TRENCH_KEYS = {"wheel": str, "clean_side": bool, "min_depth_m": float, "min_depth": str, "min_flat_width_m": float,
                "target_depth_m": float}


def _get(path: str, table: Mapping[str, Any], key: str, typ: type, where: str) -> Any:
    v = table[key]
    if typ is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ScenarioError(f"{path}: [{where}] {key} must be a number, got {v!r}")
        if not math.isfinite(float(v)):
            raise ScenarioError(f"{path}: [{where}] {key} must be finite, got {v!r}")
        return float(v)
    if not isinstance(v, typ):
        raise ScenarioError(f"{path}: [{where}] {key} must be a {typ.__name__}, got {v!r}")
    return v


def _resolve_params(path: Path, ref: str, zeta: float | None, mu: float | None = None) -> ParameterSet:
    if ref in PARAM_PRESETS:
        ps = PARAM_PRESETS[ref]
    else:
        p = param_preset_file(ref) or ((path.parent / ref) if not Path(ref).is_absolute() else Path(ref))
        if not p.is_file():
            presets = sorted([*PARAM_PRESETS, *PARAM_FILE_PRESETS])
            raise ScenarioError(f"{path}: [scenario] params = {ref!r}: neither a preset ({', '.join(presets)}) nor a "
                                f"file ({p} does not exist; a path is relative to the scenario file's folder)")
        try:
            loaded = load_toml(p)
        except ParameterError as exc:
            raise ScenarioError(f"{path}: [scenario] params = {ref!r}: {exc}") from None
        if "parameter_set" not in loaded:
            raise ScenarioError(f"{path}: [scenario] params = {ref!r} has no [soil], [wheel] and [tuning]")
        ps = loaded["parameter_set"]
    if zeta is not None:
        if not 0.0 <= zeta <= 1.0:
            raise ScenarioError(f"{path}: [scenario] grouser_volume_fraction = {zeta} outside [0, 1]")
        ps = replace(ps, wheel=replace(ps.wheel, grouser_volume_fraction=zeta))
    if mu is not None:
        if not 0.0 <= mu <= 1.0:
            raise ScenarioError(f"{path}: [scenario] grouser_area_ratio = {mu} outside [0, 1]")
        ps = replace(ps, wheel=replace(ps.wheel, grouser_area_ratio=mu))
    return ps


def rover_scale_record(spec: RoverSpec) -> Rover:
    """A :class:`~offline.physics.params.Rover` carrying a rover file's weight and nominal speed,
    and (for scales and plausibility limits only) its wheelbase, track and the height of its
    top pivots above the wheel centres: :attr:`Scenario.rover` of a rover-file scenario.

    Parameters
    ----------
    spec : RoverSpec
        The rover file.
    """
    xs = [w.position[0] for w in spec.wheels]
    ys = [w.position[1] for w in spec.wheels]
    zw = sum(w.position[2] for w in spec.wheels) / len(spec.wheels)
    tops = [lk.pivot[2] for lk in spec.links if lk.parent == "body"] or [0.0]
    return Rover(rocker_length=max(xs) - min(xs), pivot_height=max(tops[0] - zw, 1e-3), track_width=max(ys) - min(ys),
                 weight=spec.weight, travel_speed=spec.travel_speed or 0.03, name=spec.name,
                 source=f"rover file {spec.path or spec.name}: weight and speed; wheelbase, track, pivot height for scales only")


def _resolve_rover(path: Path, ref: str) -> Rover | RoverSpec:
    if ref in ROVER_PRESETS:
        return ROVER_PRESETS[ref]
    shipped = SHIPPED_ROVERS / f"{ref}.toml"
    if "/" not in ref and "\\" not in ref and not ref.endswith(".toml") and shipped.is_file():
        return _rover_file(path, ref, shipped)
    p = (path.parent / ref) if not Path(ref).is_absolute() else Path(ref)
    if p.is_file():
        head = read_toml(p, ScenarioError, "rover file")
        if "suspension" in head:
            return _rover_file(path, ref, p)
    try:
        loaded = load_toml(p)
    except ParameterError as exc:
        raise ScenarioError(f"{path}: [scenario] rover = {ref!r}: {exc}") from None
    if "rover" not in loaded:
        raise ScenarioError(f"{path}: [scenario] rover = {ref!r} has no [rover] section")
    return loaded["rover"]


def _rover_file(path: Path, ref: str, p: Path) -> RoverSpec:
    try:
        return load_rover_file(p.resolve())
    except RoverFileError as exc:
        raise ScenarioError(f"{path}: [scenario] rover = {ref!r}: {exc}") from None


def _rover_file_params(path: Path, spec: RoverSpec) -> str:
    """The one parameter set (preset name or absolute file path) of a rover file's wheels."""
    refs = {w: spec.wheel_params(w) for w in spec.wheel_names}
    if len(set(refs.values())) != 1:
        raise ScenarioError(f"{path}: [scenario] rover = {spec.path or spec.name!r}: its wheels name different parameter "
                            f"sets {sorted(set(refs.values()))}; one set shared by every wheel is supported: give "
                            "[scenario] params to use one")
    ref = next(iter(refs.values()))
    return str(Path(ref).resolve()) if ref.endswith(".toml") else ref


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file.

    Raises
    ------
    ScenarioError
        With the file, section, wheel and key in the message, e.g.
        ``stuck.toml: [wheels.RR] steer_stuck_deg = 400 outside [-90, 90]``.
    """
    p = Path(path)
    data = read_toml(p, ScenarioError, "scenario file")
    unknown = sorted(set(data) - {"scenario", "wheels", "trench", "tether", "hub_contact"})
    if unknown:
        raise ScenarioError(f"{p}: unknown section(s) {unknown}; expected [scenario], [wheels.<FR|FL|RR|RL>], [trench], "
                            "[tether], [hub_contact]")
    sc = data.get("scenario")
    if not isinstance(sc, dict):
        raise ScenarioError(f"{p}: missing [scenario] section")
    bad = sorted(set(sc) - set(_SCENARIO_KEYS))
    if bad:
        raise ScenarioError(f"{p}: [scenario] unknown key(s) {bad}; known: {sorted(_SCENARIO_KEYS)}")
    vals = {k: _get(str(p), sc, k, t, "scenario") for k, t in _SCENARIO_KEYS.items() if k in sc}
    name = vals.get("name", p.stem)
    exit_angle = vals.get("exit_angle", "classic")
    if exit_angle not in ("classic", "soil_flow"):
        raise ScenarioError(f"{p}: [scenario] exit_angle = {exit_angle!r}; use 'classic' or 'soil_flow'")
    speed = vals.get("speed_m_s", 0.03)
    if not 0.0 < speed <= MAX_SPEED:
        cm = f"; if it is in cm/s, write speed_m_s = {speed / 100:g}" if speed > MAX_SPEED else ""
        raise ScenarioError(f"{p}: [scenario] speed_m_s = {speed} m/s outside (0, {MAX_SPEED}] m/s, implausible for a "
                            f"planetary rover (is it in cm/s?){cm}")
    slope_deg = vals.get("slope_deg", 0.0)
    cross_deg = vals.get("cross_slope_deg", 0.0)
    for key, val in (("slope_deg", slope_deg), ("cross_slope_deg", cross_deg)):
        if not -MAX_SLOPE_DEG <= val <= MAX_SLOPE_DEG:
            raise ScenarioError(f"{p}: [scenario] {key} = {val} outside [-{MAX_SLOPE_DEG:g}, {MAX_SLOPE_DEG:g}] deg "
                                "(degrees expected; no rover drives steeper soft-soil slopes)")
    resolved = _resolve_rover(p, vals.get("rover", "mini-rover-t72"))
    direction = vals.get("drive_direction", "forward")
    if direction not in ("forward", "backward"):
        raise ScenarioError(f"{p}: [scenario] drive_direction = {direction!r}; use 'forward' or 'backward'")
    if direction == "backward":
        if not isinstance(resolved, RoverSpec):
            raise ScenarioError(f"{p}: [scenario] drive_direction = 'backward' needs a rover file (rover = "
                                "\"mini_rover_t72\" for the mini rover)")
        resolved = driving_backward(resolved)
    spec = resolved if isinstance(resolved, RoverSpec) else None
    rover = rover_scale_record(resolved) if isinstance(resolved, RoverSpec) else resolved
    wheel_names = WHEELS if spec is None else spec.wheel_names
    if spec is not None and "params" not in vals:
        params_ref = _rover_file_params(p, spec)
    else:
        params_ref = vals.get("params", "dissertation-ch7")
    params = _resolve_params(p, params_ref, vals.get("grouser_volume_fraction"), vals.get("grouser_area_ratio"))
    failures: dict[str, WheelFailure] = {}
    radius: list[float | None] = [None] * len(wheel_names)
    offset = [0.0] * len(wheel_names)
    for wname, tab in wheel_tables(p, data, _WHEEL_KEYS, ScenarioError, wheel_names):
        i = wheel_names.index(wname)
        if "radius_mm" in tab:
            r = 1e-3 * _get(str(p), tab, "radius_mm", float, f"wheels.{wname}")
            if not 0.5 * params.wheel.radius <= r <= 2.0 * params.wheel.radius:
                raise ScenarioError(f"{p}: [wheels.{wname}] radius_mm = {1e3 * r:g} outside [0.5, 2] x the parameter "
                                    f"set's {1e3 * params.wheel.radius:g} mm (millimetres expected)")
            radius[i] = r
        if "steer_offset_deg" in tab:
            d = _get(str(p), tab, "steer_offset_deg", float, f"wheels.{wname}")
            if not -30.0 <= d <= 30.0:
                raise ScenarioError(f"{p}: [wheels.{wname}] steer_offset_deg = {d} outside [-30, 30] (degrees expected)")
            offset[i] = math.radians(d)
        tab = {k: v for k, v in tab.items() if k not in _WORLD_WHEEL_KEYS}
        if not tab:
            continue
        kinds = []
        for kind in KINDS:
            mine = {k: tab[k] for k in kind.TOML_KEYS if k in tab}
            try:
                obj = kind.from_toml(mine) if mine else None
            except FailureSpecError as exc:
                raise ScenarioError(f"{p}: [wheels.{wname}] {exc}") from None
            if obj is not None:
                kinds.append(obj)
        f = WheelFailure.from_kinds(kinds)
        if f.steer_stuck is not None and not f.steer_min - 1e-12 <= f.steer_stuck <= f.steer_max + 1e-12:
            raise ScenarioError(f"{p}: [wheels.{wname}] steer_stuck_deg outside the wheel's steer range")
        if f.locked and f.unpowered:
            raise ScenarioError(f"{p}: [wheels.{wname}] locked and unpowered contradict each other: a locked wheel "
                                "carries a braking torque, an unpowered one carries none")
        if f.raised and (f.locked or f.unpowered or f.steer_stuck is not None or math.isfinite(f.torque_limit)):
            raise ScenarioError(f"{p}: [wheels.{wname}] a raised wheel has no ground contact: its other failure "
                                "keys have no effect; remove them")
        if spec is not None:
            _check_against_rover_file(p, wname, f, spec)
        failures[wname] = f
    if sum(f.raised for f in failures.values()) > 1:
        raise ScenarioError(f"{p}: more than one raised wheel: a 4-wheel rover cannot stand on two wheels")
    trench = None
    if "trench" in data:
        tv = _section(p, data["trench"], "trench", _TRENCH_KEYS, "wheel",
                      "the trench goal is a table, e.g. [trench] wheel = \"RR\", clean_side = true, min_depth_m = 0.02")
        if tv["wheel"] not in wheel_names:
            raise ScenarioError(f"{p}: [trench] wheel = {tv['wheel']!r}; use one of {list(wheel_names)}")
        if failures.get(tv["wheel"], WheelFailure()).raised:
            raise ScenarioError(f"{p}: [trench] wheel {tv['wheel']} is raised and cannot dig")
        min_depth = tv.get("min_depth_m", 0.0)
        if "min_depth" in tv:
            if tv["min_depth"] != "half_width":
                raise ScenarioError(f"{p}: [trench] min_depth = {tv['min_depth']!r}; use 'half_width' or min_depth_m")
            min_depth = params.wheel.width / 2
        for key in ("min_depth_m", "min_flat_width_m", "target_depth_m"):
            if key in tv and not 0.0 <= tv[key] <= 2 * params.wheel.radius:
                raise ScenarioError(f"{p}: [trench] {key} = {tv[key]} m outside [0, 2 r] (metres expected)")
        trench = TrenchGoal(tv["wheel"], tv.get("clean_side", False), min_depth, tv.get("min_flat_width_m", 0.0),
                            tv.get("target_depth_m"))
    external = _external(p, vals.get("tether_force_N", 0.0), data.get("tether"))
    return Scenario(
        name=name, params=params, rover=rover, exit_angle=exit_angle, speed=speed, slope=math.radians(slope_deg),
        cross_slope=math.radians(cross_deg),
        mz_offset=vals.get("yaw_moment_offset_Nm", 0.0), fy_offset=vals.get("lateral_force_offset_N", 0.0),
        failures=failures, trench=trench, description=vals.get("description", ""), source=str(p),
        external=external,
        wheel_radius=(tuple(params.wheel.radius if r is None else r for r in radius)
                      if any(r is not None and r != params.wheel.radius for r in radius) else None),
        steer_offset=tuple(offset) if any(offset) else None,
        hub_contact=_hub_contact(p, data["hub_contact"]) if "hub_contact" in data else None,
        rover_file=spec,
    )


def _check_against_rover_file(p: Path, wname: str, f: WheelFailure, spec: RoverSpec) -> None:
    """A wheel's failures that the rover file's wheel or suspension cannot have."""
    w = spec.wheel(wname)
    where = f"{p}: [wheels.{wname}]"
    if f.raised and spec.suspension != "rocker":
        raise ScenarioError(f"{where} raised: a raised wheel is modelled for the 'rocker' suspension only, not the rover "
                            f"file's {spec.suspension!r}")
    if f.steer_stuck is not None:
        if not w.steerable:
            raise ScenarioError(f"{where} steer_stuck_deg: wheel {wname} of rover {spec.name!r} is not steerable (its "
                                "heading is fixed straight ahead)")
        if not w.steer_min - 1e-12 <= f.steer_stuck <= w.steer_max + 1e-12:
            raise ScenarioError(f"{where} steer_stuck_deg = {math.degrees(f.steer_stuck):g} outside the rover file's "
                                f"steering range [{math.degrees(w.steer_min):g}, {math.degrees(w.steer_max):g}] deg")


def section_table(path: Path, t: Any, name: str, known: Iterable[str], required: str, what: str,
                  error: Callable[[str], Exception]) -> dict[str, Any]:
    """A ``[name]`` table of a parsed TOML file (scenario or truth), checked: a table, only
    ``known`` keys, the ``required`` key. Raises ``error(message)`` naming ``path`` (``what``:
    the hint when it is not a table)."""
    if not isinstance(t, dict):
        raise error(f"{path}: {name} = {t!r}: {what}")
    bad = sorted(set(t) - set(known))
    if bad:
        raise error(f"{path}: [{name}] unknown key(s) {bad}; known: {sorted(known)}")
    if required not in t:
        raise error(f"{path}: [{name}] missing key {required!r}")
    return t


def _section(p: Path, t: Any, name: str, keys: Mapping[str, type], required: str, what: str) -> dict[str, Any]:
    """A checked ``[name]`` table (:func:`section_table`) with its values typed (:func:`_get`)."""
    t = section_table(p, t, name, keys, required, what, ScenarioError)
    return {k: _get(str(p), t, k, typ, name) for k, typ in keys.items() if k in t}


def _hub_contact(p: Path, t: Any) -> HubFace:
    """The ``[hub_contact]`` section (keys and ranges: :data:`rtctl.physics.hub_drag.HUB_KEYS`)."""
    tv = _section(p, t, "hub_contact", {k: float for k in HUB_KEYS}, "clearance_mm",
                  "the hub contact is a table [hub_contact] with clearance_mm, face_width_mm, arm_mm")
    si = {}
    for key, v in tv.items():
        name, factor, lo, hi = HUB_KEYS[key]
        if not lo <= v <= hi:
            raise ScenarioError(f"{p}: [hub_contact] {key} = {v} outside [{lo:g}, {hi:g}] (millimetres expected)")
        si[name] = factor * v
    return HubFace(**si)


def _external(p: Path, tether: float, cable: Any) -> ExternalForce | None:
    """The scenario's external pull: ``tether_force_N`` along -x plus the ``[tether]`` cable."""
    if abs(tether) > MAX_TETHER_N:
        raise ScenarioError(f"{p}: [scenario] tether_force_N = {tether} outside [-{MAX_TETHER_N:g}, {MAX_TETHER_N:g}] N "
                            "(newtons expected)")
    ext = ExternalForce.tether(tether)
    if cable is not None:
        tv = _section(p, cable, "tether", _TETHER_KEYS, "tension_N",
                      "the cable is a table [tether] with tension_N, bearing_deg, attach_x_m")
        if not 0.0 <= tv["tension_N"] <= MAX_TETHER_N:
            raise ScenarioError(f"{p}: [tether] tension_N = {tv['tension_N']} outside [0, {MAX_TETHER_N:g}] N (a cable "
                                "only pulls; newtons expected)")
        if abs(tv.get("attach_x_m", 0.0)) > 2.0:
            raise ScenarioError(f"{p}: [tether] attach_x_m = {tv['attach_x_m']} outside [-2, 2] m (metres expected)")
        ext = ext + ExternalForce.cable(tv["tension_N"], math.radians(tv.get("bearing_deg", 180.0)),
                                        tv.get("attach_x_m", 0.0))
    return None if ext.zero else ext


def example_scenarios() -> list[Path]:
    """The scenario files shipped in ``offline/scenarios``."""
    folder = Path(str(resources.files("offline").joinpath("scenarios")))
    return sorted(folder.glob("*.toml"))


def scenario_with_world(sc: Scenario, world: Any) -> Scenario:
    """The scenario in a world described by a truth file (``offnominal tables build --world``).

    ``world`` is an :class:`offline.sim.truth.Truth` (read by the caller with
    :func:`offline.sim.truth.load_truth`, e.g. the discrepancy tool's ``accepted_truth.toml``):

    * soil: the world's (its ``soil_stiffness_scale`` and parameter file applied); wheel
      geometry other than the radius and the contact tuning stay the scenario's;
    * slope, cross slope: added to the scenario's own (a table's slope / cross-slope axes give
      the absolute inclination at each grid point, as the rover's IMU reads it);
    * ``tether_force_N`` and the anchored cable (``[tether_anchor]``: tension, bearing from the
      rover's heading, attachment x; in steady straight driving a constant body-frame force):
      added to the scenario's external pull (:class:`ExternalForce`);
    * per-wheel rim radius and steering offset: replace the scenario's;
    * hub contact (``[hub_contact]``): replaces the scenario's (its drag takes the world's soil).

    Raises
    ------
    ScenarioError
        The world's radii are implausible for the scenario's wheel (outside 0.5-2 times it).
    """
    ps = replace(sc.params, soil=world.params.soil)
    r0 = ps.wheel.radius
    radii = tuple(float(r) for r in world.wheel_radius)
    if not all(0.5 * r0 <= r <= 2.0 * r0 for r in radii):
        raise ScenarioError(f"world {Path(world.source).name or '?'}: wheel radii {[1e3 * r for r in radii]} mm are not "
                            f"within 0.5-2 x the scenario's {1e3 * r0:g} mm wheel")
    ext = (sc.external or ExternalForce()) + ExternalForce.tether(float(world.tether_force))
    anchor = getattr(world, "anchor", None)
    if anchor is not None:
        ext = ext + ExternalForce.cable(float(anchor["tension"]), float(anchor["bearing"]), float(anchor.get("attach_x", 0.0)))
    offsets = tuple(float(o) for o in world.steer_offset)
    hub = getattr(world, "hub", None)
    return replace(sc, params=ps, slope=sc.slope + world.slope, cross_slope=sc.cross_slope + world.cross_slope,
                   external=None if ext.zero else ext,
                   wheel_radius=radii if any(r != r0 for r in radii) else None,
                   steer_offset=offsets if any(offsets) else None,
                   hub_contact=sc.hub_contact if hub is None else HubFace(**hub))
