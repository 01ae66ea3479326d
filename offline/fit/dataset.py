"""Loader for single-wheel testbed trials (the ``grouser_trials.csv`` format).

The shared single-wheel dataset (Pavlov, CMU, robomechanics/3d-terramechanics; see
``offline/data/README.md``) stores one row per driving trial: steady-state window means and
standard deviations of kinematics, soil forces and sinkage, in the wheel frame of the
dissertation's Fig. 5.1 (x forward along the heading, y out of the wheel face, z up; forces
are exerted *by the soil on the wheel*; sinkage > 0 below the reference surface).

The file carries degrees, mm and mm/s in its column names. They are converted to SI
(rad, m, m/s, N) exactly once, here, and validated on the way in: a malformed file is
refused with a :class:`DatasetError` naming the file, the row (1-based data row and
``trial_id``) and the column, what was expected, what was found, and how to fix it.

Nothing here is specific to the 189 trials of the shipped file: any table in the same
format (another wheel, another soil) loads, and optional columns may be absent.

Columns
-------
Required
    ``beta_deg`` (or ``beta_cmd_deg``), ``rim_speed_mm_s``, ``vx_mm_s``, ``Fx_N``, ``Fy_N``,
    ``Fz_N``, ``sinkage_mm``, ``slip``.
Optional (fallback when absent)
    ``trial_id`` (``"row<N>"``), ``test_date`` (``""``), ``repeat`` (order of appearance
    within the condition), ``beta_cmd_deg`` / ``rim_speed_cmd_mm_s`` / ``vx_cmd_mm_s``
    (inferred by clustering the measured values, listed in :attr:`TrialSet.inferred`),
    every ``*_std_*`` and ``*_slope_N_s`` column (NaN), ``authors_excluded`` (False).
    Empty cells in optional columns are read as NaN.

Slip is the file's own ``slip`` column (for the shared data: ``(V_rim - 10)/max(V_rim, 10)``
with the commanded carriage speed, slip angle ignored); it is not recomputed.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import numpy as np

__all__ = [
    "DatasetError",
    "AUTHORS_RIM_RADIUS",
    "REQUIRED_COLUMNS",
    "Condition",
    "TrialSet",
    "SinkageSeries",
    "load_trials",
    "load_tuned_params",
    "load_sinkage_timeseries",
    "omega_from_rim_speed",
    "check_force_units",
]

#: Rim radius (m) the authors' model uses to turn rim speed into wheel rate, omega = V_rim / r.
AUTHORS_RIM_RADIUS = 0.058

#: Columns that must be present (``beta_deg`` may be replaced by ``beta_cmd_deg``).
REQUIRED_COLUMNS: tuple[str, ...] = (
    "beta_deg",
    "rim_speed_mm_s",
    "vx_mm_s",
    "Fx_N",
    "Fy_N",
    "Fz_N",
    "sinkage_mm",
    "slip",
)

_DEG = math.pi / 180.0
_MM = 1e-3

# Tolerances of the unit heuristics (see load_trials).
_BETA_MAX_DEG = 90.0 + 0.5
_BETA_RADIANS_MAX = 1.6
_SINKAGE_METRES_MAX = 0.2

# (TrialSet field, csv column, factor to SI) for optional numeric columns.
_OPTIONAL_NUMERIC: tuple[tuple[str, str, float], ...] = (
    ("beta_std", "beta_std_deg", _DEG),
    ("rim_speed_std", "rim_speed_std_mm_s", _MM),
    ("vx_std", "vx_std_mm_s", _MM),
    ("Fx_std", "Fx_std_N", 1.0),
    ("Fy_std", "Fy_std_N", 1.0),
    ("Fz_std", "Fz_std_N", 1.0),
    ("sinkage_std", "sinkage_std_mm", _MM),
    ("Fx_slope", "Fx_slope_N_s", 1.0),
    ("Fy_slope", "Fy_slope_N_s", 1.0),
    ("Fz_slope", "Fz_slope_N_s", 1.0),
)

_CHANNELS: tuple[str, ...] = ("Fx", "Fy", "Fz", "sinkage")

# Force-unit heuristics (see _check_force_columns and check_force_units).
_FORCE_RATIO_MAX = 10.0
"""Largest |F_x| / F_z or |F_y| / F_z accepted: the soil's shear and sidewall resistance on a
wheel is of the order of its load (shipped trials: max 4.0, F_y at 90 deg); a column in mN (or a load in kN)
puts the ratio near 1000."""
_FORCE_RATIO_MIN = 1e-2
"""Below this for *every* row (with >= 5 rows), a horizontal force column looks like kN: in kN
the largest ratio of the shipped trials (4.0) would read 0.004; in N even their beta = 0
F_y (mean -2.3 % of the load, sd 2.6 %, Table 5.5) exceeds 1 % on most rows."""
_LOAD_MIN_N = 0.5
"""Smallest plausible largest load of a testbed wheel, N (a load in kN of a 20 N wheel is 0.02)."""
_PRESSURE_RANGE_PA = (10.0, 1.0e6)
"""Plausible mean ground pressure F_z / (2 r b) (a lower bound of the true contact pressure:
the contact patch is shorter than the wheel's diameter), Pa. Soft soils do not bear 1 MPa;
a load of 10 Pa cannot sink a wheel measurably."""


class DatasetError(ValueError):
    """A data file is missing, malformed, or carries values in the wrong unit or range."""


# --- low-level CSV reading -----------------------------------------------------------------


def _read_table(path: Path, what: str) -> tuple[list[str], list[list[str]]]:
    """Read a (optionally gzip-compressed) CSV into a header and rows of stripped strings."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"{path}: no such {what} file; check the path") from None
    except IsADirectoryError:
        raise DatasetError(f"{path}: is a directory, expected a {what} CSV file") from None
    if path.suffix == ".gz":
        try:
            raw = gzip.decompress(raw)
        except OSError as exc:
            raise DatasetError(f"{path}: not a valid gzip file ({exc})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise DatasetError(f"{path}: not UTF-8 text ({exc}); expected a CSV file") from None
    rows = [r for r in csv.reader(io.StringIO(text)) if any(c.strip() for c in r)]
    if not rows:
        raise DatasetError(f"{path}: empty file; expected a header line and at least one data row")
    header = [c.strip() for c in rows[0]]
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise DatasetError(f"{path}: duplicated column name(s) {dup} in the header; each column must appear once")
    body = rows[1:]
    if not body:
        raise DatasetError(f"{path}: header only, no data rows; expected at least one {what} row")
    for i, r in enumerate(body, start=1):
        if len(r) != len(header):
            raise DatasetError(
                f"{path}: data row {i} has {len(r)} fields, expected {len(header)} (one per header "
                "column); fix the row's commas"
            )
    return header, [[c.strip() for c in r] for r in body]


def _row_label(i: int, ids: Sequence[str] | None) -> str:
    if ids is None:
        return f"data row {i + 1}"
    return f"data row {i + 1} (trial_id {ids[i]!r})"


def _numeric_column(
    path: Path,
    header: list[str],
    rows: list[list[str]],
    col: str,
    ids: Sequence[str] | None,
    required: bool,
) -> np.ndarray:
    """Parse one column as float; required columns refuse empty / NaN / inf cells."""
    j = header.index(col)
    out = np.empty(len(rows))
    for i, r in enumerate(rows):
        s = r[j]
        if s == "":
            if required:
                raise DatasetError(
                    f"{path}: {_row_label(i, ids)}, column '{col}': empty cell in a required column; "
                    "expected a finite number"
                )
            out[i] = math.nan
            continue
        try:
            v = float(s)
        except ValueError:
            raise DatasetError(
                f"{path}: {_row_label(i, ids)}, column '{col}': non-numeric value {s!r}; expected a number"
            ) from None
        if required and not math.isfinite(v):
            raise DatasetError(
                f"{path}: {_row_label(i, ids)}, column '{col}': got {s!r}; a required column must be "
                "finite (no NaN/inf): fix or drop the row"
            )
        if math.isinf(v):
            raise DatasetError(
                f"{path}: {_row_label(i, ids)}, column '{col}': got {s!r}; infinite values are not "
                "allowed (leave the cell empty for a missing optional value)"
            )
        out[i] = v
    return out


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


def _cluster(values: np.ndarray, rel_tol: float, abs_tol: float) -> np.ndarray:
    """Single-linkage clustering of 1-D values; each value is replaced by its cluster median.

    Consecutive sorted values join a cluster when they differ by at most
    ``max(abs_tol, rel_tol * |value|)``. Used only to infer commanded set points that the file
    does not provide.
    """
    order = np.argsort(values, kind="stable")
    labels = np.empty(len(values), dtype=int)
    lab = 0
    for k, idx in enumerate(order):
        if k > 0:
            prev = values[order[k - 1]]
            if values[idx] - prev > max(abs_tol, rel_tol * abs(values[idx])):
                lab += 1
        labels[idx] = lab
    out = np.empty(len(values))
    for c in range(lab + 1):
        m = labels == c
        out[m] = np.median(values[m])
    return out


# --- data classes ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Condition:
    """One test condition (commanded slip angle, rim speed, carriage speed) and its repeats.

    All values SI. Means are over the repeats; ``*_sd`` are the repeat sample standard
    deviations (``ddof=1``) of the per-trial means, NaN when ``n == 1``.

    Attributes
    ----------
    beta_cmd, rim_speed_cmd, vx_cmd : float
        Commanded slip angle (rad), rim speed (m/s) and carriage speed (m/s).
    indices : ndarray of int
        Rows of the parent :class:`TrialSet` in this condition.
    n : int
        Number of repeats.
    beta, rim_speed, vx, slip : float
        Mean measured slip angle (rad), rim speed (m/s), carriage speed (m/s), slip ratio.
    Fx, Fy, Fz, sinkage : float
        Mean forces (N) and sinkage (m).
    Fx_sd, Fy_sd, Fz_sd, sinkage_sd : float
        Repeat spread (sample std) of those means.
    """

    beta_cmd: float
    rim_speed_cmd: float
    vx_cmd: float
    indices: np.ndarray
    n: int
    beta: float
    rim_speed: float
    vx: float
    slip: float
    Fx: float
    Fy: float
    Fz: float
    sinkage: float
    Fx_sd: float
    Fy_sd: float
    Fz_sd: float
    sinkage_sd: float


@dataclass(frozen=True, eq=False)
class TrialSet:
    """Per-trial steady-state results, SI units, one read-only numpy array per quantity.

    Attributes
    ----------
    trial_id, test_date : ndarray of str
    repeat : ndarray of int
        Repeat index within the condition (file column, or order of appearance).
    beta, beta_cmd : ndarray
        Measured and commanded slip angle, rad.
    rim_speed, rim_speed_cmd, vx, vx_cmd : ndarray
        Measured and commanded rim speed and carriage speed, m/s.
    slip : ndarray
        Slip ratio as given in the file, in [-1, 1).
    Fx, Fy, Fz : ndarray
        Soil forces on the wheel, wheel frame, N (Fz > 0 is the load carried).
    sinkage : ndarray
        m, > 0 below the reference surface.
    beta_std, rim_speed_std, vx_std, Fx_std, Fy_std, Fz_std, sinkage_std : ndarray
        Within-trial standard deviations over the steady-state window (NaN if absent).
    Fx_slope, Fy_slope, Fz_slope : ndarray
        Force drift over the window, N/s (NaN if absent).
    authors_excluded : ndarray of bool
        Rows the data authors left out of their model comparison.
    source : str
        File the set was read from.
    inferred : tuple of str
        Columns that were absent and filled in (e.g. ``"rim_speed_cmd_mm_s"``).
    """

    trial_id: np.ndarray
    test_date: np.ndarray
    repeat: np.ndarray
    beta: np.ndarray
    beta_cmd: np.ndarray
    rim_speed: np.ndarray
    rim_speed_cmd: np.ndarray
    vx: np.ndarray
    vx_cmd: np.ndarray
    slip: np.ndarray
    Fx: np.ndarray
    Fy: np.ndarray
    Fz: np.ndarray
    sinkage: np.ndarray
    beta_std: np.ndarray
    rim_speed_std: np.ndarray
    vx_std: np.ndarray
    Fx_std: np.ndarray
    Fy_std: np.ndarray
    Fz_std: np.ndarray
    sinkage_std: np.ndarray
    Fx_slope: np.ndarray
    Fy_slope: np.ndarray
    Fz_slope: np.ndarray
    authors_excluded: np.ndarray
    source: str = ""
    inferred: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        n = len(self.trial_id)
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                if v.shape != (n,):
                    raise DatasetError(
                        f"TrialSet.{f.name} has shape {v.shape}, expected ({n},) like trial_id"
                    )
                if v.flags.writeable:
                    object.__setattr__(self, f.name, _readonly(v))

    def __len__(self) -> int:
        return len(self.trial_id)

    def _array_fields(self) -> list[str]:
        return [f.name for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)]

    def subset(self, mask: Any) -> "TrialSet":
        """Return the trials selected by a boolean mask or an index array.

        Parameters
        ----------
        mask : array_like of bool (length ``len(self)``) or of int
            Selection; integer arrays keep their order.

        Returns
        -------
        TrialSet
        """
        m = np.asarray(mask)
        if m.dtype == bool and m.shape != (len(self),):
            raise DatasetError(f"subset mask has shape {m.shape}, expected ({len(self)},)")
        if m.dtype != bool and not np.issubdtype(m.dtype, np.integer):
            raise DatasetError(f"subset expects a boolean mask or integer indices, got dtype {m.dtype}")
        kw = {name: getattr(self, name)[m] for name in self._array_fields()}
        return replace(self, **kw)

    def omega(self, r: float = AUTHORS_RIM_RADIUS) -> np.ndarray:
        """Wheel angular rate by the authors' convention, ``omega = V_rim / r`` (rad/s).

        Parameters
        ----------
        r : float
            Rim radius, m (default 0.058 m, the authors' published code).
        """
        return omega_from_rim_speed(self.rim_speed, r)

    def conditions(self) -> list[Condition]:
        """Group repeats by commanded (slip angle, rim speed, carriage speed).

        The shared data has one carriage speed, so this is the (beta_cmd, rim_speed_cmd)
        grouping; including vx_cmd keeps distinct carriage speeds apart in other datasets.
        Conditions are sorted by beta_cmd, then rim_speed_cmd, then vx_cmd.
        """
        keys = np.stack([self.beta_cmd, self.rim_speed_cmd, self.vx_cmd], axis=1)
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        inv = np.asarray(inv).reshape(-1)
        out: list[Condition] = []
        for c, (b, r, v) in enumerate(uniq):
            idx = np.flatnonzero(inv == c)
            idx.setflags(write=False)
            n = len(idx)

            def sd(x: np.ndarray) -> float:
                return float(np.std(x[idx], ddof=1)) if n >= 2 else math.nan

            out.append(
                Condition(
                    beta_cmd=float(b), rim_speed_cmd=float(r), vx_cmd=float(v), indices=idx, n=n,
                    beta=float(self.beta[idx].mean()), rim_speed=float(self.rim_speed[idx].mean()),
                    vx=float(self.vx[idx].mean()), slip=float(self.slip[idx].mean()),
                    Fx=float(self.Fx[idx].mean()), Fy=float(self.Fy[idx].mean()),
                    Fz=float(self.Fz[idx].mean()), sinkage=float(self.sinkage[idx].mean()),
                    Fx_sd=sd(self.Fx), Fy_sd=sd(self.Fy), Fz_sd=sd(self.Fz), sinkage_sd=sd(self.sinkage),
                )
            )
        return out

    def noise(self) -> dict[str, float]:
        """Pooled repeat spread per channel: the noise level for normalised residuals.

        Estimator: pooled sample standard deviation over conditions with at least two
        repeats,

        .. math:: \\hat\\sigma = \\sqrt{\\frac{\\sum_c \\sum_{i \\in c} (x_i - \\bar x_c)^2}
                                        {\\sum_c (n_c - 1)}},

        i.e. the within-condition (between-repeat) scatter of the per-trial means, which
        includes day-to-day soil preparation differences; the within-trial ``*_std``
        columns (sensor noise and stick-slip inside the window) are not used.

        Returns
        -------
        dict
            ``{"Fx": N, "Fy": N, "Fz": N, "sinkage": m, "dof": degrees of freedom}``.

        Raises
        ------
        DatasetError
            If no condition has two or more repeats.
        """
        conds = [c for c in self.conditions() if c.n >= 2]
        dof = sum(c.n - 1 for c in conds)
        if dof == 0:
            raise DatasetError(
                f"{self.source or 'TrialSet'}: no condition has >= 2 repeats, so the repeat "
                "noise cannot be estimated; supply repeated trials or a noise level by hand"
            )
        out: dict[str, float] = {}
        for ch in _CHANNELS:
            x = getattr(self, ch)
            ss = sum(float(np.sum((x[c.indices] - x[c.indices].mean()) ** 2)) for c in conds)
            out[ch] = math.sqrt(ss / dof)
        out["dof"] = float(dof)
        return out


@dataclass(frozen=True, eq=False)
class SinkageSeries:
    """One run of the 10 Hz kinematics/sinkage time series, SI units.

    Attributes
    ----------
    t : s since the first logged sample; x : carriage position, m; vx, rim_speed : m/s;
    angle : slip angle, rad; z : raw vertical position (up, arbitrary zero), m;
    sinkage : m (> 0 below the reference surface; -0.0315 at t = 0 by the authors' convention).
    """

    trial_id: str
    t: np.ndarray
    x: np.ndarray
    vx: np.ndarray
    rim_speed: np.ndarray
    angle: np.ndarray
    z: np.ndarray
    sinkage: np.ndarray

    def window_mean(self, t0: float = 70.0, t1: float = 75.0) -> float:
        """Mean sinkage over ``t0 < t <= t1`` (the authors' steady-state window), m."""
        m = (self.t > t0) & (self.t <= t1)
        if not m.any():
            raise DatasetError(f"{self.trial_id}: no samples in {t0} s < t <= {t1} s (run ends at {self.t[-1]:.1f} s)")
        return float(self.sinkage[m].mean())


def omega_from_rim_speed(rim_speed: Any, r: float = AUTHORS_RIM_RADIUS) -> np.ndarray:
    """``omega = V_rim / r`` (rad/s) with V_rim in m/s and r in m (authors' convention).

    Raises
    ------
    DatasetError
        If ``r`` is not a positive length in metres.
    """
    if not (isinstance(r, (int, float)) and math.isfinite(r) and 0.0 < r < 5.0):
        raise DatasetError(f"rim radius r = {r!r}: expected a positive length in metres (e.g. 0.058), not mm")
    return np.asarray(rim_speed, dtype=float) / float(r)


# --- loaders -------------------------------------------------------------------------------


def _shipped(name: str) -> Path:
    return Path(str(resources.files("offline").joinpath("data", name)))


def _check_angle_units(path: Path, col: str, deg: np.ndarray, ids: Sequence[str], radians_check: bool) -> None:
    bad = np.flatnonzero(np.abs(deg) > _BETA_MAX_DEG)
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{path}: {_row_label(i, ids)}, column '{col}': {float(deg[i])!r} deg is outside "
            f"[-{_BETA_MAX_DEG}, {_BETA_MAX_DEG}]; slip angles are expected in degrees within +-90"
        )
    mx = float(np.max(np.abs(deg)))
    if radians_check and 0.0 < mx <= _BETA_RADIANS_MAX:
        raise DatasetError(
            f"{path}: column '{col}' looks like radians: every |value| <= {_BETA_RADIANS_MAX} "
            f"(max {mx:.4g}) but the column is in degrees; convert with numpy.degrees, or pass "
            "check_units=False if the angles really are that small"
        )


