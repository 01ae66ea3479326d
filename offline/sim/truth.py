"""What the simulated world really is: the truth parameter file, separate from the controller's.

The controller's tables are built on a believed parameter set; the simulator's truth may
differ: softer or stiffer soil, a worn wheel (radius per wheel), a steering offset per
wheel (the wheel points elsewhere than its encoder says), slope and cross-slope, a tether
or drawbar force. The discrepancy tool fits exactly these.

File format (every key optional; units in the key names)
--------------------------------------------------------
.. code-block:: toml

    [truth]
    params = "dissertation-ch7"      # preset ("calibrated-sand" ...) or parameter TOML (soil, wheel, tuning), relative to this file
    soil_stiffness_scale = 0.7       # multiplies k (0.7: 30 % softer)
    slope_deg = 5.0                  # terrain rises along the initial heading (uphill positive)
    cross_slope_deg = 0.0            # terrain rises to the rover's initial left (left side up positive)
    tether_force_N = 1.0             # pulls the rover backward along its own -x
    mass_kg = 3.5                    # default: rover weight / 9.81
    yaw_inertia_kg_m2 = 0.06         # default: uniform plate over wheelbase x track (our estimate)
    wheel_inertia_kg_m2 = 3.3e-4     # spin inertia of each wheel; default: 0.1 kg ring at the rim (our estimate)

    [wheels.RR]                      # a wheel of the rover: FR, FL, RR, RL (mini rover) or a rover file's name
    radius_mm = 54.0                 # default: the parameter set's wheel radius
    steer_offset_deg = 2.0           # true steer = encoder steer + offset

    [tether_anchor]                  # a cable to a fixed anchor (offline.discrepancy.drive.candidates.AnchoredTether)
    tension_N = 2.0                  # required in this section
    bearing_deg = 180.0              # anchor direction from the start heading (default 180: behind)
    inverse_distance_per_m = 0.0     # 1 / anchor distance from the start (0: far away)
    attach_x_m = 0.0                 # attachment on the body's x axis
    spring_rate_N_per_m = 0.0        # tension gained per metre paid out

    [hub_contact]                    # hub / body face bulldozing (offline.discrepancy.drive.candidates.HubContact)
    clearance_mm = 4.0               # required in this section
    face_width_mm = 40.0
    arm_mm = 20.0

    [[empirical_force]]              # an empirical force or torque term (offline.discrepancy.drive.empirical), repeatable
    direction = "drag.each"          # drag.<body|FR|FL|RR|RL|each> (N) or torque.<FR|FL|RR|RL|each> (N m)
    where = "x"                      # everywhere, time (s), x, y (m, world frame), sinkage (m), slip, slip_angle (rad)
    shape = "box"                    # constant, box [lo, hi), step (from lo on), hinge (magnitude per unit above lo)
    lo_si = 0.12                     # edges / threshold in SI units of `where`
    hi_si = 0.30
    magnitude_si = 0.8               # N or N m (hinge: per unit of `where`)

A rover file's truth (:func:`load_truth` given the scenario's ``rover_file``) names that file's
wheels (``[wheels.LM]`` on the MER-class rover), has one radius and steering offset per wheel in
its order, and takes its mass and inertias from the rover-file simulator's defaults; its hook
sections are applied on its wheels by :func:`offline.discrepancy.drive.wheel_set.truth_disturbance`
(an ``[[empirical_force]]`` there names the file's wheels: ``drag.LM``, ``torque.RF``).

The last three are disturbance hooks (contract C5): :attr:`Truth.anchor`, :attr:`Truth.hub` and
:attr:`Truth.empirical` carry their parameters (SI); ``offnominal drive --truth`` applies them
through :func:`offline.discrepancy.drive.candidates.disturbance_from_truth` (an empirical term in ``time``
counts from the simulation's start; one in ``x`` / ``y`` is in the simulator's world frame, which is
the recording's pose frame when the drive starts where the recording's did; the discrepancy tool
writes only the force and torque terms here, :mod:`offline.discrepancy.drive.empirical`), and the table builder takes the
anchored tether (``--world``; a constant bearing in steady straight driving) and the hub contact
(``--world``; a drag per wheel in the NLP, :mod:`rtctl.physics.hub_drag`). The simulator
itself takes them as its ``disturbance`` argument.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from rtctl.physics.hub_drag import HUB_KEYS
from ..physics.params import ParameterError, ParameterSet, Rover, Soil, load_toml
from ..rover.scenario import PARAM_PRESETS, param_preset_file, section_table, wheel_tables
from .plant import GRAVITY, PlantModel, default_wheel_inertia, default_yaw_inertia

if TYPE_CHECKING:
    from rtctl.physics.rover_file import RoverSpec

__all__ = ["TruthError", "Truth", "load_truth", "WHEELS", "shipped_truths", "resolve_truth_path",
           "EMPIRICAL_FORCE_DIRECTIONS", "EMPIRICAL_FORCE_WHERE", "EMPIRICAL_FORCE_SHAPES", "empirical_force_directions"]

WHEELS = ("FR", "FL", "RR", "RL")


class TruthError(ValueError):
    """A truth file is malformed or out of range; the message names file, section and key."""


@dataclass(frozen=True)
class Truth:
    """The simulated world (SI units).

    Attributes
    ----------
    params : ParameterSet
        Soil, wheel geometry and contact tuning of the truth.
    wheel_radius : tuple of 4 float
        Rim radius per wheel (FR, FL, RR, RL), m.
    steer_offset : tuple of 4 float
        True steer minus encoder steer per wheel, rad.
    slope, cross_slope : float
        Terrain inclination, rad (see the module notes for the signs).
    tether_force : float
        Backward pull along the rover's -x, N.
    mass, yaw_inertia : float
        kg, kg m^2 (the yaw inertia default is our own estimate,
        :func:`offline.sim.plant.default_yaw_inertia`: the dissertation gives none).
    wheel_inertia : float
        Spin inertia of each wheel about its axle, kg m^2 (0: quasi-static wheels, the axle
        balance without inertia; :meth:`nominal` and :func:`load_truth` default to our estimate
        :func:`offline.sim.plant.default_wheel_inertia`).
    """

    params: ParameterSet
    wheel_radius: tuple[float, float, float, float]
    steer_offset: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    slope: float = 0.0
    cross_slope: float = 0.0
    tether_force: float = 0.0
    mass: float = 0.0
    yaw_inertia: float = 0.0
    wheel_inertia: float = 0.0
    source: str = ""
    notes: dict[str, Any] = field(default_factory=dict)
    anchor: dict[str, float] | None = None
    """Anchored tether (SI: ``tension`` N, ``bearing`` rad, ``inverse_distance`` 1/m, ``attach_x`` m,
    ``spring_rate`` N/m), or None."""
    hub: dict[str, float] | None = None
    """Hub contact (SI: ``clearance``, ``face_width``, ``arm``, m), or None."""
    empirical: tuple[dict[str, Any], ...] = ()
    """Empirical force and torque terms (``[[empirical_force]]``: ``direction``, ``where``,
    ``shape``, ``lo``, ``hi``, ``magnitude``, SI), applied as a disturbance hook."""

    @classmethod
    def nominal(cls, params: ParameterSet, rover: Rover, **kw: Any) -> "Truth":
        """The world the tables believe in: the parameter set's wheel on every corner, flat ground."""
        base = cls(params=params, wheel_radius=(params.wheel.radius,) * 4, mass=rover.weight / GRAVITY,
                   yaw_inertia=default_yaw_inertia(rover), wheel_inertia=default_wheel_inertia(params))
        return replace(base, **kw)

    def vector(self) -> NDArray[np.float64]:
        """The parameter vector of :class:`offline.sim.plant.PlantModel` (:data:`PARAM_NAMES`)."""
        return PlantModel.param_vector(self.wheel_radius, self.params.soil, self.slope, self.cross_slope,
                                       self.tether_force, self.mass, self.yaw_inertia, self.wheel_inertia)

    def describe(self) -> dict[str, Any]:
        """Plain values (degrees, mm) for recordings and reports."""
        return {
            "soil": self.params.soil.name, "soil_k": self.params.soil.k,
            "wheel_radius_mm": [1e3 * r for r in self.wheel_radius],
            "steer_offset_deg": [math.degrees(o) for o in self.steer_offset],
            "slope_deg": math.degrees(self.slope), "cross_slope_deg": math.degrees(self.cross_slope),
            "tether_force_N": self.tether_force, "mass_kg": self.mass, "yaw_inertia_kg_m2": self.yaw_inertia,
            "wheel_inertia_kg_m2": self.wheel_inertia,
            "source": Path(self.source).name if self.source else "",
            **({"tether_anchor_SI": dict(self.anchor)} if self.anchor is not None else {}),
            **({"hub_contact_SI": dict(self.hub)} if self.hub is not None else {}),
            **({"empirical_force_SI": [{k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                                        for k, v in e.items()} for e in self.empirical]} if self.empirical else {}),
        }


