"""The wheel set a table is for, read from its header, and whether this rtctl drives it.

A table built by ``offnominal tables build`` carries ``wheel_set`` in its header
(:func:`offline.rover.table_builder.wheel_set_header`): the wheel names in layout order, their
count, which are steerable and driven, the suspension kind, the drive direction, the rover's
name and, for a scenario that names a rover file (:mod:`rtctl.physics.rover_file`), that file's
name and sha256 (never a machine path). A table written before the entry existed has none: its
wheels are its layout's, and it was built from a rover file when its scenario record names one.

This version of rtctl drives the four-wheel rocker of Table 7.2 (wheels
:data:`rtctl.layout.WHEELS`, balance rows :data:`rtctl.layout.BALANCE_ROWS`, from a scenario without
a rover file) and the tables of a rover file whose suspension is a ``rocker`` or a
``rocker_bogie`` (the MER-class six-wheel rover) or ``rigid`` (the four-wheel skid-steer): the
exact residual of each tick
(:meth:`rtctl.physics.steady_state.SteadyStateModel.from_table_header`) is rebuilt from the
header's rover record with :class:`rtctl.physics.suspension.SuspensionStatics`, the source the
NLP's rows come from. A controller takes its wheel set from its tables (all of them agree, else a
start-up error). Any other table (:func:`unsupported_reason` says which and why) is refused at
start-up with that text (counted among the unavailable tables and flagged), never driven.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

from .layout import BALANCE_ROWS, WHEELS, NlpLayout

__all__ = ["WheelSet", "wheel_set_of", "unsupported_reason", "SUPPORTED_SUSPENSIONS"]


@dataclass(frozen=True)
class WheelSet:
    """The wheels of one table.

    Attributes
    ----------
    wheels : tuple of str
        Names in layout order.
    steerable, driven : tuple of bool or None
        Per wheel (None: not recorded, a table written before the header entry).
    suspension : str
        ``rocker`` (the four-wheel rocker of Table 7.2), ``rocker_bogie`` or ``rigid``; ``""``
        when not recorded.
    rover : str
        The rover's name.
    rover_file : str or None
        The rover file's name (None: a scenario without a rover file).
    rover_file_sha256 : str or None
        The rover file's sha256, when recorded.
    drive_direction : str
        ``forward`` or ``backward`` (the rover turned half round).
    """

    wheels: tuple[str, ...]
    steerable: tuple[bool, ...] | None
    driven: tuple[bool, ...] | None
    suspension: str
    rover: str
    rover_file: str | None
    rover_file_sha256: str | None
    drive_direction: str = "forward"

    @property
    def count(self) -> int:
        """Number of wheels."""
        return len(self.wheels)

    def text(self) -> str:
        """One line naming the wheels and the rover, e.g. ``6 wheels RF, LF, ... of rover mer_class
        (rover file mer_class_rocker_bogie.toml, suspension rocker_bogie, driving backward)``."""
        where = [f"rover file {self.rover_file}" if self.rover_file else "no rover file"]
        if self.suspension:
            where.append(f"suspension {self.suspension}")
        if self.drive_direction != "forward":
            where.append(f"driving {self.drive_direction}")
        return f"{self.count} wheels {', '.join(self.wheels)} of rover {self.rover or '?'} ({', '.join(where)})"


def _flags(value: Any, n: int) -> tuple[bool, ...] | None:
    if isinstance(value, list) and len(value) == n and all(isinstance(v, bool) for v in value):
        return tuple(value)
    return None


def wheel_set_of(header: Mapping[str, Any], layout: NlpLayout) -> WheelSet:
    """The wheel set of a table from its header's ``wheel_set`` (or, in a table written before
    it, from its layout and scenario record).

    Parameters
    ----------
    header : mapping
        The table header (:attr:`rtctl.table.Table.header`).
    layout : NlpLayout
        The table's layout (its wheel names are authoritative for the arrays).

    Returns
    -------
    WheelSet
    """
    ws = header.get("wheel_set")
    rover_rec = header.get("rover")
    rover_name = str(rover_rec.get("name", "")) if isinstance(rover_rec, Mapping) else ""
    wheels = tuple(layout.wheels)
    if isinstance(ws, Mapping):
        rf = ws.get("rover_file")
        return WheelSet(wheels, _flags(ws.get("steerable"), len(wheels)), _flags(ws.get("driven"), len(wheels)),
                        str(ws.get("suspension", "")), str(ws.get("rover", rover_name)),
                        str(rf.get("name")) if isinstance(rf, Mapping) else None,
                        str(rf.get("sha256")) if isinstance(rf, Mapping) and rf.get("sha256") else None,
                        str(ws.get("drive_direction", "forward")))
    sc = header.get("scenario")
    spec = sc.get("rover_file") if isinstance(sc, Mapping) else None
    if isinstance(spec, Mapping):  # built from a rover file before the header carried the wheel set
        path = str(spec.get("path", "")) or str(spec.get("name", "?"))
        name = path.replace("\\", "/").rsplit("/", 1)[-1]
        return WheelSet(wheels, None, None, str(spec.get("suspension", "")), str(spec.get("name", rover_name)),
                        name, None)
    return WheelSet(wheels, None, None, "rocker", rover_name, None, None)


SUPPORTED_SUSPENSIONS: tuple[str, ...] = ("rocker", "rocker_bogie", "rigid")
"""Suspension kinds of a rover file whose tables this rtctl drives (:func:`unsupported_reason`)."""


def unsupported_reason(header: Mapping[str, Any], layout: NlpLayout) -> str | None:
    """Why this rtctl cannot drive a table's wheel set, with what to do; None when it can.

    Supported:

    * the four-wheel rocker of Table 7.2 (wheels :data:`rtctl.layout.WHEELS`, balance rows
      :data:`rtctl.layout.BALANCE_ROWS`) built from a scenario without a rover file;
    * a rover file's table of a suspension in :data:`SUPPORTED_SUSPENSIONS` (``rocker``,
      ``rocker_bogie``: the MER-class six-wheel rover, ``rigid``: the four-wheel skid-steer)
      whose header carries the rover record (``scenario.rover_file``) the exact residual is
      rebuilt from, with the layout's wheels and balance rows those of that record's suspension
      (:class:`rtctl.physics.suspension.SuspensionStatics`), driving forward or backward.

    Refused (each with what to do):

    * a rover file's table without the rover record (written before the header carried it):
      the exact residual cannot be rebuilt;
    * a suspension kind outside :data:`SUPPORTED_SUSPENSIONS`, or a record whose wheels or
      balance rows are not the layout's;
    * a table without a rover file whose wheels or balance rows are not the mini rover's.

    (A rigid rover's table is driven but not mirrored: :func:`rtctl.mirror.mirror_wheel_map`.)

    Parameters
    ----------
    header : mapping
        The table header.
    layout : NlpLayout
        The table's layout.

    Returns
    -------
    str or None
    """
    ws = wheel_set_of(header, layout)
    balance = tuple(b.name[len("balance "):] for b in layout.constraints if b.name.startswith("balance "))
    sc = header.get("scenario")
    rec = sc.get("rover_file") if isinstance(sc, Mapping) else None
    if ws.rover_file is None and not isinstance(rec, Mapping):
        if ws.wheels == WHEELS and balance == BALANCE_ROWS:
            return None
        return (f"this table is for the {ws.text()}, without a rover file: rtctl drives such a table only with the "
                f"mini rover's wheels {', '.join(WHEELS)} and balance rows; rebuild it from a rover file")
    if not isinstance(rec, Mapping):
        return (f"this table is for the {ws.text()}, but its header has no rover record (scenario.rover_file) to "
                "rebuild the exact residual from: rebuild it with this library version (offnominal tables build)")
    from .physics.rover_file import RoverFileError, rover_spec_from_record
    from .physics.suspension import SuspensionStatics

    try:
        spec = rover_spec_from_record(rec, "table header scenario.rover_file")
    except RoverFileError as exc:
        return f"this table is for the {ws.text()}: {exc}"
    if spec.suspension not in SUPPORTED_SUSPENSIONS:
        return (f"this table is for the {ws.text()}: rtctl drives rover files with suspension "
                f"{', '.join(SUPPORTED_SUSPENSIONS)}, not {spec.suspension!r} (its statics are not built on the rover); "
                "take it out of the controller's index (it serves the offline tools: offnominal tables verify/info)")
    if spec.wheel_names != ws.wheels:
        return (f"this table's rover record has wheels {', '.join(spec.wheel_names)}, its layout "
                f"{', '.join(ws.wheels)}: rebuild the table")
    expect = SuspensionStatics(spec).balance_names
    if balance != expect:
        return (f"this table's balance rows {list(balance)} are not those of its rover record's {spec.suspension} "
                f"suspension {list(expect)}: rebuild the table")
    return None
