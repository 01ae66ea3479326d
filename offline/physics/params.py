"""Frozen parameter sets for soil, wheel, contact tuning and rover, with TOML I/O.

All fields are SI (m, N, Pa, rad). TOML files carry the unit in every key name
(``radius_m``, ``friction_angle_deg``, ``k_kN_per_m_n_plus_2``) and are converted once,
here, where they enter. Presets are named after their source.

Presets
-------
``SOIL_DISSERTATION_T53_GROUSERED`` / ``..._SMOOTH``
    Soil Direct #90 sand, dissertation Table 5.3 (n2 differs per wheel).
``SOIL_DISSERTATION_T42``
    Table 4.2 (soil-flow chapter): angle of repose 29 deg, c = 0.
``WHEEL_K10_MINI_T42``, ``WHEEL_GROUSERED_T52``, ``WHEEL_SMOOTH_T52``
    Dissertation Tables 4.2 and 5.2.
``WHEEL_GROUSERED_PUBLISHED_CODE``
    The geometry of the published code used with the shared single-wheel data
    (r = 0.058 m, b = 0.050 m, h_g = 0.005 m, mu = 0.1, zeta = 0.2).
``TUNING_T54_GROUSERED`` / ``TUNING_T54_SMOOTH``
    Per-slip-angle a0..b1 of Table 5.4 (a dict keyed by slip angle in degrees).
``TUNING_T72_LINEAR``
    The linear a(beta) fit of Table 7.2, eqs. (7.8)-(7.9).
``ROVER_MINI_T72``
    The mini rover of Table 7.2.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any, Mapping

__all__ = [
    "ParameterError",
    "Soil",
    "Wheel",
    "ContactTuning",
    "TuningTable",
    "CONTACT_RATIO_RANGE",
    "Rover",
    "ParameterSet",
    "load_toml",
    "save_toml",
    "SOIL_DISSERTATION_T53_GROUSERED",
    "SOIL_DISSERTATION_T53_SMOOTH",
    "SOIL_DISSERTATION_T42",
    "WHEEL_K10_MINI_T42",
    "WHEEL_GROUSERED_T52",
    "WHEEL_SMOOTH_T52",
    "WHEEL_GROUSERED_PUBLISHED_CODE",
    "TUNING_T54_GROUSERED",
    "TUNING_T54_SMOOTH",
    "TUNING_T54_GROUSERED_TABLE",
    "TUNING_T54_SMOOTH_TABLE",
    "TUNING_T72_LINEAR",
    "ROVER_MINI_T72",
]


from rtctl.physics.parameters import ParameterError, read_toml  # noqa: E402  (one class on both sides)


def _check_finite(owner: str, name: str, value: float) -> None:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise ParameterError(f"{owner}.{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(f"{owner}.{name} must be finite, got {value!r}")


def _check_positive(owner: str, name: str, value: float) -> None:
    _check_finite(owner, name, value)
    if value <= 0.0:
        raise ParameterError(f"{owner}.{name} must be > 0, got {value!r}")


def _check_range(owner: str, name: str, value: float, lo: float, hi: float, hint: str = "") -> None:
    _check_finite(owner, name, value)
    if not lo <= value <= hi:
        raise ParameterError(f"{owner}.{name} = {value!r} outside [{lo}, {hi}]{hint}")


_DEG_HINT = " (radians expected: did you pass degrees? use math.radians)"


@dataclass(frozen=True)
class Soil:
    """Soil properties of the terramechanics (ch. 5) and soil-flow (ch. 4) models.

    Parameters
    ----------
    k : float
        Pressure-sinkage modulus of eq. (5.5), N/m^(n+2) (Table 5.3: 8000 kN/m^(n+2) = 8e6).
    n0, n1, n2 : float
        Sinkage exponent coefficients of eq. (5.6): n = n0 + n1 s (slip), n0 - n2 s (skid).
    friction_angle : float
        Internal friction angle phi, rad.
    unit_weight : float
        Soil specific weight rho of eqs. (5.22)-(5.24), N/m^3 (13.03 kN/m^3 = 13030).
    cohesion : float
        Cohesion c, Pa.
    shear_modulus : float
        Shear deformation modulus K of eq. (5.10), m.
    repose_angle : float
        Angle of repose used by the soil-flow model (ch. 4), rad.
    name, source : str
        Provenance.
    """

    k: float
    n0: float
    n1: float
    n2: float
    friction_angle: float
    unit_weight: float
    cohesion: float
    shear_modulus: float
    repose_angle: float
    name: str = "soil"
    source: str = ""

    def __post_init__(self) -> None:
        o = "Soil"
        _check_positive(o, "k", self.k)
        _check_positive(o, "n0", self.n0)
        _check_range(o, "n1", self.n1, 0.0, 10.0)
        _check_range(o, "n2", self.n2, 0.0, 10.0)
        _check_range(o, "friction_angle", self.friction_angle, 1e-6, math.radians(60.0), _DEG_HINT)
        _check_range(o, "repose_angle", self.repose_angle, 1e-6, math.radians(60.0), _DEG_HINT)
        _check_positive(o, "unit_weight", self.unit_weight)
        _check_range(o, "cohesion", self.cohesion, 0.0, 1e6)
        _check_positive(o, "shear_modulus", self.shear_modulus)
        if self.k < 1e4:
            raise ParameterError(
                f"Soil.k = {self.k!r} N/m^(n+2) is implausibly small: k is in SI; "
                "8000 kN/m^(n+2) is 8.0e6 (did you pass kN?)"
            )
        if self.k > 1e10:
            raise ParameterError(f"Soil.k = {self.k!r} N/m^(n+2) is implausibly large (did you convert kN twice?)")


@dataclass(frozen=True)
class Wheel:
    """Rigid wheel geometry (Tables 4.2, 5.2).

    Parameters
    ----------
    radius : float
        Rim radius r, m.
    width : float
        Width b, m.
    grouser_height : float
        h_g, m; the shearing radius is r_s = r + h_g (section 5.2).
    grouser_area_ratio : float
        mu of eq. (5.9): fraction of the rim covered by grouser tips (1 for a smooth wheel).
    grouser_volume_fraction : float
        zeta of eq. (4.3): fraction of each grouser filled with transported soil.
    name, source : str
        A label and where the values come from (written to parameter files).
    """

    radius: float
    width: float
    grouser_height: float
    grouser_area_ratio: float
    grouser_volume_fraction: float
    name: str = "wheel"
    source: str = ""

    def __post_init__(self) -> None:
        o = "Wheel"
        _check_positive(o, "radius", self.radius)
        _check_positive(o, "width", self.width)
        _check_range(o, "grouser_height", self.grouser_height, 0.0, self.radius)
        _check_range(o, "grouser_area_ratio", self.grouser_area_ratio, 0.0, 1.0)
        _check_range(o, "grouser_volume_fraction", self.grouser_volume_fraction, 0.0, 1.0)
        if self.radius > 5.0 or self.width > 5.0:
            raise ParameterError(
                f"Wheel radius {self.radius!r} m / width {self.width!r} m: lengths are in metres "
                "(did you pass millimetres?)"
            )

    @property
    def shearing_radius(self) -> float:
        """r_s = r + h_g (section 5.2)."""
        return self.radius + self.grouser_height


CONTACT_RATIO_RANGE = (-1.25, 1.25)
"""Allowed range of theta_m / theta_f and theta_r / theta_f from the tuning (eqs. 5.3-5.4),
at every slip angle up to 90 deg (the per-degree slopes extrapolated) and slip ratio.

