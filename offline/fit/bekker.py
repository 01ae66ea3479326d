"""Static pressure-sinkage (plate and wheel) tests and the Bekker fit ``p = k delta^n``.

Reads the ``pressure_sinkage/`` tables of the shared single-wheel dataset (Pavlov, CMU,
robomechanics/3d-terramechanics, MIT licence) and reproduces the authors' procedure
(data README, "How the authors computed pressure"):

1. smooth Fz with a 10-sample moving mean (MATLAB ``movmean(F, 10)``) and subtract the
   test's ``authors_Fz_offset_N``;
2. keep the samples inside the authors' loading window (``start < t <= end``);
3. plates: pressure = F / (pi d^2 / 4); wheels: F / (b 2 r sin(theta)),
   ``theta = acos((r - delta) / r)`` with r = 0.058 m, b = 0.050 m (the published code);
4. fit ``p = k delta^n`` (eq. (5.5) with a single modulus, no kc/b split).

Only samples with delta > 0 and p > 0 enter the fits. Two estimators are reported, per
test and pooled over the selected tests:

* **log**: ordinary least squares of ``ln p = ln k + n ln delta`` (relative errors, every
  sample weighted alike on a log scale);
* **nls**: ``scipy.optimize.least_squares`` on the pressure residual ``k delta^n - p`` in Pa,
  parametrised by (ln k, n) and started from the log fit (absolute errors: dominated by
  the deepest, highest-pressure samples).

Measured on the shared data (large-box plates, 9 tests): the per-test NLS fits give
k = 3.7e3-1.15e4 kN/m^(n+2) and n = 1.33-1.61, the ranges the data README quotes, with a
per-test mean n = 1.47 close to the dissertation's 1.46. Per-test log-space fits scatter
more (n = 1.14-1.66): they weight the sub-millimetre samples, where the pressure is a few
Pa and dominated by force noise, as much as the deep ones. Pooled fits mix plate sizes
(60-100 mm reach different depths; the single-k model has no kc/b size term), so pooled n
is lower (log 1.34, NLS 1.14) although the predicted pressure at 20 mm sinkage is within
3 % of the dissertation's curve.

Units: SI inside (m, Pa, N/m^(n+2)); ``k_kN`` properties give kN/m^(n+2), the unit of the
dissertation's k = 8000 kN/m^(n+2), n0 = 1.46 (Table 5.3; ``set_soil_params.m``). Because k
and n are strongly correlated (k's unit depends on n), comparisons are also made on the
pressure predicted at reference sinkages, see :meth:`BekkerFit.comparison`.

Run ``python -m offline.fit.bekker /path/to/single_wheel`` for the report.
"""

from __future__ import annotations

import argparse
import sys
import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy.optimize import least_squares

from .dataset import DatasetError

__all__ = [
    "DISSERTATION_K",
    "DISSERTATION_N0",
    "AUTHORS_WHEEL_RADIUS",
    "AUTHORS_WHEEL_WIDTH",
    "SELECTIONS",
    "PressureTest",
    "PressureTestInfo",
    "TestFit",
    "BekkerFit",
    "load_pressure_test",
    "load_pressure_index",
    "moving_mean",
    "compute_pressure",
    "fit_power_law",
    "fit_bekker",
    "plot_bekker",
]

#: Dissertation / published-code pressure-sinkage modulus, N/m^(n+2) (8000 kN/m^(n+2)).
DISSERTATION_K = 8.0e6
#: Dissertation / published-code sinkage exponent at zero slip.
DISSERTATION_N0 = 1.46
#: Wheel radius and width the authors used for the chord contact area, m.
AUTHORS_WHEEL_RADIUS = 0.058
AUTHORS_WHEEL_WIDTH = 0.050
#: Window of the authors' moving mean, samples.
SMOOTHING_SAMPLES = 10

_MM = 1e-3