def _check_force_columns(path: Path | str, Fx: np.ndarray, Fy: np.ndarray, Fz: np.ndarray, ids: Sequence[str]) -> None:
    """Force columns against the load and the physics (every column is in N by its name).

    * the largest load below 0.5 N: ``Fz_N`` looks like kN;
    * |F_x| or |F_y| above 10 times the load on some row: that column looks like mN (or the
      load like kN); soil cannot push on a wheel with many times its load;
    * |F_x| or |F_y| below 0.01 times the load on every row (5 rows or more): that column
      looks like kN.
    """
    mx_load = float(np.max(Fz))
    if mx_load < _LOAD_MIN_N:
        raise DatasetError(
            f"{path}: column 'Fz_N': the largest load is {mx_load:.4g} N, below {_LOAD_MIN_N} N for every trial; the "
            "column looks like kN (a 20 N load is 0.02 kN): multiply the force columns by 1000, or pass "
            "check_units=False if the loads really are that small"
        )
    for col, F in (("Fx_N", Fx), ("Fy_N", Fy)):
        ratio = np.abs(F) / Fz
        i = int(np.argmax(ratio))
        if ratio[i] > _FORCE_RATIO_MAX:
            raise DatasetError(
                f"{path}: {_row_label(i, ids)}, column '{col}': |{col[:2]}| = {abs(float(F[i])):.4g} is "
                f"{float(ratio[i]):.0f} times the load Fz_N = {float(Fz[i]):.4g}; soil cannot push a wheel with more "
                f"than about its load. '{col}' looks like mN (divide it by 1000), or 'Fz_N' like kN; every force "
                "column must be in newtons"
            )
        if F.size >= 5 and float(np.max(ratio)) < _FORCE_RATIO_MIN and np.any(F != 0.0):
            raise DatasetError(
                f"{path}: column '{col}': |{col[:2]}| stays below {_FORCE_RATIO_MIN} times the load on every row "
                f"(max {float(np.max(ratio)):.2g}); '{col}' looks like kN (multiply it by 1000), or 'Fz_N' like mN. "
                "Every force column must be in newtons; pass check_units=False if the forces really are that small"
            )


