"""Failure kinds and trenching goals of the steady-state NLP (7.25): one object per kind.

Each kind says, in one place, everything the optimizer needs to know about it:

* ``TOML_KEYS`` and :meth:`FailureKind.from_toml`: how it is written in a scenario file
  (``[wheels.<name>]`` keys) and which values are physically plausible;
* :meth:`FailureKind.apply`: its constraints, as bounds on the wheel's decision variables
  (``omega``, ``beta``, ``W``, ``h``, ``h0``), on its wheel-torque row and on the wheel's
  ground contact (:class:`WheelBounds`);
* :meth:`FailureKind.mirror`: the same failure on the left-right mirror-image rover;
* :meth:`FailureKind.check`: its residuals at a solution, for the independent numeric check;
* :meth:`FailureKind.evidence`: what the furthest feasible point reached shows when the
  target could not be reached (e.g. the lowest rim speed actually reached by a capped wheel);
* :meth:`FailureKind.start`: optional hints for start points (a stuck wheel's angle);
* ``ROVER_KIND``, ``ROVER_VALUE``, ``RULES``, ``ODOMETRY`` and :meth:`FailureKind.rover_description`:
  the same constraints as data for the rover. Every table header carries the description of
  every kind the builder knew (``failure_kinds``) and the table's own failures (``failures``);
  rtctl reads them (:mod:`rtctl.failures`) and has no list of kinds of its own, so a kind added
  here drives on the rover with no rtctl change. ``RULES`` must say what :meth:`apply` does:
  ``tests/test_failure_descriptions.py`` applies both to the same bounds for every kind.

Adding a failure kind means adding one class here and listing it in :data:`KINDS`
(see the recipe in :mod:`offline.rover.scenario`). The trenching goal (7.28)-(7.29) is
:class:`TrenchGoal`, with the same methods for its three constraint rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping

__all__ = [
    "FailureKind",
    "WheelBounds",
    "SolutionView",
    "SteerRange",
    "StuckSteering",
    "RimSpeedCap",
    "Locked",
    "Unpowered",
    "Raised",
    "TorqueLimit",
    "TrenchGoal",
    "KINDS",
    "FailureSpecError",
    "with_task",
]


class FailureSpecError(ValueError):
    """A failure value that is out of its physical range; the message names the key."""


@dataclass
class WheelBounds:
    """Mutable bounds of one wheel, physical units, filled by the failure kinds.

    Attributes
    ----------
    lo, hi : dict
        Bounds per wheel variable (``omega`` rad/s, ``beta`` rad, ``W`` N, ``h``, ``h0`` m).
    torque : tuple
        Bounds on the wheel torque row (soil moment M_y, N m).
    contact : float
        1 in ground contact, 0 raised.
    rim_radius : float
        Command radius, m: the shearing radius r_s of the parameter set's wheel, with which the
        rover's software turns a rim-speed command into a wheel speed (rim-speed command =
        omega r_s), so a rim-speed cap (7.30) is a cap on the command. A wheel whose own radius
        differs (``[wheels.X] radius_mm``) has it in its physics only.
    speed : float
        Travel speed, m/s.
    """

    lo: dict[str, float]
    hi: dict[str, float]
    torque: tuple[float, float] = (-math.inf, math.inf)
    contact: float = 1.0
    rim_radius: float = 1.0
    speed: float = 0.03


@dataclass(frozen=True)
class SolutionView:
    """One wheel of a solution or of the furthest point reached, physical units, as the
    failure kinds need it for checks and evidence."""

    omega: float
    beta: float
    load: float
    sinkage: float
    torque: float  # soil moment M_y about the axle (motor torque = -M_y), N m
    rim_radius: float  # command radius (WheelBounds.rim_radius)
    speed: float

    @property
    def rim_speed(self) -> float:
        """Rim-speed command omega r_s (command radius), m/s."""
        return self.omega * self.rim_radius


_MIRROR_WHEEL = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}


def _num(values: Mapping[str, Any], key: str, lo: float, hi: float, unit_hint: str = "") -> float:
    v = values[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise FailureSpecError(f"{key} must be a finite number, got {v!r}")
    v = float(v)
    if not lo <= v <= hi:
        raise FailureSpecError(f"{key} = {v} outside [{lo}, {hi}]{unit_hint}")
    return v


def _flag(values: Mapping[str, Any], key: str) -> bool:
    v = values[key]
    if not isinstance(v, bool):
        raise FailureSpecError(f"{key} must be true or false, got {v!r}")
    return v


class FailureKind:
    """Base of the failure kinds (see the module docstring for the interface)."""

    TOML_KEYS: ClassVar[tuple[str, ...]] = ()
    """Keys of ``[wheels.<name>]`` this kind reads."""

    ROVER_KIND: ClassVar[str] = ""
    """The kind's name in the rover's :class:`rtctl.messages.FailureDeclaration` (``""``: the
    rover cannot declare it)."""

    ROVER_VALUE: ClassVar[Mapping[str, Any] | None] = None
    """The declared value: ``name``, ``unit``, plausible range ``lo``/``hi`` (SI), ``required``
    (False: NaN is allowed and means what the rules say, e.g. "at the measured angle"); None:
    the kind takes no value (a flag)."""

    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = ()
    """What :meth:`apply` imposes, as data in the rover's vocabulary (:mod:`rtctl.failures`):
    each rule names its target ``on`` (a wheel variable ``omega``, ``beta``, ``W``, ``h``,
    ``h0``; ``rim_speed`` = omega x command radius; the wheel-torque row ``torque``; the
    parameters ``contact`` and ``pivot_locked``) and either ``fix`` (both bounds set), ``lo``
    / ``hi`` (tightened) or ``free`` (both bounds removed), each an affine expression
    ``{"const": c, "value": a, "speed": b, "value_speed": d}`` = c + a v + b V + d v V of the
    declared value v and the travel speed V (or ``{"bound": "lo"}``, the target's own lower
    bound); ``frame: "encoder"`` on a steering rule means the value is an encoder angle (the
    wheel's steering offset is added); ``prefer_measured: true`` that a measured steering angle
    replaces the declared one."""

    ODOMETRY: ClassVar[bool] = True
    """Whether the failed wheel's speed still tells the travel speed (False: leave it out of the
    odometry)."""

    @classmethod
    def from_declared(cls, value: float) -> "FailureKind":
        """The kind from the rover's declared value (NaN for a flag kind)."""
        return cls()

    def declared_value(self) -> float:
        """The value the rover declares for this failure (NaN: none, or not representable)."""
        return math.nan

    @classmethod
    def rover_description(cls) -> dict[str, Any]:
        """The kind as data for the rover (written into every table header's ``failure_kinds``):
        ``kind``, ``class``, ``text``, ``value``, ``rules``, ``odometry`` and ``mirror_value``
        (the factor the declared value takes on the mirror-image wheel, from :meth:`mirror`)."""
        mirror_value = None
        if cls.ROVER_VALUE is not None:
            lo, hi = float(cls.ROVER_VALUE["lo"]), float(cls.ROVER_VALUE["hi"])
            probe = 0.3 * hi if hi > 0 else 0.3 * lo
            mirror_value = cls.from_declared(probe).mirror().declared_value() / probe
        return {"kind": cls.ROVER_KIND, "class": f"{cls.__module__}.{cls.__qualname__}",
                "text": (cls.__doc__ or cls.__name__).strip().splitlines()[0],
                "value": dict(cls.ROVER_VALUE) if cls.ROVER_VALUE is not None else None,
                "rules": [dict(r) for r in cls.RULES], "odometry": cls.ODOMETRY, "mirror_value": mirror_value}

    def rover_record(self, wheel: str) -> dict[str, Any]:
        """This failure on ``wheel`` as the table header's ``failures`` lists it."""
        v = self.declared_value()
        return {"wheel": wheel, "kind": self.ROVER_KIND, "value": v if math.isfinite(v) else None,
                "text": self.describe()}

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "FailureKind | None":
        """The kind from the wheel table's values (only its own keys present), or ``None``."""
        raise NotImplementedError

    def apply(self, b: WheelBounds) -> None:
        """Tighten the wheel's bounds (variables, torque row, contact)."""
        raise NotImplementedError

    def mirror(self) -> "FailureKind":
        """The same failure on the mirror-image (left-right swapped) rover."""
        return self

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """Residuals ``name -> (value, scale)`` (0 when met; |value| <= rtol * scale passes)."""
        return {}

    def evidence(self, s: SolutionView) -> str:
        """What the furthest feasible point reached shows about this constraint."""
        return ""

    def start(self, b: WheelBounds) -> dict[str, float]:
        """Start-point hints for this wheel (variable name -> physical value), given its bounds."""
        return {}

    def tightened(self) -> "FailureKind | None":
        """A stricter version whose every solution also satisfies this kind (a lower cap),
        or ``None``. A solution of the tightened scenario is a feasible start for this one."""
        return None

    def describe(self) -> str:
        """Short human-readable description."""
        return type(self).__name__