# --- loading -------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PressureTest:
    """One static test, 100 Hz, SI.

    Attributes
    ----------
    time : s since the start of the force recording; z : raw vertical position (up), m;
    displacement : penetration below the contact position, m (+ into the sand);
    Fz : vertical force, N (+ compressive), zeroed on the lifted recording, unsmoothed,
    *without* ``authors_Fz_offset_N``; in_window : bool, inside the authors' loading window.
    """

    source: str
    time: np.ndarray
    z: np.ndarray
    displacement: np.ndarray
    Fz: np.ndarray
    in_window: np.ndarray

    def __len__(self) -> int:
        return len(self.time)


@dataclass(frozen=True)
class PressureTestInfo:
    """One row of ``pressure_sinkage/index.csv`` (SI; None where the cell is blank)."""

    test_id: str
    file: Path | None
    test_date: str
    box: str
    object: str
    plate_diameter: float | None
    clock_offset_h: float | None
    window_start: float | None
    window_end: float | None
    z_contact: float | None
    Fz_offset: float | None
    notes: str

    @property
    def is_plate(self) -> bool:
        """True for circular-plate tests."""
        return self.object == "circular plate"

    @property
    def is_wheel(self) -> bool:
        """True for wheel tests (grousered or smooth)."""
        return self.object.endswith("wheel")


def _read_csv(path: Path, what: str) -> tuple[list[str], list[list[str]]]:
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            rows = [r for r in csv.reader(fh) if any(c.strip() for c in r)]
    except FileNotFoundError:
        raise DatasetError(f"{path}: no such {what} file; check the path") from None
    if not rows:
        raise DatasetError(f"{path}: empty file; expected a header and data rows")
    header = [c.strip() for c in rows[0]]
    if len(rows) < 2:
        raise DatasetError(f"{path}: header only, no data rows")
    for i, r in enumerate(rows[1:], start=1):
        if len(r) != len(header):
            raise DatasetError(f"{path}: data row {i} has {len(r)} fields, expected {len(header)}")
    return header, [[c.strip() for c in r] for r in rows[1:]]


def _float_cell(path: Path, row: int, col: str, s: str, allow_blank: bool) -> float | None:
    if s == "":
        if allow_blank:
            return None
        raise DatasetError(f"{path}: data row {row}, column '{col}': empty cell; expected a number")
    try:
        v = float(s)
    except ValueError:
        raise DatasetError(f"{path}: data row {row}, column '{col}': non-numeric value {s!r}") from None
    if not math.isfinite(v):
        raise DatasetError(f"{path}: data row {row}, column '{col}': got {s!r}, expected a finite number")
    return v


_TEST_COLUMNS = ("time_s", "z_mm", "displacement_mm", "Fz_N", "in_authors_window")


def load_pressure_test(path: str | Path) -> PressureTest:
    """Load one per-test table (``pressure_sinkage/<folder>__<test>.csv``), SI units.

    Raises
    ------
    DatasetError
        Missing file or column, empty file, non-numeric or non-finite value, window flag
        not 0/1, or time not strictly increasing.
    """
    p = Path(path)
    header, rows = _read_csv(p, "pressure-sinkage test")
    missing = [c for c in _TEST_COLUMNS if c not in header]
    if missing:
        raise DatasetError(f"{p}: missing column(s) {missing}; expected {list(_TEST_COLUMNS)}, found {header}")
    cols: dict[str, np.ndarray] = {}
    for c in _TEST_COLUMNS:
        j = header.index(c)
        try:
            a = np.array([r[j] for r in rows], dtype=float)
            ok = bool(np.all(np.isfinite(a)))
        except ValueError:
            ok = False
        if not ok:
            for i, r in enumerate(rows, start=1):
                _float_cell(p, i, c, r[j], allow_blank=False)
        cols[c] = a
    flag = cols["in_authors_window"]
    if not np.all(np.isin(flag, (0.0, 1.0))):
        i = int(np.flatnonzero(~np.isin(flag, (0.0, 1.0)))[0])
        raise DatasetError(f"{p}: data row {i + 1}, column 'in_authors_window': {float(flag[i])!r}, expected 0 or 1")
    dt = np.diff(cols["time_s"])
    if np.any(dt <= 0):
        i = int(np.flatnonzero(dt <= 0)[0])
        raise DatasetError(f"{p}: data row {i + 2}, column 'time_s': time does not increase; rows must be in time order")
    arrs = {
        "time": cols["time_s"],
        "z": cols["z_mm"] * _MM,
        "displacement": cols["displacement_mm"] * _MM,
        "Fz": cols["Fz_N"],
        "in_window": flag == 1.0,
    }
    for a in arrs.values():
        a.setflags(write=False)
    return PressureTest(source=str(p), **arrs)


