"""Tests of offline.fit.dataset: validation paths, SI conversion, frame sanity, repeat noise."""

from __future__ import annotations

import csv
import gzip
import math
import os
from pathlib import Path

import numpy as np
import pytest

from offline.fit.dataset import (
    AUTHORS_RIM_RADIUS,
    DatasetError,
    TrialSet,
    load_sinkage_timeseries,
    load_trials,
    load_tuned_params,
    omega_from_rim_speed,
)

SHARED = Path(os.environ.get("SINGLE_WHEEL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "single_wheel"))

# A minimal, valid table in the shipped format: 2 conditions x 2 repeats.
HEADER = [
    "trial_id", "beta_cmd_deg", "rim_speed_cmd_mm_s", "vx_cmd_mm_s", "repeat", "slip", "vx_mm_s",
    "rim_speed_mm_s", "beta_deg", "Fx_N", "Fy_N", "Fz_N", "sinkage_mm", "Fx_std_N", "authors_excluded",
]
ROWS = [
    ["a/10_0_0_1", "0", "0", "10", "1", "-1", "9.99", "0", "0", "-40", "1", "20", "50", "5", "0"],
    ["a/10_0_0_2", "0", "0", "10", "2", "-1", "10.01", "0", "0", "-38", "2", "21", "48", "4", "0"],
    ["a/10_20_30_1", "30", "20", "10", "1", "0.5", "10.0", "20", "30.1", "3", "10", "22", "30", "1", "0"],
    ["a/10_20_30_2", "30", "20", "10", "2", "0.5", "10.0", "20", "29.9", "5", "12", "24", "34", "1", "1"],
]


def write(tmp_path: Path, header: list[str], rows: list[list[str]], name: str = "trials.csv") -> Path:
    p = tmp_path / name
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return p


def edit(col: str, row: int, value: str) -> list[list[str]]:
    rows = [list(r) for r in ROWS]
    rows[row][HEADER.index(col)] = value
    return rows


def drop(col: str) -> tuple[list[str], list[list[str]]]:
    j = HEADER.index(col)
    return [c for c in HEADER if c != col], [[v for k, v in enumerate(r) if k != j] for r in ROWS]


# --- valid small files ------------------------------------------------------------------------


def test_small_file_si_conversion(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, ROWS))
    assert len(t) == 4
    assert t.beta[2] == pytest.approx(math.radians(30.1))
    assert t.beta_cmd[3] == pytest.approx(math.pi / 6)
    assert t.rim_speed[2] == pytest.approx(0.020)
    assert t.rim_speed_cmd[2] == pytest.approx(0.020)
    assert t.vx[0] == pytest.approx(0.00999)
    assert t.vx_cmd[0] == pytest.approx(0.010)
    assert t.sinkage[0] == pytest.approx(0.050)
    assert t.Fx[0] == -40.0 and t.Fz[3] == 24.0
    assert t.Fx_std[0] == 5.0
    assert np.all(np.isnan(t.sinkage_std)) and np.all(np.isnan(t.Fz_slope))  # absent optional columns
    assert t.authors_excluded.tolist() == [False, False, False, True]
    assert t.inferred == ()
    assert t.omega(0.05)[2] == pytest.approx(0.4)


def test_small_file_conditions_and_noise(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, ROWS))
    conds = t.conditions()
    assert [c.n for c in conds] == [2, 2]
    c0, c1 = conds
    assert c0.beta_cmd == 0.0 and c1.beta_cmd == pytest.approx(math.pi / 6)
    assert c0.Fx == -39.0 and c0.Fx_sd == pytest.approx(math.sqrt(2.0))
    assert c1.sinkage == pytest.approx(0.032) and c1.sinkage_sd == pytest.approx(math.sqrt(8.0) * 1e-3)
    assert c0.indices.tolist() == [0, 1] and c1.indices.tolist() == [2, 3]
    nz = t.noise()
    # pooled: ((1+1) + (1+1)) / 2 dof for Fx -> sqrt(2); sinkage ((1+1)+(4+4))/2 -> sqrt(5) mm
    assert nz["Fx"] == pytest.approx(math.sqrt(2.0))
    assert nz["sinkage"] == pytest.approx(math.sqrt(5.0) * 1e-3)
    assert nz["dof"] == 2.0