def check_force_units(trials: "TrialSet", wheel: Any) -> None:
    """Check the trials' loads against a wheel: mean ground pressure ``F_z / (2 r b)`` in
    [10 Pa, 1 MPa] (a lower bound of the true contact pressure, see ``_PRESSURE_RANGE_PA``).

    Catches every force column in mN (or kN) together, which the ratios between columns
    checked by :func:`load_trials` cannot see.

    Parameters
    ----------
    trials : TrialSet
    wheel : offline.physics.params.Wheel
        The wheel the trials were run with (radius and width used).

    Raises
    ------
    DatasetError
        Naming the likely unit and the fix.
    """
    area = 2.0 * wheel.radius * wheel.width
    p = trials.Fz / area
    lo, hi = _PRESSURE_RANGE_PA
    i = int(np.argmax(p))
    if p[i] > hi:
        raise DatasetError(
            f"{trials.source or 'trials'}: {_row_label(i, list(trials.trial_id))}, column 'Fz_N': load "
            f"{float(trials.Fz[i]):.4g} N on the {wheel.name!r} wheel (r = {wheel.radius} m, b = {wheel.width} m) is a "
            f"ground pressure of at least {float(p[i]):.3g} Pa, above the {hi:.0e} Pa soft soil can bear; the force "
            "columns look like mN: divide Fx_N, Fy_N and Fz_N by 1000 (or check the wheel file)"
        )
    if float(np.max(p)) < lo:
        raise DatasetError(
            f"{trials.source or 'trials'}: column 'Fz_N': every load is a ground pressure below {lo:g} Pa on the "
            f"{wheel.name!r} wheel (largest load {float(np.max(trials.Fz)):.4g} N); the force columns look like kN: "
            "multiply Fx_N, Fy_N and Fz_N by 1000 (or check the wheel file)"
        )