@dataclass(frozen=True)
class SteerRange(FailureKind):
    """Steering range of the wheel (bound 7.3 narrowed): ``steer_min <= beta <= steer_max``."""

    steer_min: float = -math.pi / 2
    steer_max: float = math.pi / 2
    TOML_KEYS: ClassVar[tuple[str, ...]] = ("steer_min_deg", "steer_max_deg")
    ROVER_KIND: ClassVar[str] = "steer_range"
    ROVER_VALUE: ClassVar[Mapping[str, Any] | None] = {"name": "half range", "unit": "rad", "lo": 0.0,
                                                        "hi": math.pi / 2, "required": True}
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = (
        {"on": "beta", "lo": {"value": -1.0}, "hi": {"value": 1.0}, "frame": "encoder"},)

    @classmethod
    def from_declared(cls, value: float) -> "SteerRange":
        """A symmetric range ``|beta| <= value`` (the rover declares one number)."""
        return cls(-float(value), float(value))

    def declared_value(self) -> float:
        """The half range of a symmetric range (NaN for an asymmetric one)."""
        return self.steer_max if self.steer_min == -self.steer_max else math.nan

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "SteerRange | None":
        """From ``steer_min_deg`` / ``steer_max_deg`` (degrees, within +-90)."""
        if not any(k in values for k in cls.TOML_KEYS):
            return None
        lo = _num(values, "steer_min_deg", -90.0, 90.0, " (degrees expected)") if "steer_min_deg" in values else -90.0
        hi = _num(values, "steer_max_deg", -90.0, 90.0, " (degrees expected)") if "steer_max_deg" in values else 90.0
        if lo > hi:
            raise FailureSpecError(f"steer_min_deg = {lo} > steer_max_deg = {hi}")
        return cls(math.radians(lo), math.radians(hi))

    def apply(self, b: WheelBounds) -> None:
        """Narrow the steer bounds."""
        b.lo["beta"], b.hi["beta"] = max(b.lo["beta"], self.steer_min), min(b.hi["beta"], self.steer_max)

    def mirror(self) -> "SteerRange":
        """Angles negated and swapped."""
        return SteerRange(-self.steer_max, -self.steer_min)

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """Distance outside the range, rad."""
        return {"steer range": (max(self.steer_min - s.beta, s.beta - self.steer_max, 0.0), 1.0)}

    def describe(self) -> str:
        """Range in degrees."""
        return f"steer range [{math.degrees(self.steer_min):.0f}, {math.degrees(self.steer_max):.0f}] deg"