_TRUTH_KEYS = {"params": str, "soil_stiffness_scale": float, "slope_deg": float, "cross_slope_deg": float,
               "tether_force_N": float, "mass_kg": float, "yaw_inertia_kg_m2": float, "wheel_inertia_kg_m2": float}
_RANGES = {"soil_stiffness_scale": (0.05, 20.0), "slope_deg": (-40.0, 40.0), "cross_slope_deg": (-40.0, 40.0),
           "tether_force_N": (-100.0, 100.0), "mass_kg": (0.01, 1e4), "yaw_inertia_kg_m2": (1e-6, 1e4),
           "wheel_inertia_kg_m2": (0.0, 1e2)}
_WHEEL_KEYS = {"radius_mm": (10.0, 2000.0), "steer_offset_deg": (-30.0, 30.0)}
_HOOKS: dict[str, tuple[str, dict[str, tuple[str, float, float, float]]]] = {
    # section -> (required key, {key: (SI name, factor to SI, lo, hi) in file units})
    "tether_anchor": ("tension_N", {"tension_N": ("tension", 1.0, 0.0, 100.0),
                                    "bearing_deg": ("bearing", math.pi / 180, -360.0, 360.0),
                                    "inverse_distance_per_m": ("inverse_distance", 1.0, 0.0, 100.0),
                                    "attach_x_m": ("attach_x", 1.0, -2.0, 2.0),
                                    "spring_rate_N_per_m": ("spring_rate", 1.0, 0.0, 1e3)}),
    "hub_contact": ("clearance_mm", HUB_KEYS),
}


