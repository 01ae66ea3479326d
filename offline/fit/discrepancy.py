"""Discrepancy tool: locate where model and recordings disagree, name the missing physics,
model it, and show the fit improve on held-out data.

Pipeline (:func:`diagnose`)
---------------------------
1. **Residuals.** The model (a parameter set and model options) predicts every recorded
   condition; residuals ``measured - predicted`` per channel are normalised by the
   measurement noise (the pooled repeat spread divided by sqrt(repeats); a documented
   fallback when there are no repeats).
2. **Locate.** An exhaustive search over one- and two-feature boxes (intervals between
   quantiles of slip ratio, |slip angle|, sinkage, load, rim speed) finds the region whose
   summed normalised residual is largest, ``Z = sum(z) / sqrt(n)``. Its significance is a
   Monte-Carlo test of the *maximum* Z over all boxes under the null of exchangeable
   Gaussian residuals at a robust scale (MAD of z, at least 1), so the many boxes searched
   are accounted for and the model's general misfit level is not mistaken for a region. Significant regions are reported with their magnitude in
   physical units (mean residual +/- standard error); up to three per channel, each found
   after the previous one is explained away (its mean removed).
3. **Explain.** A library of candidate physics, each a real model extension with physical
   parameters and bounds (:data:`CANDIDATES`), is fitted by least squares. Candidates are
   screened in-sample, then the best are scored by grouped K-fold cross-validation; the
   decision criterion is ``chi2_cv(base) - chi2_cv(candidate) > 2 k`` (held-out AIC-like
   penalty, k parameters) together with a one-sided paired t-test over conditions at
   ``p < 0.01``. Forward selection adds a second term if it passes the same criterion on
   top of the first. When nothing passes but significant regions remain, a sparse
   regression over physically motivated features (sequentially thresholded least squares,
   SINDy-like) is fitted per channel and labelled *unexplained*.
4. **Prove.** :meth:`Verdict.write` writes a report folder: ``report.md``, PNG residual maps
   before and after, measured-vs-predicted plots, and ``verdict.json``.

The recording side is an adapter (:class:`SingleWheelRecording` for testbed trials); rover
drive logs will plug in with their own adapter exposing the same fields.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .dataset import TrialSet
from ..physics.params import ParameterSet
from ..physics.terramechanics import ModelOptions, WheelModel, bulldozing_resistance
from ..physics.backend import NUMPY
from .validation import average_conditions, trial_states

__all__ = [
    "SingleWheelRecording",
    "Extension",
    "Candidate",
    "CANDIDATES",
    "Region",
    "CandidateScore",
    "Verdict",
    "diagnose",
    "predict_recording",
]

CHANNELS = ("Fx", "Fy", "sinkage")
UNITS = {"Fx": "N", "Fy": "N", "sinkage": "mm"}
SCALE_OUT = {"Fx": 1.0, "Fy": 1.0, "sinkage": 1e3}


# ------------------------------------------------------------------------- recordings
@dataclass(frozen=True)
class SingleWheelRecording:
    """Single-wheel testbed recordings, one row per condition (repeat means).

    Attributes
    ----------
    vx, vy, omega, load : ndarray
        Wheel-frame state and measured load of each row (SI).
    measured : dict
        ``{"Fx", "Fy", "sinkage"}`` arrays (N, N, m).
    noise : dict
        Per-row noise standard deviation of each channel (the pooled repeat spread over
        sqrt(n_repeats)).
    features : dict
        Operating-point features for locating regions: ``slip``, ``abs_beta_deg``,
        ``sinkage_mm`` (measured), ``load_N``, ``rim_speed_mm_s``.
    beta_cmd : ndarray
        Commanded slip angle (rad) for stratified folds.
    travel : ndarray
        Distance travelled when the window was recorded, m (for the transient candidate).
    noise_source : str
        How the noise was estimated.
    """

    vx: NDArray[np.float64]
    vy: NDArray[np.float64]
    omega: NDArray[np.float64]
    load: NDArray[np.float64]
    measured: dict[str, NDArray[np.float64]]
    noise: dict[str, NDArray[np.float64]]
    features: dict[str, NDArray[np.float64]]
    beta_cmd: NDArray[np.float64]
    travel: NDArray[np.float64]
    noise_source: str
    source: str = ""

    def __len__(self) -> int:
        return self.vx.size

    @classmethod
    def from_trials(cls, trials: TrialSet, window_time: float = 72.5) -> "SingleWheelRecording":
        """Average repeats per condition and attach the noise level.

        The noise of a condition mean is the pooled repeat spread divided by sqrt(n). With
        no repeats anywhere, 5 % of the median load (forces) and 2 mm (sinkage) are used and
        the report says so.
        """
        avg = average_conditions(trials)
        nrep = np.maximum(avg.repeat.astype(float), 1.0)
        try:
            nz = trials.noise()
            src = f"pooled repeat spread over {int(nz['dof'])} degrees of freedom"
        except Exception:
            med = float(np.median(trials.Fz))
            nz = {"Fx": 0.05 * med, "Fy": 0.05 * med, "sinkage": 2e-3}
            src = "no repeats: assumed 5 % of the median load for forces and 2 mm for sinkage"
        vx, vy, w = trial_states(avg)
        return cls(
            vx=vx, vy=vy, omega=w, load=avg.Fz.copy(),
            measured={"Fx": avg.Fx.copy(), "Fy": avg.Fy.copy(), "sinkage": avg.sinkage.copy()},
            noise={ch: np.full(len(avg), nz[ch]) / np.sqrt(nrep) for ch in CHANNELS},
            features={
                "slip": avg.slip.copy(),
                "abs_beta_deg": np.abs(np.degrees(avg.beta_cmd)),
                "sinkage_mm": avg.sinkage * 1e3,
                "load_N": avg.Fz.copy(),
                "rim_speed_mm_s": avg.rim_speed * 1e3,
            },
            beta_cmd=avg.beta_cmd.copy(), travel=avg.vx * window_time, noise_source=src, source=str(trials.source),
        )

    def subset(self, idx: NDArray[np.int_]) -> "SingleWheelRecording":
        """Rows ``idx`` only."""
        return replace(
            self, vx=self.vx[idx], vy=self.vy[idx], omega=self.omega[idx], load=self.load[idx],
            measured={k: v[idx] for k, v in self.measured.items()}, noise={k: v[idx] for k, v in self.noise.items()},
            features={k: v[idx] for k, v in self.features.items()}, beta_cmd=self.beta_cmd[idx], travel=self.travel[idx],
        )

    def with_measured(self, measured: Mapping[str, NDArray[np.float64]]) -> "SingleWheelRecording":
        """Same conditions, other measurements (for synthetic studies)."""
        m = {k: np.asarray(v, dtype=float).copy() for k, v in measured.items()}
        feats = dict(self.features)
        feats["sinkage_mm"] = m["sinkage"] * 1e3
        return replace(self, measured=m, features=feats)


# ------------------------------------------------------------------------- extensions
@dataclass(frozen=True)
class Extension:
    """A model extension: changes to parameters, inputs and outputs. Defaults change nothing.

    Attributes
    ----------
    soil, wheel, tuning : dict
        Field replacements (SI) of the base :class:`~offline.physics.params.Soil`, ``Wheel``,
        ``ContactTuning``.
    options : dict
        Field replacements of :class:`~offline.physics.terramechanics.ModelOptions`.
    beta_offset : float
        Steering offset added to every slip angle, rad.
    omega_max : float
        Actuator speed saturation, rad/s (the wheel turns at most this fast).
    hub_clearance, hub_width : float
        A hub or body that ploughs the soil once the sinkage passes the clearance (m): a
        passive-earth-pressure blade of that width (eq. 5.24 form) resisting the travel.
    force_along : float
        External force along the travel direction on the wheel (tether, cable), N.
    tilt : float
        Unmodelled slope or sensor tilt in the x-z plane, rad: the measured F_x picks up
        ``F_z sin(tilt)``.
    sinkage_relaxation : float
        Sinkage relaxation length, m: the recorded sinkage is
        ``h (1 - exp(-travel / length))`` (not yet at steady state).
    """

    soil: Mapping[str, float] = field(default_factory=dict)
    wheel: Mapping[str, float] = field(default_factory=dict)
    tuning: Mapping[str, float] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)
    beta_offset: float = 0.0
    omega_max: float = math.inf
    hub_clearance: float = math.inf
    hub_width: float = 0.0
    force_along: float = 0.0
    tilt: float = 0.0
    sinkage_relaxation: float = 0.0

    def merge(self, other: "Extension") -> "Extension":
        """Both extensions at once (the other's non-default fields win)."""
        d = Extension()
        kw: dict[str, Any] = {}
        for f in ("soil", "wheel", "tuning", "options"):
            kw[f] = {**getattr(self, f), **getattr(other, f)}
        for f in ("beta_offset", "omega_max", "hub_clearance", "hub_width", "force_along", "tilt", "sinkage_relaxation"):
            kw[f] = getattr(other, f) if getattr(other, f) != getattr(d, f) else getattr(self, f)
        return Extension(**kw)


def predict_recording(
    params: ParameterSet, options: ModelOptions, rec: SingleWheelRecording, ext: Extension | None = None
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
    """Predict every row of ``rec`` with the (extended) model, the load given.

    Returns
    -------
    predicted : dict
        ``Fx``, ``Fy`` (N), ``sinkage`` (m); NaN where the model cannot carry the load.
    ok : ndarray of bool
    """
    ext = ext or Extension()
    soil = replace(params.soil, **ext.soil)
    wheel = replace(params.wheel, **ext.wheel)
    tuning = replace(params.tuning, **ext.tuning)
    opts = replace(options, **ext.options)
    model = WheelModel(soil, wheel, tuning, opts)
    vx, vy, w = rec.vx, rec.vy, rec.omega
    if ext.beta_offset:
        c, s = math.cos(ext.beta_offset), math.sin(ext.beta_offset)
        # travel fixed, wheel turned by the offset: rotate the velocity into the new heading
        vx, vy = c * vx - s * vy, s * vx + c * vy
        vx = np.maximum(vx, 0.0)
    if math.isfinite(ext.omega_max):
        w = np.sign(w) * np.minimum(np.abs(w), ext.omega_max)
    sol = model.sinkage_from_load(rec.load, vx, vy, w)
    ok = sol.converged
    out = {ch: np.full(len(rec), np.nan) for ch in CHANNELS}
    if ok.any():
        wr = model.wrench(vx[ok], vy[ok], w[ok], sol.h[ok], sol.h_zero_slip[ok])
        out["Fx"][ok], out["Fy"][ok], out["sinkage"][ok] = wr.Fx, wr.Fy, sol.h[ok]
        fz = wr.Fz
        v = np.hypot(vx[ok], vy[ok])
        if ext.hub_width > 0 and math.isfinite(ext.hub_clearance):
            depth = np.maximum(sol.h[ok] - ext.hub_clearance, 0.0)
            drag = ext.hub_width * bulldozing_resistance(NUMPY, depth, soil.unit_weight, soil.cohesion, soil.friction_angle, "pavlov")
            out["Fx"][ok] -= drag * vx[ok] / v
            out["Fy"][ok] -= drag * vy[ok] / v
        if ext.force_along:
            out["Fx"][ok] += ext.force_along * vx[ok] / v
            out["Fy"][ok] += ext.force_along * vy[ok] / v
        if ext.tilt:
            out["Fx"][ok] += fz * math.sin(ext.tilt)
        if ext.sinkage_relaxation > 0:
            out["sinkage"][ok] *= 1.0 - np.exp(-rec.travel[ok] / ext.sinkage_relaxation)
    return out, ok


# ------------------------------------------------------------------------- candidates
@dataclass(frozen=True)
class Candidate:
    """One candidate piece of missing physics.

    Attributes
    ----------
    key : str
        Identifier.
    physics : str
        What physics the base model left out (report text).
    params : tuple
        ``(name, unit, lower, upper, start, to_si)``; ``to_si`` converts the reported unit
        to SI.
    build : callable
        ``theta (SI) -> Extension``.
    channels : tuple of str
        Channels the term acts on (for the report).
    """

    key: str
    physics: str
    params: tuple[tuple[str, str, float, float, float, float], ...]
    build: Callable[[NDArray[np.float64], ParameterSet], Extension]
    channels: tuple[str, ...] = CHANNELS
    family: str = ""
    """Candidates of one family change the same model part and are never combined."""

    @property
    def k(self) -> int:
        return len(self.params)


def _deg(x: float) -> float:
    return math.radians(x)


CANDIDATES: tuple[Candidate, ...] = (
    Candidate(
        "sidewall_bulldozing",
        "sidewall bulldozing: passive earth pressure on the wheel face, eqs. (5.22)-(5.27); "
        "scale 1 is the published form, 0 is no sidewall force",
        (("scale", "-", 0.0, 4.0, 1.0, 1.0),),
        lambda t, p: Extension(options={"bulldozing": "pavlov", "bulldozing_scale": float(t[0])}),
        ("Fy", "Fx"),
        "bulldozing",
    ),
    Candidate(
        "sidewall_bulldozing_ishigami",
        "sidewall bulldozing in the Ishigami 2007 form, eq. (5.29)",
        (("scale", "-", 0.0, 4.0, 1.0, 1.0),),
        lambda t, p: Extension(options={"bulldozing": "ishigami", "bulldozing_scale": float(t[0])}),
        ("Fy", "Fx"),
        "bulldozing",
    ),
    Candidate(
        "slip_skid_sinkage",
        "slip- and skid-sinkage: the sinkage exponent grows with |slip|, eq. (5.6) (n1, n2)",
        (("n1", "-", 0.0, 2.0, 0.1, 1.0), ("n2", "-", 0.0, 2.0, 0.5, 1.0)),
        lambda t, p: Extension(soil={"n1": float(t[0]), "n2": float(t[1])}),
        ("sinkage", "Fx"),
    ),
    Candidate(
        "rear_contact",
        "rear contact: the exit angle theta_r = theta_f (b0 + b1 s), eq. (5.4)",
        (("b0", "-", -1.0, 0.0, -0.5, 1.0), ("b1", "-", -1.0, 0.0, -0.2, 1.0)),
        lambda t, p: Extension(tuning={"b0": float(t[0]), "b1": float(t[1])}),
    ),
    Candidate(
        "grouser_shearing_radius",
        "grouser shearing radius: soil fails at r_s = r + h_g (section 5.2)",
        (("h_g", "mm", 0.0, 20.0, 5.0, 1e-3),),
        lambda t, p: Extension(wheel={"grouser_height": float(t[0])}),
    ),
    Candidate(
        "cohesion",
        "soil cohesion c in the shear strength (5.10) and passive pressure (5.22)",
        (("c", "kPa", 0.0, 10.0, 1.0, 1e3),),
        lambda t, p: Extension(soil={"cohesion": float(t[0])}),
    ),
    Candidate(
        "hub_drag",
        "a hub or body dragging in the soil once the sinkage passes a clearance "
        "(passive-pressure blade, eq. 5.24 form, resisting the travel)",
        (("clearance", "mm", 0.0, 120.0, 40.0, 1e-3), ("width", "mm", 0.0, 300.0, 30.0, 1e-3)),
        lambda t, p: Extension(hub_clearance=float(t[0]), hub_width=float(t[1])),
        ("Fx", "Fy"),
    ),
    Candidate(
        "external_force",
        "an external force along the travel direction: tether, cable or towing rig",
        (("force", "N", -30.0, 30.0, 0.0, 1.0),),
        lambda t, p: Extension(force_along=float(t[0])),
        ("Fx", "Fy"),
    ),
    Candidate(
        "slope_or_tilt",
        "an unmodelled slope or sensor tilt: the measured F_x picks up F_z sin(angle)",
        (("angle", "deg", -15.0, 15.0, 0.0, math.pi / 180),),
        lambda t, p: Extension(tilt=float(t[0])),
        ("Fx",),
    ),
    Candidate(
        "wheel_radius",
        "a changed effective wheel radius (wear, deflection, wrong geometry)",
        (("radius_change", "%", -20.0, 20.0, 0.0, 1e-2),),
        lambda t, p: Extension(wheel={"radius": p.wheel.radius * (1.0 + float(t[0]))}),
    ),
    Candidate(
        "steering_offset",
        "a steering offset: the wheel's true slip angle differs from the recorded one",
        (("offset", "deg", -15.0, 15.0, 0.0, math.pi / 180),),
        lambda t, p: Extension(beta_offset=float(t[0])),
    ),
    Candidate(
        "speed_saturation",
        "actuator speed saturation: the wheel cannot turn faster than a limit",
        (("omega_max", "rad/s", 0.05, 5.0, 1.0, 1.0),),
        lambda t, p: Extension(omega_max=float(t[0])),
    ),
    Candidate(
        "sinkage_transient",
        "sinkage not at steady state: recorded sinkage h (1 - exp(-travel / length))",
        (("length", "m", 0.01, 5.0, 0.3, 1.0),),
        lambda t, p: Extension(sinkage_relaxation=float(t[0])),
        ("sinkage",),
    ),
)


# ------------------------------------------------------------------------- locate
@dataclass(frozen=True)
class Region:
    """A region of the operating space with a significant residual."""

    channel: str
    bounds: dict[str, tuple[float, float]]
    n: int
    mean: float
    stderr: float
    z: float
    p_value: float

    def describe(self) -> str:
        verb = "under-predicted" if self.mean > 0 else "over-predicted"
        parts = []
        for f, (lo, hi) in self.bounds.items():
            nice = {"slip": "slip", "abs_beta_deg": "|beta| (deg)", "sinkage_mm": "sinkage (mm)", "load_N": "load (N)",
                    "rim_speed_mm_s": "rim speed (mm/s)"}[f]
            parts.append(f"{lo:.3g} <= {nice} <= {hi:.3g}")
        u = UNITS[self.channel]
        return (f"{self.channel} {verb} by {abs(self.mean):.3g} ± {self.stderr:.2g} {u} for "
                f"{' and '.join(parts)} ({self.n} conditions, Z = {self.z:.1f}, p = {self.p_value:.3g})")


def _boxes(features: Mapping[str, NDArray[np.float64]], n_cuts: int = 6) -> tuple[NDArray[np.bool_], list[dict[str, tuple[float, float]]]]:
    """All one- and two-feature interval boxes between quantile cut points."""
    names = [k for k, v in features.items() if np.ptp(v) > 0]
    intervals: dict[str, list[tuple[NDArray[np.bool_], tuple[float, float]]]] = {}
    for f in names:
        x = features[f]
        cuts = np.unique(np.quantile(x, np.linspace(0, 1, n_cuts + 1)))
        ivs = []
        for i in range(len(cuts)):
            for j in range(i + 1, len(cuts)):
                lo, hi = cuts[i], cuts[j]
                if i == 0 and j == len(cuts) - 1:
                    continue  # everything
                ivs.append(((x >= lo) & (x <= hi), (float(lo), float(hi))))
        intervals[f] = ivs
    masks, desc = [], []
    for f in names:
        for m, b in intervals[f]:
            masks.append(m)
            desc.append({f: b})
    for a in range(len(names)):
        for b_ in range(a + 1, len(names)):
            for m1, d1 in intervals[names[a]]:
                for m2, d2 in intervals[names[b_]]:
                    m = m1 & m2
                    if m.sum() >= 3:
                        masks.append(m)
                        desc.append({names[a]: d1, names[b_]: d2})
    return np.array(masks), desc


_PRIORITY = {"abs_beta_deg": 0, "slip": 1, "sinkage_mm": 2, "load_N": 3, "rim_speed_mm_s": 4}


def locate(
    z: NDArray[np.float64], raw: NDArray[np.float64], features: Mapping[str, NDArray[np.float64]], channel: str,
    rng: np.random.Generator, alpha: float = 0.01, max_regions: int = 3, n_perm: int = 400, min_rows: int = 3,
) -> list[Region]:
    """Significant regions of one channel's residuals (see module docstring, step 2)."""
    ok = np.isfinite(z)
    z, raw = z[ok], raw[ok]
    feats = {k: v[ok] for k, v in features.items()}
    if z.size < 6:
        return []
    masks, desc = _boxes(feats)
    counts = masks.sum(axis=1)
    keep = counts >= min_rows
    masks, counts = masks[keep].astype(float), counts[keep]
    desc = [d for d, k in zip(desc, keep) if k]
    regions: list[Region] = []
    zc = z.copy()
    rawc = raw.copy()
    for _ in range(max_regions):
        # Null: the normalised residuals are exchangeable Gaussian noise at a robust scale
        # (MAD, never below 1: the model cannot beat the measurement noise). The maximum of
        # Z over all boxes under that null is simulated, so the many boxes are accounted for,
        # and a few conditions far outside the noise still count as evidence.
        scale = max(1.0, 1.4826 * float(np.median(np.abs(zc - np.median(zc)))))
        stat = masks @ zc / np.sqrt(counts)
        # among boxes selecting the same conditions, describe with the fewest and most
        # telling features (slip angle, slip, sinkage, load, rim speed)
        top = np.flatnonzero(np.abs(stat) >= np.abs(stat).max() * (1 - 1e-9))
        best = int(min(top, key=lambda i: (len(desc[i]), min(_PRIORITY.get(f, 9) for f in desc[i]))))
        draws = rng.normal(0.0, scale, size=(n_perm, zc.size))
        null = np.abs(draws @ masks.T / np.sqrt(counts)).max(axis=1)
        p = (1 + np.sum(null >= abs(stat[best]))) / (n_perm + 1)
        if p > alpha:
            break
        m = masks[best] > 0
        vals = rawc[m]
        regions.append(Region(channel, desc[best], int(m.sum()), float(vals.mean()),
                              float(vals.std(ddof=1) / math.sqrt(m.sum())) if m.sum() > 1 else math.nan,
                              float(stat[best]), float(p)))
        zc[m] -= zc[m].mean()  # explained away
        rawc[m] -= rawc[m].mean()
    return regions


# ------------------------------------------------------------------------- explain
@dataclass(frozen=True)
class CandidateScore:
    """A fitted candidate (or combination) and its scores."""

    keys: tuple[str, ...]
    physics: tuple[str, ...]
    names: tuple[str, ...]
    units: tuple[str, ...]
    values: tuple[float, ...]
    std_errors: tuple[float, ...]
    k: int
    chi2_in: float
    chi2_cv: float
    delta_cv: float
    p_paired: float
    accepted: bool
    seconds: float


def _normalised(pred: Mapping[str, NDArray[np.float64]], rec: SingleWheelRecording, fail_z: float) -> NDArray[np.float64]:
    cols = []
    for ch in CHANNELS:
        zz = (rec.measured[ch] - pred[ch]) / rec.noise[ch]
        cols.append(np.where(np.isfinite(zz), zz, fail_z))
    return np.stack(cols, axis=1)


def _fit(
    cands: Sequence[Candidate], params: ParameterSet, options: ModelOptions, rec: SingleWheelRecording, fail_z: float,
    x0: NDArray[np.float64] | None = None, max_nfev: int = 25,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float, NDArray[np.float64]]:
    """Least-squares fit of the candidates' parameters (in reported units)."""
    from scipy.optimize import least_squares

    specs = [q for c in cands for q in c.params]
    lb = np.array([q[2] for q in specs])
    ub = np.array([q[3] for q in specs])
    start = np.array([q[4] for q in specs]) if x0 is None else x0
    start = np.clip(start, lb + 1e-6 * (ub - lb), ub - 1e-6 * (ub - lb))
    conv = np.array([q[5] for q in specs])

    def ext_of(x: NDArray[np.float64]) -> Extension:
        e = Extension()
        i = 0
        for c in cands:
            e = e.merge(c.build(x[i:i + c.k] * conv[i:i + c.k], params))
            i += c.k
        return e

    def resid(x: NDArray[np.float64]) -> NDArray[np.float64]:
        pred, _ = predict_recording(params, options, rec, ext_of(x))
        return _normalised(pred, rec, fail_z).ravel()

    res = least_squares(resid, start, bounds=(lb, ub), diff_step=1e-3, max_nfev=max_nfev, x_scale=(ub - lb) * 0.1)
    r = res.fun
    dof = max(r.size - len(specs), 1)
    s2 = max(float(r @ r) / dof, 1.0)
    try:
        se = np.sqrt(np.clip(np.diag(np.linalg.pinv(res.jac.T @ res.jac)) * s2, 0, None))
    except np.linalg.LinAlgError:
        se = np.full(len(specs), np.nan)
    return res.x, se, float(r @ r), r.reshape(-1, len(CHANNELS))


def _folds(rec: SingleWheelRecording, k: int) -> NDArray[np.int_]:
    """Fold of each row, stratified by commanded slip angle (rows are conditions)."""
    fold = np.empty(len(rec), dtype=int)
    for b in np.unique(rec.beta_cmd):
        idx = np.flatnonzero(rec.beta_cmd == b)
        order = idx[np.argsort(rec.features["slip"][idx])]
        fold[order] = np.arange(order.size) % k
    return fold


def _cv(
    cands: Sequence[Candidate], params: ParameterSet, options: ModelOptions, rec: SingleWheelRecording, folds: NDArray[np.int_],
    fail_z: float, x_full: NDArray[np.float64] | None,
) -> NDArray[np.float64]:
    """Held-out squared normalised residual of every row (summed over channels)."""
    out = np.empty(len(rec))
    for f in np.unique(folds):
        tr, te = np.flatnonzero(folds != f), np.flatnonzero(folds == f)
        if cands:
            x, _, _, _ = _fit(cands, params, options, rec.subset(tr), fail_z, x0=x_full, max_nfev=12)
            conv = np.array([q[5] for c in cands for q in c.params])
            e = Extension()
            i = 0
            for c in cands:
                e = e.merge(c.build(x[i:i + c.k] * conv[i:i + c.k], params))
                i += c.k
        else:
            e = Extension()
        sub = rec.subset(te)
        pred, _ = predict_recording(params, options, sub, e)
        out[te] = (_normalised(pred, sub, fail_z) ** 2).sum(axis=1)
    return out


def _paired_p(base: NDArray[np.float64], cand: NDArray[np.float64]) -> float:
    """One-sided paired t-test that the candidate lowers the held-out squared error."""
    from scipy import stats

    d = base - cand
    if np.allclose(d, 0):
        return 1.0
    t = d.mean() / (d.std(ddof=1) / math.sqrt(d.size))
    return float(stats.t.sf(t, d.size - 1))


@dataclass(frozen=True)
class SparseTerm:
    """One fitted term of the unexplained sparse residual model."""

    channel: str
    formula: str
    coefficients: dict[str, float]
    chi2_cv_before: float
    chi2_cv_after: float


def _sparse_fit(rec: SingleWheelRecording, resid: Mapping[str, NDArray[np.float64]], folds: NDArray[np.int_]) -> list[SparseTerm]:
    """SINDy-like sequentially thresholded least squares over physical features."""
    s = rec.features["slip"]
    sb = np.sin(np.radians(rec.features["abs_beta_deg"]))
    h = rec.features["sinkage_mm"] * 1e-3
    W = rec.load
    # residual units: N for forces, m for sinkage; h in m, W in N
    lib = {"1": np.ones_like(s), "s": s, "s^2": s**2, "|s|": np.abs(s), "sin b": sb, "sin^2 b": sb**2, "h": h,
           "h^2": h**2, "W": W, "s h": s * h, "h sin b": h * sb, "h^2 sin b": h**2 * sb}
    names = list(lib)
    X = np.stack([lib[n] for n in names], axis=1)
    scale = np.abs(X).max(axis=0) + 1e-12
    Xs = X / scale
    out = []
    for ch in CHANNELS:
        y = resid[ch]
        wgt = 1.0 / rec.noise[ch]
        ok = np.isfinite(y)
        if ok.sum() < 8:
            continue

        def stlsq(rows: NDArray[np.bool_], thr: float) -> NDArray[np.float64]:
            A = Xs[rows] * wgt[rows, None]
            b = y[rows] * wgt[rows]
            coef = np.linalg.lstsq(A, b, rcond=None)[0]
            for _ in range(10):
                small = np.abs(coef) < thr * np.abs(coef).max()
                coef[small] = 0
                big = ~small
                if not big.any():
                    break
                coef[big] = np.linalg.lstsq(A[:, big], b, rcond=None)[0]
            return coef

        best = None
        before = float(np.sum((y[ok] * wgt[ok]) ** 2))
        for thr in (0.05, 0.1, 0.2, 0.4):
            err = 0.0
            for f in np.unique(folds):
                tr, te = ok & (folds != f), ok & (folds == f)
                c = stlsq(tr, thr)
                err += float(np.sum(((y[te] - Xs[te] @ c) * wgt[te]) ** 2))
            if best is None or err < best[0]:
                best = (err, thr)
        assert best is not None
        if best[0] > 0.8 * before:
            continue  # no sparse form predicts held-out data clearly better than nothing
        coef = stlsq(ok, best[1]) / scale
        terms = {n: float(c) for n, c in zip(names, coef) if c != 0}
        formula = " + ".join(f"{c:.3g}·{n}" if n != "1" else f"{c:.3g}" for n, c in terms.items())
        out.append(SparseTerm(ch, formula or "0", terms, before, best[0]))
    return out


# ------------------------------------------------------------------------- verdict
@dataclass
class Verdict:
    """Everything the tool found, and the files it can write."""

    recording: SingleWheelRecording
    params: ParameterSet
    options: ModelOptions
    residual_before: dict[str, NDArray[np.float64]]
    residual_after: dict[str, NDArray[np.float64]]
    pred_before: dict[str, NDArray[np.float64]]
    pred_after: dict[str, NDArray[np.float64]]
    failed_before: int
    regions: list[Region]
    regions_after: list[Region]
    scores: list[CandidateScore]
    chosen: CandidateScore | None
    chi2_cv_base: float
    sparse: list[SparseTerm]
    criterion: str
    seconds: float

    @property
    def missing_physics(self) -> list[str]:
        """Keys of the accepted candidate terms (empty: nothing is missing)."""
        return list(self.chosen.keys) if self.chosen else []

    def summary(self) -> str:
        lines = [f"{len(self.recording)} conditions; noise: {self.recording.noise_source}"]
        if self.failed_before:
            lines.append(f"model could not carry the load in {self.failed_before} conditions")
        lines.append("significant regions:" if self.regions else "no significant region (model and data agree within noise structure)")
        lines += [f"  - {r.describe()}" for r in self.regions]
        if self.chosen:
            lines.append("missing physics (accepted): " + "; ".join(self.chosen.physics))
            for n, u, v, e in zip(self.chosen.names, self.chosen.units, self.chosen.values, self.chosen.std_errors):
                lines.append(f"  {n} = {v:.4g} ± {e:.2g} {u}")
            lines.append(f"held-out chi2: {self.chi2_cv_base:.1f} -> {self.chosen.chi2_cv:.1f} "
                         f"({100 * self.chosen.delta_cv / self.chi2_cv_base:.0f} % lower), paired p = {self.chosen.p_paired:.2g}")
        else:
            lines.append("no candidate physics passes the criterion")
        for t in self.sparse:
            lines.append(f"unexplained {t.channel} residual ~ {t.formula} (held-out chi2 {t.chi2_cv_before:.1f} -> {t.chi2_cv_after:.1f})")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        def sc(s: CandidateScore) -> dict[str, Any]:
            return {"terms": list(s.keys), "physics": list(s.physics),
                    "parameters": [{"name": n, "unit": u, "value": v, "std_error": e}
                                   for n, u, v, e in zip(s.names, s.units, s.values, s.std_errors)],
                    "k": s.k, "chi2_in_sample": s.chi2_in, "chi2_held_out": s.chi2_cv, "held_out_improvement": s.delta_cv,
                    "paired_p": s.p_paired, "accepted": s.accepted}

        return {
            "conditions": len(self.recording),
            "noise": self.recording.noise_source,
            "failed_conditions_before": self.failed_before,
            "regions": [{"channel": r.channel, "bounds": r.bounds, "n": r.n, "mean_residual": r.mean, "stderr": r.stderr,
                         "unit": UNITS[r.channel], "z": r.z, "p_value": r.p_value, "text": r.describe()} for r in self.regions],
            "regions_after": [r.describe() for r in self.regions_after],
            "missing_physics": self.missing_physics,
            "chosen": sc(self.chosen) if self.chosen else None,
            "held_out_chi2_before": self.chi2_cv_base,
            "held_out_chi2_after": self.chosen.chi2_cv if self.chosen else self.chi2_cv_base,
            "candidates": [sc(s) for s in self.scores],
            "unexplained_sparse_fit": [{"channel": t.channel, "formula": t.formula, "coefficients": t.coefficients,
                                        "held_out_chi2_before": t.chi2_cv_before, "held_out_chi2_after": t.chi2_cv_after}
                                       for t in self.sparse],
            "decision_criterion": self.criterion,
            "seconds": self.seconds,
        }

    def write(self, folder: str | Path) -> Path:
        """Write ``report.md``, ``verdict.json`` and PNG plots into ``folder``."""
        out = Path(folder)
        out.mkdir(parents=True, exist_ok=True)
        (out / "verdict.json").write_text(json.dumps(self.to_json(), indent=2, default=float))
        pngs = _plots(self, out)
        md = ["# Discrepancy report", "", f"Recording: `{self.recording.source}`", "",
              f"Model: soil `{self.params.soil.name}`, wheel `{self.params.wheel.name}`, tuning `{self.params.tuning.name}`, "
              f"options `{self.options}`", "", "## Summary", "", "```", self.summary(), "```", "",
              "## Candidates (ranked by held-out improvement)", "",
              "| terms | parameters | held-out chi2 | improvement | paired p | accepted |", "|---|---|---|---|---|---|",
              f"| (model as given) | | {self.chi2_cv_base:.1f} | | | |"]
        for s in sorted(self.scores, key=lambda s: -(s.delta_cv if math.isfinite(s.delta_cv) else -1e300)):
            par = ", ".join(f"{n} = {v:.3g} ± {e:.2g} {u}" for n, u, v, e in zip(s.names, s.units, s.values, s.std_errors))
            if math.isfinite(s.chi2_cv):
                md.append(f"| {' + '.join(s.keys)} | {par} | {s.chi2_cv:.1f} | {s.delta_cv:.1f} | {s.p_paired:.2g} | "
                          f"{'yes' if s.accepted else ''} |")
            else:
                md.append(f"| {' + '.join(s.keys)} | {par} | screened out (in-sample chi2 {s.chi2_in:.1f}) | | | |")
        md += ["", "## Decision criterion", "", self.criterion, ""]
        if self.regions_after:
            md += ["## Regions still significant after the accepted terms", ""] + [f"- {r.describe()}" for r in self.regions_after] + [""]
        md += ["## Plots", ""] + [f"![{p.stem}]({p.name})" for p in pngs]
        (out / "report.md").write_text("\n".join(md) + "\n")
        return out


def _plots(v: Verdict, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rec = v.recording
    paths = []
    fig, axes = plt.subplots(2, 3, figsize=(13, 7), sharex=True, sharey="row")
    for j, ch in enumerate(CHANNELS):
        for i, (label, res) in enumerate((("before", v.residual_before), ("after", v.residual_after))):
            ax = axes[i, j]
            zz = res[ch] / rec.noise[ch]
            sc = ax.scatter(rec.features["slip"], rec.features["abs_beta_deg"], c=np.clip(zz, -10, 10), cmap="RdBu_r",
                            vmin=-10, vmax=10, s=40, edgecolors="k", linewidths=0.3)
            bad = ~np.isfinite(zz)
            ax.scatter(rec.features["slip"][bad], rec.features["abs_beta_deg"][bad], marker="x", c="k", s=30)
            ax.set_title(f"{ch} residual / noise, {label}")
            if i == 1:
                ax.set_xlabel("slip ratio")
            if j == 0:
                ax.set_ylabel("|slip angle| [deg]")
    fig.colorbar(sc, ax=axes, label="(measured - predicted) / noise (clipped at ±10; x: model failed)")
    p = out / "residual_map.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    paths.append(p)
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2))
    for j, ch in enumerate(CHANNELS):
        ax = axes[j]
        sc_ = SCALE_OUT[ch]
        m = rec.measured[ch] * sc_
        ax.plot(m, v.pred_before[ch] * sc_, "o", mfc="none", color="tab:gray", label="model as given")
        ax.plot(m, v.pred_after[ch] * sc_, ".", color="tab:red", label="with accepted terms")
        lim = [np.nanmin(m), np.nanmax(m)]
        ax.plot(lim, lim, "k-", lw=0.8)
        ax.set_xlabel(f"measured {ch} [{UNITS[ch]}]")
        ax.set_ylabel(f"predicted {ch} [{UNITS[ch]}]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    p = out / "measured_vs_predicted.png"
    fig.savefig(p, dpi=100)
    plt.close(fig)
    paths.append(p)
    return paths


CRITERION = (
    "A term (or pair of terms) with k fitted parameters is accepted when its grouped {k_folds}-fold cross-validated "
    "chi-square (sum over held-out conditions and channels of ((measured - predicted) / noise)^2) is lower than the "
    "current model's by more than 2 k, and a one-sided paired t-test over conditions of that reduction gives "
    "p < {p_max}. Candidates are screened in-sample and the best {n_cv} are cross-validated; a second term is added "
    "only if it passes the same test on top of the first. Conditions the model cannot carry count as a residual of "
    "{fail_z} noise units per channel."
)


def diagnose(
    trials_or_recording: TrialSet | SingleWheelRecording,
    params: ParameterSet,
    options: ModelOptions | None = None,
    candidates: Sequence[Candidate] = CANDIDATES,
    k_folds: int = 5,
    n_cv: int = 4,
    p_max: float = 0.01,
    max_terms: int = 2,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> Verdict:
    """Run the whole pipeline (module docstring) and return a :class:`Verdict`.

    Parameters
    ----------
    trials_or_recording : TrialSet or SingleWheelRecording
        Recordings; trials are averaged per condition.
    params : ParameterSet
        The model to check.
    options : ModelOptions, optional
    candidates : sequence of Candidate
        The physics library (default :data:`CANDIDATES`).
    """
    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    options = options or ModelOptions()
    rec = (trials_or_recording if isinstance(trials_or_recording, SingleWheelRecording)
           else SingleWheelRecording.from_trials(trials_or_recording))
    rng = np.random.default_rng(seed)
    fail_z = 10.0
    pred0, ok0 = predict_recording(params, options, rec)
    res0 = {ch: rec.measured[ch] - pred0[ch] for ch in CHANNELS}
    say("locating regions")
    regions = []
    for ch in CHANNELS:
        regions += locate(res0[ch] / rec.noise[ch], res0[ch] * SCALE_OUT[ch], rec.features, ch, rng)
    folds = _folds(rec, k_folds)
    say("cross-validating the model as given")
    cv_base_rows = _cv([], params, options, rec, folds, fail_z, None)
    chi2_cv_base = float(cv_base_rows.sum())

    def score(cands: Sequence[Candidate], base_rows: NDArray[np.float64], x_full: NDArray[np.float64], se: NDArray[np.float64],
              chi2_in: float, t_start: float) -> CandidateScore:
        rows = _cv(cands, params, options, rec, folds, fail_z, x_full)
        k = sum(c.k for c in cands)
        delta = float(base_rows.sum() - rows.sum())
        p = _paired_p(base_rows, rows)
        return CandidateScore(tuple(c.key for c in cands), tuple(c.physics for c in cands),
                              tuple(q[0] for c in cands for q in c.params), tuple(q[1] for c in cands for q in c.params),
                              tuple(float(x) for x in x_full), tuple(float(e) for e in se), k, chi2_in, float(rows.sum()),
                              delta, p, bool(delta > 2 * k and p < p_max), time.perf_counter() - t_start)

    # screen in-sample
    screened = []
    for c in candidates:
        say(f"fitting {c.key}")
        ts = time.perf_counter()
        x, se, chi2, _ = _fit([c], params, options, rec, fail_z)
        screened.append((chi2 + 2 * c.k, c, x, se, chi2, ts))
    screened.sort(key=lambda t: t[0])
    scores: list[CandidateScore] = []
    for _, c, x, se, chi2, ts in screened[:n_cv]:
        say(f"cross-validating {c.key}")
        scores.append(score([c], cv_base_rows, x, se, chi2, ts))
    for _, c, x, se, chi2, ts in screened[n_cv:]:
        scores.append(CandidateScore((c.key,), (c.physics,), tuple(q[0] for q in c.params), tuple(q[1] for q in c.params),
                                     tuple(float(v) for v in x), tuple(float(e) for e in se), c.k, chi2, math.nan, math.nan,
                                     math.nan, False, time.perf_counter() - ts))
    passed = sorted([s for s in scores if s.accepted], key=lambda s: -(s.delta_cv - 2 * s.k))
    chosen = passed[0] if passed else None
    if chosen and max_terms > 1:
        first = next(c for c in candidates if c.key == chosen.keys[0])
        base_rows = _cv([first], params, options, rec, folds, fail_z, np.array(chosen.values))
        fam = {c.key: c.family or c.key for c in candidates}
        seconds = [s for s in sorted(scores, key=lambda s: -(s.delta_cv if math.isfinite(s.delta_cv) else -1e9))
                   if len(s.keys) == 1 and fam[s.keys[0]] != fam[first.key]][: max(n_cv - 1, 1)]
        best2 = None
        for s2 in seconds:
            c2 = next(c for c in candidates if c.key == s2.keys[0])
            say(f"trying {first.key} + {c2.key}")
            ts = time.perf_counter()
            x, se, chi2, _ = _fit([first, c2], params, options, rec, fail_z, x0=np.array([*chosen.values, *s2.values]))
            sc2 = score([first, c2], base_rows, x, se, chi2, ts)
            extra = sc2.delta_cv  # improvement over the one-term model
            ok2 = extra > 2 * c2.k and sc2.p_paired < p_max
            sc2 = replace(sc2, delta_cv=float(cv_base_rows.sum() - sc2.chi2_cv), accepted=ok2)
            scores.append(sc2)
            if ok2 and (best2 is None or sc2.chi2_cv < best2.chi2_cv):
                best2 = sc2
        if best2 is not None:
            chosen = best2
    if chosen:
        conv = np.array([q[5] for key in chosen.keys for c in candidates if c.key == key for q in c.params])
        e = Extension()
        i = 0
        for key in chosen.keys:
            c = next(c for c in candidates if c.key == key)
            e = e.merge(c.build(np.array(chosen.values[i:i + c.k]) * conv[i:i + c.k], params))
            i += c.k
        pred1, _ = predict_recording(params, options, rec, e)
    else:
        pred1 = pred0
    res1 = {ch: rec.measured[ch] - pred1[ch] for ch in CHANNELS}
    regions_after = []
    for ch in CHANNELS:
        regions_after += locate(res1[ch] / rec.noise[ch], res1[ch] * SCALE_OUT[ch], rec.features, ch, rng)
    sparse = _sparse_fit(rec, res1, folds) if regions_after else []
    crit = CRITERION.format(k_folds=k_folds, p_max=p_max, n_cv=n_cv, fail_z=fail_z)
    return Verdict(rec, params, options, res0, res1, pred0, pred1, int((~ok0).sum()), regions, regions_after, scores,
                   chosen, chi2_cv_base, sparse, crit, time.perf_counter() - t0)
