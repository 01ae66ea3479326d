"""``offnominal drive``: outputs, recordings, and errors instead of tracebacks."""

from __future__ import annotations

import json
from pathlib import Path

from offline.cli import main
from rtctl.recording import read_recording
from rtctl.table import load_index

DATA = Path(__file__).parent / "data"


def test_drive_writes_metrics_plot_and_recordings(tmp_path, capsys):
    out = tmp_path / "drive"
    rc = main(["drive", "rr_steer_stuck_50", "--controllers", "none,rtctl", "--tables", str(DATA / "tables"),
               "--distance", "0.06", "--out", str(out), "--quiet"])
    assert rc == 0
    rows = json.loads((out / "metrics.json").read_text())
    assert [r["controller"] for r in rows] == ["none", "rtctl"]
    assert all(r["metrics"]["distance_m"] >= 0.06 for r in rows)
    assert (out / "rr_steer_stuck_50.png").stat().st_size > 1000
    rec = read_recording(out / "rr_steer_stuck_50_rtctl.mcap")
    assert rec.metadata["controller"] == "rtctl" and len(rec.commands) == len(rec.measurements) == len(rec.truth)
    text = capsys.readouterr().out
    assert "| rr_steer_stuck_50 | believed | rtctl |" in text and "13 cm right and 3 deg" in text


def test_drive_errors(tmp_path, capsys):
    assert main(["drive", "rr_steer_stuck_50", "--controllers", "pid9", "--out", str(tmp_path / "a"), "--quiet",
                 "--no-record", "--distance", "0.01"]) == 2
    assert "unknown controller 'pid9'" in capsys.readouterr().err
    assert main(["drive", "rr_steer_stuck_50", "--controllers", "rtctl", "--tables", str(tmp_path / "none"),
                 "--out", str(tmp_path / "b"), "--quiet"]) == 2
    assert "no table index" in capsys.readouterr().err
    assert main(["drive", "no_such_scenario", "--controllers", "ff", "--out", str(tmp_path / "c"), "--quiet"]) == 2
    assert "no scenario 'no_such_scenario'" in capsys.readouterr().err
    assert main(["drive", "--truth", "no_such_truth", "--controllers", "ff", "--out", str(tmp_path / "d"), "--quiet"]) == 2
    assert "no such truth file" in capsys.readouterr().err


def test_replay_cli(tmp_path, capsys):
    """The committed recording carries its provenance (tables, configuration, versions): the
    replay checks it, then compares within a tolerance (1e-6 m/s or rad: OSQP's eps of 1e-6 on
    variables of scale <= 1), for a bench on another architecture."""
    rec = str(DATA / "rec_rr_steer_stuck_50_rtctl.mcap")
    assert main(["replay", rec, "--tables", str(DATA / "tables"), "--csv", str(tmp_path / "csv"),
                 "--rtol", "0", "--atol", "1e-6"]) == 0
    out = capsys.readouterr().out
    assert "provenance" not in out  # same tables and configuration: nothing to refuse or warn about
    assert "commands equal within rtol 0, atol 1e-06" in out and (tmp_path / "csv" / "commands.csv").exists()
    # the same recording through a controller that lacks the stuck-steering table: reported, exit 1
    only_nominal = tmp_path / "nominal.npz"
    only_nominal.write_bytes((DATA / "tables" / "nominal.npz").read_bytes())
    assert main(["replay", rec, "--tables", str(only_nominal)]) == 2  # refused by the provenance, by name
    out = capsys.readouterr()
    assert "the replaying controller is not the recorded one" in out.err + out.out and "tables.rr_steer_stuck_50: recorded" in out.err + out.out
    assert main(["replay", rec, "--tables", str(only_nominal), "--allow-mismatch"]) == 1
    # the first tick already differs: it is prepared on the table of the declared failure
    assert "differ; first: tick 0 (t = 0.000 s, seq 0)" in capsys.readouterr().out
    assert main(["replay", str(tmp_path / "missing.mcap")]) == 2
    assert "no such recording" in capsys.readouterr().err


def test_drive_records_provenance_and_replay_checks_it(tmp_path, capsys):
    """``offnominal drive`` stores the tables, configuration, versions and platform; a replay on
    this machine is bit for bit; other tables or another configuration are refused by name;
    --allow-mismatch replays anyway; --rtol/--atol compare within a tolerance."""
    out = tmp_path / "drive"
    assert main(["drive", "rr_steer_stuck_50", "--controllers", "rtctl", "--tables", str(DATA / "tables"),
                 "--distance", "0.02", "--out", str(out), "--quiet"]) == 0
    path = out / "rr_steer_stuck_50_rtctl.mcap"
    prov = read_recording(path).provenance
    index = load_index(DATA / "tables" / "index.json")
    files = {k: {"file": v.path.name, "content_hash": v.content_hash} for k, v in index.items()}
    assert {k: prov["tables"][k] for k in files} == files
    mirrors = {k: v for k, v in prov["tables"].items() if k not in files}  # the mirrors rtctl adds (rtctl.mirror)
    assert mirrors and all(v["file"].startswith("mirror of ") and v["content_hash"] for v in mirrors.values())
    assert prov["controller_config"]["qp"]["eps"] == 1e-6 and prov["numpy"] and prov["osqp"] and prov["platform"]
    assert prov["library_version"] and prov["python"].count(".") == 2
    capsys.readouterr()
    assert main(["replay", str(path), "--tables", str(DATA / "tables")]) == 0
    text = capsys.readouterr().out
    assert "identical bit for bit" in text and "warning" not in text
    only_nominal = tmp_path / "nominal.npz"
    only_nominal.write_bytes((DATA / "tables" / "nominal.npz").read_bytes())
    assert main(["replay", str(path), "--tables", str(only_nominal)]) == 2
    err = capsys.readouterr().err
    assert "not the recorded one" in err and "tables.rr_steer_stuck" in err
    cfg = tmp_path / "eps.toml"
    cfg.write_text("[qp]\neps = 1e-5\n")
    assert main(["replay", str(path), "--tables", str(DATA / "tables"), "--config", str(cfg)]) == 2
    assert "controller_config.qp.eps: recorded 1e-06, now 1e-05" in capsys.readouterr().err
    rc = main(["replay", str(path), "--tables", str(DATA / "tables"), "--config", str(cfg), "--allow-mismatch",
               "--atol", "1e-3"])
    text = capsys.readouterr().out
    assert "--allow-mismatch" in text and rc in (0, 1) and "steps replayed" in text
    assert main(["replay", str(path), "--tables", str(DATA / "tables"), "--atol", "-1"]) == 2
    assert "--atol must be finite and >= 0" in capsys.readouterr().err


def test_drive_hil(tmp_path, capsys):
    """rtctl in its own process at the real 5 Hz clock drives the simulator (a few ticks)."""
    out = tmp_path / "hil"
    assert main(["drive", "--controllers", "rtctl", "--hil", "--tables", str(DATA / "tables"), "--distance", "0.02",
                 "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "HIL rr_steer_stuck_50: rtctl in its own process" in text and "deadline misses" in text
    rows = json.loads((out / "metrics.json").read_text())
    assert rows[0]["metrics"]["distance_m"] >= 0.02 and "deadline_misses" in rows[0]["metrics"]
    rec = read_recording(out / "rr_steer_stuck_50_rtctl.mcap")
    assert rec.metadata["hil"] == "true" and len(rec.measurements) == len(rec.truth) >= 2
