"""MCAP recordings: round trip bit for bit, standard MCAP reader, CSV export, atomic writes, errors."""

from __future__ import annotations

import csv
import json
import math

import pytest

from rtctl.messages import Commands, FailureDeclaration, Measurements, Pose
from rtctl.recording import (TOPICS, Recorder, RecordingError, export_csv, read_recording)


def _stream(n=6):
    ms, cs = [], []
    for k in range(n):
        t = 0.2 * k + 1e-13 * k  # not representable in few digits: tests the float round trip
        pose = Pose(t - 0.1, 0.03 * t, -1e-3 * k, 0.01 / 3) if k % 2 == 0 else None
        ms.append(Measurements(t=t, seq=k, wheel_speed=(0.5 + k / 7, 0.5, math.nan if k == 3 else 0.49, 0.51),
                               steer_angle=(0.1, -0.2, -0.8726646259971648, 0.0), yaw_rate=1e-3 / 3,
                               roll=0.01, pitch=-0.02, motor_torque=(0.1, 0.2, math.inf, -0.1) if k == 4 else None,
                               pose=pose, failures=(FailureDeclaration("RR", "steer_stuck", -0.8726646259971648),
                                                    FailureDeclaration("FL", "locked"))))
        cs.append(Commands(t, k, (0.03 + k / 1e5, 0.031, 0.0312, 0.03), (0.1, 0.2 / 3, -0.87, 0.0)))
    return ms, cs


def _same(a, b):
    """Equality that treats NaN as equal to NaN (bit-level round trip of a float)."""
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, (tuple, list)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if hasattr(a, "__dataclass_fields__"):
        return type(a) is type(b) and all(_same(getattr(a, f), getattr(b, f)) for f in a.__dataclass_fields__)
    return a == b


def test_round_trip_bit_for_bit_and_standard_reader(tmp_path):
    from mcap.reader import make_reader

    ms, cs = _stream()
    path = tmp_path / "drive.mcap"
    with Recorder(path, {"scenario": "rr_steer_stuck_50", "seed": 3}, truth=True) as rec:
        for m, c in zip(ms, cs):
            rec.measurements(m)
            rec.commands(c)
            rec.diagnostics(m.t, {"fallback": False, "slip": [0.1, 0.2, math.nan, 0.3]})
            rec.timing(m.t, m.seq, 1e-4)
            rec.truth(m.t, {"x": m.t * 0.03, "heading": 0.0})
        assert not path.exists()  # written under a temporary name until close
    rec2 = read_recording(path)
    assert _same(rec2.measurements, ms) and _same(rec2.commands, cs)
    assert rec2.metadata["scenario"] == "rr_steer_stuck_50" and json.loads(rec2.metadata["seed"]) == 3
    assert rec2.diagnostics[0]["slip"][2] == "NaN" and rec2.timing[0]["missed"] is False
    assert len(rec2.truth) == len(ms)
    # standard MCAP reading: schemas are JSON schema, messages JSON
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        topics = {ch.topic: ch for ch in summary.channels.values()}
        assert set(topics) == set(TOPICS.values())
        for ch in topics.values():
            assert ch.message_encoding == "json"
            assert summary.schemas[ch.schema_id].encoding == "jsonschema"
            json.loads(summary.schemas[ch.schema_id].data)
        n = sum(1 for _ in reader.iter_messages(topics=[TOPICS["commands"]]))
    assert n == len(cs)


def test_csv_export(tmp_path):
    ms, cs = _stream()
    path = tmp_path / "d.mcap"
    with Recorder(path) as rec:
        for m, c in zip(ms, cs):
            rec.measurements(m)
            rec.commands(c)
    files = export_csv(path, tmp_path / "csv")
    assert sorted(f.name for f in files) == ["commands.csv", "measurements.csv"]
    with open(tmp_path / "csv" / "commands.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == len(cs)
    assert float(rows[2]["rim_speed.RR"]) == cs[2].rim_speed[2]
    with open(tmp_path / "csv" / "measurements.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert rows[3]["wheel_speed.RR"] == "NaN" and rows[0]["pose.x"] != "" and rows[1]["pose"] == ""


def test_aborted_recording_leaves_nothing(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with Recorder(path) as rec:
            rec.commands(Commands(0.0, 0, (0.0,) * 4, (0.0,) * 4))
            raise RuntimeError("drive interrupted")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.mcap"]


def test_errors(tmp_path):
    with pytest.raises(RecordingError, match="no such recording"):
        read_recording(tmp_path / "missing.mcap")
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="bad.mcap: not a readable MCAP file"):
        read_recording(bad)
    rec = Recorder(tmp_path / "y.mcap")
    with pytest.raises(RecordingError, match="no 'truth' channel"):
        rec.truth(0.0, {"x": 1.0})
    rec.close()
    with pytest.raises(RecordingError, match="already closed"):
        rec.commands(Commands(0.0, 0, (0.0,) * 4, (0.0,) * 4))
