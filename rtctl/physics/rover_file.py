"""A rover described by a file: wheels, suspension, mass and actuator limits (TOML).

Both sides read it (the ground side's NLP and table builder, the rover's exact residual), so it
lives with the shared physics and needs only the standard library's ``tomllib``. The balance a
file's suspension implies is built by :class:`rtctl.physics.suspension.SuspensionStatics`.

Format
------
Units are in the key names (SI except degrees for angles, converted once here). Frames: the
body frame of Fig. 7.2, x forward, y left, z up, origin at the body's reference point O (the
moment rows are about O); positions are given with the rover standing level with every wheel
centre where the file puts it (the nominal pose).

.. code-block:: toml

    [rover]
    name = "mini_rover"
    source = "dissertation Table 7.2"     # where the numbers come from (free text)
    weight_N = 34.3                       # or mass_kg together with gravity_m_s2
    centre_of_mass_m = [0.0, 0.0, 0.0]    # in the body frame, relative to O
    travel_speed_m_s = 0.03               # optional: nominal speed

    [suspension]
    kind = "rocker"                       # "rocker" | "rocker_bogie" | "rigid"
    body_fixed_to = "rocker_right"        # rocker only: the rocker the body is fixed to

    [links.rocker_right]                  # one table per passive link (none for rigid)
    parent = "body"                       # "body" or another link (a bogie's rocker)
    pivot_m = [0.0, -0.1655, 0.0]         # the link's pitch pivot, body frame

    [actuators]
    drive_speed_max_rad_s = 4.817
    drive_torque_max_N_m = 4.1
    steer_rate_max_deg_s = 582.0          # required when a wheel is steerable

    [wheels.FR]                           # one table per wheel, in layout order
    link = "rocker_right"                 # the link carrying it ("body" for rigid)
    position_m = [0.16, -0.1655, -0.112]  # wheel centre, body frame
    params = "dissertation-ch7"           # wheel/soil parameter preset or file (relative to this file)
    driven = true
    steerable = true
    steer_min_deg = -90.0                 # steerable only
    steer_max_deg = 90.0

Suspension kinds (what the loader enforces; the statics derives its rows from the link tree):

* ``rocker``: the four-wheel rocker of Table 7.2: two links with parent ``body``, one each
  side of the x-z plane, two wheels each, pivots on one lateral (y) axis; the rockers are
  joined by a passive pivot and the body is fixed to one of them (``body_fixed_to``; the mini
  rover's electronics are fixed to the right rocker, section 7.3).
* ``rocker_bogie``: a rocker each side (parent ``body``, pivots on one lateral axis) carrying
  one wheel and a bogie (parent: that rocker) with two wheels, and a differential between the
  rockers (the body pitches by their mean angle), as on MER and MSL.
* ``rigid``: every wheel on ``body`` (a skid-steer rover): at least three wheels, their
  centres at one body height and not on one line.

Every error is a :class:`RoverFileError` naming the file, the section and the key, and saying
what was expected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from .parameters import ParameterError, read_toml

__all__ = ["RoverFileError", "WheelSpec", "LinkSpec", "ActuatorLimits", "RoverSpec", "load_rover_file",
           "parse_rover", "SHIPPED_ROVERS", "shipped_rover", "SUSPENSION_KINDS", "driving_backward",
           "rover_spec_from_record"]

SUSPENSION_KINDS: tuple[str, ...] = ("rocker", "rocker_bogie", "rigid")
"""The suspension kinds a rover file may name (module docstring)."""

SHIPPED_ROVERS: Path = Path(__file__).resolve().parent / "rovers"
"""Folder of the example rover files shipped with the package."""

_GEOM_TOL_M = 1e-9
"""m; two coordinates that must be equal (pivots on one axis, rigid wheel heights) may differ by this."""

_ROVER_KEYS = {"name", "source", "weight_N", "mass_kg", "gravity_m_s2", "centre_of_mass_m", "travel_speed_m_s"}
_SUSPENSION_KEYS = {"kind", "body_fixed_to"}
_LINK_KEYS = {"parent", "pivot_m"}
_ACTUATOR_KEYS = {"drive_speed_max_rad_s", "drive_torque_max_N_m", "steer_rate_max_deg_s"}
_WHEEL_KEYS = {"link", "position_m", "params", "driven", "steerable", "steer_min_deg", "steer_max_deg"}
_SECTIONS = {"rover", "suspension", "links", "actuators", "wheels"}


class RoverFileError(ParameterError):
    """A rover file that cannot be used: the message names the file, section and key."""


@dataclass(frozen=True)
class WheelSpec:
    """One wheel of a rover file (SI).

    Attributes
    ----------
    name : str
        The wheel's name (its ``[wheels.<name>]`` table).
    link : str
        The link carrying it (``"body"`` on a rigid rover).
    position : tuple of float
        Wheel centre in the body frame at the nominal pose, m.
    params : str
        Wheel/soil parameter preset name or parameter file (relative to the rover file).
    driven : bool
        Has a drive motor.
    steerable : bool
        Has a steering motor.
    steer_min, steer_max : float
        Steering range, rad (both 0 for a wheel that is not steerable).
    """

    name: str
    link: str
    position: tuple[float, float, float]
    params: str
    driven: bool
    steerable: bool
    steer_min: float = 0.0
    steer_max: float = 0.0


@dataclass(frozen=True)
class LinkSpec:
    """A passive suspension link (rocker or bogie) pivoting in pitch about a lateral axis.

    Attributes
    ----------
    name : str
    parent : str
        ``"body"`` or the name of the link it pivots on.
    pivot : tuple of float
        Pivot point in the body frame at the nominal pose, m (the axis is the body y axis).
    """

    name: str
    parent: str
    pivot: tuple[float, float, float]


@dataclass(frozen=True)
class ActuatorLimits:
    """Actuator limits (SI).

    Attributes
    ----------
    drive_speed_max : float
        Largest wheel angular speed, rad/s (bound 7.2).
    drive_torque_max : float
        Largest drive torque, N m.
    steer_rate_max : float or None
        Largest steering rate, rad/s (None: no steerable wheel).
    """

    drive_speed_max: float
    drive_torque_max: float
    steer_rate_max: float | None = None


@dataclass(frozen=True)
class RoverSpec:
    """A rover as a rover file describes it (SI; see the module docstring for the format).

    Attributes
    ----------
    name, source : str
    weight : float
        N (``mass_kg * gravity_m_s2`` when the file gives a mass).
    centre_of_mass : tuple of float
        Body frame, relative to O, m.
    suspension : str
        One of :data:`SUSPENSION_KINDS`.
    links : tuple of LinkSpec
        The passive links (empty for ``rigid``).
    wheels : tuple of WheelSpec
        In file order (the layout order of every per-wheel array).
    actuators : ActuatorLimits
    body_fixed_to : str or None
        ``rocker``: the link the body is fixed to.
    travel_speed : float or None
        Nominal speed, m/s.
    path : str
        The file it was read from (as given), for messages; "" when parsed from a mapping.
    """

    name: str
    source: str
    weight: float
    centre_of_mass: tuple[float, float, float]
    suspension: str
    links: tuple[LinkSpec, ...]
    wheels: tuple[WheelSpec, ...]
    actuators: ActuatorLimits
    body_fixed_to: str | None = None
    travel_speed: float | None = None
    path: str = ""

    @property
    def wheel_names(self) -> tuple[str, ...]:
        """Wheel names in layout order."""
        return tuple(w.name for w in self.wheels)

    def wheel(self, name: str) -> WheelSpec:
        """The wheel called ``name`` (KeyError naming the known wheels otherwise)."""
        for w in self.wheels:
            if w.name == name:
                return w
        raise KeyError(f"{self.path or self.name}: no wheel {name!r}; wheels: {list(self.wheel_names)}")

    def wheel_params(self, name: str) -> str:
        """The wheel's ``params`` resolved: a ``.toml`` name becomes a path beside the rover file
        (when the spec was read from a file); a preset name is returned as it is.

        Parameters
        ----------
        name : str
            Wheel name.
        """
        value = self.wheel(name).params
        if value.endswith(".toml") and self.path:
            return str(Path(self.path).parent / value)
        return value

    def link(self, name: str) -> LinkSpec:
        """The link called ``name`` (KeyError naming the known links otherwise)."""
        for lk in self.links:
            if lk.name == name:
                return lk
        raise KeyError(f"{self.path or self.name}: no link {name!r}; links: {[lk.name for lk in self.links]}")


# --- parsing helpers --------------------------------------------------------------------------

class _Ctx:
    """Error messages that name the file, section and key."""

    def __init__(self, path: str) -> None:
        self.path = path or "<rover mapping>"

    def err(self, section: str, key: str | None, what: str) -> RoverFileError:
        where = f"[{section}]" + (f" {key}" if key else "")
        return RoverFileError(f"{self.path}: {where}: {what}")

    def table(self, data: Mapping[str, Any], section: str, required: bool = True) -> Mapping[str, Any]:
        parts = section.split(".")
        node: Any = data
        for p in parts:
            if not isinstance(node, Mapping) or p not in node:
                if required:
                    raise self.err(section, None, "missing section (expected a TOML table)")
                return {}
            node = node[p]
        if not isinstance(node, Mapping):
            raise self.err(section, None, f"expected a TOML table, got {node!r}")
        return node

    def unknown(self, table: Mapping[str, Any], section: str, known: set[str]) -> None:
        extra = sorted(set(table) - known)
        if extra:
            k = extra[0]
            stem = k.rsplit("_", 1)[0]
            near = sorted(kk for kk in known if kk.startswith(stem + "_"))
            hint = f" (wrong unit? expected {near})" if near and "_" in k else ""
            raise self.err(section, k, f"unknown key{hint}; known keys: {sorted(known)}")

    def opt_number(self, table: Mapping[str, Any], section: str, key: str, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False, required: bool = True) -> float | None:
        if key not in table:
            if required:
                raise self.err(section, key, "missing key (expected a finite number)")
            return None
        v = table[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(section, key, f"expected a finite number, got {v!r} ({type(v).__name__})")
        x = float(v)
        if not math.isfinite(x):
            raise self.err(section, key, f"expected a finite number, got {v!r}")
        if lo is not None and (x < lo or (lo_open and x == lo)):
            raise self.err(section, key, f"= {v!r} is out of range: expected {'>' if lo_open else '>='} {lo:g}")
        if hi is not None and x > hi:
            raise self.err(section, key, f"= {v!r} is out of range: expected <= {hi:g}")
        return x

    def number(self, table: Mapping[str, Any], section: str, key: str, lo: float | None = None,
               hi: float | None = None, lo_open: bool = False) -> float:
        x = self.opt_number(table, section, key, lo, hi, lo_open, required=True)
        if x is None:  # unreachable: a required key raises in opt_number
            raise self.err(section, key, "missing key (expected a finite number)")
        return x

    def vector3(self, table: Mapping[str, Any], section: str, key: str) -> tuple[float, float, float]:
        if key not in table:
            raise self.err(section, key, "missing key (expected [x, y, z] in metres)")
        v = table[key]
        if not isinstance(v, list) or len(v) != 3:
            raise self.err(section, key, f"expected a list of three numbers [x, y, z] in metres, got {v!r}")
        out = []
        for i, c in enumerate(v):
            if isinstance(c, bool) or not isinstance(c, (int, float)) or not math.isfinite(float(c)):
                raise self.err(section, f"{key}[{i}]", f"expected a finite number (metres), got {c!r}")
            out.append(float(c))
        return out[0], out[1], out[2]

    def opt_string(self, table: Mapping[str, Any], section: str, key: str, required: bool = True) -> str | None:
        if key not in table:
            if required:
                raise self.err(section, key, "missing key (expected a string)")
            return None
        v = table[key]
        if not isinstance(v, str) or not v.strip():
            raise self.err(section, key, f"expected a non-empty string, got {v!r}")
        return v

    def string(self, table: Mapping[str, Any], section: str, key: str) -> str:
        v = self.opt_string(table, section, key, required=True)
        if v is None:  # unreachable: a required key raises in opt_string
            raise self.err(section, key, "missing key (expected a string)")
        return v

    def boolean(self, table: Mapping[str, Any], section: str, key: str) -> bool:
        if key not in table:
            raise self.err(section, key, "missing key (expected true or false)")
        v = table[key]
        if not isinstance(v, bool):
            raise self.err(section, key, f"expected true or false, got {v!r}")
        return v


def _parse_wheel(c: _Ctx, name: str, t: Any) -> WheelSpec:
    sec = f"wheels.{name}"
    if not isinstance(t, Mapping):
        raise c.err(sec, None, f"expected a TOML table, got {t!r}")
    c.unknown(t, sec, _WHEEL_KEYS)
    link = c.string(t, sec, "link")
    pos = c.vector3(t, sec, "position_m")
    params = c.string(t, sec, "params")
    if params.startswith("/") or params.startswith("\\") or (len(params) > 1 and params[1] == ":"):
        raise c.err(sec, "params", f"expected a preset name or a path relative to the rover file, got the absolute path {params!r}")
    driven = c.boolean(t, sec, "driven")
    steerable = c.boolean(t, sec, "steerable")
    if steerable:
        lo = c.number(t, sec, "steer_min_deg", -180.0, 180.0)
        hi = c.number(t, sec, "steer_max_deg", -180.0, 180.0)
        if not lo < hi:
            raise c.err(sec, "steer_max_deg", f"= {hi!r} must exceed steer_min_deg = {lo!r}")
        if not lo <= 0.0 <= hi:
            raise c.err(sec, "steer_min_deg", f"the range [{lo!r}, {hi!r}] deg must contain 0 (straight ahead)")
        return WheelSpec(name, link, pos, params, driven, True, math.radians(lo), math.radians(hi))
    for k in ("steer_min_deg", "steer_max_deg"):
        if k in t:
            raise c.err(sec, k, "given for a wheel with steerable = false (remove it, or set steerable = true)")
    return WheelSpec(name, link, pos, params, driven, False)


def _check_tree(c: _Ctx, kind: str, links: tuple[LinkSpec, ...], wheels: tuple[WheelSpec, ...],
                body_fixed_to: str | None) -> None:
    names = {lk.name for lk in links}
    if "body" in names:
        raise c.err("links.body", None, "'body' is the rover body, not a link name; name the link otherwise")
    for lk in links:
        if lk.parent != "body" and lk.parent not in names:
            raise c.err(f"links.{lk.name}", "parent", f"= {lk.parent!r}: expected 'body' or one of the links {sorted(names)}")
        if lk.parent == lk.name:
            raise c.err(f"links.{lk.name}", "parent", "a link cannot pivot on itself")
    for w in wheels:
        if w.link != "body" and w.link not in names:
            raise c.err(f"wheels.{w.name}", "link", f"= {w.link!r}: expected 'body' or one of the links {sorted(names)}")
    # cycles: every chain of parents must reach the body
    parent = {lk.name: lk.parent for lk in links}
    for lk in links:
        seen, p = {lk.name}, lk.parent
        while p != "body":
            if p in seen:
                raise c.err(f"links.{lk.name}", "parent", f"the parents form a cycle through {sorted(seen)}")
            seen.add(p)
            p = parent[p]
    children = {n: [lk for lk in links if lk.parent == n] for n in [*names, "body"]}
    on = {n: [w for w in wheels if w.link == n] for n in [*names, "body"]}
    rockers = children["body"]

    def need(cond: bool, section: str, key: str | None, what: str) -> None:
        if not cond:
            raise c.err(section, key, what)

    for lk in links:
        supports = len(on[lk.name]) + len(children[lk.name])
        need(supports == 2, f"links.{lk.name}", None,
             f"a passive link must rest on exactly two supports (wheels or child pivots); it has {supports} "
             f"(wheels {[w.name for w in on[lk.name]]}, child links {[x.name for x in children[lk.name]]})")
        xs = [w.position[0] for w in on[lk.name]] + [x.pivot[0] for x in children[lk.name]]
        need(abs(xs[0] - xs[1]) > 1e-6, f"links.{lk.name}", None,
             f"its two supports must be apart along x (got x = {xs[0]!r} and {xs[1]!r} m): its pitch angle "
             "follows from their height difference")
    if kind == "rigid":
        need(not links, "links", None, "a rigid rover has no passive links (remove the [links] tables)")
        need(len(on["body"]) >= 3, "wheels", None, f"a rigid rover needs at least three wheels on 'body', got {len(on['body'])}")
        z0 = wheels[0].position[2]
        for w in wheels:
            need(abs(w.position[2] - z0) <= _GEOM_TOL_M, f"wheels.{w.name}", "position_m",
                 f"rigid rover: every wheel centre at one body height (z = {z0!r} m as the first wheel), got {w.position[2]!r}; "
                 "the compatibility of non-coplanar centres is not implemented")
        p0 = wheels[0].position
        area = max(abs((a.position[0] - p0[0]) * (b.position[1] - p0[1]) - (a.position[1] - p0[1]) * (b.position[0] - p0[0]))
                   for a in wheels for b in wheels)
        need(area > 1e-6, "wheels", None, "rigid rover: the wheel centres lie on one line (the loads are not determined)")
    else:
        need(not on["body"], f"wheels.{on['body'][0].name}" if on["body"] else "wheels", "link",
             f"suspension kind {kind!r}: every wheel rides on a link, not on 'body'")
        need(len(rockers) == 2, "links", None,
             f"suspension kind {kind!r}: exactly two links with parent = 'body' (the rockers), got {[r.name for r in rockers]}")
        r0, r1 = rockers
        need(r0.pivot[1] * r1.pivot[1] < 0, f"links.{r1.name}", "pivot_m",
             "the two rockers must pivot on opposite sides of the x-z plane (y < 0 right, y > 0 left)")
        need(abs(r0.pivot[0] - r1.pivot[0]) <= _GEOM_TOL_M and abs(r0.pivot[2] - r1.pivot[2]) <= _GEOM_TOL_M,
             f"links.{r1.name}", "pivot_m",
             f"the rocker pivots must lie on one lateral axis (same x and z as {r0.name}'s {list(r0.pivot)})")
        if kind == "rocker":
            for r in rockers:
                need(len(on[r.name]) == 2 and not children[r.name], f"links.{r.name}", None,
                     "suspension kind 'rocker': each rocker carries two wheels and no bogie")
            need(body_fixed_to in {r.name for r in rockers}, "suspension", "body_fixed_to",
                 f"= {body_fixed_to!r}: expected one of the rockers {[r.name for r in rockers]}")
        else:
            for r in rockers:
                need(len(on[r.name]) == 1 and len(children[r.name]) == 1, f"links.{r.name}", None,
                     "suspension kind 'rocker_bogie': each rocker carries one wheel and one bogie")
                bogie = children[r.name][0]
                need(len(on[bogie.name]) == 2 and not children[bogie.name], f"links.{bogie.name}", None,
                     "suspension kind 'rocker_bogie': each bogie carries two wheels")


def parse_rover(data: Mapping[str, Any], path: str = "") -> RoverSpec:
    """Validate the parsed TOML of a rover file and convert it to SI.

    Parameters
    ----------
    data : mapping
        The parsed TOML.
    path : str
        The file's name as given, for the messages.

    Returns
    -------
    RoverSpec

    Raises
    ------
    RoverFileError
        Naming the file, section and key: an unknown or missing section or key, a wrong type or
        unit, a non-finite or out-of-range number, or a link tree that does not fit the kind.
    """
    c = _Ctx(path)
    extra = sorted(set(data) - _SECTIONS)
    if extra:
        raise c.err(extra[0], None, f"unknown section; expected the sections {sorted(_SECTIONS)}")
    rv = c.table(data, "rover")
    c.unknown(rv, "rover", _ROVER_KEYS)
    name = c.string(rv, "rover", "name")
    source = c.opt_string(rv, "rover", "source", required=False) or ""
    if "weight_N" in rv:
        for k in ("mass_kg", "gravity_m_s2"):
            if k in rv:
                raise c.err("rover", k, "give either weight_N, or mass_kg with gravity_m_s2, not both")
        weight = c.number(rv, "rover", "weight_N", 0.0, lo_open=True)
    elif "mass_kg" in rv or "gravity_m_s2" in rv:
        m = c.number(rv, "rover", "mass_kg", 0.0, lo_open=True)
        g = c.number(rv, "rover", "gravity_m_s2", 0.0, 30.0, lo_open=True)
        weight = m * g
    else:
        raise c.err("rover", "weight_N", "missing key (expected weight_N, or mass_kg with gravity_m_s2)")
    com = c.vector3(rv, "rover", "centre_of_mass_m")
    speed = c.opt_number(rv, "rover", "travel_speed_m_s", 0.0, 10.0, lo_open=True, required=False)

    sus = c.table(data, "suspension")
    c.unknown(sus, "suspension", _SUSPENSION_KEYS)
    kind = c.string(sus, "suspension", "kind")
    if kind not in SUSPENSION_KINDS:
        raise c.err("suspension", "kind", f"= {kind!r}: expected one of {list(SUSPENSION_KINDS)}")
    body_fixed_to = c.opt_string(sus, "suspension", "body_fixed_to", required=(kind == "rocker"))
    if kind != "rocker" and body_fixed_to is not None:
        raise c.err("suspension", "body_fixed_to", f"only for kind = 'rocker' (the body of a {kind!r} rover is "
                    + ("carried by the differential)" if kind == "rocker_bogie" else "itself the frame)"))

    lt = c.table(data, "links", required=False)
    links = []
    for ln, t in lt.items():
        sec = f"links.{ln}"
        if not isinstance(t, Mapping):
            raise c.err(sec, None, f"expected a TOML table, got {t!r}")
        c.unknown(t, sec, _LINK_KEYS)
        parent = c.string(t, sec, "parent")
        links.append(LinkSpec(ln, parent, c.vector3(t, sec, "pivot_m")))

    wt = c.table(data, "wheels")
    if not wt:
        raise c.err("wheels", None, "expected at least one [wheels.<name>] table")
    wheels = tuple(_parse_wheel(c, wn, t) for wn, t in wt.items())

    act = c.table(data, "actuators")
    c.unknown(act, "actuators", _ACTUATOR_KEYS)
    speed_max = c.number(act, "actuators", "drive_speed_max_rad_s", 0.0, lo_open=True)
    torque_max = c.number(act, "actuators", "drive_torque_max_N_m", 0.0, lo_open=True)
    any_steer = any(w.steerable for w in wheels)
    rate = c.opt_number(act, "actuators", "steer_rate_max_deg_s", 0.0, lo_open=True, required=any_steer)
    if rate is not None and not any_steer:
        raise c.err("actuators", "steer_rate_max_deg_s", "given but no wheel is steerable (remove it)")
    actuators = ActuatorLimits(speed_max, torque_max, None if rate is None else math.radians(rate))

    _check_tree(c, kind, tuple(links), wheels, body_fixed_to)
    return RoverSpec(name, source, weight, com, kind, tuple(links), wheels, actuators, body_fixed_to, speed, path)


def load_rover_file(path: str | Path) -> RoverSpec:
    """Read and validate a rover file (module docstring).

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    RoverSpec

    Raises
    ------
    RoverFileError
        The file is missing or not TOML, or :func:`parse_rover` rejects it.
    """
    p = Path(path)
    return parse_rover(read_toml(p, RoverFileError, "rover file"), str(p))


def driving_backward(spec: RoverSpec) -> RoverSpec:
    """The rover turned half round about the vertical: the file's rover driving backward.

    The optimizer's frames are tied to the travel direction (x forward along it, Fig. 7.2), so
    driving backward is driving forward with the body turned by 180 deg about z: every wheel
    centre, link pivot and the centre of mass ``(x, y, z) -> (-x, -y, z)``. Wheel names stay,
    so a rear wheel of the file leads and the file's right side is on the left of the travel
    direction (Spirit's dragged right-front wheel trails). Steering angles are rotations about
    z, which the half turn leaves unchanged: a wheel's steering range and a stuck angle keep
    their values (measured from the body's own +x, now pointing backward, the wheel's heading is
    the same physical direction). Link names stay (a link's side follows its pivot's ``y``).

    Parameters
    ----------
    spec : RoverSpec
        The rover as its file describes it.

    Returns
    -------
    RoverSpec
        The turned rover; ``name`` gains ``" (backward)"``.
    """
    from dataclasses import replace

    def turn(v: tuple[float, float, float]) -> tuple[float, float, float]:
        return -v[0] + 0.0, -v[1] + 0.0, v[2]

    return replace(spec, name=f"{spec.name} (backward)", centre_of_mass=turn(spec.centre_of_mass),
                   links=tuple(replace(lk, pivot=turn(lk.pivot)) for lk in spec.links),
                   wheels=tuple(replace(w, position=turn(w.position)) for w in spec.wheels))


def shipped_rover(name: str) -> RoverSpec:
    """One of the example rover files shipped in :data:`SHIPPED_ROVERS` (``name`` without ``.toml``).

    Parameters
    ----------
    name : str
        ``"mini_rover_t72"``, ``"mer_class_rocker_bogie"`` or ``"skid_steer_4w"``.

    Returns
    -------
    RoverSpec
    """
    p = SHIPPED_ROVERS / f"{name}.toml"
    if not p.is_file():
        known = sorted(q.stem for q in SHIPPED_ROVERS.glob("*.toml") if not q.stem.endswith("_wheel"))
        raise RoverFileError(f"no shipped rover {name!r}; shipped rovers: {known}")
    return load_rover_file(p)


def _plain(v: Any) -> Any:
    """A header record's value without its type tags (``{"__tuple__": [...]}``, ``{"__float__": "inf"}``)."""
    if isinstance(v, Mapping):
        if "__tuple__" in v:
            return [_plain(q) for q in v["__tuple__"]]
        if "__float__" in v:
            return float(v["__float__"])
        return {k: _plain(q) for k, q in v.items() if k != "__class__"}
    if isinstance(v, list):
        return [_plain(q) for q in v]
    return v


def rover_spec_from_record(rec: Mapping[str, Any], where: str = "table header") -> RoverSpec:
    """The :class:`RoverSpec` a table was built with, from the record its header stores
    (``scenario.rover_file``: the spec as the builder used it, already turned round for a
    backward drive by :func:`driving_backward`), so the rover rebuilds the same statics the NLP
    used without the file itself.

    Parameters
    ----------
    rec : mapping
        The record (``dataclasses.asdict`` of a RoverSpec, with the header's type tags).
    where : str
        Named in the error.

    Returns
    -------
    RoverSpec

    Raises
    ------
    RoverFileError
        A key missing or of the wrong type (naming it).
    """
    d = _plain(rec)
    try:
        def vec(v: Any) -> tuple[float, float, float]:
            a = [float(q) for q in v]
            if len(a) != 3:
                raise ValueError(f"expected 3 coordinates, got {len(a)}")
            return a[0], a[1], a[2]

        act = d["actuators"]
        srm = act.get("steer_rate_max")
        return RoverSpec(
            name=str(d["name"]), source=str(d.get("source", "")), weight=float(d["weight"]),
            centre_of_mass=vec(d["centre_of_mass"]), suspension=str(d["suspension"]),
            links=tuple(LinkSpec(str(lk["name"]), str(lk["parent"]), vec(lk["pivot"])) for lk in d["links"]),
            wheels=tuple(WheelSpec(str(w["name"]), str(w["link"]), vec(w["position"]), str(w["params"]),
                                   bool(w["driven"]), bool(w["steerable"]), float(w.get("steer_min", 0.0)),
                                   float(w.get("steer_max", 0.0))) for w in d["wheels"]),
            actuators=ActuatorLimits(float(act["drive_speed_max"]), float(act["drive_torque_max"]),
                                     None if srm is None else float(srm)),
            body_fixed_to=None if d.get("body_fixed_to") is None else str(d["body_fixed_to"]),
            travel_speed=None if d.get("travel_speed") is None else float(d["travel_speed"]),
            path=str(d.get("path", "")))
    except (KeyError, TypeError, ValueError) as exc:
        raise RoverFileError(f"{where}: rover record malformed ({type(exc).__name__}: {exc}); rebuild the table") from exc