@dataclass(frozen=True)
class StuckSteering(FailureKind):
    """Steering actuator frozen, eq. (7.31): ``beta = angle``."""

    angle: float
    TOML_KEYS: ClassVar[tuple[str, ...]] = ("steer_stuck_deg",)
    ROVER_KIND: ClassVar[str] = "steer_stuck"
    ROVER_VALUE: ClassVar[Mapping[str, Any] | None] = {"name": "angle", "unit": "rad", "lo": -math.pi / 2,
                                                        "hi": math.pi / 2, "required": False}
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = (
        {"on": "beta", "fix": {"value": 1.0}, "frame": "encoder", "prefer_measured": True},)

    @classmethod
    def from_declared(cls, value: float) -> "StuckSteering":
        """Stuck at ``value`` rad."""
        return cls(float(value))

    def declared_value(self) -> float:
        """The angle, rad."""
        return self.angle

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "StuckSteering | None":
        """From ``steer_stuck_deg`` (degrees, within +-90)."""
        if "steer_stuck_deg" not in values:
            return None
        return cls(math.radians(_num(values, "steer_stuck_deg", -90.0, 90.0, " (degrees expected)")))

    def apply(self, b: WheelBounds) -> None:
        """Fix beta at the stuck angle, eq. (7.31).

        The optimizer's steering limit of +-89 deg
        (:data:`offline.rover.primitives.BETA_LIMIT`) bounds a *free* steering decision; a
        stuck angle is a fact and is held as declared, clipped only to the wheel model's
        domain ``|beta| <= 90 deg`` (``v_x = v cos(beta) >= 0``). Clipping it to 89 deg made the
        NLP solve a scenario 1 deg away from the declared one, which the independent check
        (rightly) rejected: every point of a stuck-angle axis at +-90 deg read "IPOPT converged
        but the independent numeric check failed" (residual ``steer`` = 1.75e-2 rad).
        """
        a = min(max(self.angle, -0.5 * math.pi), 0.5 * math.pi)
        b.lo["beta"] = b.hi["beta"] = a

    def mirror(self) -> "StuckSteering":
        """Angle negated."""
        return StuckSteering(-self.angle)

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """Steer error, rad."""
        return {"steer": (s.beta - self.angle, 1.0)}

    def evidence(self, s: SolutionView) -> str:
        """Steer angle reached."""
        return f"steer reached {math.degrees(s.beta):.1f} deg (stuck at {math.degrees(self.angle):.1f} deg)"

    def start(self, b: WheelBounds) -> dict[str, float]:
        """Start at the stuck angle."""
        return {"beta": self.angle}

    def describe(self) -> str:
        """Angle in degrees."""
        return f"steering stuck at {math.degrees(self.angle):.1f} deg"