def test_trialset_is_immutable(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, ROWS))
    with pytest.raises(ValueError):
        t.Fx[0] = 1.0
    with pytest.raises(AttributeError):
        t.Fx = np.zeros(4)  # type: ignore[misc]


def test_subset_mask_and_indices(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, ROWS))
    s = t.subset(~t.authors_excluded)
    assert isinstance(s, TrialSet) and len(s) == 3 and s.trial_id[-1] == "a/10_20_30_1"
    s2 = t.subset([3, 0])
    assert s2.Fx.tolist() == [5.0, -40.0]
    with pytest.raises(DatasetError, match="mask has shape"):
        t.subset(np.array([True, False]))


def test_optional_columns_absent_are_inferred(tmp_path: Path) -> None:
    keep = ["beta_deg", "rim_speed_mm_s", "vx_mm_s", "Fx_N", "Fy_N", "Fz_N", "sinkage_mm", "slip"]
    idx = [HEADER.index(c) for c in keep]
    t = load_trials(write(tmp_path, keep, [[r[j] for j in idx] for r in ROWS]))
    assert set(t.inferred) >= {"trial_id", "beta_cmd_deg", "rim_speed_cmd_mm_s", "vx_cmd_mm_s"}
    assert t.trial_id.tolist() == ["row1", "row2", "row3", "row4"]
    assert [c.n for c in t.conditions()] == [2, 2]  # 30.1 and 29.9 deg cluster together
    assert t.authors_excluded.tolist() == [False] * 4


def test_beta_cmd_may_replace_beta(tmp_path: Path) -> None:
    h, r = drop("beta_deg")
    t = load_trials(write(tmp_path, h, r))
    assert t.beta[2] == pytest.approx(math.pi / 6) and "beta_deg" in t.inferred


def test_empty_optional_cell_is_nan(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, edit("Fx_std_N", 1, "")))
    assert math.isnan(t.Fx_std[1]) and t.Fx_std[0] == 5.0


# --- every validation error path --------------------------------------------------------------


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"nope\.csv: no such trials file"):
        load_trials(tmp_path / "nope.csv")


def test_empty_file(tmp_path: Path) -> None:
    p = tmp_path / "empty.csv"
    p.write_text("")
    with pytest.raises(DatasetError, match=r"empty\.csv: empty file"):
        load_trials(p)


def test_header_only(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="header only, no data rows"):
        load_trials(write(tmp_path, HEADER, []))


@pytest.mark.parametrize("col", ["rim_speed_mm_s", "vx_mm_s", "Fx_N", "Fy_N", "Fz_N", "sinkage_mm", "slip"])
def test_missing_required_column(tmp_path: Path, col: str) -> None:
    h, r = drop(col)
    with pytest.raises(DatasetError, match=rf"trials\.csv: missing required column\(s\) \['{col}'\]"):
        load_trials(write(tmp_path, h, r))


def test_missing_both_beta_columns(tmp_path: Path) -> None:
    h, r = drop("beta_deg")
    j = h.index("beta_cmd_deg")
    h2 = [c for c in h if c != "beta_cmd_deg"]
    r2 = [[v for k, v in enumerate(row) if k != j] for row in r]
    with pytest.raises(DatasetError, match=r"missing required column\(s\) \['beta_deg'\]"):
        load_trials(write(tmp_path, h2, r2))


def test_ragged_row(tmp_path: Path) -> None:
    rows = [list(r) for r in ROWS]
    rows[2] = rows[2][:-1]
    with pytest.raises(DatasetError, match=r"data row 3 has 14 fields, expected 15"):
        load_trials(write(tmp_path, HEADER, rows))


def test_duplicated_column(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"duplicated column name\(s\) \['Fx_N'\]"):
        load_trials(write(tmp_path, HEADER + ["Fx_N"], [r + ["1"] for r in ROWS]))


def test_non_numeric(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"trials\.csv: data row 2 \(trial_id 'a/10_0_0_2'\), column 'Fy_N': non-numeric value '1,5x'"):
        load_trials(write(tmp_path, HEADER, edit("Fy_N", 1, "1,5x")))


def test_non_numeric_optional(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"data row 1 .*column 'Fx_std_N': non-numeric value 'abc'"):
        load_trials(write(tmp_path, HEADER, edit("Fx_std_N", 0, "abc")))


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf"])
def test_nonfinite_required(tmp_path: Path, bad: str) -> None:
    with pytest.raises(DatasetError, match=rf"data row 4 \(trial_id 'a/10_20_30_2'\), column 'Fx_N': got '{bad}'.*finite"):
        load_trials(write(tmp_path, HEADER, edit("Fx_N", 3, bad)))