def _hook(path: Path, data: dict[str, Any], section: str) -> dict[str, float] | None:
    """A disturbance-hook section (:data:`_HOOKS`) in SI, or None when absent."""
    if section not in data:
        return None
    required, keys = _HOOKS[section]
    tab = section_table(path, data[section], section, keys, required, f"must be a table with keys {sorted(keys)}",
                        TruthError)
    out = {si: f * _num(path, section, k, tab[k], lo, hi) for k, (si, f, lo, hi) in keys.items() if k in tab}
    if section == "tether_anchor":
        out.setdefault("bearing", math.pi)
    return out


EMPIRICAL_FORCE_DIRECTIONS = (*(f"drag.{w}" for w in ("body", *WHEELS, "each")),
                              *(f"torque.{w}" for w in (*WHEELS, "each")))  # = empirical_force_directions(WHEELS)
"""Directions of ``[[empirical_force]]`` (the force and torque directions of
:data:`offline.discrepancy.drive.empirical.DIRECTIONS`; a test keeps the two equal)."""
EMPIRICAL_FORCE_WHERE = ("everywhere", "time", "x", "y", "sinkage", "slip", "slip_angle")
EMPIRICAL_FORCE_SHAPES = ("constant", "box", "step", "hinge")
_EMPIRICAL_KEYS = {"direction", "where", "shape", "lo_si", "hi_si", "magnitude_si"}


def empirical_force_directions(wheels: tuple[str, ...] = WHEELS) -> tuple[str, ...]:
    """Directions of ``[[empirical_force]]`` on a wheel set (:data:`EMPIRICAL_FORCE_DIRECTIONS` for
    the mini rover's; a rover file's wheels by their own names, issue 23)."""
    return (*(f"drag.{w}" for w in ("body", *wheels, "each")), *(f"torque.{w}" for w in (*wheels, "each")))