@dataclass(frozen=True)
class RimSpeedCap(FailureKind):
    """Speed-limited wheel, eq. (7.30): ``omega r_s <= cap``."""

    cap: float
    TOML_KEYS: ClassVar[tuple[str, ...]] = ("rim_speed_max_m_s",)
    ROVER_KIND: ClassVar[str] = "rim_speed_cap"
    ROVER_VALUE: ClassVar[Mapping[str, Any] | None] = {"name": "cap", "unit": "m/s", "lo": 0.0, "hi": 2.0,
                                                        "required": True}
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = ({"on": "rim_speed", "hi": {"value": 1.0}},)

    @classmethod
    def from_declared(cls, value: float) -> "RimSpeedCap":
        """Capped at ``value`` m/s."""
        return cls(float(value))

    def declared_value(self) -> float:
        """The cap, m/s."""
        return self.cap

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "RimSpeedCap | None":
        """From ``rim_speed_max_m_s`` (m/s; above 2 m/s is taken as a unit mistake)."""
        if "rim_speed_max_m_s" not in values:
            return None
        return cls(_num(values, "rim_speed_max_m_s", 0.0, 2.0, " m/s (is it in cm/s? 1.5 cm/s = 0.015)"))

    def apply(self, b: WheelBounds) -> None:
        """Upper bound on omega."""
        b.hi["omega"] = min(b.hi["omega"], self.cap / b.rim_radius)

    def start(self, b: WheelBounds) -> dict[str, float]:
        """Start well below the cap (the wheel skidding, others slipping more): a solution
        for a lower cap satisfies this one, and the nominal primitive may sit across the
        zero-slip kink from it."""
        return {"omega": 0.5 * self.cap / b.rim_radius}

    def tightened(self) -> "RimSpeedCap":
        """Half the cap."""
        return RimSpeedCap(0.5 * self.cap)

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """Rim speed above the cap, m/s."""
        return {"rim speed": (max(s.rim_speed - self.cap, 0.0), s.speed)}

    def evidence(self, s: SolutionView) -> str:
        """Lowest rim speed reached at a feasible, checked point."""
        return (f"lowest rim speed reached at a feasible point {s.rim_speed * 100:.2f} cm/s "
                f"(cap {self.cap * 100:.2f} cm/s)")

    def describe(self) -> str:
        """Cap in cm/s."""
        return f"rim speed <= {self.cap * 100:.2f} cm/s"


