"""Recordings of a drive as MCAP: every controller input, output, diagnostic and timing.

The recorder's input is the controller's own stream (:class:`rtctl.messages.Measurements`
in, :class:`rtctl.messages.Commands` out, diagnostics, step timing), so the same recorder
runs on the rover and in simulation; a simulator may add its truth on an extra channel.

Format
------
An MCAP file (https://mcap.dev) with JSON-schema'd channels (``message_encoding = "json"``,
schema encoding ``"jsonschema"``), readable by standard MCAP tools (``mcap info``, Foxglove):

=====================  ==========================================================
topic                  content
=====================  ==========================================================
``/rtctl/measurements``  one :class:`Measurements` per tick
``/rtctl/commands``      one :class:`Commands` per tick
``/rtctl/diagnostics``   the controller's diagnostics (free-form object)
``/rtctl/timing``        ``{"t", "seq", "step_s", "deadline_s", "missed"}``
``/sim/truth``           optional simulator truth (free-form object)
=====================  ==========================================================

Provenance (self-describing recordings): a recorder given ``provenance=`` (``offnominal drive``
passes :func:`provenance` of its controller) stores a second metadata record ``"provenance"``:
the table names with their files and content hashes, the controller configuration, the library
version, the Python, numpy, scipy, osqp and filterpy versions and the platform (each value JSON).
:func:`compare_provenance` tells a replay what differs, by name: a different table or
configuration means another controller (a replay refuses); another version or platform may
change the last bits of a float (a replay warns, and a tolerance mode compares within
``--rtol/--atol``).

Log time is the message's own time stamp ``t`` in integer nanoseconds. Floats are written
with Python's shortest round-trip repr, so a read gives back the same bits; non-finite
values (a NaN measurement the controller must reject) are written as the strings
``"NaN"``, ``"Infinity"``, ``"-Infinity"`` (JSON has no such numbers). The file is written
to a temporary name beside the target and renamed into place at :meth:`Recorder.close`, so
an interrupted drive leaves no truncated recording.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from .layout import WHEELS
from .messages import Commands, FailureDeclaration, Measurements, Pose, Task

__all__ = ["RecordingError", "Recorder", "Recording", "read_recording", "export_csv", "TOPICS", "FORMAT_VERSION",
           "READABLE_VERSIONS", "to_jsonable", "provenance", "compare_provenance", "PROVENANCE_REFUSE",
           "PROVENANCE_WARN", "MINI_ROVER_WHEELS"]

FORMAT_VERSION = "2"
"""Written by this recorder. 2 added the measurements' ``task`` (the operator's driving task)."""
READABLE_VERSIONS = ("1", "2")
"""Versions this reader reads: a version-1 recording predates tasks, so its measurements are read
with ``task = None`` (what its controller saw: version 1 had no way to declare one)."""
TOPICS = {
    "measurements": "/rtctl/measurements",
    "commands": "/rtctl/commands",
    "diagnostics": "/rtctl/diagnostics",
    "timing": "/rtctl/timing",
    "truth": "/sim/truth",
}
"""Channel topics by kind."""

_NUM = {"type": ["number", "string"], "description": "SI value; non-finite as 'NaN' / 'Infinity' / '-Infinity'"}
_WHEELS4 = {"type": "array", "items": _NUM, "minItems": 4, "maxItems": 4, "description": "FR, FL, RR, RL"}
MINI_ROVER_WHEELS: tuple[str, ...] = WHEELS
"""The wheels of a recording whose metadata names none (every recording before issue 23; the mini
rover of Table 7.2, :data:`rtctl.layout.WHEELS`)."""


def _wheel_array(wheels: tuple[str, ...]) -> dict[str, Any]:
    if wheels == MINI_ROVER_WHEELS:
        return _WHEELS4  # the schema every mini-rover recording has carried
    n = len(wheels)
    return {"type": "array", "items": _NUM, "minItems": n, "maxItems": n, "description": ", ".join(wheels)}


def _schemas(wheels: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """The channel schemas of a recording of ``wheels`` (the mini rover's: :data:`_SCHEMAS` itself)."""
    if wheels == MINI_ROVER_WHEELS:
        return _SCHEMAS
    arr = _wheel_array(wheels)
    out = json.loads(json.dumps(_SCHEMAS))
    props = out["measurements"]["properties"]
    props["wheel_speed"] = props["steer_angle"] = arr
    props["motor_torque"] = {"oneOf": [arr, {"type": "null"}]}
    out["commands"]["properties"]["rim_speed"] = out["commands"]["properties"]["steer_angle"] = arr
    return out


_SCHEMAS: dict[str, dict[str, Any]] = {
    "measurements": {
        "title": "rtctl.Measurements", "type": "object",
        "properties": {
            "t": _NUM, "seq": {"type": "integer"}, "wheel_speed": _WHEELS4, "steer_angle": _WHEELS4,
            "yaw_rate": _NUM, "roll": _NUM, "pitch": _NUM,
            "motor_torque": {"oneOf": [_WHEELS4, {"type": "null"}]},
            "pose": {"oneOf": [{"type": "null"}, {"type": "object", "properties": {
                "t": _NUM, "x": _NUM, "y": _NUM, "heading": _NUM}}]},
            "failures": {"type": "array", "items": {"type": "object", "properties": {
                "wheel": {"type": "string"}, "kind": {"type": "string"}, "value": _NUM}}},
            "task": {"oneOf": [{"type": "null"}, {"type": "object", "properties": {
                "kind": {"type": "string"}, "wheel": {"type": "string"}, "value": _NUM}}]},
        },
        "required": ["t", "seq", "wheel_speed", "steer_angle", "yaw_rate"],
    },
    "commands": {
        "title": "rtctl.Commands", "type": "object",
        "properties": {"t": _NUM, "seq": {"type": "integer"}, "rim_speed": _WHEELS4, "steer_angle": _WHEELS4},
        "required": ["t", "seq", "rim_speed", "steer_angle"],
    },
    "diagnostics": {"title": "rtctl.Diagnostics", "type": "object", "additionalProperties": True},
    "timing": {
        "title": "rtctl.StepTiming", "type": "object",
        "properties": {"t": _NUM, "seq": {"type": "integer"}, "step_s": _NUM, "deadline_s": _NUM,
                       "missed": {"type": "boolean"}},
    },
    "truth": {"title": "offnominal.SimTruth", "type": "object", "additionalProperties": True},
}


class RecordingError(ValueError):
    """A recording cannot be written or read (the message names the file and what is wrong)."""


def _num_out(x: float) -> float | str:
    x = float(x)
    if math.isfinite(x):
        return x
    return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


def _num_in(x: Any) -> float:
    if isinstance(x, str):
        if x in ("NaN", "Infinity", "-Infinity"):
            return float(x.replace("Infinity", "inf"))
        raise RecordingError(f"expected a number or 'NaN'/'Infinity'/'-Infinity', got {x!r}")
    return float(x)


def to_jsonable(obj: Any) -> Any:
    """Dataclasses, numpy arrays and scalars, tuples and mappings as JSON values (non-finite
    floats as strings, see the module notes)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, np.ndarray):
        return [to_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _num_out(float(obj))
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


def _measurements_out(m: Measurements) -> dict[str, Any]:
    return to_jsonable(m)


def _commands_out(c: Commands) -> dict[str, Any]:
    return to_jsonable(c)


def _per_wheel(v: Any, what: str, wheels: tuple[str, ...]) -> tuple[float, ...]:
    if not isinstance(v, list) or len(v) != len(wheels):
        raise RecordingError(f"{what}: expected {len(wheels)} values ({', '.join(wheels)}), got {v!r}")
    return tuple(_num_in(x) for x in v)


def measurements_from_json(d: Mapping[str, Any], wheels: tuple[str, ...] = MINI_ROVER_WHEELS) -> Measurements:
    """Rebuild a :class:`Measurements` from its recorded JSON object (``wheels``: the recording's
    wheel set, :attr:`Recording.wheels`)."""
    pose = d.get("pose")
    mt = d.get("motor_torque")
    task = d.get("task")
    return Measurements(
        t=_num_in(d["t"]), seq=int(d["seq"]), wheel_speed=_per_wheel(d["wheel_speed"], "wheel_speed", wheels),
        steer_angle=_per_wheel(d["steer_angle"], "steer_angle", wheels), yaw_rate=_num_in(d["yaw_rate"]),
        roll=_num_in(d.get("roll", 0.0)), pitch=_num_in(d.get("pitch", 0.0)),
        motor_torque=None if mt is None else _per_wheel(mt, "motor_torque", wheels),
        pose=None if pose is None else Pose(_num_in(pose["t"]), _num_in(pose["x"]), _num_in(pose["y"]),
                                            _num_in(pose["heading"])),
        failures=tuple(FailureDeclaration(f["wheel"], f["kind"], _num_in(f.get("value", "NaN")))
                       for f in d.get("failures", [])),
        task=None if task is None else Task(task["kind"], task["wheel"], _num_in(task.get("value", "NaN"))),
    )


def commands_from_json(d: Mapping[str, Any], wheels: tuple[str, ...] = MINI_ROVER_WHEELS) -> Commands:
    """Rebuild a :class:`Commands` from its recorded JSON object (``wheels`` as
    :func:`measurements_from_json`)."""
    return Commands(t=_num_in(d["t"]), seq=int(d["seq"]), rim_speed=_per_wheel(d["rim_speed"], "rim_speed", wheels),
                    steer_angle=_per_wheel(d["steer_angle"], "steer_angle", wheels))


def _ns(t: float) -> int:
    if not math.isfinite(t):
        return 0
    return max(0, int(round(t * 1e9)))


class Recorder:
    """Write a drive to an MCAP file (atomically: temporary name, renamed at :meth:`close`).

    Parameters
    ----------
    path : str or Path
        Target ``.mcap`` file. Its folder is created; an existing file is replaced only at close.
    metadata : mapping, optional
        Free-form facts about the run (scenario, seed, truth), stored as an MCAP metadata record
        ``"run"`` (values as strings).
    truth : bool
        Register the ``/sim/truth`` channel.
    provenance : mapping, optional
        What made the commands (:func:`provenance`), stored as the metadata record
        ``"provenance"`` (each value as JSON).
    wheels : sequence of str, optional
        The wheel set of every per-wheel vector (the controller's
        :attr:`~rtctl.controller.Controller.wheels`): stored in the ``"run"`` record as
        ``wheels`` (a JSON list) and sizing the channel schemas. None: the mini rover's four
        wheels, written as every recording before the entry existed (no ``wheels`` entry, the
        same schemas), which is how a reader takes a recording without one.

    Examples
    --------
    >>> with Recorder("drive.mcap", {"seed": 1}) as rec:   # doctest: +SKIP
    ...     rec.measurements(m); rec.commands(c)
    """

    def __init__(self, path: str | Path, metadata: Mapping[str, Any] | None = None, truth: bool = False,
                 provenance: Mapping[str, Any] | None = None, wheels: Iterable[str] | None = None) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = Path(path)
        if self.path.is_dir():
            raise RecordingError(f"{self.path}: is a folder; give a file name ending in .mcap")
        self.wheels = MINI_ROVER_WHEELS if wheels is None else tuple(str(w) for w in wheels)
        if not self.wheels or len(set(self.wheels)) != len(self.wheels):
            raise RecordingError(f"wheels: expected distinct wheel names, got {list(self.wheels)}")
        schemas = _schemas(self.wheels)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent)
        self._tmp = Path(tmp)
        self._fh = os.fdopen(fd, "wb")
        self._writer = Writer(self._fh, compression=CompressionType.NONE)
        self._writer.start(profile="", library="offnominal-rover rtctl.recording")
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        kinds = [k for k in TOPICS if k != "truth" or truth]
        for kind in kinds:
            sid = self._writer.register_schema(schemas[kind]["title"], "jsonschema",
                                               json.dumps(schemas[kind]).encode())
            self._channels[kind] = self._writer.register_channel(TOPICS[kind], "json", sid)
            self._seq[kind] = 0
        meta = {"format_version": FORMAT_VERSION}
        for k, v in (metadata or {}).items():
            meta[str(k)] = v if isinstance(v, str) else json.dumps(to_jsonable(v))
        if wheels is not None:
            meta["wheels"] = json.dumps(list(self.wheels))
        self._writer.add_metadata("run", meta)
        if provenance is not None:
            self._writer.add_metadata("provenance", {str(k): json.dumps(to_jsonable(v), sort_keys=True)
                                                     for k, v in provenance.items()})
        self._closed = False

    def _write(self, kind: str, t: float, obj: Mapping[str, Any]) -> None:
        if self._closed:
            raise RecordingError(f"{self.path}: recorder already closed")
        if kind not in self._channels:
            raise RecordingError(f"{self.path}: no {kind!r} channel (open the recorder with truth=True)")
        data = json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()
        ns = _ns(t)
        self._writer.add_message(self._channels[kind], log_time=ns, data=data, publish_time=ns,
                                 sequence=self._seq[kind])
        self._seq[kind] += 1

    def measurements(self, m: Measurements) -> None:
        """Record one tick's measurements."""
        self._write("measurements", m.t, _measurements_out(m))

    def commands(self, c: Commands) -> None:
        """Record one tick's commands."""
        self._write("commands", c.t, _commands_out(c))

    def diagnostics(self, t: float, diag: Any) -> None:
        """Record the controller's diagnostics (a dataclass or mapping) at time ``t``."""
        d = to_jsonable(diag)
        if not isinstance(d, dict):
            d = {"value": d}
        d.setdefault("t", _num_out(t))
        self._write("diagnostics", t, d)

    def timing(self, t: float, seq: int, step_s: float, deadline_s: float = 0.2, missed: bool | None = None) -> None:
        """Record a step's computation time and whether it missed its deadline."""
        self._write("timing", t, {"t": _num_out(t), "seq": int(seq), "step_s": _num_out(step_s),
                                  "deadline_s": _num_out(deadline_s),
                                  "missed": bool(step_s > deadline_s) if missed is None else bool(missed)})

    def truth(self, t: float, state: Any) -> None:
        """Record the simulator's truth (a dataclass or mapping) at time ``t``."""
        d = to_jsonable(state)
        self._write("truth", t, d if isinstance(d, dict) else {"value": d})

    def close(self) -> Path:
        """Finish the file and rename it onto the target path."""
        if self._closed:
            return self.path
        self._writer.finish()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        os.replace(self._tmp, self.path)
        self._closed = True
        return self.path

    def abort(self) -> None:
        """Drop the recording (the target path is left untouched)."""
        if not self._closed:
            self._fh.close()
            self._closed = True
        if self._tmp.exists():
            self._tmp.unlink()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


@dataclass
class Recording:
    """A recording read back: typed measurements and commands, the rest as JSON objects."""

    measurements: list[Measurements] = field(default_factory=list)
    commands: list[Commands] = field(default_factory=list)
    diagnostics: list[dict[str, Any]] = field(default_factory=list)
    timing: list[dict[str, Any]] = field(default_factory=list)
    truth: list[dict[str, Any]] = field(default_factory=list)
    metadata: dict[str, str] = field(default_factory=dict)
    path: str = ""
    provenance: dict[str, Any] = field(default_factory=dict)
    """The ``"provenance"`` record, values decoded from JSON (empty: the recording has none)."""

    @property
    def wheels(self) -> tuple[str, ...]:
        """The wheel set of the per-wheel vectors: the ``"run"`` record's ``wheels`` entry, else
        (a recording before it) the mini rover's :data:`MINI_ROVER_WHEELS`."""
        return _wheels_of(self.metadata, self.path)


def _wheels_of(meta: Mapping[str, str], path: str) -> tuple[str, ...]:
    raw = meta.get("wheels")
    if raw is None:
        return MINI_ROVER_WHEELS
    try:
        names = json.loads(raw)
    except ValueError:
        names = None
    if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)):
        raise RecordingError(f"{path}: metadata 'wheels' is {raw!r}, expected a JSON list of wheel names")
    return tuple(names)