def test_empty_required_cell(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"data row 3 .*column 'sinkage_mm': empty cell in a required column"):
        load_trials(write(tmp_path, HEADER, edit("sinkage_mm", 2, "")))


def test_inf_in_optional_column(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"column 'Fx_std_N': got 'inf'; infinite values are not allowed"):
        load_trials(write(tmp_path, HEADER, edit("Fx_std_N", 0, "inf")))


@pytest.mark.parametrize("bad", ["1", "1.0", "-1.01", "50"])
def test_slip_out_of_range(tmp_path: Path, bad: str) -> None:
    with pytest.raises(DatasetError, match=r"data row 3 .*column 'slip': .* is outside \[-1, 1\)"):
        load_trials(write(tmp_path, HEADER, edit("slip", 2, bad)))


def test_beta_beyond_90(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"data row 3 .*column 'beta_deg': 120\.0 deg is outside"):
        load_trials(write(tmp_path, HEADER, edit("beta_deg", 2, "120")))


def test_beta_tolerance_90_5_accepted(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, edit("beta_deg", 2, "90.4")))
    assert t.beta[2] == pytest.approx(math.radians(90.4))


def test_beta_looks_like_radians(tmp_path: Path) -> None:
    rows = edit("beta_deg", 2, "0.5236")
    rows[3][HEADER.index("beta_deg")] = "0.5236"
    with pytest.raises(DatasetError, match=r"column 'beta_deg' looks like radians"):
        load_trials(write(tmp_path, HEADER, rows))
    # the escape hatch, for data that genuinely has tiny angles
    t = load_trials(tmp_path / "trials.csv", check_units=False)
    assert t.beta[2] == pytest.approx(math.radians(0.5236))


def test_beta_cmd_looks_like_radians(tmp_path: Path) -> None:
    h, r = drop("beta_deg")
    j = h.index("beta_cmd_deg")
    r[2][j] = r[3][j] = "0.5236"
    with pytest.raises(DatasetError, match=r"column 'beta_cmd_deg' looks like radians"):
        load_trials(write(tmp_path, h, r))


@pytest.mark.parametrize("bad,shown", [("0", "0.0"), ("-20.5", "-20.5")])
def test_nonpositive_load(tmp_path: Path, bad: str, shown: str) -> None:
    with pytest.raises(DatasetError, match=rf"data row 2 .*column 'Fz_N': {shown} N; .* must be > 0"):
        load_trials(write(tmp_path, HEADER, edit("Fz_N", 1, bad)))


def test_sinkage_looks_like_metres(tmp_path: Path) -> None:
    rows = [list(r) for r in ROWS]
    for r, v in zip(rows, ["0.050", "0.048", "0.030", "0.034"]):
        r[HEADER.index("sinkage_mm")] = v
    with pytest.raises(DatasetError, match=r"column 'sinkage_mm' looks like metres"):
        load_trials(write(tmp_path, HEADER, rows))


def test_duplicated_trial_id(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"data row 3, column 'trial_id': duplicated trial_id 'a/10_0_0_1' \(first at data row 1\)"):
        load_trials(write(tmp_path, HEADER, edit("trial_id", 2, "a/10_0_0_1")))


def test_negative_std(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"column 'Fx_std_N': -1\.0 is negative"):
        load_trials(write(tmp_path, HEADER, edit("Fx_std_N", 0, "-1")))


def test_authors_excluded_not_binary(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"column 'authors_excluded': 2\.0; expected 0 or 1"):
        load_trials(write(tmp_path, HEADER, edit("authors_excluded", 0, "2")))


def test_noise_needs_repeats(tmp_path: Path) -> None:
    t = load_trials(write(tmp_path, HEADER, ROWS)).subset([0, 2])
    with pytest.raises(DatasetError, match="no condition has >= 2 repeats"):
        t.noise()


def test_omega_radius_in_metres() -> None:
    assert omega_from_rim_speed(0.058) == pytest.approx(1.0)
    with pytest.raises(DatasetError, match="metres"):
        omega_from_rim_speed(0.01, 58.0)


# --- the shipped file ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def shipped() -> TrialSet:
    return load_trials()


