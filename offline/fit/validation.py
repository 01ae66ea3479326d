"""Validate the terramechanics model on single-wheel trials (dissertation section 5.4).

For every trial the measured load ``F_z`` is given; the sinkage that carries it is solved
(eq. 5.34) and ``F_x``, ``F_y`` and the sinkage are predicted. Errors are reported per slip
angle as in Table 5.5: forces in % of the applied load, sinkage in % of the wheel radius,
signed ``prediction - measurement``; mean +/- standard deviation over the trials, plus the
mean absolute error, which a signed mean can hide.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .dataset import TrialSet
from ..files import atomic_path, write_text
from ..physics.params import ContactTuning, Soil, TuningTable, Wheel
from ..physics.terramechanics import ModelOptions, WheelModel
from .dataset import DatasetError

__all__ = [
    "Variant",
    "Prediction",
    "ErrorRow",
    "TABLE_5_5_GROUSERED",
    "TABLE_5_5_SMOOTH",
    "REFERENCE_SETS",
    "ReferenceSet",
    "MatchedReference",
    "ValidationError",
    "load_reference",
    "wheel_kind",
    "model_kind",
    "compare_with_reference",
    "failed_conditions",
    "predict",
    "error_rows",
    "errors_percent",
    "average_conditions",
    "trial_states",
    "beats_table_5_5",
    "format_table",
    "write_csv",
    "plot_fig_5_6",
    "tuning_for_angle",
]

# Dissertation Table 5.5, grousered wheel: beta_deg -> (Fx mean, sd, Fy mean, sd, h mean, sd) in %.
TABLE_5_5_GROUSERED: dict[str, dict[float, tuple[float, ...]]] = {
    "without soil flow": {
        0.0: (7.1, 21.2, -2.3, 2.6, 5.5, 6.8),
        15.0: (9.7, 25.2, -9.1, 8.7, 3.3, 6.7),
        30.0: (11.5, 24.9, -12.4, 17.2, 2.2, 6.8),
        45.0: (12.1, 23.6, -15.5, 22.1, 3.5, 10.0),
        60.0: (10.3, 25.9, -19.7, 33.4, 4.8, 14.2),
    },
    "with soil flow": {
        0.0: (15.6, 32.3, -2.3, 2.6, 1.6, 6.4),
        15.0: (23.8, 38.5, -8.3, 10.2, -2.6, 6.4),
        30.0: (25.9, 41.0, -9.3, 17.0, -4.2, 4.3),
        45.0: (26.9, 38.2, -6.0, 17.6, -2.5, 5.7),
        60.0: (27.2, 38.4, 0.0, 22.0, -1.6, 12.6),
    },
}

# Dissertation Table 5.5, smooth wheel (same layout as TABLE_5_5_GROUSERED).
TABLE_5_5_SMOOTH: dict[str, dict[float, tuple[float, ...]]] = {
    "without soil flow": {
        0.0: (8.3, 25.7, -2.9, 2.3, 2.2, 11.9),
        15.0: (14.7, 39.7, -9.0, 10.5, 0.0, 14.2),
        30.0: (11.5, 26.8, -11.5, 20.0, -0.7, 4.5),
        45.0: (16.1, 26.1, -19.2, 26.6, -1.7, 3.6),
        60.0: (16.1, 19.2, -23.2, 26.9, -1.6, 5.8),
    },
    "with soil flow": {
        0.0: (22.3, 32.8, -2.9, 2.3, -3.1, 13.4),
        15.0: (31.2, 46.1, -8.1, 12.0, -5.9, 15.6),
        30.0: (29.5, 36.5, -8.1, 20.8, -6.4, 7.6),
        45.0: (33.6, 36.6, -11.1, 24.1, -7.9, 5.9),
        60.0: (35.4, 26.3, -4.9, 21.4, -7.7, 5.0),
    },
}

REFERENCE_SETS: dict[str, str] = {"table-5.5": "table_5_5.csv"}
_REFERENCE_TITLES = {"table-5.5": "Table 5.5"}
"""Named built-in reference sets -> file in ``offline/data`` (Table 5.5: grousered and smooth rows)."""

_REF_COLUMNS = ("wheel_kind", "model", "beta_deg", "fx_mean", "fx_sd", "fy_mean", "fy_sd", "h_mean", "h_sd")
_MODELS = ("without soil flow", "with soil flow")
_WHEEL_KINDS = ("grousered", "smooth")


class ValidationError(ValueError):
    """A validation cannot give an answer (most conditions failed, bad reference file, ...)."""


def wheel_kind(wheel: Wheel) -> str:
    """``"grousered"`` when the wheel has grousers (h_g > 0), else ``"smooth"``: the wheel rows of a reference set."""
    return "grousered" if wheel.grouser_height > 0.0 else "smooth"


def model_kind(options: ModelOptions) -> str | None:
    """The Table 5.5 model a variant corresponds to: ``"with soil flow"`` (soil-flow exit angle),
    ``"without soil flow"`` (classic exit angle, the dissertation's sidewall force), or ``None``
    (a model the table has no rows for, e.g. the Ishigami 2007 sidewall or no sidewall)."""
    if options.bulldozing != "pavlov" or options.bulldozing_scale != 1.0:
        return None
    return "with soil flow" if options.exit_angle == "soil_flow" else "without soil flow"


@dataclass(frozen=True)
class MatchedReference:
    """Reference rows that match one variant (wheel kind and model): beta_deg -> 6 numbers in %."""

    label: str
    rows: Mapping[float, tuple[float, ...]]


@dataclass(frozen=True)
class ReferenceSet:
    """Published error rows to compare validations with, per wheel kind and model.

    Attributes
    ----------
    name : str
        Built-in name or file name.
    title : str
        How printed tables name the set (``"Table 5.5"``).
    source : str
        Where the numbers come from (file name and sha256 of the file).
    rows : mapping
        ``(wheel_kind, model) -> {beta_deg: (fx_mean, fx_sd, fy_mean, fy_sd, h_mean, h_sd)}``, %.
    """

    name: str
    source: str
    rows: Mapping[tuple[str, str], Mapping[float, tuple[float, ...]]]
    title: str = ""

    def match(self, wheel: Wheel, options: ModelOptions) -> MatchedReference | None:
        """The rows for this wheel's kind and this model, or ``None`` when the set has none."""
        model = model_kind(options)
        key = (wheel_kind(wheel), model or "")
        if model is None or key not in self.rows:
            return None
        return MatchedReference(f"{self.title} {key[0]}, {model} model", self.rows[key])


def load_reference(spec: str | Path) -> ReferenceSet:
    """Load a reference set: a built-in name (:data:`REFERENCE_SETS`) or a CSV file.

    The CSV has the columns ``wheel_kind`` (grousered / smooth), ``model`` (without soil flow /
    with soil flow), ``beta_deg`` and ``fx_mean, fx_sd, fy_mean, fy_sd, h_mean, h_sd`` in %
    (forces in % of the load, sinkage in % of the wheel radius), as ``offline/data/table_5_5.csv``.

    Raises
    ------
    DatasetError
        Missing file or column, bad value (file, row and column named), duplicated row.
    """
    import hashlib

    from .dataset import _numeric_column, _read_table, _shipped

    name = str(spec)
    path = _shipped(REFERENCE_SETS[name]) if name in REFERENCE_SETS else Path(spec)
    header, body = _read_table(path, "reference")
    missing = [c for c in _REF_COLUMNS if c not in header]
    if missing:
        raise DatasetError(f"{path}: missing column(s) {missing}; expected {list(_REF_COLUMNS)}, found {header}")
    rows: dict[tuple[str, str], dict[float, tuple[float, ...]]] = {}
    nums = {c: _numeric_column(path, header, body, c, None, True) for c in _REF_COLUMNS[2:]}
    for i, r in enumerate(body):
        kind, model = r[header.index("wheel_kind")], r[header.index("model")]
        if kind not in _WHEEL_KINDS:
            raise DatasetError(f"{path}: data row {i + 1}, column 'wheel_kind': {kind!r}; expected one of {list(_WHEEL_KINDS)}")
        if model not in _MODELS:
            raise DatasetError(f"{path}: data row {i + 1}, column 'model': {model!r}; expected one of {list(_MODELS)}")
        b = float(nums["beta_deg"][i])
        block = rows.setdefault((kind, model), {})
        if b in block:
            raise DatasetError(f"{path}: data row {i + 1}: a second row for {kind}, {model}, beta_deg {b:g}")
        block[b] = tuple(float(nums[c][i]) for c in _REF_COLUMNS[3:])
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    short = name if name in REFERENCE_SETS else path.name
    return ReferenceSet(short, f"{path.name} (sha256 {digest[:12]})", rows, _REFERENCE_TITLES.get(short, path.name))


TuningSpec = ContactTuning | TuningTable | Mapping[float, ContactTuning]


def tuning_for_angle(spec: TuningSpec, beta_cmd_deg: float) -> ContactTuning | None:
    """The tuning for a commanded slip angle: the single continuous tuning, the per-angle table
    interpolated in |beta| (``None`` outside its angles), or the per-angle mapping entry within
    0.5 deg (``None`` if the mapping has no entry for that angle)."""
    if isinstance(spec, ContactTuning):
        return spec
    if isinstance(spec, TuningTable):
        b = math.radians(abs(beta_cmd_deg))
        return spec.tuning_at(b) if spec.covers(b) else None
    for b, t in spec.items():
        if abs(float(b) - abs(beta_cmd_deg)) <= 0.5:
            return t
    return None


@dataclass(frozen=True)
class Variant:
    """One model configuration to validate.

    Parameters
    ----------
    name : str
        Short identifier (CSV, plots).
    soil, wheel : Soil, Wheel
    tuning : ContactTuning or mapping
        Continuous tuning, or per-commanded-slip-angle (deg) tunings.
    options : ModelOptions
    """

    name: str
    soil: Soil
    wheel: Wheel
    tuning: TuningSpec
    options: ModelOptions = field(default_factory=ModelOptions)

    def model(self, beta_cmd_deg: float) -> WheelModel | None:
        """The wheel model for one commanded slip angle (None if no tuning covers it)."""
        t = tuning_for_angle(self.tuning, beta_cmd_deg)
        return None if t is None else WheelModel(self.soil, self.wheel, t, self.options)


@dataclass(frozen=True)
class Prediction:
    """Model predictions for every trial (NaN where the model had no tuning or failed).

    Attributes
    ----------
    Fx, Fy, sinkage : ndarray
        Predicted values (N, N, m).
    status : ndarray of str
        ``"ok"``, ``"no_tuning"`` or the sinkage solver's failure status.
    """

    variant: str
    Fx: NDArray[np.float64]
    Fy: NDArray[np.float64]
    Fz: NDArray[np.float64]
    sinkage: NDArray[np.float64]
    sinkage_zero_slip: NDArray[np.float64]
    status: NDArray[np.str_]


def trial_states(
    trials: TrialSet, angle: str = "commanded"
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Wheel-frame velocities of each trial: ``v_x = V cos(beta)``, ``v_y = -V sin(beta)``
    with the measured carriage speed V, and ``omega = V_rim / 0.058`` (the authors'
    conversion; data README).

    Parameters
    ----------
    trials : TrialSet
        The trials.
    angle : {"commanded", "measured"}
        Slip angle used. The testbed holds the commanded angle (measured within 0.3 deg),
        and the dissertation evaluates its model at the commanded angles; ``"measured"``
        uses the logged mean, clipped to [-90, 90] deg (at the 90 deg setting it reaches
        90.1 deg, which the model would read as travel against the wheel's rotation).
    """
    if angle not in ("commanded", "measured"):
        raise ValueError(f"angle must be 'commanded' or 'measured', got {angle!r}")
    v = trials.vx
    beta = np.clip(trials.beta_cmd if angle == "commanded" else trials.beta, -math.pi / 2, math.pi / 2)
    return v * np.cos(beta), -v * np.sin(beta), trials.omega()


def predict(trials: TrialSet, variant: Variant) -> Prediction:
    """Given each trial's measured load, solve the sinkage and predict the forces.

    Returns
    -------
    Prediction
    """
    n = len(trials)
    out = {k: np.full(n, np.nan) for k in ("Fx", "Fy", "Fz", "sinkage", "sinkage_zero_slip")}
    status = np.full(n, "no_tuning", dtype=object)
    vx, vy, w = trial_states(trials)
    for b in np.unique(trials.beta_cmd):
        idx = np.flatnonzero(trials.beta_cmd == b)
        m = variant.model(math.degrees(b))
        if m is None:
            continue
        sol = m.sinkage_from_load(trials.Fz[idx], vx[idx], vy[idx], w[idx])
        status[idx] = sol.status
        ok = idx[sol.converged]
        if ok.size:
            good = sol.converged
            wr = m.wrench(vx[ok], vy[ok], w[ok], sol.h[good], sol.h_zero_slip[good])
            out["Fx"][ok], out["Fy"][ok], out["Fz"][ok] = wr.Fx, wr.Fy, wr.Fz
            out["sinkage"][ok] = sol.h[good]
            out["sinkage_zero_slip"][ok] = sol.h_zero_slip[good]
    return Prediction(variant.name, status=status.astype(str), **out)


@dataclass(frozen=True)
class ErrorRow:
    """Table 5.5 row: errors at one commanded slip angle, in %."""

    variant: str
    beta_deg: float
    n: int
    n_failed: int
    fx_mean: float
    fx_sd: float
    fx_mae: float
    fy_mean: float
    fy_sd: float
    fy_mae: float
    h_mean: float
    h_sd: float
    h_mae: float


def errors_percent(trials: TrialSet, pred: Prediction, radius: float) -> dict[str, NDArray[np.float64]]:
    """Per-trial errors: forces in % of the applied load, sinkage in % of the wheel radius."""
    return {
        "Fx": 100.0 * (pred.Fx - trials.Fx) / trials.Fz,
        "Fy": 100.0 * (pred.Fy - trials.Fy) / trials.Fz,
        "sinkage": 100.0 * (pred.sinkage - trials.sinkage) / radius,
    }


def average_conditions(trials: TrialSet) -> TrialSet:
    """One row per condition (commanded slip angle and rim speed): the repeat means.

    This is how the dissertation scores its model (the published ``average_data_to_model``
    step): the model runs at each condition's mean load and speeds and is compared with the
    condition's mean forces and sinkage. The ``*_std`` fields hold the repeat spread.
    """
    conds = trials.conditions()
    nan = np.full(len(conds), np.nan)

    def col(name: str) -> NDArray[np.float64]:
        return np.array([float(np.mean(getattr(trials, name)[c.indices])) for c in conds])

    def sd(name: str) -> NDArray[np.float64]:
        return np.array([float(np.std(getattr(trials, name)[c.indices], ddof=1)) if c.n > 1 else np.nan for c in conds])

    return TrialSet(
        trial_id=np.array([f"cond_b{math.degrees(c.beta_cmd):g}_rim{c.rim_speed_cmd * 1e3:g}" for c in conds]),
        test_date=np.array([""] * len(conds)),
        repeat=np.array([c.n for c in conds]),
        beta=col("beta"), beta_cmd=np.array([c.beta_cmd for c in conds]), rim_speed=col("rim_speed"),
        rim_speed_cmd=np.array([c.rim_speed_cmd for c in conds]), vx=col("vx"),
        vx_cmd=np.array([c.vx_cmd for c in conds]), slip=col("slip"), Fx=col("Fx"), Fy=col("Fy"), Fz=col("Fz"),
        sinkage=col("sinkage"), beta_std=sd("beta"), rim_speed_std=sd("rim_speed"), vx_std=sd("vx"),
        Fx_std=sd("Fx"), Fy_std=sd("Fy"), Fz_std=sd("Fz"), sinkage_std=sd("sinkage"),
        Fx_slope=nan.copy(), Fy_slope=nan.copy(), Fz_slope=nan.copy(),
        authors_excluded=np.array([bool(np.any(trials.authors_excluded[c.indices])) for c in conds]),
        source=f"condition means of {trials.source}",
    )


def error_rows(trials: TrialSet, pred: Prediction, radius: float) -> list[ErrorRow]:
    """Summarise errors per commanded slip angle: mean, population sd (``ddof = 0``) and
    mean absolute error over the rows of ``trials``.

    Pass :func:`average_conditions` output to score as Table 5.5 does (one row per slip
    ratio); this reproduces the table's beta = 0 F_y row exactly (the model predicts
    F_y = 0 there, so the row is the data's own offset: -2.3 +/- 2.6 %). Rows whose
    prediction failed are counted in ``n_failed`` and left out.
    """
    e = errors_percent(trials, pred, radius)
    rows = []
    for b in np.unique(trials.beta_cmd):
        idx = trials.beta_cmd == b
        ok = idx & (pred.status == "ok")
        if not ok.any():
            if np.all(pred.status[idx] == "no_tuning"):
                continue  # the variant does not cover this angle
            nan = math.nan
            rows.append(ErrorRow(pred.variant, round(math.degrees(b), 3), int(idx.sum()), int(idx.sum()),
                                 nan, nan, nan, nan, nan, nan, nan, nan, nan))
            continue
        stats = []
        for ch in ("Fx", "Fy", "sinkage"):
            x = e[ch][ok]
            stats += [float(x.mean()), float(x.std(ddof=0)), float(np.abs(x).mean())]
        rows.append(ErrorRow(pred.variant, round(math.degrees(b), 3), int(idx.sum()), int((idx & ~ok).sum()), *stats))
    return rows


def beats_table_5_5(row: ErrorRow, reference: str = "without soil flow", wheel: str = "grousered") -> dict[str, bool] | None:
    """Whether a row is at least as good as Table 5.5 (|mean| and sd no larger), per channel.

    ``wheel`` selects the table's grousered or smooth rows (see :func:`wheel_kind`)."""
    table = TABLE_5_5_GROUSERED if wheel == "grousered" else TABLE_5_5_SMOOTH
    return compare_with_reference(row, table[reference])


def failed_conditions(rows: Sequence[ErrorRow]) -> dict[str, tuple[int, int]]:
    """Per variant: (conditions whose prediction failed, conditions scored)."""
    out: dict[str, tuple[int, int]] = {}
    for r in rows:
        f, n = out.get(r.variant, (0, 0))
        out[r.variant] = (f + r.n_failed, n + r.n)
    return out


def compare_with_reference(row: ErrorRow, reference: Mapping[float, tuple[float, ...]]) -> dict[str, bool] | None:
    """Whether a row is at least as good as the reference row at its slip angle (|mean| and
    sd no larger, at the reference's printed precision), per channel; ``None`` if there is
    no reference row for that angle. A row with failed predictions is never "as good"."""
    ref = reference.get(row.beta_deg)
    if ref is None:
        return None
    # compared at the table's printed precision (one decimal)
    def le(a: float, b: float) -> bool:
        return round(a, 1) <= b + 1e-9

    ok = row.n_failed == 0
    return {
        "Fx": ok and le(abs(row.fx_mean), abs(ref[0])) and le(row.fx_sd, ref[1]),
        "Fy": ok and le(abs(row.fy_mean), abs(ref[2])) and le(row.fy_sd, ref[3]),
        "sinkage": ok and le(abs(row.h_mean), abs(ref[4])) and le(row.h_sd, ref[5]),
    }


def format_table(
    rows: Sequence[ErrorRow], reference: str | None | Mapping[str, MatchedReference | None] = "auto"
) -> str:
    """Plain-text table laid out like Table 5.5, with the reference row beside ours.

    ``reference`` is a mapping ``variant name -> MatchedReference`` (or ``None``: no
    comparison for that variant), as the CLI builds from :meth:`ReferenceSet.match`, so
    each variant is marked only against the rows of its own wheel kind and model.
    ``"auto"`` (legacy) compares by name with the grousered rows of Table 5.5; ``None``
    omits every comparison.
    """
    lines = []
    by_variant: dict[str, list[ErrorRow]] = {}
    for r in rows:
        by_variant.setdefault(r.variant, []).append(r)
    hdr = f"{'beta':>6} {'n':>3}  {'Fx err (%)':>14} {'|Fx|':>6}  {'Fy err (%)':>14} {'|Fy|':>6}  {'h0 err (%)':>14} {'|h0|':>6}"
    for variant, vrows in by_variant.items():
        matched: MatchedReference | None = None
        if reference == "auto":
            ref_name = "with soil flow" if "soil-flow" in variant or "soil flow" in variant else "without soil flow"
            matched = MatchedReference(f"Table 5.5 grousered, {ref_name} model", TABLE_5_5_GROUSERED[ref_name])
        elif isinstance(reference, Mapping):
            matched = reference.get(variant)
        elif reference is not None:
            raise ValueError(f"reference must be 'auto', None or a mapping of variant name to MatchedReference, got {reference!r}")
        lines += [f"== {variant} ==" + (f"  (T5.5: {matched.label})" if matched else "  (no matching reference rows)"
                                        if reference is not None else ""), hdr]
        for r in vrows:
            fail = f"  ({r.n_failed} failed)" if r.n_failed else ""
            lines.append(
                f"{r.beta_deg:>5.0f}° {r.n:>3}  {r.fx_mean:>6.1f} ± {r.fx_sd:<5.1f} {r.fx_mae:>6.1f}  "
                f"{r.fy_mean:>6.1f} ± {r.fy_sd:<5.1f} {r.fy_mae:>6.1f}  {r.h_mean:>6.1f} ± {r.h_sd:<5.1f} {r.h_mae:>6.1f}{fail}"
            )
            if matched is not None:
                ref = matched.rows.get(r.beta_deg)
                if ref is not None:
                    ok = compare_with_reference(r, matched.rows) or {}
                    mark = " ".join(f"{k}:{'ok' if v else 'WORSE'}" for k, v in ok.items())
                    lines.append(
                        f"{'T5.5':>6} {'':>3}  {ref[0]:>6.1f} ± {ref[1]:<5.1f} {'':>6}  {ref[2]:>6.1f} ± {ref[3]:<5.1f} {'':>6}  "
                        f"{ref[4]:>6.1f} ± {ref[5]:<5.1f}   [{mark}]"
                    )
        lines.append("")
    return "\n".join(lines)


def write_csv(rows: Sequence[ErrorRow], path: str | Path) -> Path:
    """Write the error rows (one per variant and slip angle) to CSV."""
    import io

    names = list(ErrorRow.__dataclass_fields__)
    buf = io.StringIO()
    wr = csv.writer(buf, lineterminator="\n")
    wr.writerow(names)
    for r in rows:
        wr.writerow([getattr(r, k) for k in names])
    return write_text(Path(path), buf.getvalue())  # atomic


def plot_fig_5_6(
    trials: TrialSet,
    variants: Sequence[Variant],
    path: str | Path,
    predictions: Sequence[Prediction] | None = None,
    title: str = "",
) -> Path:
    """Fig. 5.6-style figure: one row per slip angle, columns F_x, F_y, sinkage vs slip ratio.

    Measured trials are points; each variant is drawn as its per-trial predictions joined
    in slip order (the load differs from trial to trial, so a smooth model line at one load
    would not be what the table scores).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    preds = list(predictions) if predictions is not None else [predict(trials, v) for v in variants]
    betas = np.unique(trials.beta_cmd)
    fig, axes = plt.subplots(len(betas), 3, figsize=(11, 2.2 * len(betas) + 0.6), sharex=True, squeeze=False)

    def style(k: int, v: Variant) -> tuple[str, str]:
        # Fig. 5.6: classic exit angle green solid, soil flow red dashed, Ishigami blue dotted
        if v.options.bulldozing == "ishigami":
            return ":", "tab:blue"
        if v.options.exit_angle == "soil_flow":
            return "--", "tab:red"
        return ("-", "tab:green") if k == 0 else ("-.", "tab:purple")

    for i, b in enumerate(betas):
        idx = np.flatnonzero(trials.beta_cmd == b)
        order = idx[np.argsort(trials.slip[idx], kind="stable")]
        for j, (ch, scale, unit) in enumerate((("Fx", 1.0, "N"), ("Fy", 1.0, "N"), ("sinkage", 1e3, "mm"))):
            ax = axes[i, j]
            ax.plot(trials.slip[idx], getattr(trials, ch)[idx] * scale, "k.", ms=5, label="measured")
            for k, (p, v) in enumerate(zip(preds, variants)):
                y = getattr(p, ch)[order] * scale
                s_ = trials.slip[order]
                # mean over repeats at each slip for a readable line
                us = np.unique(np.round(s_, 3))
                ym = [np.mean(v_) if (v_ := y[(np.round(s_, 3) == u) & np.isfinite(y)]).size else np.nan for u in us]
                ls, col = style(k, v)
                ax.plot(us, ym, ls, color=col, lw=1.5, label=p.variant)
            ax.set_ylabel(f"{ch} [{unit}]" if ch != "sinkage" else "sinkage [mm]")
            if j == 0:
                ax.text(0.02, 0.85, f"β = {math.degrees(b):.0f}°", transform=ax.transAxes, fontsize=9, weight="bold")
            ax.grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    top = 1.0 - 0.3 / fig.get_figheight()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, top), ncol=min(len(labels), 4), fontsize=9,
               frameon=False)
    if title:
        fig.suptitle(title, y=0.998, fontsize=10)
    for ax in axes[-1]:
        ax.set_xlabel("slip ratio s")
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.7 / fig.get_figheight()))
    out = Path(path)
    try:
        with atomic_path(out) as tmp:  # written whole or not at all
            fig.savefig(tmp, dpi=110, format=out.suffix.lstrip(".") or "png")
    finally:
        plt.close(fig)
    return out