def _index_path(folder: Path) -> Path:
    for cand in (folder / "index.csv", folder / "pressure_sinkage" / "index.csv"):
        if cand.is_file():
            return cand
    if folder.is_file():
        return folder
    raise DatasetError(
        f"{folder}: no index.csv found (looked in the folder and in its pressure_sinkage/); pass the "
        "single_wheel data folder, its pressure_sinkage/ folder, or the index file"
    )


def _resolve(index_file: Path, rel: str) -> Path:
    base = index_file.parent
    for cand in (base / rel, base.parent / rel, base / Path(rel).name):
        if cand.is_file():
            return cand
    return base.parent / rel  # reported as missing when loaded


_INDEX_COLUMNS = (
    "test_id", "file", "test_date", "box", "object", "plate_diameter_mm", "clock_offset_h",
    "authors_window_start_s", "authors_window_end_s", "z_contact_mm", "authors_Fz_offset_N", "notes",
)


def load_pressure_index(folder: str | Path) -> list[PressureTestInfo]:
    """Load ``pressure_sinkage/index.csv`` (the list of static tests and their meaning).

    Parameters
    ----------
    folder : str or Path
        The single-wheel data folder, its ``pressure_sinkage/`` folder, or ``index.csv``.

    Returns
    -------
    list of PressureTestInfo
        In file order, SI (plate diameter, z_contact in m). ``file`` is None for tests that
        were not exported.

    Raises
    ------
    DatasetError
        No index, missing column, non-numeric value, duplicated test_id, or an exported test
        without its loading window.
    """
    idx = _index_path(Path(folder))
    header, rows = _read_csv(idx, "pressure-sinkage index")
    missing = [c for c in _INDEX_COLUMNS if c not in header]
    if missing:
        raise DatasetError(f"{idx}: missing column(s) {missing}; expected {list(_INDEX_COLUMNS)}, found {header}")
    h = {c: header.index(c) for c in _INDEX_COLUMNS}
    out: list[PressureTestInfo] = []
    seen: set[str] = set()
    for i, r in enumerate(rows, start=1):
        tid = r[h["test_id"]]
        if tid in seen:
            raise DatasetError(f"{idx}: data row {i}, column 'test_id': duplicated test_id {tid!r}")
        seen.add(tid)

        def f(col: str, scale: float = 1.0) -> float | None:
            v = _float_cell(idx, i, col, r[h[col]], allow_blank=True)
            return None if v is None else v * scale

        file = r[h["file"]]
        info = PressureTestInfo(
            test_id=tid,
            file=_resolve(idx, file) if file else None,
            test_date=r[h["test_date"]],
            box=r[h["box"]],
            object=r[h["object"]],
            plate_diameter=f("plate_diameter_mm", _MM),
            clock_offset_h=f("clock_offset_h"),
            window_start=f("authors_window_start_s"),
            window_end=f("authors_window_end_s"),
            z_contact=f("z_contact_mm", _MM),
            Fz_offset=f("authors_Fz_offset_N"),
            notes=r[h["notes"]],
        )
        if info.file is not None and (info.window_start is None or info.window_end is None):
            raise DatasetError(f"{idx}: data row {i} ({tid}): exported test without authors_window_start_s/end_s")
        if info.is_plate and info.plate_diameter is None:
            raise DatasetError(f"{idx}: data row {i} ({tid}), column 'plate_diameter_mm': plate test without a diameter")
        out.append(info)
    return out