def test_shipped_counts(shipped: TrialSet) -> None:
    assert len(shipped) == 189
    conds = shipped.conditions()
    assert len(conds) == 63
    assert all(c.n == 3 for c in conds)
    assert sorted({round(math.degrees(c.beta_cmd)) for c in conds}) == [0, 15, 30, 45, 60, 75, 90]
    assert sorted({round(c.rim_speed_cmd * 1e3) for c in conds}) == [0, 3, 5, 8, 10, 12, 20, 40, 100]
    assert shipped.inferred == ()
    assert int(shipped.authors_excluded.sum()) == 54  # beta 75 and 90: 2 x 9 x 3


def _cond(t: TrialSet, beta_deg: float, rim_mm_s: float):
    (c,) = [c for c in t.conditions() if math.isclose(c.beta_cmd, math.radians(beta_deg), abs_tol=1e-9)
            and math.isclose(c.rim_speed_cmd, rim_mm_s * 1e-3, abs_tol=1e-12)]
    return c


def test_shipped_frame_sanity(shipped: TrialSet) -> None:
    # README table "Resulting signs (means of 3 trials)"
    c = _cond(shipped, 0, 0)
    assert c.slip == pytest.approx(-1.0)
    assert c.Fx == pytest.approx(-38.9, abs=0.05)  # locked wheel: resisting
    assert c.Fz == pytest.approx(19.8, abs=0.05)
    assert c.sinkage == pytest.approx(0.0493, abs=1e-4)
    c = _cond(shipped, 0, 100)
    assert c.Fx == pytest.approx(4.8, abs=0.05) and c.slip == pytest.approx(0.90, abs=0.005)  # traction
    c = _cond(shipped, 90, 10)
    assert c.Fy == pytest.approx(52.4, abs=0.05)  # lateral reaction toward +y
    assert c.Fx == pytest.approx(-0.5, abs=0.05)
    assert c.sinkage == pytest.approx(0.0705, abs=5e-5)


def test_shipped_si_ranges(shipped: TrialSet) -> None:
    assert np.all(np.abs(shipped.beta - shipped.beta_cmd) <= math.radians(0.3) + 1e-12)
    assert np.allclose(shipped.vx_cmd, 0.010)
    assert 13.0 <= shipped.Fz.min() and shipped.Fz.max() <= 30.2  # README: "13 to 30 N"
    assert 0.0 < shipped.sinkage.min() and shipped.sinkage.max() < 0.1  # metres
    assert shipped.rim_speed.max() == pytest.approx(0.0996075)
    # omega by the authors' convention
    assert np.allclose(shipped.omega(), shipped.rim_speed / AUTHORS_RIM_RADIUS)
    # the file's slip column agrees with the README definition (commanded carriage speed)
    v = shipped.rim_speed
    assert np.allclose(shipped.slip, (v - 0.010) / np.maximum(v, 0.010), atol=1e-5)


def test_shipped_noise_plausible(shipped: TrialSet) -> None:
    nz = shipped.noise()
    # dissertation: average repeat spread below 1.9 N for force and below 3 mm for sinkage
    for ch in ("Fx", "Fy", "Fz"):
        assert 0.1 < nz[ch] < 1.9, (ch, nz[ch])
    assert 1e-4 < nz["sinkage"] < 3e-3
    assert nz["dof"] == 126.0
    # pooled estimator equals the RMS of per-condition sample stds when all n are equal
    sd = np.array([c.Fx_sd for c in shipped.conditions()])
    assert nz["Fx"] == pytest.approx(float(np.sqrt(np.mean(sd**2))))


def test_tuned_params_shipped() -> None:
    tp = load_tuned_params()
    assert sorted(tp) == [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0]
    a0, a1, b0, b1 = tp[0.0]
    assert (a0, a1, b0, b1) == pytest.approx((0.273355, 0.672903, -0.663964, -0.176576))
    for a0, a1, b0, b1 in tp.values():  # the authors' bounds and constraints
        assert 0 <= a0 <= 1 and 0 <= a1 <= 1 and -1 <= b0 <= 0 and -1 <= b1 <= 0
        assert a0 + a1 <= 1 + 1e-9 and b0 + b1 >= -1 - 1e-9


