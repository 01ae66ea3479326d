"""Tests of offline.fit.bekker: authors' pressure procedure, power-law fits, loaders, plot."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np
import pytest

from offline.fit.bekker import (
    DISSERTATION_K,
    DISSERTATION_N0,
    PressureTestInfo,
    compute_pressure,
    fit_bekker,
    fit_power_law,
    load_pressure_index,
    load_pressure_test,
    moving_mean,
    plot_bekker,
)
from offline.fit.dataset import DatasetError

SHARED = Path(os.environ.get("SINGLE_WHEEL_DATA", Path(__file__).resolve().parents[2] / "shared" / "data" / "single_wheel"))
TEST_HEADER = ["time_s", "z_mm", "displacement_mm", "Fz_N", "in_authors_window"]


def need_shared() -> None:
    if not (SHARED / "pressure_sinkage" / "index.csv").is_file():
        pytest.skip(f"shared single_wheel data folder absent ({SHARED}); CI provides it beside the repo")


# --- pieces ---------------------------------------------------------------------------------------


def test_moving_mean_matches_matlab_movmean() -> None:
    x = np.arange(1.0, 13.0)  # 1..12
    m = moving_mean(x, 10)
    # MATLAB movmean(1:12, 10): window [i-5, i+4], shrinking at the ends
    assert m[0] == pytest.approx(np.mean(x[0:5]))
    assert m[5] == pytest.approx(np.mean(x[0:10]))
    assert m[6] == pytest.approx(np.mean(x[1:11]))
    assert m[-1] == pytest.approx(np.mean(x[6:12]))
    assert np.allclose(moving_mean(x, 3)[1:-1], x[1:-1])  # odd window, linear data


@pytest.mark.parametrize("k,n", [(8.0e6, 1.46), (2.0e5, 0.8), (3.0e7, 2.0)])
def test_power_law_recovers_exact_parameters(k: float, n: float) -> None:
    d = np.linspace(0.001, 0.04, 200)
    r = fit_power_law(d, k * d**n)
    assert r["k_log"] == pytest.approx(k, rel=1e-8) and r["n_log"] == pytest.approx(n, abs=1e-10)
    assert r["k_nls"] == pytest.approx(k, rel=1e-6) and r["n_nls"] == pytest.approx(n, abs=1e-7)


def test_log_and_nls_weight_errors_differently() -> None:
    # additive noise of constant size: NLS (absolute residuals) stays close, the log fit is
    # pulled by the noisy low-pressure samples at shallow sinkage
    rng = np.random.default_rng(0)
    d = np.linspace(0.0005, 0.04, 2000)
    p = 8e6 * d**1.46 + rng.normal(0, 300.0, d.size)
    keep = p > 0
    r = fit_power_law(d[keep], p[keep])
    assert abs(r["n_nls"] - 1.46) < 0.02
    assert r["rms_nls"] <= r["rms_log"]


def test_fit_needs_samples() -> None:
    with pytest.raises(DatasetError, match=">= 3 samples"):
        fit_power_law(np.array([0.01, 0.02]), np.array([1.0, 2.0]))


def _info(obj: str = "circular plate", diameter: float | None = 0.1, offset: float = 0.5) -> PressureTestInfo:
    return PressureTestInfo("t/1", None, "2022-01-14", "large", obj, diameter, 5.0, 1.0, 2.0, 0.0, offset, "")


def _write_test(tmp_path: Path, F: np.ndarray, d_mm: np.ndarray, t: np.ndarray) -> Path:
    p = tmp_path / "t.csv"
    with p.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TEST_HEADER)
        for ti, di, fi in zip(t, d_mm, F):
            w.writerow([f"{ti:.2f}", f"{-di:.4f}", f"{di:.4f}", f"{fi:.6f}", int(1.0 < ti <= 2.0)])
    return p


def test_pressure_plate_procedure(tmp_path: Path) -> None:
    t = np.arange(0, 300) * 0.01
    d_mm = np.clip(t - 0.5, 0, None) * 10.0  # 10 mm/s after 0.5 s
    F = np.full(t.size, 20.5)  # constant: the moving mean leaves it unchanged
    test = load_pressure_test(_write_test(tmp_path, F, d_mm, t))
    assert test.displacement[100] == pytest.approx(0.005) and test.in_window.sum() == 100
    d, p = compute_pressure(test, _info(offset=0.5))
    assert d.size == 100 and d.min() > 0.005 - 1e-9 and d.max() <= 0.015 + 1e-9  # 1 < t <= 2 s
    assert np.allclose(p, 20.0 / (math.pi * 0.1**2 / 4))  # offset subtracted, plate area


def test_pressure_wheel_chord_area(tmp_path: Path) -> None:
    t = np.arange(0, 300) * 0.01
    d_mm = np.full(t.size, 8.0)
    test = load_pressure_test(_write_test(tmp_path, np.full(t.size, 10.0), d_mm, t))
    d, p = compute_pressure(test, _info("grousered wheel", None, 0.0))
    theta = math.acos((0.058 - 0.008) / 0.058)
    assert np.allclose(p, 10.0 / (0.050 * 2 * 0.058 * math.sin(theta)))


def test_load_pressure_test_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no such pressure-sinkage test file"):
        load_pressure_test(tmp_path / "x.csv")
    p = tmp_path / "bad.csv"
    p.write_text("time_s,z_mm,Fz_N,in_authors_window\n0,1,2,0\n")
    with pytest.raises(DatasetError, match=r"missing column\(s\) \['displacement_mm'\]"):
        load_pressure_test(p)
    p.write_text("time_s,z_mm,displacement_mm,Fz_N,in_authors_window\n0,1,1,2,0\n0.01,1,1,abc,0\n")
    with pytest.raises(DatasetError, match=r"data row 2, column 'Fz_N': non-numeric value 'abc'"):
        load_pressure_test(p)
    p.write_text("time_s,z_mm,displacement_mm,Fz_N,in_authors_window\n0,1,1,2,0\n0.01,1,1,2,3\n")
    with pytest.raises(DatasetError, match=r"column 'in_authors_window': 3\.0, expected 0 or 1"):
        load_pressure_test(p)
    p.write_text("time_s,z_mm,displacement_mm,Fz_N,in_authors_window\n0,1,1,2,0\n0,1,1,2,0\n")
    with pytest.raises(DatasetError, match=r"data row 2, column 'time_s': time does not increase"):
        load_pressure_test(p)


def test_index_errors(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no index.csv found"):
        load_pressure_index(tmp_path)
    (tmp_path / "index.csv").write_text("test_id,file\na,b\n")
    with pytest.raises(DatasetError, match=r"missing column\(s\) \['test_date'"):
        load_pressure_index(tmp_path)


def test_unknown_selection(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="unknown test selection 'plates'"):
        fit_bekker(tmp_path, "plates")


# --- the shared static tests ----------------------------------------------------------------------


def test_index_shared() -> None:
    need_shared()
    idx = load_pressure_index(SHARED)
    assert len(idx) == 42
    exported = [i for i in idx if i.file is not None]
    assert len(exported) == 36 and all(i.file.is_file() for i in exported)  # type: ignore[union-attr]
    plates = [i for i in exported if i.is_plate and i.box == "large"]
    assert sorted(round(i.plate_diameter * 1e3) for i in plates) == [60, 60, 60, 80, 80, 80, 100, 100, 100]  # type: ignore[operator]
    assert load_pressure_index(SHARED / "pressure_sinkage")[0] == idx[0]


def test_window_flag_matches_index() -> None:
    need_shared()
    info = load_pressure_index(SHARED)[0]
    test = load_pressure_test(info.file)  # type: ignore[arg-type]
    recomputed = (test.time > info.window_start) & (test.time <= info.window_end)
    assert np.array_equal(recomputed, test.in_window)


@pytest.fixture(scope="module")
def large_plates():
    need_shared()
    return fit_bekker(SHARED, "large_box_plates")


def test_large_box_plates_in_readme_range(large_plates) -> None:
    # README: applying the procedure to the large-box plate tests gives
    # k ~ 3.7e3-1.2e4 kN/m^(n+2) and n ~ 1.3-1.6 (per test, least-squares power fit)
    fit = large_plates
    assert len(fit.tests) == 9
    for t in fit.tests:
        assert 3.6e3 <= t.k_nls_kN <= 1.2e4, (t.info.test_id, t.k_nls_kN)
        assert 1.3 <= t.n_nls <= 1.65, (t.info.test_id, t.n_nls)
    m, sd, lo, hi = fit.spread()["n_nls"]
    assert 1.4 < m < 1.55 and sd < 0.15
    # the per-test mean is close to the dissertation's n0 = 1.46 and k = 8000 kN/m^(n+2)
    assert abs(m - DISSERTATION_N0) < 0.05
    assert 0.8 < fit.spread()["k_nls_kN"][0] / (DISSERTATION_K / 1e3) < 1.3


def test_large_box_pooled_fits_predict_dissertation_pressure(large_plates) -> None:
    # k and n trade off; pooled fits agree with the dissertation's curve in pressure at
    # the driving trials' sinkage (15-70 mm) better than their (k, n) suggest
    cmp = large_plates.comparison()
    assert 0.85 < cmp["p_log/p_ref@20mm"] < 1.15
    assert 0.85 < cmp["p_nls/p_ref@20mm"] < 1.15
    assert 1.2 < large_plates.n_log < 1.5
    assert large_plates.n_samples == sum(t.delta.size for t in large_plates.tests)


def test_report_and_plot(large_plates, tmp_path: Path) -> None:
    text = large_plates.report()
    assert "pooled NLS fit" in text and "force-displacement_9" in text
    out = plot_bekker(large_plates, tmp_path / "bekker.png")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 20_000


def test_wheel_selection_uses_chord_area() -> None:
    need_shared()
    fit = fit_bekker(SHARED, "large_box_smooth_wheel")
    assert len(fit.tests) == 3 and all(t.info.object == "smooth wheel" for t in fit.tests)
    assert all(np.all(t.p > 0) and np.all(t.delta > 0) for t in fit.tests)