@dataclass(frozen=True)
class Locked(FailureKind):
    """Jammed wheel: ``omega = 0`` (it still steers unless its steering is stuck too)."""

    TOML_KEYS: ClassVar[tuple[str, ...]] = ("locked",)
    ROVER_KIND: ClassVar[str] = "locked"
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = ({"on": "omega", "fix": {"const": 0.0}},)
    ODOMETRY: ClassVar[bool] = False

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "Locked | None":
        """From ``locked = true``."""
        return cls() if "locked" in values and _flag(values, "locked") else None

    def apply(self, b: WheelBounds) -> None:
        """omega fixed at 0."""
        b.hi["omega"] = 0.0
        b.lo["omega"] = 0.0

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """Rim speed, m/s."""
        return {"rim speed": (abs(s.rim_speed), s.speed)}

    def evidence(self, s: SolutionView) -> str:
        """Lowest rim speed reached at a feasible point."""
        return f"lowest rim speed reached at a feasible point {s.rim_speed * 100:.2f} cm/s (locked: 0)"

    def start(self, b: WheelBounds) -> dict[str, float]:
        """Start at rest."""
        return {"omega": 0.0}

    def describe(self) -> str:
        """'locked'."""
        return "locked (omega = 0)"


@dataclass(frozen=True)
class Unpowered(FailureKind):
    """Drive motor without power: free rolling, wheel torque ``M_y = 0``."""

    TOML_KEYS: ClassVar[tuple[str, ...]] = ("unpowered",)
    ROVER_KIND: ClassVar[str] = "unpowered"
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = ({"on": "torque", "fix": {"const": 0.0}},)
    ODOMETRY: ClassVar[bool] = False

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "Unpowered | None":
        """From ``unpowered = true``."""
        return cls() if "unpowered" in values and _flag(values, "unpowered") else None

    def apply(self, b: WheelBounds) -> None:
        """Torque row fixed at 0."""
        b.torque = (0.0, 0.0)

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """|torque|, N m (scale: weight times rocker length is applied by the caller)."""
        return {"torque": (abs(s.torque), math.nan)}

    def evidence(self, s: SolutionView) -> str:
        """Smallest |torque| reached at a feasible point."""
        return f"smallest |torque| reached at a feasible point {abs(s.torque):.4f} N m (unpowered: 0)"

    def describe(self) -> str:
        """'unpowered'."""
        return "unpowered (M_y = 0)"