def test_tuned_params_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match=r"missing required column\(s\) \['b1'\]"):
        load_tuned_params(write(tmp_path, ["beta_deg", "a0", "a1", "b0"], [["0", "0.2", "0.6", "-0.6"]], "tp.csv"))
    with pytest.raises(DatasetError, match=r"data row 2, column 'beta_deg': duplicated slip angle 0\.0"):
        load_tuned_params(write(tmp_path, ["beta_deg", "a0", "a1", "b0", "b1"], [["0", "1", "0", "0", "0"]] * 2, "tp.csv"))
    with pytest.raises(DatasetError, match=r"data row 1, column 'a1': non-numeric value 'x'"):
        load_tuned_params(write(tmp_path, ["beta_deg", "a0", "a1", "b0", "b1"], [["0", "1", "x", "0", "0"]], "tp.csv"))
    with pytest.raises(DatasetError, match=r"'beta_deg': 100\.0 is outside"):
        load_tuned_params(write(tmp_path, ["beta_deg", "a0", "a1", "b0", "b1"], [["100", "1", "0", "0", "0"]], "tp.csv"))


# --- sinkage time series --------------------------------------------------------------------------

TS_HEADER = ["trial_id", "t_s", "x_mm", "vx_mm_s", "rim_speed_mm_s", "angle_deg", "z_mm", "sinkage_mm"]


def _ts_rows() -> list[list[str]]:
    rows = []
    for tid, z0 in (("r/10_3_0_1", 30.0), ("r/10_3_0_2", 40.0)):
        for k in range(800):
            t = k * 0.1
            z = z0 - 0.5 * t
            rows.append([tid, f"{t:.1f}", f"{10 * t:.2f}", "10", "3", "0", f"{z:.3f}", f"{-(z - z0 + 31.5):.3f}"])
    return rows


def test_timeseries_small_gz(tmp_path: Path) -> None:
    p = tmp_path / "ts.csv.gz"
    with gzip.open(p, "wt", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TS_HEADER)
        w.writerows(_ts_rows())
    ts = load_sinkage_timeseries(p)
    assert list(ts) == ["r/10_3_0_1", "r/10_3_0_2"]
    s = ts["r/10_3_0_1"]
    assert s.sinkage[0] == pytest.approx(-0.0315)
    assert s.x[10] == pytest.approx(0.010) and s.vx[0] == pytest.approx(0.010)
    # sinkage = -(z - z0 + 31.5 mm) = 0.5 mm/s * t - 31.5 mm; mean over 70 < t <= 75 at t = 72.55
    assert s.window_mean() == pytest.approx((0.5 * 72.55 - 31.5) * 1e-3)


def test_timeseries_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no such sinkage time-series file"):
        load_sinkage_timeseries(tmp_path / "missing.csv.gz")
    rows = _ts_rows()
    rows[5][TS_HEADER.index("z_mm")] = "oops"
    with pytest.raises(DatasetError, match=r"data row 6 \(trial_id 'r/10_3_0_1'\), column 'z_mm': non-numeric value 'oops'"):
        load_sinkage_timeseries(write(tmp_path, TS_HEADER, rows, "ts.csv"))
    rows = _ts_rows()
    rows[1][1] = rows[0][1]
    with pytest.raises(DatasetError, match=r"trial_id 'r/10_3_0_1', column 't_s': repeated time stamp"):
        load_sinkage_timeseries(write(tmp_path, TS_HEADER, rows, "ts.csv"))
    with pytest.raises(DatasetError, match=r"missing required column\(s\) \['sinkage_mm'\]"):
        load_sinkage_timeseries(write(tmp_path, TS_HEADER[:-1], [r[:-1] for r in _ts_rows()], "ts.csv"))


@pytest.mark.skipif(not (SHARED / "grouser_sinkage_timeseries.csv.gz").is_file(), reason="shared single_wheel data folder not present")
def test_timeseries_shared_reproduces_trial_sinkage(shipped: TrialSet) -> None:
    ts = load_sinkage_timeseries(SHARED / "grouser_sinkage_timeseries.csv.gz")
    assert len(ts) == 199
    assert set(shipped.trial_id) <= set(ts)
    diff = np.array([abs(ts[t].window_mean() - s) for t, s in zip(shipped.trial_id, shipped.sinkage)])
    # README: window means reproduce sinkage_mm to within 0.31 mm (median 0.001 mm)
    assert diff.max() < 0.31e-3 and np.median(diff) < 0.01e-3