def _empirical(path: Path, data: dict[str, Any], wheels: tuple[str, ...] = WHEELS) -> tuple[dict[str, Any], ...]:
    """The ``[[empirical_force]]`` entries in SI (names and numbers checked here; the term's own
    class checks the combination when the hook is built); ``wheels``: the wheel set the per-wheel
    directions name."""
    if "empirical_force" not in data:
        return ()
    entries = data["empirical_force"]
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise TruthError(f"{path}: empirical_force must be an array of tables ([[empirical_force]])")
    out = []
    for i, e in enumerate(entries):
        where = f"empirical_force #{i + 1}"
        bad = sorted(set(e) - _EMPIRICAL_KEYS)
        if bad:
            raise TruthError(f"{path}: [{where}] unknown key(s) {bad}; known: {sorted(_EMPIRICAL_KEYS)}")
        for key, allowed, default in (("direction", empirical_force_directions(wheels), None),
                                      ("where", EMPIRICAL_FORCE_WHERE, "everywhere"),
                                      ("shape", EMPIRICAL_FORCE_SHAPES, "constant")):
            v = e.get(key, default)
            if v not in allowed:
                raise TruthError(f"{path}: [{where}] {key} = {v!r}; expected one of {list(allowed)}")
        if "magnitude_si" not in e:
            raise TruthError(f"{path}: [{where}] magnitude_si is required")
        out.append({"direction": e["direction"], "where": e.get("where", "everywhere"), "shape": e.get("shape", "constant"),
                    "lo": _num(path, where, "lo_si", e["lo_si"], -1e9, 1e9) if "lo_si" in e else -math.inf,
                    "hi": _num(path, where, "hi_si", e["hi_si"], -1e9, 1e9) if "hi_si" in e else math.inf,
                    "magnitude": _num(path, where, "magnitude_si", e["magnitude_si"], -1e6, 1e6)})
    return tuple(out)