def load_trials(path: str | Path | None = None, *, check_units: bool = True) -> TrialSet:
    """Load and validate a single-wheel trials table, converting to SI once.

    Parameters
    ----------
    path : str or Path, optional
        CSV in the ``grouser_trials.csv`` format. ``None`` loads the copy shipped in
        ``offline/data`` (the 189 grousered-wheel trials, MIT licence, see its README).
    check_units : bool
        Run the unit heuristics (default True): a slip-angle column whose values all lie
        within +-1.6 (and are not all zero) is taken as radians, and a sinkage column whose
        values all lie within +-0.2 (not all zero) is taken as metres; both are refused.
        Disable only for data that genuinely has tiny angles or sinkage.

    Returns
    -------
    TrialSet

    Raises
    ------
    DatasetError
        Missing file, empty file, missing required column, ragged row, non-numeric value,
        NaN/inf in a required column, slip outside [-1, 1), |slip angle| > 90.5 deg,
        angles, sinkage or forces in the wrong unit (forces: loads below 0.5 N, or a
        horizontal force above 10 times or, on every row, below 0.01 times the load),
        Fz <= 0, negative std, ``authors_excluded`` not 0/1, duplicated ``trial_id``, a
        row repeated verbatim in a file without ``trial_id``. The message names file,
        row and column.
    """
    p = _shipped("grouser_trials.csv") if path is None else Path(path)
    header, rows = _read_table(p, "trials")
    cols = set(header)

    # Required columns (beta_deg may be replaced by beta_cmd_deg).
    missing = [c for c in REQUIRED_COLUMNS if c not in cols and not (c == "beta_deg" and "beta_cmd_deg" in cols)]
    if missing:
        raise DatasetError(
            f"{p}: missing required column(s) {missing}; required: {list(REQUIRED_COLUMNS)} "
            f"('beta_cmd_deg' may stand in for 'beta_deg'); found: {header}. Rename the columns "
            "(units are part of the name: degrees, mm, mm/s, N)"
        )

    n = len(rows)
    inferred: list[str] = []
    if "trial_id" in cols:
        j = header.index("trial_id")
        ids = [r[j] for r in rows]
        seen: dict[str, int] = {}
        for i, t in enumerate(ids):
            if t == "":
                raise DatasetError(f"{p}: data row {i + 1}, column 'trial_id': empty trial_id; give every trial a unique id")
            if t in seen:
                raise DatasetError(
                    f"{p}: data row {i + 1}, column 'trial_id': duplicated trial_id {t!r} (first at data "
                    f"row {seen[t] + 1}); each trial must appear once"
                )
            seen[t] = i
    else:
        ids = [f"row{i + 1}" for i in range(n)]
        inferred.append("trial_id")
        # without trial ids, a duplicated row would silently count as one more repeat
        # (the noise estimate shrinks and every z-score grows)
        first: dict[tuple[str, ...], int] = {}
        for i, r in enumerate(rows):
            key = tuple(r)
            if key in first:
                raise DatasetError(
                    f"{p}: data row {i + 1} is identical to data row {first[key] + 1} and the file has no "
                    "'trial_id' column, so it would count as an extra repeat; remove the duplicated row, or add "
                    "a trial_id column if these really are two trials"
                )
            first[key] = i

    def num(col: str, required: bool = True) -> np.ndarray:
        return _numeric_column(p, header, rows, col, ids, required)

    def text(col: str) -> np.ndarray:
        if col not in cols:
            return np.array([""] * n, dtype=object)
        j = header.index(col)
        return np.array([r[j] for r in rows], dtype=object)

    beta_deg = num("beta_deg") if "beta_deg" in cols else None
    beta_cmd_deg = num("beta_cmd_deg") if "beta_cmd_deg" in cols else None
    rim = num("rim_speed_mm_s")
    vx = num("vx_mm_s")
    slip = num("slip")
    Fx, Fy, Fz = num("Fx_N"), num("Fy_N"), num("Fz_N")
    sink = num("sinkage_mm")

    for col, arr in (("beta_deg", beta_deg), ("beta_cmd_deg", beta_cmd_deg)):
        if arr is not None:
            _check_angle_units(p, col, arr, ids, radians_check=check_units)

    bad = np.flatnonzero((slip < -1.0) | (slip >= 1.0))
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{p}: {_row_label(i, ids)}, column 'slip': {float(slip[i])!r} is outside [-1, 1); slip is a "
            "ratio (-1 locked wheel, -> 1 spinning), not a percentage"
        )
    bad = np.flatnonzero(Fz <= 0.0)
    if bad.size:
        i = int(bad[0])
        raise DatasetError(
            f"{p}: {_row_label(i, ids)}, column 'Fz_N': {float(Fz[i])!r} N; the vertical soil force (wheel "
            "load) must be > 0 with z up. Check the sign convention (soil force on the wheel) or drop "
            "trials where the wheel lost contact"
        )
    if check_units:
        _check_force_columns(p, Fx, Fy, Fz, ids)
        mx = float(np.max(np.abs(sink)))
        if 0.0 < mx < _SINKAGE_METRES_MAX:
            raise DatasetError(
                f"{p}: column 'sinkage_mm' looks like metres: every |value| < {_SINKAGE_METRES_MAX} "
                f"(max {mx:.4g}) but the column is in mm; multiply by 1000, or pass check_units=False "
                "if sinkage really is that small"
            )

    # Commanded set points: from the file, or inferred by clustering measured values.
    if beta_cmd_deg is None:
        assert beta_deg is not None
        beta_cmd_deg = _cluster(beta_deg, rel_tol=0.0, abs_tol=1.0)
        inferred.append("beta_cmd_deg")
    if beta_deg is None:
        beta_deg = beta_cmd_deg.copy()
        inferred.append("beta_deg")
    if "rim_speed_cmd_mm_s" in cols:
        rim_cmd = num("rim_speed_cmd_mm_s")
    else:
        rim_cmd = _cluster(rim, rel_tol=0.1, abs_tol=0.5)
        inferred.append("rim_speed_cmd_mm_s")
    if "vx_cmd_mm_s" in cols:
        vx_cmd = num("vx_cmd_mm_s")
    else:
        vx_cmd = _cluster(vx, rel_tol=0.1, abs_tol=0.5)
        inferred.append("vx_cmd_mm_s")

    opt: dict[str, np.ndarray] = {}
    for fname, col, factor in _OPTIONAL_NUMERIC:
        if col in cols:
            a = num(col, required=False)
            if "_std" in col:
                bad = np.flatnonzero(a < 0.0)
                if bad.size:
                    i = int(bad[0])
                    raise DatasetError(
                        f"{p}: {_row_label(i, ids)}, column '{col}': {float(a[i])!r} is negative; a standard "
                        "deviation must be >= 0"
                    )
            opt[fname] = a * factor
        else:
            opt[fname] = np.full(n, math.nan)

    if "authors_excluded" in cols:
        ex = num("authors_excluded", required=False)
        bad = np.flatnonzero(~np.isin(ex, (0.0, 1.0)) & ~np.isnan(ex))
        if bad.size:
            i = int(bad[0])
            raise DatasetError(
                f"{p}: {_row_label(i, ids)}, column 'authors_excluded': {float(ex[i])!r}; expected 0 or 1"
            )
        excluded = ex == 1.0
    else:
        excluded = np.zeros(n, dtype=bool)

    if "repeat" in cols:
        rep_f = num("repeat", required=False)
        rep = np.where(np.isnan(rep_f), -1, rep_f).astype(int)
    else:
        rep = np.zeros(n, dtype=int)
        counter: dict[tuple[Any, ...], int] = {}
        for i, key in enumerate(zip(beta_cmd_deg, rim_cmd, vx_cmd)):
            counter[key] = counter.get(key, 0) + 1
            rep[i] = counter[key]
        inferred.append("repeat")

    return TrialSet(
        trial_id=np.array(ids, dtype=object),
        test_date=text("test_date"),
        repeat=rep,
        beta=beta_deg * _DEG,
        beta_cmd=beta_cmd_deg * _DEG,
        rim_speed=rim * _MM,
        rim_speed_cmd=rim_cmd * _MM,
        vx=vx * _MM,
        vx_cmd=vx_cmd * _MM,
        slip=slip,
        Fx=Fx,
        Fy=Fy,
        Fz=Fz,
        sinkage=sink * _MM,
        authors_excluded=excluded,
        source=str(p),
        inferred=tuple(inferred),
        **opt,
    )