# --- the authors' procedure ----------------------------------------------------------------


def moving_mean(x: np.ndarray, k: int = SMOOTHING_SAMPLES) -> np.ndarray:
    """MATLAB ``movmean(x, k)``: centred moving mean with shrinking end windows.

    For even ``k`` the window holds ``k/2`` samples before and ``k/2 - 1`` after the
    current one (MATLAB's convention); for odd ``k``, ``(k-1)/2`` on each side.
    """
    x = np.asarray(x, dtype=float)
    if k < 1:
        raise ValueError(f"moving-mean window must be >= 1 sample, got {k}")
    before = k // 2
    after = k - before - 1
    c = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(len(x))
    lo = np.clip(i - before, 0, len(x))
    hi = np.clip(i + after + 1, 0, len(x))
    return (c[hi] - c[lo]) / (hi - lo)


def compute_pressure(
    test: PressureTest,
    info: PressureTestInfo,
    wheel_radius: float = AUTHORS_WHEEL_RADIUS,
    wheel_width: float = AUTHORS_WHEEL_WIDTH,
) -> tuple[np.ndarray, np.ndarray]:
    """Sinkage (m) and pressure (Pa) of one test by the authors' procedure (steps 1-3).

    Returns only window samples with delta > 0 and p > 0 (the fit's domain).
    """
    F = moving_mean(test.Fz, SMOOTHING_SAMPLES) - (info.Fz_offset or 0.0)
    if info.window_start is not None and info.window_end is not None:
        win = (test.time > info.window_start) & (test.time <= info.window_end)
    else:
        win = test.in_window
    d = test.displacement[win]
    F = F[win]
    if info.is_plate:
        assert info.plate_diameter is not None
        area = np.full_like(d, math.pi * info.plate_diameter**2 / 4.0)
    elif info.is_wheel:
        cos_t = np.clip((wheel_radius - d) / wheel_radius, -1.0, 1.0)
        area = wheel_width * 2.0 * wheel_radius * np.sin(np.arccos(cos_t))
    else:
        raise DatasetError(f"{info.test_id}: object {info.object!r} is neither a plate nor a wheel; no contact area")
    ok = (d > 0) & (area > 0)
    p = np.full_like(d, np.nan)
    p[ok] = F[ok] / area[ok]
    keep = ok & (p > 0)
    return d[keep], p[keep]


def fit_power_law(delta: np.ndarray, p: np.ndarray) -> dict[str, float]:
    """Fit ``p = k delta^n`` in log space and by nonlinear least squares.

    Parameters
    ----------
    delta : ndarray
        Sinkage, m (> 0).
    p : ndarray
        Pressure, Pa (> 0).

    Returns
    -------
    dict
        ``k_log, n_log, k_nls, n_nls`` (k in N/m^(n+2)), ``rms_log, rms_nls`` (pressure
        residual RMS, Pa), ``n_samples``.
    """
    delta = np.asarray(delta, dtype=float)
    p = np.asarray(p, dtype=float)
    if delta.size < 3 or np.ptp(np.log(delta)) == 0:
        raise DatasetError(f"power-law fit needs >= 3 samples at distinct sinkages, got {delta.size}")
    A = np.stack([np.ones_like(delta), np.log(delta)], axis=1)
    (lnk, n), *_ = np.linalg.lstsq(A, np.log(p), rcond=None)
    scale = float(np.median(p))

    def res(x: np.ndarray) -> np.ndarray:
        return (np.exp(x[0]) * delta ** x[1] - p) / scale

    sol = least_squares(res, x0=[lnk, n], method="lm")
    k_log, k_nls = math.exp(lnk), math.exp(sol.x[0])
    rms = lambda k, e: float(np.sqrt(np.mean((k * delta**e - p) ** 2)))  # noqa: E731
    return {
        "k_log": k_log, "n_log": float(n), "k_nls": k_nls, "n_nls": float(sol.x[1]),
        "rms_log": rms(k_log, n), "rms_nls": rms(k_nls, sol.x[1]), "n_samples": float(delta.size),
    }


