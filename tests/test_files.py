"""Files are never lost: atomic writes, inputs never overwritten, output paths checked before
the work starts, and a true message on interrupt (offline.files, offline.cli)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

import offline.cli.fit as cli_fit
from cli_run import run
from offline.cli import main
from offline.files import OutputError, atomic_path, check_output_dir, check_output_path, write_text
from offline.fit import calibration as C

DATA = Path(__file__).resolve().parents[1] / "offline" / "data"


@pytest.fixture
def no_fit(monkeypatch):
    """Fail the test if a command reaches the fit (the refusal must come first)."""
    def boom(*a, **k):
        raise AssertionError("the fit ran before the output path was checked")

    monkeypatch.setattr(C, "fit_joint", boom)


def test_atomic_write_interrupted_leaves_the_old_file_and_no_temporary(tmp_path):
    p = write_text(tmp_path / "out.txt", "old complete content")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(p) as tmp:
            tmp.write_text("half of the new")
            raise KeyboardInterrupt
    assert p.read_text() == "old complete content"
    assert os.listdir(tmp_path) == ["out.txt"]


def test_calibrate_refuses_to_overwrite_its_data(tmp_path, no_fit):
    data = tmp_path / "X.csv"
    shutil.copy(DATA / "grouser_trials.csv", data)
    before = data.read_bytes()
    rc, stdout, stderr = run(["calibrate", "--data", str(data), "--out", str(data), "--quiet"])
    assert rc == 2 and "is an input of the run; refusing to overwrite it" in stderr and "Traceback" not in stderr
    assert data.read_bytes() == before


def test_calibrate_refuses_to_overwrite_its_wheel_file(tmp_path, no_fit):
    wheel = tmp_path / "w.toml"
    wheel.write_text("[wheel]\nradius_m = 0.0625\nwidth_m = 0.06\ngrouser_height_m = 0.0\ngrouser_area_ratio = 1.0\n"
                     "grouser_volume_fraction = 0.1\n")
    rc, _, stderr = run(["calibrate", "--wheel-file", str(wheel), "--out", str(wheel), "--quiet"])
    assert rc == 2 and "refusing to overwrite it" in stderr


def test_validate_refuses_an_out_folder_whose_outputs_are_its_inputs(tmp_path):
    d = tmp_path / "D"
    d.mkdir()
    data = d / "table_5_5.csv"  # an input named like an output
    shutil.copy(DATA / "grouser_trials.csv", data)
    before = data.read_bytes()
    rc, stdout, stderr = run(["validate", "--data", str(data), "--out", str(d)])
    assert rc == 2 and f"{data}: would overwrite the input" in stderr
    assert data.read_bytes() == before and stdout == ""


def test_validate_into_a_folder_holding_other_inputs_keeps_them(tmp_path):
    d = tmp_path / "D"
    d.mkdir()
    data = d / "trials.csv"
    shutil.copy(DATA / "grouser_trials.csv", data)
    rc, _, stderr = run(["validate", "--data", str(data), "--out", str(d), "--skip-dissertation"])
    assert rc == 0, stderr
    assert data.read_bytes() == (DATA / "grouser_trials.csv").read_bytes()
    assert sorted(os.listdir(d)) == ["fig_5_6_calibrated.png", "table_5_5.csv", "trials.csv"]  # no temporaries


@pytest.mark.parametrize("where", ["under_a_file", "is_a_folder"])
def test_bad_calibrate_out_is_a_clean_error_before_the_fit(tmp_path, no_fit, where):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    out = blocker / "cal.toml" if where == "under_a_file" else tmp_path
    rc, stdout, stderr = run(["calibrate", "--out", str(out), "--quiet"])
    assert rc == 2 and stderr.startswith("offnominal: error: ") and "choose another --out" in stderr
    assert "Traceback" not in stderr and "joint fit" not in stdout


def test_bad_validate_out_is_a_clean_error_and_leaves_nothing(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    rc, _, stderr = run(["validate", "--out", str(blocker)])
    assert rc == 2 and "exists and is not a folder" in stderr
    assert blocker.read_text() == "x"


def test_output_checks_create_nothing(tmp_path):
    check_output_dir(tmp_path / "a" / "b")
    check_output_path(tmp_path / "c" / "p.toml")
    assert os.listdir(tmp_path) == []
    with pytest.raises(OutputError, match="is an input of the run"):
        check_output_path(tmp_path / "x.csv", [tmp_path / "." / "x.csv"])


@pytest.mark.parametrize("command, atomic", [("validate", True), ("calibrate", True), ("chapter7", False)])
def test_interrupt_message_is_true_for_each_command(monkeypatch, command, atomic, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    import offline.cli.rover as cli_rover

    for mod in (cli_fit, cli_rover):
        for name in dir(mod):
            if name.startswith("cmd_"):
                monkeypatch.setattr(mod, name, interrupted)
    argv = [command]
    try:
        rc = main(argv)
    except SystemExit:  # a command needing arguments: pick another without atomic outputs
        pytest.skip(f"'{command}' needs arguments")
    err = capsys.readouterr().err
    assert rc == 130
    if atomic:
        assert "every output file is either complete or absent" in err
    else:
        assert "may be incomplete" in err and "complete or absent" not in err