def load_tuned_params(path: str | Path | None = None) -> dict[float, tuple[float, float, float, float]]:
    """Load the authors' tuned contact-angle coefficients per slip angle.

    ``theta_m = theta_f (a0 + a1 s)``, ``theta_r = theta_f (b0 + b1 s)`` (eqs. (5.3)-(5.4)).

    Parameters
    ----------
    path : str or Path, optional
        CSV with columns ``beta_deg, a0, a1, b0, b1``; ``None`` loads the shipped copy.

    Returns
    -------
    dict
        Slip angle in **degrees** (the table's key, as in ``params.TUNING_T54_GROUSERED``)
        to ``(a0, a1, b0, b1)``.

    Raises
    ------
    DatasetError
        Missing column, non-numeric or non-finite value, |beta| > 90.5 deg, duplicated beta.
    """
    p = _shipped("grouser_tuned_params.csv") if path is None else Path(path)
    header, rows = _read_table(p, "tuned-parameter")
    need = ["beta_deg", "a0", "a1", "b0", "b1"]
    missing = [c for c in need if c not in header]
    if missing:
        raise DatasetError(f"{p}: missing required column(s) {missing}; expected {need}, found {header}")
    arr = {c: _numeric_column(p, header, rows, c, None, True) for c in need}
    out: dict[float, tuple[float, float, float, float]] = {}
    for i, b in enumerate(arr["beta_deg"]):
        if abs(b) > _BETA_MAX_DEG:
            raise DatasetError(
                f"{p}: data row {i + 1}, column 'beta_deg': {float(b)!r} is outside +-{_BETA_MAX_DEG} deg; "
                "slip angles are in degrees"
            )
        if float(b) in out:
            raise DatasetError(f"{p}: data row {i + 1}, column 'beta_deg': duplicated slip angle {float(b)!r}; one row per angle")
        out[float(b)] = tuple(float(arr[c][i]) for c in ("a0", "a1", "b0", "b1"))  # type: ignore[assignment]
    return out