@dataclass(frozen=True, eq=False)
class TestFit:
    """Fit of one test. k in N/m^(n+2) (``k_*_kN`` in kN/m^(n+2)); delta (m), p (Pa) data."""

    __test__ = False  # not a pytest class

    info: PressureTestInfo
    delta: np.ndarray
    p: np.ndarray
    k_log: float
    n_log: float
    k_nls: float
    n_nls: float
    rms_log: float
    rms_nls: float

    @property
    def k_log_kN(self) -> float:
        return self.k_log / 1e3

    @property
    def k_nls_kN(self) -> float:
        return self.k_nls / 1e3


@dataclass(frozen=True, eq=False)
class BekkerFit:
    """Per-test and pooled Bekker fits of one selection of static tests.

    Attributes
    ----------
    which : str
        Selection name.
    tests : list of TestFit
    k_log, n_log, k_nls, n_nls : float
        Pooled fits (all selected samples together), k in N/m^(n+2).
    rms_log, rms_nls : float
        Pooled pressure residual RMS, Pa.
    n_samples : int
    """

    which: str
    tests: list[TestFit]
    k_log: float
    n_log: float
    k_nls: float
    n_nls: float
    rms_log: float
    rms_nls: float
    n_samples: int

    @property
    def k_log_kN(self) -> float:
        """Pooled log-space k, kN/m^(n+2)."""
        return self.k_log / 1e3

    @property
    def k_nls_kN(self) -> float:
        """Pooled nonlinear-least-squares k, kN/m^(n+2)."""
        return self.k_nls / 1e3

    def spread(self) -> dict[str, tuple[float, float, float, float]]:
        """Per-test spread: ``name -> (mean, sample std, min, max)``.

        Names: ``k_log_kN, n_log, k_nls_kN, n_nls``. (k's unit depends on n, so its mean
        over tests is only indicative; see :meth:`comparison`.)
        """
        out = {}
        for name in ("k_log_kN", "n_log", "k_nls_kN", "n_nls"):
            v = np.array([getattr(t, name) for t in self.tests])
            sd = float(np.std(v, ddof=1)) if v.size > 1 else math.nan
            out[name] = (float(v.mean()), sd, float(v.min()), float(v.max()))
        return out

    def comparison(
        self, k_ref: float = DISSERTATION_K, n_ref: float = DISSERTATION_N0, depths: Sequence[float] = (0.01, 0.02, 0.04)
    ) -> dict[str, float]:
        """Compare with the dissertation's k = 8000 kN/m^(n+2), n0 = 1.46.

        Returns ratios k/k_ref, differences n - n_ref, and for each reference sinkage
        ``depth`` (m) the ratio of predicted pressures ``p_fit(depth) / p_ref(depth)``
        (pooled fits; ``p_ref = k_ref depth^n_ref``), which is independent of the k-n
        trade-off.
        """
        out = {
            "k_ref_kN": k_ref / 1e3, "n_ref": n_ref,
            "k_log/k_ref": self.k_log / k_ref, "n_log-n_ref": self.n_log - n_ref,
            "k_nls/k_ref": self.k_nls / k_ref, "n_nls-n_ref": self.n_nls - n_ref,
        }
        for d in depths:
            pref = k_ref * d**n_ref
            out[f"p_log/p_ref@{d * 1e3:g}mm"] = self.k_log * d**self.n_log / pref
            out[f"p_nls/p_ref@{d * 1e3:g}mm"] = self.k_nls * d**self.n_nls / pref
        return out

    def report(self) -> str:
        """Human-readable table (k in kN/m^(n+2), sinkage range in mm)."""
        lines = [f"Bekker fit p = k delta^n, selection '{self.which}' ({len(self.tests)} tests, {self.n_samples} samples)"]
        lines.append(f"{'test':48s} {'d_mm':>5s} {'N':>5s} {'delta_mm':>11s} {'k_log':>9s} {'n_log':>6s} {'k_nls':>9s} {'n_nls':>6s}")
        for t in self.tests:
            dmm = f"{t.info.plate_diameter * 1e3:.0f}" if t.info.plate_diameter else "-"
            rng = f"{t.delta.min() * 1e3:.1f}-{t.delta.max() * 1e3:.1f}"
            lines.append(
                f"{t.info.test_id:48s} {dmm:>5s} {t.delta.size:5d} {rng:>11s} {t.k_log_kN:9.0f} {t.n_log:6.3f} "
                f"{t.k_nls_kN:9.0f} {t.n_nls:6.3f}"
            )
        lines.append(f"pooled log fit : k = {self.k_log_kN:8.0f} kN/m^(n+2), n = {self.n_log:.3f}, rms {self.rms_log / 1e3:.2f} kPa")
        lines.append(f"pooled NLS fit : k = {self.k_nls_kN:8.0f} kN/m^(n+2), n = {self.n_nls:.3f}, rms {self.rms_nls / 1e3:.2f} kPa")
        for name, (m, sd, lo, hi) in self.spread().items():
            lines.append(f"per-test {name:9s}: mean {m:9.3f}  sd {sd:8.3f}  min {lo:9.3f}  max {hi:9.3f}")
        lines.append("vs dissertation (k = 8000 kN/m^(n+2), n0 = 1.46):")
        for name, v in self.comparison().items():
            lines.append(f"  {name:22s} {v:.3f}")
        return "\n".join(lines)