The contact patch spans theta_r..theta_f with -theta_f <= theta_r <= 0, so both ratios
belong in [-1, 1]. The model clips theta_m into the patch, and lines fitted on 0-60 deg
overshoot a little when extrapolated to 90 deg (a fit to synthetic data: 1.06), so 25 %
slack is left; beyond it the numbers are not a tuning but a mistake (e.g. slopes per
radian written as per degree, 57 times too large)."""


def _check_contact_ratios(owner: str, t: Any) -> None:
    """Refuse a tuning (with its per-radian slopes) that puts theta_m or theta_r outside the
    contact patch at any slip angle |beta| in [0, 90] deg and slip ratio s in [0, 1]
    (linear in both, so the extremes are at the corners). Skid uses a0, b0 (s = 0)."""
    lo, hi = CONTACT_RATIO_RANGE
    for beta_deg in (0.0, 90.0):
        a0, a1, b0, b1 = t.at(math.radians(beta_deg))
        for what, c0, c1 in (("theta_m", a0, a1), ("theta_r", b0, b1)):
            for s_ in (0.0, 1.0):
                ratio = c0 + c1 * s_
                if not lo <= ratio <= hi:
                    p = "a" if what == "theta_m" else "b"
                    raise ParameterError(
                        f"{owner}: {what} / theta_f = {p}0 + {p}1 s = {ratio:.3g} at |beta| = {beta_deg:g} deg, "
                        f"s = {s_:g} ({p}0 = {c0:.4g}, {p}1 = {c1:.4g} there, from {p}0, {p}1 and their per-degree "
                        f"slopes {p}0_per_deg = {math.radians(getattr(t, p + '0_per_rad')):.4g}, "
                        f"{p}1_per_deg = {math.radians(getattr(t, p + '1_per_rad')):.4g}); it must stay inside the "
                        f"contact patch, [{lo}, {hi}]: check the per-degree slopes (per degree, not per radian?)"
                    )


@dataclass(frozen=True)
class ContactTuning:
    """Contact-angle tuning of eqs. (5.3)-(5.4), optionally linear in |beta| (7.8)-(7.9).

    ``theta_m = theta_f (a0 + a1 s)``, ``theta_r = theta_f (b0 + b1 s)`` in slip, with

    .. math:: a_0 = a_{0} + a_{0,\\beta} |\\beta|, \\quad a_1 = a_{1} + a_{1,\\beta} |\\beta|

    and likewise for b0, b1 (slopes per radian). Using |beta| keeps the model mirror
    symmetric in beta; the dissertation fits beta >= 0 only.
    """

    a0: float
    a1: float
    b0: float
    b1: float
    a0_per_rad: float = 0.0
    a1_per_rad: float = 0.0
    b0_per_rad: float = 0.0
    b1_per_rad: float = 0.0
    name: str = "tuning"
    source: str = ""

    def __post_init__(self) -> None:
        for f in ("a0", "a1", "b0", "b1", "a0_per_rad", "a1_per_rad", "b0_per_rad", "b1_per_rad"):
            _check_finite("ContactTuning", f, getattr(self, f))
        for f in ("a0", "a1", "b0", "b1"):
            _check_range("ContactTuning", f, getattr(self, f), -1.5, 1.5)
        _check_contact_ratios("ContactTuning", self)

    def at(self, abs_beta: Any) -> tuple[Any, Any, Any, Any]:
        """Return (a0, a1, b0, b1) at slip-angle magnitude ``abs_beta`` (rad)."""
        return (
            self.a0 + self.a0_per_rad * abs_beta,
            self.a1 + self.a1_per_rad * abs_beta,
            self.b0 + self.b0_per_rad * abs_beta,
            self.b1 + self.b1_per_rad * abs_beta,
        )


@dataclass(frozen=True)
class TuningTable:
    """Per-slip-angle contact tuning (a published table such as Table 5.4), interpolated in |beta|.

    Between two listed slip angles a0, a1, b0, b1 are linear in |beta| (so the Table 7.2
    lines are the special case of two rows); outside ``[beta[0], beta[-1]]`` there is no
    value (:meth:`at` raises) rather than an extrapolation. The physics model takes one
    :class:`ContactTuning`: use :meth:`tuning_at` for the tuning at one slip angle.

    Parameters
    ----------
    abs_beta : tuple of float
        Slip-angle magnitudes of the rows, rad, strictly increasing, within [0, pi/2].
    rows : tuple of ContactTuning
        The tuning of each row (no per-radian slopes).
    name, source : str
        A label and where the values come from (written to parameter files).
    """

    abs_beta: tuple[float, ...]
    rows: tuple[ContactTuning, ...]
    name: str = "tuning_table"
    source: str = ""

    def __post_init__(self) -> None:
        o = "TuningTable"
        if len(self.abs_beta) != len(self.rows) or not self.rows:
            raise ParameterError(f"{o}: needs one row per slip angle and at least one row, got {len(self.abs_beta)} "
                                 f"angles and {len(self.rows)} rows")
        for i, b in enumerate(self.abs_beta):
            _check_range(o, f"abs_beta[{i}]", b, 0.0, math.pi / 2 + 1e-12, _DEG_HINT)
        if any(b2 <= b1 for b1, b2 in zip(self.abs_beta, self.abs_beta[1:])):
            raise ParameterError(f"{o}: slip angles must be strictly increasing, got "
                                 f"{[round(math.degrees(b), 6) for b in self.abs_beta]} deg")
        for i, r in enumerate(self.rows):
            if not isinstance(r, ContactTuning):
                raise ParameterError(f"{o}: row {i} must be a ContactTuning, got {type(r).__name__}")
            if any((r.a0_per_rad, r.a1_per_rad, r.b0_per_rad, r.b1_per_rad)):
                raise ParameterError(f"{o}: row {i} has per-degree slopes; a table row holds a0..b1 at its angle only")

    @classmethod
    def from_degrees(cls, table: Mapping[float, ContactTuning], name: str = "tuning_table", source: str = "") -> "TuningTable":
        """Build from ``{slip angle in degrees: ContactTuning}`` (e.g. :data:`TUNING_T54_GROUSERED`)."""
        keys = sorted(table, key=lambda b: abs(float(b)))
        return cls(tuple(math.radians(abs(float(b))) for b in keys), tuple(table[b] for b in keys), name, source)

    def at(self, abs_beta: float) -> tuple[float, float, float, float]:
        """(a0, a1, b0, b1) at slip-angle magnitude ``abs_beta`` (rad), linear between rows.

        Raises
        ------
        ParameterError
            If ``abs_beta`` lies outside the table's slip angles (no extrapolation).
        """
        b = abs(float(abs_beta))
        lo, hi = self.abs_beta[0], self.abs_beta[-1]
        tol = math.radians(0.5)  # commanded angles are logged to within 0.5 deg
        if not lo - tol <= b <= hi + tol:
            raise ParameterError(
                f"TuningTable {self.name!r}: |beta| = {math.degrees(b):.4g} deg is outside the table's slip angles "
                f"[{math.degrees(lo):g}, {math.degrees(hi):g}] deg; the table is not extrapolated (add a row)"
            )
        b = min(max(b, lo), hi)
        cols = [[getattr(r, f) for r in self.rows] for f in ("a0", "a1", "b0", "b1")]
        if len(self.rows) == 1:
            return (float(cols[0][0]), float(cols[1][0]), float(cols[2][0]), float(cols[3][0]))
        import numpy as np

        a0, a1, b0, b1 = (float(np.interp(b, self.abs_beta, c)) for c in cols)
        return a0, a1, b0, b1

    def covers(self, abs_beta: float) -> bool:
        """True when :meth:`at` has a value at ``abs_beta`` (rad)."""
        try:
            self.at(abs_beta)
        except ParameterError:
            return False
        return True

    def tuning_at(self, abs_beta: float) -> ContactTuning:
        """The :class:`ContactTuning` at one slip angle (interpolated, no slopes), for the model."""
        a0, a1, b0, b1 = self.at(abs_beta)
        return ContactTuning(a0, a1, b0, b1, name=f"{self.name}@{math.degrees(abs(abs_beta)):.4g}deg",
                             source=f"{self.source} (interpolated in |beta|)" if self.source else "interpolated in |beta|")

    def _no_single_value(self) -> Any:
        raise ParameterError(
            f"TuningTable {self.name!r} holds one tuning per slip angle, not a single a0..b1: use "
            "table.tuning_at(abs_beta) for the ContactTuning at one slip angle (e.g. to build a WheelModel), or "
            "offline.fit.calibration.fit_linear_in_beta for lines in |beta|"
        )

    a0 = property(_no_single_value, doc="Not defined for a table (raises): see :meth:`tuning_at`.")
    a1 = property(_no_single_value, doc="Not defined for a table (raises): see :meth:`tuning_at`.")
    b0 = property(_no_single_value, doc="Not defined for a table (raises): see :meth:`tuning_at`.")
    b1 = property(_no_single_value, doc="Not defined for a table (raises): see :meth:`tuning_at`.")


@dataclass(frozen=True)
class Rover:
    """Four-wheel rocker rover of Table 7.2 (geometry used by chapter 7)."""

    rocker_length: float
    pivot_height: float
    track_width: float
    weight: float
    travel_speed: float
    name: str = "rover"
    source: str = ""

    def __post_init__(self) -> None:
        for f in ("rocker_length", "pivot_height", "track_width", "weight", "travel_speed"):
            _check_positive("Rover", f, getattr(self, f))


@dataclass(frozen=True)
class ParameterSet:
    """A complete set for one wheel on one soil: what calibration writes and the rest reads."""

    soil: Soil
    wheel: Wheel
    tuning: ContactTuning | TuningTable
    notes: str = ""


# --- presets -----------------------------------------------------------------------------

_T53 = "dissertation Table 5.3"
SOIL_DISSERTATION_T53_GROUSERED = Soil(
    k=8.0e6, n0=1.46, n1=0.01, n2=0.74, friction_angle=math.radians(29.0), unit_weight=13.03e3,
    cohesion=1.0e3, shear_modulus=0.021, repose_angle=math.radians(29.0),
    name="soil_direct_90_grousered", source=_T53 + " (grousered row); repose angle from Table 4.2",
)
SOIL_DISSERTATION_T53_SMOOTH = replace(
    SOIL_DISSERTATION_T53_GROUSERED, n2=0.55, name="soil_direct_90_smooth", source=_T53 + " (smooth row)"
)
SOIL_DISSERTATION_T42 = replace(
    SOIL_DISSERTATION_T53_GROUSERED, cohesion=0.0, name="soil_direct_90_t42",
    source="dissertation Table 4.2 (phi = 29 deg, c = 0); other fields Table 5.3",
)

WHEEL_K10_MINI_T42 = Wheel(0.048, 0.050, 0.005, 1.0, 0.1, name="k10_mini", source="dissertation Table 4.2 (mu not listed: 1.0 assumed)")
WHEEL_GROUSERED_T52 = Wheel(0.0575, 0.060, 0.005, 0.5, 0.2, name="grousered_t52", source="dissertation Table 5.2 (zeta from Table 5.4)")
WHEEL_SMOOTH_T52 = Wheel(0.0625, 0.060, 0.0, 1.0, 0.1, name="smooth_t52", source="dissertation Table 5.2 (zeta from Table 5.4)")
WHEEL_GROUSERED_PUBLISHED_CODE = Wheel(
    0.058, 0.050, 0.005, 0.1, 0.2, name="grousered_published_code",
    source="published code for the 3d-terramechanics data (data README)",
)

_T54 = "dissertation Table 5.4"
TUNING_T54_GROUSERED: dict[float, ContactTuning] = {
    b: ContactTuning(a0, a1, b0, b1, name=f"t54_grousered_{int(b)}", source=_T54)
    for b, a0, a1, b0, b1 in [
        (0.0, 0.27, 0.67, -0.66, -0.18),
        (15.0, 0.29, 0.65, -0.50, -0.41),
        (30.0, 0.47, 0.45, -0.44, -0.56),
        (45.0, 0.62, 0.30, -0.51, -0.49),
        (60.0, 0.71, 0.21, -0.53, -0.47),
    ]
}
TUNING_T54_SMOOTH: dict[float, ContactTuning] = {
    b: ContactTuning(a0, a1, b0, b1, name=f"t54_smooth_{int(b)}", source=_T54)
    for b, a0, a1, b0, b1 in [
        (0.0, 0.20, 0.70, -0.48, -0.00),
        (15.0, 0.22, 0.70, -0.47, -0.01),
        (30.0, 0.57, 0.20, -0.51, -0.01),
        (45.0, 0.63, 0.17, -0.46, -0.15),
        (60.0, 0.72, 0.13, -0.54, -0.13),
    ]
}
TUNING_T54_GROUSERED_TABLE = TuningTable.from_degrees(TUNING_T54_GROUSERED, "t54_grousered", _T54 + " (grousered wheel)")
TUNING_T54_SMOOTH_TABLE = TuningTable.from_degrees(TUNING_T54_SMOOTH, "t54_smooth", _T54 + " (smooth wheel)")
# Table 7.2: a0 = 0.24 + beta / 129.1 deg, a1 = 0.69 - beta / 133.5 deg. Chapter 7 takes the
# exit angle from the soil-flow model; b0, b1 here are the mean grousered Table 5.4 values,
# used only when the classic exit angle is selected.
TUNING_T72_LINEAR = ContactTuning(
    a0=0.24, a1=0.69, b0=-0.53, b1=-0.42,
    a0_per_rad=math.degrees(1.0) / 129.1, a1_per_rad=-math.degrees(1.0) / 133.5,
    name="t72_linear", source="dissertation Table 7.2 eqs. (7.8)-(7.9); b0, b1 = mean of Table 5.4 grousered",
)

ROVER_MINI_T72 = Rover(
    rocker_length=0.32, pivot_height=0.112, track_width=0.331, weight=34.3, travel_speed=0.03,
    name="mini_rover", source="dissertation Table 7.2",
)

# --- TOML ----------------------------------------------------------------------------------

# (field, toml key, factor from toml unit to SI)
_SOIL_KEYS = [
    ("k", "k_kN_per_m_n_plus_2", 1e3),
    ("n0", "n0", 1.0),
    ("n1", "n1", 1.0),
    ("n2", "n2", 1.0),
    ("friction_angle", "friction_angle_deg", math.pi / 180.0),
    ("unit_weight", "unit_weight_kN_per_m3", 1e3),
    ("cohesion", "cohesion_kPa", 1e3),
    ("shear_modulus", "shear_modulus_m", 1.0),
    ("repose_angle", "repose_angle_deg", math.pi / 180.0),
]
_WHEEL_KEYS = [
    ("radius", "radius_m", 1.0),
    ("width", "width_m", 1.0),
    ("grouser_height", "grouser_height_m", 1.0),
    ("grouser_area_ratio", "grouser_area_ratio", 1.0),
    ("grouser_volume_fraction", "grouser_volume_fraction", 1.0),
]
_TUNING_KEYS = [
    ("a0", "a0", 1.0),
    ("a1", "a1", 1.0),
    ("b0", "b0", 1.0),
    ("b1", "b1", 1.0),
    ("a0_per_rad", "a0_per_deg", 180.0 / math.pi),
    ("a1_per_rad", "a1_per_deg", 180.0 / math.pi),
    ("b0_per_rad", "b0_per_deg", 180.0 / math.pi),
    ("b1_per_rad", "b1_per_deg", 180.0 / math.pi),
]
_ROVER_KEYS = [
    ("rocker_length", "rocker_length_m", 1.0),
    ("pivot_height", "pivot_height_m", 1.0),
    ("track_width", "track_width_m", 1.0),
    ("weight", "weight_N", 1.0),
    ("travel_speed", "travel_speed_m_s", 1.0),
]
_SECTIONS: dict[str, tuple[type, list[tuple[str, str, float]]]] = {
    "soil": (Soil, _SOIL_KEYS),
    "wheel": (Wheel, _WHEEL_KEYS),
    "tuning": (ContactTuning, _TUNING_KEYS),
    "rover": (Rover, _ROVER_KEYS),
}


def _table_from_section(path: str, table: Mapping[str, Any]) -> TuningTable:
    """``[tuning]`` with ``beta_deg = [...]`` and a list per coefficient: a :class:`TuningTable`."""
    cols = ("a0", "a1", "b0", "b1")
    known = {"beta_deg", *cols, "name", "source"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ParameterError(f"{path}: [tuning] per-angle table: unknown key(s) {unknown} (per-degree slopes do not "
                             f"apply to a table); known keys: {sorted(known)}")
    arrays: dict[str, list[float]] = {}
    for key in ("beta_deg", *cols):
        if key not in table:
            raise ParameterError(f"{path}: [tuning] per-angle table: missing key '{key}' (a list, one value per slip angle)")
        v = table[key]
        if not isinstance(v, list) or not v:
            raise ParameterError(f"{path}: [tuning] {key} must be a non-empty list in a per-angle table, got {v!r}")
        for i, x in enumerate(v):
            if not isinstance(x, (int, float)) or isinstance(x, bool) or not math.isfinite(x):
                raise ParameterError(f"{path}: [tuning] {key}[{i}] must be a finite number, got {x!r}")
        arrays[key] = [float(x) for x in v]
    n = len(arrays["beta_deg"])
    for key in cols:
        if len(arrays[key]) != n:
            raise ParameterError(f"{path}: [tuning] {key} has {len(arrays[key])} values but beta_deg has {n}; "
                                 "give one value per slip angle")
    for i, b in enumerate(arrays["beta_deg"]):
        if not 0.0 <= b <= 90.0:
            raise ParameterError(f"{path}: [tuning] beta_deg[{i}] = {b!r} outside [0, 90] (slip-angle magnitude, degrees)")
    meta = {m: table[m] for m in ("name", "source") if m in table}
    for m, v in meta.items():
        if not isinstance(v, str):
            raise ParameterError(f"{path}: [tuning] {m} must be a string, got {v!r}")
    rows = []
    for i, b in enumerate(arrays["beta_deg"]):
        try:
            a0, a1, b0, b1 = (float(arrays[c][i]) for c in cols)
            rows.append(ContactTuning(a0, a1, b0, b1, name=f"row_{b:g}deg"))
        except ParameterError as exc:
            raise ParameterError(f"{path}: [tuning] row {i} (beta_deg = {b:g}): {exc}") from None
    try:
        return TuningTable(tuple(math.radians(b) for b in arrays["beta_deg"]), tuple(rows), **meta)
    except ParameterError as exc:
        raise ParameterError(f"{path}: [tuning] {exc}") from None


def _from_section(path: str, section: str, table: Mapping[str, Any]) -> Any:
    if section == "tuning" and ("beta_deg" in table or any(isinstance(table.get(c), list) for c in ("a0", "a1", "b0", "b1"))):
        return _table_from_section(path, table)
    cls, keys = _SECTIONS[section]
    known = {k for _, k, _ in keys} | {"name", "source"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ParameterError(f"{path}: [{section}] unknown key(s) {unknown}; known keys: {sorted(known)}")
    kwargs: dict[str, Any] = {}
    for fname, key, factor in keys:
        if key not in table:
            default = next((f.default for f in fields(cls) if f.name == fname), None)
            if isinstance(default, float):
                continue
            raise ParameterError(f"{path}: [{section}] missing key '{key}'")
        value = table[key]
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ParameterError(f"{path}: [{section}] {key} must be a number, got {value!r}")
        if fname.endswith("_per_rad"):
            kwargs[fname] = float(value) * factor
        else:
            kwargs[fname] = float(value) * factor
    for meta in ("name", "source"):
        if meta in table:
            if not isinstance(table[meta], str):
                raise ParameterError(f"{path}: [{section}] {meta} must be a string, got {table[meta]!r}")
            kwargs[meta] = table[meta]
    try:
        return cls(**kwargs)
    except ParameterError as exc:
        # name the key and value the user wrote (TOML units), not the SI field
        for fname, key, factor in keys:
            if f".{fname} " in str(exc) or f".{fname} =" in str(exc):
                raise ParameterError(
                    f"{path}: [{section}] {key} = {table.get(key)!r} is out of its physical range "
                    f"({str(exc).split(' (radians expected')[0]})"
                ) from None
        raise ParameterError(f"{path}: [{section}] {exc}") from None


def load_toml(path: str | Path) -> dict[str, Any]:
    """Load any of ``[soil]``, ``[wheel]``, ``[tuning]``, ``[rover]`` from a TOML file.

    Returns
    -------
    dict
        Section name to dataclass; a file holding soil, wheel and tuning also yields
        ``"parameter_set"`` (a :class:`ParameterSet`). ``[meta]`` is returned as a dict.

    Raises
    ------
    ParameterError
        Unknown or missing key, wrong type, or a value outside its physical range; the
        message names the file, section and key.
    """
    p = Path(path)
    data = read_toml(p, ParameterError, "parameter file")
    out: dict[str, Any] = {}
    for section, table in data.items():
        if section == "meta":
            if not isinstance(table, dict):
                raise ParameterError(f"{p}: [meta] must be a table, got {table!r}")
            out["meta"] = dict(table)
            continue
        if section not in _SECTIONS:
            raise ParameterError(f"{p}: unknown section [{section}]; expected one of {sorted(_SECTIONS)} or [meta]")
        if not isinstance(table, dict):
            raise ParameterError(f"{p}: [{section}] must be a table")
        out[section] = _from_section(str(p), section, table)
    if {"soil", "wheel", "tuning"} <= set(out):
        out["parameter_set"] = ParameterSet(out["soil"], out["wheel"], out["tuning"], notes=str(out.get("meta", {}).get("notes", "")))
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, str):
        # JSON string escapes (\\uXXXX, \\r, \\t, ...) are valid TOML basic-string escapes
        return json.dumps(v, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if v is None:
        raise ParameterError("TOML has no null: leave the key out instead of None")
    return repr(float(v))


def save_toml(path: str | Path, meta: Mapping[str, Any] | None = None, **sections: Any) -> Path:
    """Write dataclasses as TOML sections with unit-named keys (inverse of :func:`load_toml`).

    Examples
    --------
    >>> save_toml("p.toml", soil=SOIL_DISSERTATION_T53_GROUSERED)  # doctest: +SKIP
    """
    lines: list[str] = []
    if meta:
        lines.append("[meta]")
        lines += [f"{json.dumps(str(k))} = {_fmt(v)}" for k, v in meta.items()]
        lines.append("")
    for section, obj in sections.items():
        if section == "tuning" and isinstance(obj, TuningTable):
            lines += ["[tuning]", f"name = {_fmt(obj.name)}", f"source = {_fmt(obj.source)}",
                      "beta_deg = [" + ", ".join(_fmt(round(math.degrees(b), 9)) for b in obj.abs_beta) + "]"]
            for c in ("a0", "a1", "b0", "b1"):
                lines.append(f"{c} = [" + ", ".join(_fmt(getattr(r, c)) for r in obj.rows) + "]")
            lines.append("")
            continue
        if section not in _SECTIONS:
            raise ParameterError(f"cannot save unknown section '{section}'")
        cls, keys = _SECTIONS[section]
        if not isinstance(obj, cls):
            raise ParameterError(f"section [{section}] needs a {cls.__name__}, got {type(obj).__name__}")
        d = asdict(obj)  # type: ignore[call-overload]  # obj is one of the _SECTIONS dataclasses (checked above)
        lines.append(f"[{section}]")
        for meta_key in ("name", "source"):
            lines.append(f"{meta_key} = {_fmt(d[meta_key])}")
        for fname, key, factor in keys:
            lines.append(f"{key} = {_fmt(d[fname] / factor)}")
        lines.append("")
    from ..files import write_text  # atomic: a file is written whole or not at all

    return write_text(Path(path), "\n".join(lines))
