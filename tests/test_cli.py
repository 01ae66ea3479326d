"""Tests of the ``offnominal`` command line, run in-process through offline.cli.main."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from offline.fit.calibration import JOINT_PARAMETERS
from cli_run import run
from offline.cli import main
from offline.physics.params import SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, load_toml
from offline.fit.validation import TABLE_5_5_GROUSERED, ErrorRow, beats_table_5_5

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
DATA_DIR = Path(__file__).resolve().parents[1] / "offline" / "data"
SHIPPED_PARAMS = DATA_DIR / "calibrated_grousered.toml"
SHIPPED_TRIALS = DATA_DIR / "grouser_trials.csv"
VARIANTS = [f"{group}: {kind}" for group in ("dissertation", "calibrated")
            for kind in ("classic exit angle", "soil-flow exit angle", "Ishigami 2007 sidewall")]
TABLE_ANGLES = (0.0, 15.0, 30.0, 45.0, 60.0)


@pytest.fixture(scope="module")
def validated(tmp_path_factory):
    """One default 'validate' run (shipped data, shipped parameters) shared by the tests."""
    out = tmp_path_factory.mktemp("validate")
    rc, stdout, stderr = run(["validate", "--out", str(out)])
    return rc, stdout, stderr, out


def read_rows(path: Path) -> list[ErrorRow]:
    with path.open() as fh:
        reader = csv.DictReader(fh)
        assert reader.fieldnames == list(ErrorRow.__dataclass_fields__)
        rows = []
        for d in reader:
            vals = {k: (d[k] if k == "variant" else int(d[k]) if k in ("n", "n_failed") else float(d[k])) for k in d}
            rows.append(ErrorRow(**vals))
    return rows


# ------------------------------------------------------------------------------ validate
def test_validate_succeeds_and_prints_a_table_5_5_layout(validated):
    rc, stdout, stderr, out = validated
    assert rc == 0, stderr
    for v in VARIANTS:
        assert f"== {v} ==" in stdout
    assert "(T5.5: Table 5.5 grousered, without soil flow model)" in stdout
    assert "(T5.5: Table 5.5 grousered, with soil flow model)" in stdout
    assert "Fx err (%)" in stdout and "h0 err (%)" in stdout
    # every variant of a model Table 5.5 has rows for prints the five published rows beside its own;
    # the Ishigami 2007 sidewall is not one of them (no rows: no pass/fail marks)
    assert stdout.count("  T5.5 ") == 5 * (len(VARIANTS) - 2)
    assert stdout.count("(no matching reference rows)") == 2
    assert "   7.1 ± 21.2" in stdout  # the dissertation's beta = 0 F_x row
    assert "scored on 63 condition means" in stdout
    for name in ("table_5_5.csv", "fig_5_6_dissertation.png", "fig_5_6_calibrated.png"):
        assert f"wrote {out / name}" in stdout


def test_validate_csv_has_every_variant_and_angle(validated):
    *_, out = validated
    rows = read_rows(out / "table_5_5.csv")
    got = {(r.variant, r.beta_deg) for r in rows}
    for v in VARIANTS:
        for beta in (*TABLE_ANGLES, 75.0):
            assert (v, beta) in got, (v, beta)
    assert all(r.n == 9 for r in rows)  # nine slip ratios per angle, scored on condition means
    assert len(got) == len(rows)  # no duplicates


def test_validate_csv_numbers_are_the_library_numbers(validated):
    """Cross-check: the CLI's CSV equals scoring through the API (and Table 5.5's F_y at 0 deg)."""
    from offline.fit.dataset import load_trials, load_tuned_params
    from offline.physics.params import ContactTuning
    from offline.fit.validation import Variant, average_conditions, error_rows, predict

    *_, out = validated
    csv_rows = {(r.variant, r.beta_deg): r for r in read_rows(out / "table_5_5.csv")}
    avg = average_conditions(load_trials())
    tuned = {b: ContactTuning(*v) for b, v in load_tuned_params().items()}
    v = Variant("dissertation: classic exit angle", SOIL_DISSERTATION_T53_GROUSERED, WHEEL_GROUSERED_PUBLISHED_CODE, tuned)
    for r in error_rows(avg, predict(avg, v), v.wheel.radius):
        assert csv_rows[(v.name, r.beta_deg)] == r
    r0 = csv_rows[("dissertation: classic exit angle", 0.0)]
    assert (round(r0.fy_mean, 1), round(r0.fy_sd, 1)) == TABLE_5_5_GROUSERED["without soil flow"][0.0][2:4]
    for beta in TABLE_ANGLES:  # the shipped calibration beats the published table
        assert all(beats_table_5_5(csv_rows[("calibrated: classic exit angle", beta)]).values()), beta


def test_validate_writes_both_figures(validated):
    *_, out = validated
    for name in ("fig_5_6_dissertation.png", "fig_5_6_calibrated.png"):
        data = (out / name).read_bytes()
        assert data[:8] == PNG_MAGIC, name
        assert len(data) > 10_000, name


def test_validate_skip_dissertation_and_per_trial(tmp_path):
    rc, stdout, stderr = run(["validate", "--out", str(tmp_path), "--skip-dissertation", "--per-trial"])
    assert rc == 0, stderr
    assert "dissertation:" not in stdout and "scored on" not in stdout
    rows = read_rows(tmp_path / "table_5_5.csv")
    assert {r.variant for r in rows} == set(VARIANTS[3:])
    assert all(r.n == 27 for r in rows)  # per trial: 9 slip ratios x 3 repeats
    assert not (tmp_path / "fig_5_6_dissertation.png").exists()
    assert (tmp_path / "fig_5_6_calibrated.png").read_bytes()[:8] == PNG_MAGIC


# ----------------------------------------------------------------------- input errors
def test_validate_malformed_params_exits_2_naming_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(SHIPPED_PARAMS.read_text().replace("[soil]\n", "[soil]\nn3 = 1.0\n"))
    out = tmp_path / "never"
    rc = main(["validate", "--params", str(bad), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("offnominal: error: ")
    assert f"{bad}: [soil] unknown key(s) ['n3']" in err
    assert not out.exists()  # refused before anything was written


def test_validate_params_without_all_sections_exits_2(tmp_path, capsys):
    soil_only = tmp_path / "soil_only.toml"
    soil_only.write_text(SHIPPED_PARAMS.read_text().split("[wheel]")[0])
    rc = main(["validate", "--params", str(soil_only), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "needs [soil], [wheel] and [tuning] sections" in capsys.readouterr().err


def test_validate_data_missing_a_column_exits_2(tmp_path, capsys):
    with SHIPPED_TRIALS.open() as fh:
        table = list(csv.reader(fh))
    j = table[0].index("Fz_N")
    bad = tmp_path / "no_load.csv"
    with bad.open("w", newline="") as fh:
        csv.writer(fh).writerows([r[:j] + r[j + 1:] for r in table])
    rc = main(["validate", "--data", str(bad), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2
    assert f"offnominal: error: {bad}: missing required column(s) ['Fz_N']" in err


def test_validate_missing_data_file_exits_2(tmp_path, capsys):
    rc = main(["validate", "--data", str(tmp_path / "nowhere.csv"), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "nowhere.csv" in capsys.readouterr().err


# ----------------------------------------------------------------------------- calibrate
def test_calibrate_writes_a_parameter_file_the_library_reads(tmp_path):
    path = tmp_path / "x.toml"
    rc, stdout, stderr = run(["calibrate", "--wheel", "published-code", "--max-evals", "15", "--quiet", "--out", str(path)])
    assert rc == 0, stderr
    assert f"wrote {path}" in stdout
    loaded = load_toml(path)
    ps = loaded["parameter_set"]
    meta = loaded["meta"]
    assert meta["wheel_choice"] == "published-code"
    assert meta["written_by"] == "offnominal calibrate"
    assert meta["free_parameters"].split(",") == list(JOINT_PARAMETERS)
    assert ps.notes == meta["notes"]
    for f in ("radius", "width", "grouser_height", "grouser_area_ratio", "grouser_volume_fraction", "name"):
        assert getattr(ps.wheel, f) == getattr(WHEEL_GROUSERED_PUBLISHED_CODE, f)
    # k is not free unless --free-k: it stays the Table 5.3 value
    assert ps.soil.k == pytest.approx(SOIL_DISSERTATION_T53_GROUSERED.k, rel=1e-12)
    assert ps.soil.source.startswith("offline.fit.calibration.fit_joint")
    assert meta["rms_normalised_residual"] > 0
    beats = json.loads(meta["beats_table_5_5"])
    assert sorted(beats, key=float) == ["0", "15", "30", "45", "60"]
    assert set(json.loads(meta["noise_normalisation"])) == {"Fx", "Fy", "Fz", "sinkage", "dof"}


def test_calibrate_without_trials_in_range_exits_2(tmp_path, capsys):
    rc = main(["calibrate", "--max-beta-deg", "-5", "--quiet", "--out", str(tmp_path / "x.toml")])
    assert rc == 2
    assert "no trials with |beta| <= -5.0 deg" in capsys.readouterr().err
    assert not (tmp_path / "x.toml").exists()


def test_calibrate_soil_flow_variant_fits_zeta_instead_of_b(tmp_path):
    path = tmp_path / "sf.toml"
    rc, stdout, stderr = run(["calibrate", "--wheel", "published-code", "--exit-angle", "soil_flow", "--max-evals", "5",
                              "--quiet", "--out", str(path)])
    assert rc == 0, stderr
    meta = load_toml(path)["meta"]
    assert meta["exit_angle"] == "soil_flow"
    free = meta["free_parameters"].split(",")
    assert "zeta" in free and not any(n.startswith("b") for n in free)
    assert "with soil flow model" in stdout  # scored against the soil-flow rows of Table 5.5


def test_validate_missing_soil_flow_params_exits_2(tmp_path, capsys):
    rc = main(["validate", "--params-soil-flow", str(tmp_path / "nowhere.toml"), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "nowhere.toml: no such parameter file" in capsys.readouterr().err


def test_validate_soil_flow_params_without_all_sections_exits_2_with_a_clear_message(tmp_path, capsys):
    soil_only = tmp_path / "soil_only.toml"
    soil_only.write_text(SHIPPED_PARAMS.read_text().split("[wheel]")[0])
    rc = main(["validate", "--params-soil-flow", str(soil_only), "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "needs [soil], [wheel] and [tuning] sections" in capsys.readouterr().err


# ------------------------------------------------------------------------- misc commands
def test_no_arguments_prints_help(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: offnominal")
    for cmd in ("validate", "calibrate", "bekker", "soil-flow"):
        assert cmd in out


def test_unknown_command_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["validat"])
    assert exc.value.code == 2
    assert "invalid choice: 'validat'" in capsys.readouterr().err


def test_soil_flow_phase_map_writes_only_the_phase_map(tmp_path):
    rc, stdout, stderr = run(["soil-flow", "phase-map", "--out", str(tmp_path)])
    assert rc == 0, stderr
    png = tmp_path / "fig_4_7_phase_map.png"
    assert f"wrote {png}" in stdout
    assert png.read_bytes()[:8] == PNG_MAGIC
    assert png.stat().st_size > 10_000
    assert not (tmp_path / "fig_4_6_sweep.png").exists()


def test_calibrate_soil_flow_cv_tables_are_marked_against_the_soil_flow_rows(tmp_path):
    """Issue 9: held-out tables used to be marked against the rows *without* soil flow."""
    rc, stdout, stderr = run(["calibrate", "--wheel", "published-code", "--exit-angle", "soil_flow", "--max-evals", "2",
                              "--max-beta-deg", "15", "--cv", "--quiet", "--out", str(tmp_path / "sf.toml")])
    assert rc == 0, stderr
    held = [line for line in stdout.splitlines() if line.startswith("== held-out")]
    assert len(held) == 4  # one angle table, three repeat tables
    assert all(line.endswith("(T5.5: Table 5.5 grousered, with soil flow model)") for line in held), held
    assert "without soil flow" not in stdout


def test_shipped_parameter_files_record_the_data_by_name_and_hash():
    import hashlib

    digest = hashlib.sha256(SHIPPED_TRIALS.read_bytes()).hexdigest()
    for name in ("calibrated_grousered.toml", "calibrated_grousered_soil_flow.toml"):
        text = (DATA_DIR / name).read_text()
        meta = load_toml(DATA_DIR / name)["meta"]
        assert meta["data"] == "grouser_trials.csv" and meta["data_sha256"] == digest
        assert "/work" not in text and "/home" not in text


def test_calibrate_records_no_machine_path(tmp_path):
    path = tmp_path / "x.toml"
    rc, _, stderr = run(["calibrate", "--wheel", "published-code", "--max-evals", "2", "--max-beta-deg", "0", "--quiet",
                         "--out", str(path)])
    assert rc == 0, stderr
    assert str(tmp_path) not in path.read_text() and str(DATA_DIR) not in path.read_text()
    assert load_toml(path)["meta"]["data"] == "grouser_trials.csv"