def _sel(box: Callable[[str], bool], obj: str) -> Callable[[PressureTestInfo], bool]:
    return lambda i: box(i.box) and i.object == obj


#: Named selections of the index for :func:`fit_bekker`.
SELECTIONS: dict[str, Callable[[PressureTestInfo], bool]] = {
    "large_box_plates": _sel(lambda b: b == "large", "circular plate"),
    "small_box_plates": _sel(lambda b: b == "small", "circular plate"),
    "all_plates": lambda i: i.object == "circular plate",
    "large_box_grousered_wheel": _sel(lambda b: b == "large", "grousered wheel"),
    "large_box_smooth_wheel": _sel(lambda b: b == "large", "smooth wheel"),
    "small_box_grousered_wheel": _sel(lambda b: b.startswith("small"), "grousered wheel"),
    "small_box_smooth_wheel": _sel(lambda b: b.startswith("small"), "smooth wheel"),
}


def fit_bekker(
    index_folder: str | Path,
    which: str | Callable[[PressureTestInfo], bool] = "large_box_plates",
    wheel_radius: float = AUTHORS_WHEEL_RADIUS,
    wheel_width: float = AUTHORS_WHEEL_WIDTH,
) -> BekkerFit:
    """Fit ``p = k delta^n`` to a selection of static tests by the authors' procedure.

    Parameters
    ----------
    index_folder : str or Path
        Single-wheel data folder (or its ``pressure_sinkage/``), see :func:`load_pressure_index`.
    which : str or callable
        A key of :data:`SELECTIONS` or a predicate on :class:`PressureTestInfo`. Only
        exported tests (``file`` not blank) are used.
    wheel_radius, wheel_width : float
        Chord-area geometry for wheel tests, m (authors: 0.058, 0.050).

    Returns
    -------
    BekkerFit

    Raises
    ------
    DatasetError
        Unknown selection, or no exported test matches it.
    """
    if isinstance(which, str):
        if which not in SELECTIONS:
            raise DatasetError(f"unknown test selection {which!r}; choose one of {sorted(SELECTIONS)} or pass a predicate")
        pred, name = SELECTIONS[which], which
    else:
        pred, name = which, getattr(which, "__name__", "custom")
    infos = [i for i in load_pressure_index(index_folder) if i.file is not None and pred(i)]
    if not infos:
        raise DatasetError(f"{index_folder}: no exported static test matches selection {name!r}")
    tests: list[TestFit] = []
    for info in infos:
        assert info.file is not None
        d, p = compute_pressure(load_pressure_test(info.file), info, wheel_radius, wheel_width)
        r = fit_power_law(d, p)
        tests.append(TestFit(info, d, p, r["k_log"], r["n_log"], r["k_nls"], r["n_nls"], r["rms_log"], r["rms_nls"]))
    D = np.concatenate([t.delta for t in tests])
    P = np.concatenate([t.p for t in tests])
    r = fit_power_law(D, P)
    return BekkerFit(name, tests, r["k_log"], r["n_log"], r["k_nls"], r["n_nls"], r["rms_log"], r["rms_nls"], int(D.size))


