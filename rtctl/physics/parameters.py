"""What the shared physics reads of a parameter set: protocols, the error, and plain records.

The ground side's frozen dataclasses (``offline.physics.params``: ``Soil``, ``Wheel``,
``ContactTuning``, ``Rover``) satisfy these protocols; on the rover the same values come from a
table header's ``params`` and ``rover`` records (:func:`record`), so the physics never depends
on the ground side's classes (arrows point down only: offline imports rtctl, never the reverse).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Protocol

__all__ = ["ParameterError", "SoilLike", "WheelLike", "TuningLike", "RoverLike", "Record", "record"]


class ParameterError(ValueError):
    """A parameter is missing, non-finite, out of its physical range or in the wrong unit."""


class SoilLike(Protocol):
    """Soil parameters (SI): Bekker/Reece pressure terms, shear and flow properties."""

    @property
    def k(self) -> float: ...

    @property
    def n0(self) -> float: ...

    @property
    def n1(self) -> float: ...

    @property
    def n2(self) -> float: ...

    @property
    def friction_angle(self) -> float: ...

    @property
    def unit_weight(self) -> float: ...

    @property
    def cohesion(self) -> float: ...

    @property
    def shear_modulus(self) -> float: ...

    @property
    def repose_angle(self) -> float: ...



class WheelLike(Protocol):
    """Rigid grousered wheel geometry (SI)."""

    @property
    def radius(self) -> float: ...

    @property
    def width(self) -> float: ...

    @property
    def grouser_height(self) -> float: ...

    @property
    def grouser_area_ratio(self) -> float: ...

    @property
    def grouser_volume_fraction(self) -> float: ...


    @property
    def shearing_radius(self) -> float:
        """r_s = r + h_g (section 5.2)."""
        ...


class TuningLike(Protocol):
    """Contact-angle tuning lines a0..b1 and their slip-angle slopes, eqs. (7.8)-(7.9)."""

    @property
    def a0(self) -> float: ...

    @property
    def a1(self) -> float: ...

    @property
    def b0(self) -> float: ...

    @property
    def b1(self) -> float: ...

    @property
    def a0_per_rad(self) -> float: ...

    @property
    def a1_per_rad(self) -> float: ...

    @property
    def b0_per_rad(self) -> float: ...

    @property
    def b1_per_rad(self) -> float: ...



class RoverLike(Protocol):
    """Rocker rover geometry of Table 7.2 (SI)."""

    @property
    def rocker_length(self) -> float: ...

    @property
    def pivot_height(self) -> float: ...

    @property
    def track_width(self) -> float: ...

    @property
    def weight(self) -> float: ...



@dataclass(frozen=True)
class Record:
    """Read-only attribute view of a JSON record (a table header's ``soil``, ``wheel``, ...)."""

    values: Mapping[str, Any]

    def __getattr__(self, name: str) -> Any:
        try:
            return self.values[name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def shearing_radius(self) -> float:
        """r_s = r + h_g (section 5.2), for a wheel record."""
        return float(self.values["radius"]) + float(self.values.get("grouser_height", 0.0))


def record(values: Mapping[str, Any], required: tuple[str, ...], owner: str) -> Record:
    """A :class:`Record` of ``values`` whose ``required`` entries are finite numbers.

    Raises
    ------
    ParameterError
        Naming the record (``owner``) and the missing or non-finite key.
    """
    if not isinstance(values, Mapping):
        raise ParameterError(f"{owner}: expected a record (mapping), got {type(values).__name__}")
    for k in required:
        v = values.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
            raise ParameterError(f"{owner}.{k}: expected a finite number, got {v!r}")
    return Record(dict(values))


def read_toml(path: str | Path, error: type[Exception], what: str, hint: str = "") -> dict[str, Any]:
    """The TOML document of a file, or ``error`` naming the file: missing (``"<path>: no such
    <what>"`` plus ``hint``) or not TOML (``"<path>: not valid TOML (<reason>)"``). One reader for
    every file the library takes (parameter, scenario, rover and controller files)."""
    p = Path(path)
    try:
        return tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise error(f"{p}: no such {what}{hint}") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{p}: not valid TOML ({exc})") from None