@dataclass(frozen=True)
class Raised(FailureKind):
    """Wheel off the ground (stuck suspension): ``W = 0``, no soil wrench, pivot locked.

    The wheel's sinkage variables are fixed at the grouser height only to keep the (zeroed)
    wheel model finite; they enter neither the balance nor the rocker angle
    (:meth:`offline.rover.statics.FourWheelRocker.rocker_angles`) and are reported as 0.
    """

    TOML_KEYS: ClassVar[tuple[str, ...]] = ("raised",)
    ROVER_KIND: ClassVar[str] = "raised"
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = (
        {"on": "contact", "fix": {"const": 0.0}}, {"on": "pivot_locked", "fix": {"const": 1.0}},
        {"on": "rim_speed", "fix": {"speed": 1.0}}, {"on": "beta", "fix": {"const": 0.0}},
        {"on": "W", "fix": {"const": 0.0}}, {"on": "h", "hi": {"bound": "lo"}}, {"on": "h0", "hi": {"bound": "lo"}},
        {"on": "torque", "free": True})
    ODOMETRY: ClassVar[bool] = False

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "Raised | None":
        """From ``raised = true``."""
        return cls() if "raised" in values and _flag(values, "raised") else None

    def apply(self, b: WheelBounds) -> None:
        """Contact 0, load 0; speed at the rolling value, straight, sinkage parked."""
        b.contact = 0.0
        om = b.speed / b.rim_radius
        b.lo.update(omega=om, beta=0.0, W=0.0)
        b.hi.update(omega=om, beta=0.0, W=0.0)
        b.hi["h"], b.hi["h0"] = b.lo["h"], b.lo["h0"]
        b.torque = (-math.inf, math.inf)

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """Load carried, N (scale: the weight, applied by the caller)."""
        return {"load": (s.load, math.nan)}

    def describe(self) -> str:
        """'raised'."""
        return "raised (W = 0, pivot locked)"


@dataclass(frozen=True)
class TorqueLimit(FailureKind):
    """Weak motor: ``|M_y| <= limit``."""

    limit: float
    TOML_KEYS: ClassVar[tuple[str, ...]] = ("torque_limit_Nm",)
    ROVER_KIND: ClassVar[str] = "torque_limit"
    ROVER_VALUE: ClassVar[Mapping[str, Any] | None] = {"name": "limit", "unit": "N m", "lo": 0.0, "hi": 1e4,
                                                        "required": True}
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = ({"on": "torque", "lo": {"value": -1.0}, "hi": {"value": 1.0}},)

    @classmethod
    def from_declared(cls, value: float) -> "TorqueLimit":
        """Limited to ``value`` N m."""
        return cls(float(value))

    def declared_value(self) -> float:
        """The limit, N m."""
        return self.limit

    @classmethod
    def from_toml(cls, values: Mapping[str, Any]) -> "TorqueLimit | None":
        """From ``torque_limit_Nm`` (N m, within [0, 1e4])."""
        if "torque_limit_Nm" not in values:
            return None
        return cls(_num(values, "torque_limit_Nm", 0.0, 1e4, " N m"))

    def apply(self, b: WheelBounds) -> None:
        """Torque row within +-limit."""
        lo, hi = b.torque
        b.torque = (max(lo, -self.limit), min(hi, self.limit))

    def check(self, s: SolutionView) -> dict[str, tuple[float, float]]:
        """|torque| above the limit, N m."""
        return {"torque": (max(abs(s.torque) - self.limit, 0.0), math.nan)}

    def evidence(self, s: SolutionView) -> str:
        """Smallest |torque| reached at a feasible point."""
        return f"smallest |torque| reached at a feasible point {abs(s.torque):.4f} N m (limit {self.limit:.4f} N m)"

    def tightened(self) -> "TorqueLimit":
        """Half the limit."""
        return TorqueLimit(0.5 * self.limit)

    def describe(self) -> str:
        """Limit in N m."""
        return f"|torque| <= {self.limit:.4f} N m"


def with_task(kind: FailureKind, wheel: str, trench: Any) -> bool:
    """Whether a failure kind on ``wheel`` is part of the scenario's task rather than a failure the
    rover declares: a kind that takes a value but cannot state it as one number (the trenching
    wheel's one-sided steer range), on the wheel of the trench goal ``trench`` (None: no task)."""
    return (trench is not None and getattr(trench, "wheel", None) == wheel and kind.ROVER_VALUE is not None
            and math.isnan(kind.declared_value()))