def plot_bekker(fit: BekkerFit, path: str | Path) -> Path:
    """Log-log plot of pressure (kPa) vs sinkage (mm): data per test, pooled fits, dissertation.

    Returns
    -------
    Path
        The PNG written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.5), dpi=110)
    diam = sorted({t.info.plate_diameter for t in fit.tests}, key=lambda x: -1 if x is None else x)
    cmap = plt.get_cmap("viridis")
    colours = {dd: cmap(i / max(1, len(diam) - 1) * 0.85) for i, dd in enumerate(diam)}
    labelled: set[object] = set()
    for t in fit.tests:
        dd = t.info.plate_diameter
        lab = None
        if dd not in labelled:
            lab = f"{dd * 1e3:.0f} mm plate" if dd else t.info.object
            labelled.add(dd)
        ax.plot(t.delta * 1e3, t.p / 1e3, ".", ms=2, alpha=0.45, color=colours[dd], label=lab)
    D = np.concatenate([t.delta for t in fit.tests])
    x = np.geomspace(D.min(), D.max(), 100)
    ax.plot(x * 1e3, fit.k_log * x**fit.n_log / 1e3, "k-", lw=2,
            label=f"pooled log fit: k={fit.k_log_kN:.0f} kN/m$^{{n+2}}$, n={fit.n_log:.2f}")
    ax.plot(x * 1e3, fit.k_nls * x**fit.n_nls / 1e3, "r--", lw=2,
            label=f"pooled NLS fit: k={fit.k_nls_kN:.0f}, n={fit.n_nls:.2f}")
    ax.plot(x * 1e3, DISSERTATION_K * x**DISSERTATION_N0 / 1e3, "b:", lw=2,
            label=f"dissertation: k={DISSERTATION_K / 1e3:.0f}, n={DISSERTATION_N0}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("sinkage $\\delta$ (mm)")
    ax.set_ylabel("pressure p (kPa)")
    ax.set_title(f"Pressure-sinkage, {fit.which} ({len(fit.tests)} tests)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, markerscale=4)
    fig.tight_layout()
    from ..files import atomic_path

    out = Path(path)
    try:
        with atomic_path(out) as tmp:  # written whole or not at all
            fig.savefig(tmp, format=out.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """CLI: print the fit report for one or more selections; optionally write the plot."""
    ap = argparse.ArgumentParser(prog="python -m offline.fit.bekker", description=__doc__.splitlines()[0])
    ap.add_argument("folder", help="single_wheel data folder (holding pressure_sinkage/)")
    ap.add_argument("--which", nargs="+", default=["large_box_plates"], choices=sorted(SELECTIONS))
    ap.add_argument("--plot", help="PNG path for the first selection")
    a = ap.parse_args(argv)
    if a.plot:
        from ..files import OutputError, check_output_path

        try:
            check_output_path(a.plot, [a.folder])
        except OutputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    for i, w in enumerate(a.which):
        fit = fit_bekker(a.folder, w)
        print(fit.report())
        print()
        if a.plot and i == 0:
            print(f"plot: {plot_bekker(fit, a.plot)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