_TS_COLUMNS: tuple[tuple[str, str, float], ...] = (
    ("t", "t_s", 1.0),
    ("x", "x_mm", _MM),
    ("vx", "vx_mm_s", _MM),
    ("rim_speed", "rim_speed_mm_s", _MM),
    ("angle", "angle_deg", _DEG),
    ("z", "z_mm", _MM),
    ("sinkage", "sinkage_mm", _MM),
)


def load_sinkage_timeseries(path: str | Path) -> dict[str, SinkageSeries]:
    """Load the 10 Hz kinematics/sinkage time series (``grouser_sinkage_timeseries.csv.gz``).

    Not shipped with the package (2.5 MB); pass the path of the shared data file. Plain
    ``.csv`` files are read as well.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    dict
        ``trial_id`` -> :class:`SinkageSeries` (SI), runs in file order, samples sorted by time.

    Raises
    ------
    DatasetError
        Missing file or column, empty file, non-numeric / non-finite value (row and column
        named), or a repeated time stamp within a run.
    """
    p = Path(path)
    header, rows = _read_table(p, "sinkage time-series")
    need = ["trial_id"] + [c for _, c, _ in _TS_COLUMNS]
    missing = [c for c in need if c not in header]
    if missing:
        raise DatasetError(f"{p}: missing required column(s) {missing}; expected {need}, found {header}")
    jid = header.index("trial_id")
    ids = [r[jid] for r in rows]
    cols = {}
    for fname, col, factor in _TS_COLUMNS:
        j = header.index(col)
        try:
            a = np.array([r[j] if r[j] != "" else "nan" for r in rows], dtype=float)
            ok = bool(np.all(np.isfinite(a)))
        except ValueError:
            ok = False
        if not ok:  # slow path: locate the bad cell and raise with its row and column
            a = _numeric_column(p, header, rows, col, ids, True)
        cols[fname] = a * factor
    id_arr = np.array(ids, dtype=object)
    out: dict[str, SinkageSeries] = {}
    order: list[str] = list(dict.fromkeys(ids))
    for tid in order:
        if tid == "":
            raise DatasetError(f"{p}: empty trial_id in column 'trial_id'; every sample must name its run")
        m = id_arr == tid
        t = cols["t"][m]
        srt = np.argsort(t, kind="stable")
        if np.any(np.diff(t[srt]) <= 0.0):
            raise DatasetError(f"{p}: trial_id {tid!r}, column 't_s': repeated time stamp; one sample per time")
        out[tid] = SinkageSeries(tid, **{k: _readonly(v[m][srt]) for k, v in cols.items()})
    return out