def read_recording(path: str | Path) -> Recording:
    """Read an MCAP recording written by :class:`Recorder`.

    Raises
    ------
    RecordingError
        Missing or unreadable file, not MCAP, a message that does not decode.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such recording")
    rec = Recording(path=str(p))
    by_topic = {v: k for k, v in TOPICS.items()}
    try:
        with open(p, "rb") as fh:
            reader = make_reader(fh)
            for md in reader.iter_metadata():
                if md.name == "run":
                    rec.metadata = dict(md.metadata)
                elif md.name == "provenance":
                    try:
                        rec.provenance = {k: json.loads(v) for k, v in md.metadata.items()}
                    except ValueError as exc:
                        raise RecordingError(f"{p}: provenance record does not decode ({exc})") from None
            wheels = _wheels_of(rec.metadata, str(p))
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                kind = by_topic.get(channel.topic)
                if kind is None:
                    continue
                try:
                    obj = json.loads(message.data)
                    if kind == "measurements":
                        rec.measurements.append(measurements_from_json(obj, wheels))
                    elif kind == "commands":
                        rec.commands.append(commands_from_json(obj, wheels))
                    else:
                        getattr(rec, kind).append(obj)
                except (ValueError, KeyError, TypeError) as exc:
                    raise RecordingError(f"{p}: message {message.sequence} on {channel.topic} does not decode ({exc})") from None
    except McapError as exc:
        raise RecordingError(f"{p}: not a readable MCAP file ({exc})") from None
    if rec.metadata.get("format_version", FORMAT_VERSION) not in READABLE_VERSIONS:
        raise RecordingError(f"{p}: recording format {rec.metadata.get('format_version')!r}, this reader reads "
                             f"{', '.join(READABLE_VERSIONS)}; re-record it with this version's recorder")
    return rec


def _flatten(prefix: str, v: Any, out: dict[str, Any]) -> None:
    """Flatten nested JSON into ``a.b`` columns; per-wheel lists of 4 into ``a.FR`` ... ``a.RL``."""
    if isinstance(v, dict):
        for k, x in v.items():
            _flatten(f"{prefix}.{k}" if prefix else str(k), x, out)
    elif isinstance(v, list) and all(not isinstance(x, (dict, list)) for x in v):
        labels = ("FR", "FL", "RR", "RL") if len(v) == 4 else tuple(str(i) for i in range(len(v)))
        for n, x in zip(labels, v):
            out[f"{prefix}.{n}"] = x
    elif isinstance(v, list):
        out[prefix] = json.dumps(v)
    else:
        out[prefix] = v


def _rows(objs: Iterable[Any]) -> list[dict[str, Any]]:
    rows = []
    for o in objs:
        flat: dict[str, Any] = {}
        _flatten("", to_jsonable(o), flat)
        rows.append(flat)
    return rows


def export_csv(path: str | Path, out_dir: str | Path) -> list[Path]:
    """Write one CSV per channel of a recording into ``out_dir`` (atomically, one file each);
    per-wheel arrays become ``<field>.FR`` ... columns. Returns the files written."""
    rec = read_recording(path)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for kind in ("measurements", "commands", "diagnostics", "timing", "truth"):
        rows = _rows(getattr(rec, kind))
        if not rows:
            continue
        cols: list[str] = []
        for r in rows:
            cols.extend(c for c in r if c not in cols)
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        target = out / f"{kind}.csv"
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=out)
        with os.fdopen(fd, "w") as fh:
            fh.write(buf.getvalue())
        os.replace(tmp, target)
        written.append(target)
    return written


PROVENANCE_REFUSE = ("tables", "controller_config")
"""Provenance entries whose difference means another controller: a replay refuses."""
PROVENANCE_WARN = ("library_version", "python", "numpy", "scipy", "osqp", "filterpy", "platform", "machine")
"""Provenance entries whose difference may change the last bits of a float: a replay warns."""
_IGNORED_CONFIG = ("tables_index",)  # a path on the recording machine; the table hashes say what was loaded


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "not installed"


def provenance(controller: Any = None) -> dict[str, Any]:
    """What made a recording's commands: the library, its dependencies' versions and the platform,
    and, for a controller with ``tables`` and ``config`` (:class:`rtctl.controller.Controller`),
    each table's file name and content hash and the configuration (a nested mapping).

    Parameters
    ----------
    controller : object, optional
        The controller that drives (anything else: versions and platform only).
    """
    import dataclasses as dc
    import platform
    import sys

    out: dict[str, Any] = {
        "library_version": _version("offnominal-rover"), "python": platform.python_version(),
        "numpy": np.__version__, "scipy": _version("scipy"), "osqp": _version("osqp"), "filterpy": _version("filterpy"),
        "platform": platform.platform(), "machine": platform.machine(), "byteorder": sys.byteorder}
    tables = getattr(controller, "tables", None)
    if isinstance(tables, Mapping):
        out["tables"] = {str(k): {"file": str(getattr(t, "source", "")),
                                  "content_hash": str(getattr(t, "header", {}).get("content_hash", ""))}
                         for k, t in sorted(tables.items())}
    cfg = getattr(controller, "config", None)
    if cfg is not None and dc.is_dataclass(cfg) and not isinstance(cfg, type):
        out["controller_config"] = to_jsonable(dc.asdict(cfg))
    return out


def _diff(prefix: str, a: Any, b: Any, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in _IGNORED_CONFIG and prefix == "controller_config":
                continue
            _diff(f"{prefix}.{k}", a.get(k, "<absent>"), b.get(k, "<absent>"), out)
    elif a != b:
        out.append(f"{prefix}: recorded {a!r}, now {b!r}")


def compare_provenance(recorded: Mapping[str, Any], current: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """What differs between a recording's provenance and the replaying side's, by name.

    Returns
    -------
    refuse : list of str
        Differences in :data:`PROVENANCE_REFUSE` (a table, a configuration key: another
        controller), e.g. ``controller_config.qp.eps: recorded 1e-05, now 1e-06``; a recording
        without provenance, or without an entry the current side has, is no refusal (it says
        nothing), but is warned about.
    warn : list of str
        Differences in :data:`PROVENANCE_WARN` (versions, platform), and missing entries.
    """
    refuse: list[str] = []
    warn: list[str] = []
    current = json.loads(json.dumps(to_jsonable(current)))  # the same JSON round trip as the recording's
    if not recorded:
        return refuse, ["the recording has no provenance record (made before it existed): cannot tell whether "
                        "the same tables, configuration and versions replay it"]
    for key in PROVENANCE_REFUSE:
        if key not in recorded or key not in current:
            if key in current:
                warn.append(f"{key}: not in the recording")
            continue
        _diff(key, recorded[key], current[key], refuse)
    for key in PROVENANCE_WARN:
        if recorded.get(key) != current.get(key):
            warn.append(f"{key}: recorded {recorded.get(key, '<absent>')!r}, now {current.get(key, '<absent>')!r}")
    return refuse, warn