KINDS: tuple[type[FailureKind], ...] = (SteerRange, StuckSteering, RimSpeedCap, Locked, Unpowered, Raised, TorqueLimit)
"""Every failure kind, in the order they are applied (a range before a stuck angle)."""


@dataclass(frozen=True)
class TrenchGoal:
    """Trenching objective for one wheel, eqs. (7.28)-(7.29), as bounds on the trench rows.

    Rows (see :mod:`rtctl.layout`): ``trench clean-side pile`` (the rim-side pile area margin,
    m^2; <= 0 for a clean side, 7.28), ``trench depth`` (m; >= min_depth (7.29) or = target),
    ``trench flat width`` (m; >= min_flat_width).
    """

    wheel: str
    clean_side: bool = False
    min_depth: float = 0.0
    min_flat_width: float = 0.0
    target_depth: float | None = None

    ROVER_KIND: ClassVar[str] = "trench"
    """The task's name in the rover's :class:`rtctl.messages.Task`."""
    ROVER_VALUE: ClassVar[Mapping[str, Any]] = {"name": "depth", "unit": "m", "lo": 0.0, "hi": 0.5}
    """The task's value on the rover: the target trench depth below the surface (SI)."""
    ODOMETRY: ClassVar[bool] = False
    """The digging wheel spins at several times the travel speed on purpose (section 7.3.1): its
    speed does not tell the travel speed."""

    @classmethod
    def rover_description(cls) -> dict[str, Any]:
        """The task kind as data for the rover, in the format of a failure kind's description
        (:meth:`FailureKind.rover_description`; no rules: a task is served by its own table,
        never imposed on another): written into a trench table header's ``task``, and read by
        :func:`rtctl.failures.read_task_kinds`."""
        return {"kind": cls.ROVER_KIND, "class": f"{cls.__module__}.{cls.__qualname__}",
                "text": (cls.__doc__ or cls.__name__).strip().splitlines()[0],
                "value": dict(cls.ROVER_VALUE), "rules": [], "odometry": cls.ODOMETRY, "mirror_value": 1.0}

    def row_bounds(self) -> dict[str, tuple[float, float]]:
        """Physical bounds per trench row (``clean-side pile``, ``depth``, ``flat width``)."""
        out = {"clean-side pile": (-math.inf, 0.0 if self.clean_side else math.inf)}
        if self.target_depth is not None:
            out["depth"] = (self.target_depth, self.target_depth)
        else:
            out["depth"] = (self.min_depth if self.min_depth > 0 else -math.inf, math.inf)
        out["flat width"] = (self.min_flat_width if self.min_flat_width > 0 else -math.inf, math.inf)
        return out

    def mirror(self) -> "TrenchGoal":
        """The same goal dug by the mirror-image wheel."""
        return TrenchGoal(_MIRROR_WHEEL[self.wheel], self.clean_side, self.min_depth, self.min_flat_width, self.target_depth)

    def check(self, trench: Any, tol: float = 5e-4) -> dict[str, tuple[float, float]]:
        """Residuals of the goal on a trench profile, m, each with its absolute tolerance
        ``tol`` (default 0.5 mm; section 7.2.7 used 1 mm)."""
        res: dict[str, tuple[float, float]] = {}
        if self.clean_side:
            res["trench rim-side pile height"] = (trench.h_R2, tol)
        if self.target_depth is not None:
            res["trench depth"] = (trench.d - self.target_depth, tol)
        else:
            res["trench depth"] = (max(self.min_depth - trench.d, 0.0), tol)
        if self.min_flat_width > 0:
            res["trench flat width"] = (max(self.min_flat_width - trench.p, 0.0), tol)
        return res

    def evidence(self, trench: Any) -> str:
        """Trench reached at the furthest feasible point."""
        return (f"trench reached: depth {trench.d * 1e3:.1f} mm, rim-side pile {trench.h_R2 * 1e3:.1f} mm, "
                f"flat width {trench.p * 1e3:.1f} mm")