def _num(path: Path, where: str, key: str, v: Any, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
        raise TruthError(f"{path}: [{where}] {key} must be a finite number, got {v!r}")
    if not lo <= float(v) <= hi:
        hint = " (degrees expected)" if key.endswith("_deg") else " (millimetres expected)" if key.endswith("_mm") else ""
        raise TruthError(f"{path}: [{where}] {key} = {v} outside [{lo}, {hi}]{hint}")
    return float(v)


def load_truth(path: str | Path, rover: "Rover | RoverSpec", default_params: ParameterSet | None = None) -> Truth:
    """Read a truth file (format in the module notes).

    Parameters
    ----------
    path : str or Path
    rover : Rover or RoverSpec
        The mini rover (:class:`offline.physics.params.Rover`: wheels FR, FL, RR, RL) or a rover
        file (:class:`rtctl.physics.rover_file.RoverSpec`, a scenario's ``rover_file``): its wheel
        names are the ``[wheels.<name>]`` sections the file may have, and the truth has one radius
        and steering offset per wheel in its order. A rover file's defaults are the simulator's
        (:func:`offline.sim.simulator.rover_file_truth`): mass its weight over its gravity, yaw
        inertia :func:`~offline.sim.suspension_plant.suspension_yaw_inertia`, wheel spin inertia
        :func:`~offline.sim.suspension_plant.rover_file_wheel_inertia`. On a rover file an
        ``[[empirical_force]]`` term's per-wheel direction names one of its wheels (``drag.LM``).
    default_params : ParameterSet, optional
        The parameter set when ``[truth] params`` is not given (default ``dissertation-ch7``).

    Raises
    ------
    TruthError
        Unknown section, wheel or key, non-numeric or out-of-range value, unreadable parameter file
        (the message names the file, the section and the key).
    """
    from rtctl.physics.rover_file import RoverSpec

    from .suspension_plant import rover_file_wheel_inertia, rover_gravity, suspension_yaw_inertia

    spec = rover if isinstance(rover, RoverSpec) else None
    wheels = spec.wheel_names if spec is not None else WHEELS
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise TruthError(f"{p}: no such truth file") from None
    except tomllib.TOMLDecodeError as exc:
        raise TruthError(f"{p}: not valid TOML ({exc})") from None
    bad = sorted(set(data) - {"truth", "wheels", "empirical_force", *_HOOKS})
    if bad:
        raise TruthError(f"{p}: unknown section(s) {bad}; expected [truth], [wheels.<{'|'.join(wheels)}>], "
                         "[tether_anchor], [hub_contact], [[empirical_force]]")
    t = data.get("truth", {})
    bad = sorted(set(t) - set(_TRUTH_KEYS))
    if bad:
        raise TruthError(f"{p}: [truth] unknown key(s) {bad}; known: {sorted(_TRUTH_KEYS)}")
    ref = t.get("params")
    if ref is None:
        ps = default_params or PARAM_PRESETS["dissertation-ch7"]
    elif not isinstance(ref, str):
        raise TruthError(f"{p}: [truth] params must be a preset name or a file path, got {ref!r}")
    elif ref in PARAM_PRESETS:
        ps = PARAM_PRESETS[ref]
    else:  # a shipped parameter file by name (as a scenario's params = "calibrated-sand") or a path
        f = param_preset_file(ref) or (Path(ref) if Path(ref).is_absolute() else p.parent / ref)
        try:
            loaded = load_toml(f)
        except (ParameterError, OSError) as exc:
            raise TruthError(f"{p}: [truth] params = {ref!r}: {exc}") from None
        if "parameter_set" not in loaded:
            raise TruthError(f"{p}: [truth] params = {ref!r} has no [soil], [wheel] and [tuning]")
        ps = loaded["parameter_set"]
    vals = {k: _num(p, "truth", k, t[k], *_RANGES[k]) for k in _RANGES if k in t}
    if "soil_stiffness_scale" in vals:
        soil: Soil = ps.soil
        ps = replace(ps, soil=replace(soil, k=soil.k * vals["soil_stiffness_scale"],
                                      name=f"{soil.name} x{vals['soil_stiffness_scale']:g} k"))
    radius = [ps.wheel.radius] * len(wheels)
    offset = [0.0] * len(wheels)
    for name, tab in wheel_tables(p, data, _WHEEL_KEYS, TruthError, wheels):
        i = wheels.index(name)
        if "radius_mm" in tab:
            radius[i] = 1e-3 * _num(p, f"wheels.{name}", "radius_mm", tab["radius_mm"], *_WHEEL_KEYS["radius_mm"])
            if radius[i] <= ps.wheel.grouser_height:
                raise TruthError(f"{p}: [wheels.{name}] radius_mm must exceed the grouser height")
        if "steer_offset_deg" in tab:
            offset[i] = math.radians(_num(p, f"wheels.{name}", "steer_offset_deg", tab["steer_offset_deg"],
                                          *_WHEEL_KEYS["steer_offset_deg"]))
    empirical = _empirical(p, data, tuple(wheels))
    if spec is None:
        mass, yaw, spin = rover.weight / GRAVITY, default_yaw_inertia(rover), default_wheel_inertia(ps)  # type: ignore[arg-type]
    else:
        mass, yaw, spin = spec.weight / rover_gravity(spec), suspension_yaw_inertia(spec), rover_file_wheel_inertia(ps)
    return Truth(
        params=ps, wheel_radius=tuple(radius), steer_offset=tuple(offset),  # type: ignore[arg-type]
        slope=math.radians(vals.get("slope_deg", 0.0)), cross_slope=math.radians(vals.get("cross_slope_deg", 0.0)),
        tether_force=vals.get("tether_force_N", 0.0), mass=vals.get("mass_kg", mass),
        yaw_inertia=vals.get("yaw_inertia_kg_m2", yaw),
        wheel_inertia=vals.get("wheel_inertia_kg_m2", spin), source=str(p),
        anchor=_hook(p, data, "tether_anchor"), hub=_hook(p, data, "hub_contact"), empirical=empirical,
    )


def shipped_truths() -> dict[str, Path]:
    """Example truth files shipped in ``offline/sim/truths`` by name (file stem)."""
    from importlib import resources

    folder = Path(str(resources.files("offline.sim").joinpath("truths")))
    return {p.stem: p for p in sorted(folder.glob("*.toml"))}


def resolve_truth_path(name: str | Path) -> Path:
    """A truth file path, or the shipped file of that name.

    Raises
    ------
    TruthError
        Neither a file nor a shipped name.
    """
    p = Path(name)
    if p.exists():
        return p
    shipped = shipped_truths()
    if str(name) in shipped:
        return shipped[str(name)]
    raise TruthError(f"{name}: no such truth file; give a path or one of {sorted(shipped)}")
