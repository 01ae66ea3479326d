"""Statistics of the discrepancy engine: regions, fits, held-out scores and their null distribution.

Everything here works on *normalised residuals* ``z = (measured - predicted) / (noise s)``
(rows x channels) of any :class:`~offline.discrepancy.observations.Observations`, so the same test
serves single-wheel conditions and, later, drive segments.

* :func:`dispersion` -- the per-channel scale ``s >= 1``: the robust (MAD) spread of the
  model's normalised residuals. The model may miss everywhere by more than the repeat noise
  (the calibrated model does, by a factor of ~3 on the shared data); evidence is then
  counted in units of that misfit, not of the repeat noise.
* :func:`locate` -- where the residuals depart from noise: the largest box sum over one- and
  two-feature boxes, with a Monte-Carlo null of the maximum (multiplicity accounted for).
* :func:`fit` -- bounded least squares of a candidate's parameters (several starts).
* :func:`held_out` -- grouped K-fold held-out chi-square per row, by one Gauss-Newton step
  from the full-data fit on each training fold, then the nonlinear model on the held-out
  rows (exact for a model linear in its parameters; an approximation otherwise).
* :func:`tangent_null` -- the null distribution of the held-out improvement of every
  candidate when the data are noise around the model: a parametric bootstrap in the
  tangent spaces of each candidate at several points of its parameter box (so a threshold
  parameter, unidentified under the null, is searched over as the real fit does).
* :func:`adjusted_p` -- Westfall-Young min-P adjustment over the whole library, so choosing
  the best of ~20 candidates does not inflate the false-alarm rate.
* :func:`vuong` -- the paired test of two non-nested explanations on held-out rows
  (Vuong 1989): not significant means "indistinguishable on these data".

References
----------
Vuong, Q. H. (1989). Likelihood ratio tests for model selection and non-nested hypotheses.
Econometrica 57(2), 307-333. Westfall, P. H., Young, S. S. (1993). Resampling-based
multiple testing. Wiley, algorithm 2.8 (min-P).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .observations import FEATURE_LABELS

__all__ = [
    "Region",
    "locate",
    "dispersion",
    "normalised",
    "fail_floor",
    "FitResult",
    "fit",
    "held_out",
    "refit_held_out",
    "refit_fold_held_out",
    "linear_held_out",
    "tangent_null",
    "adjusted_p",
    "vuong",
]

FAIL_Z = 10.0
"""Normalised residual counted for a row the model cannot predict (it fails to carry the load)."""


# ------------------------------------------------------------------------- residuals
def normalised(obs: Any, pred: Mapping[str, NDArray[np.float64]], scale: Mapping[str, float],
               fail: Mapping[str, float] | None = None) -> NDArray[np.float64]:
    """``(measured - predicted) / (noise s)``, rows x channels.

    A failed prediction (NaN: the model cannot carry the load, a re-simulated drive is lost)
    counts ``fail[channel]`` (default :data:`FAIL_Z` on every channel). The engine passes
    :func:`fail_floor` of the model as given, so that a lost prediction never scores better
    than the model as given does on any of its rows.
    """
    cols = []
    for ch in obs.channels:
        zz = (obs.measured[ch] - pred[ch]) / (obs.noise[ch] * scale[ch])
        cols.append(np.where(np.isfinite(zz), zz, FAIL_Z if fail is None else fail[ch]))
    return np.stack(cols, axis=1)


def fail_floor(obs: Any, pred: Mapping[str, NDArray[np.float64]], scale: Mapping[str, float]) -> dict[str, float]:
    """What a failed prediction counts per channel: the worst the model as given does on it.

    ``max(FAIL_Z, max_rows |z|)`` with ``z`` the finite normalised residuals of ``pred`` (the
    model as given) on the channel. With a constant :data:`FAIL_Z` a candidate whose
    re-simulation is lost (every row NaN) scored ``FAIL_Z**2`` per value, which beats a model
    as given that misses by more than ``FAIL_Z`` noise units: the fit then sought parameters
    that lose the drive (issue 24, a per-wheel slew limit and a hub contact fitted to a lost
    drive, 110102 -> 54102). With this floor a lost row is never better than the model as given
    on its worst row, so no held-out improvement can come from losing rows.
    """
    out = {}
    for ch in obs.channels:
        z = np.abs((obs.measured[ch] - pred[ch]) / (obs.noise[ch] * scale[ch]))
        z = z[np.isfinite(z)]
        out[ch] = max(FAIL_Z, float(z.max())) if z.size else FAIL_Z
    return out


def dispersion(obs: Any, pred: Mapping[str, NDArray[np.float64]]) -> dict[str, float]:
    """Per-channel scale ``s = max(1, 1.4826 MAD(z))`` of the normalised residuals (module docstring).

    The median absolute deviation is centred, so a constant offset does not inflate it, and a
    region of a few rows does not move it; a model that misses everywhere does.
    """
    out = {}
    for ch in obs.channels:
        z = (obs.measured[ch] - pred[ch]) / obs.noise[ch]
        z = z[np.isfinite(z)]
        out[ch] = max(1.0, 1.4826 * float(np.median(np.abs(z - np.median(z))))) if z.size else 1.0
    return out


# ------------------------------------------------------------------------- locate
@dataclass(frozen=True)
class Region:
    """A region of the operating space with a significant residual.

    Attributes
    ----------
    channel : str
    bounds : dict
        ``feature -> (low, high)``.
    n : int
        Rows inside.
    mean, stderr : float
        Mean residual and its standard error, in the channel's report unit.
    unit : str
    z, p_value : float
        Box statistic ``sum(z) / sqrt(n)`` and its multiplicity-adjusted p-value.
    """

    channel: str
    bounds: dict[str, tuple[float, float]]
    n: int
    mean: float
    stderr: float
    unit: str
    z: float
    p_value: float

    def describe(self) -> str:
        """One report line."""
        verb = "under-predicted" if self.mean > 0 else "over-predicted"
        parts = [f"{lo:.3g} <= {FEATURE_LABELS.get(f, f)} <= {hi:.3g}" for f, (lo, hi) in self.bounds.items()]
        return (f"{self.channel} {verb} by {abs(self.mean):.3g} ± {self.stderr:.2g} {self.unit} for "
                f"{' and '.join(parts)} ({self.n} rows, Z = {self.z:.1f}, p = {self.p_value:.3g})")


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
                if i == 0 and j == len(cuts) - 1:
                    continue  # everything
                ivs.append(((x >= cuts[i]) & (x <= cuts[j]), (float(cuts[i]), float(cuts[j]))))
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


def _max_abs_box_stat(draws: NDArray[np.float64], masks: NDArray[np.float64], root_counts: NDArray[np.float64],
                      block: int = 4_000_000) -> NDArray[np.float64]:
    """``max |draws @ masks.T / root_counts|`` of each draw, in blocks of draws of at most ``block``
    products: a drive's region test draws 42000 null series against about a thousand boxes, and the
    whole product (330 MB) cost three times the CPU of the blocks (page faults and memory traffic;
    the same numbers, bit for bit, with one BLAS thread: a thread split of a block can round a
    product's last bit differently from the split of the whole)."""
    out = np.empty(draws.shape[0])
    step = max(1, block // max(masks.shape[0], 1))
    for i in range(0, draws.shape[0], step):
        out[i:i + step] = np.abs(draws[i:i + step] @ masks.T / root_counts).max(axis=1)
    return out


_PRIORITY = {"abs_beta_deg": 0, "slip": 1, "sinkage_mm": 2, "load_N": 3, "rim_speed_mm_s": 4}


def locate(
    z: NDArray[np.float64], raw: NDArray[np.float64], features: Mapping[str, NDArray[np.float64]], channel: str, unit: str,
    rng: np.random.Generator, alpha: float = 0.01, max_regions: int = 3, n_perm: int = 400, min_rows: int = 3,
    draw: Callable[[np.random.Generator, int], NDArray[np.float64]] | None = None,
) -> list[Region]:
    """Significant regions of one channel's residuals.

    The statistic of a box is ``Z = sum(z) / sqrt(n)``; its significance is a Monte-Carlo
    test of the *maximum* |Z| over all boxes under the null of Gaussian residuals at a
    robust scale (MAD of z, at least 1): independent rows by default, or the correlated
    unit-variance noise ``draw(rng, n_perm)`` gives (``(n_perm, len(z))``, e.g. a time
    series' MA(1) noise, so that correlated noise does not make a long box significant).
    Up to ``max_regions`` regions, each found after the previous one is explained away (its
    mean removed). ``raw`` is the residual in report units (for the magnitude).
    """
    ok = np.isfinite(z)
    z, raw = z[ok], raw[ok]
    feats = {k: v[ok] for k, v in features.items()}
    if z.size < 6:
        return []
    masks, desc = _boxes(feats)
    if masks.size == 0:
        return []
    counts = masks.sum(axis=1)
    keep = counts >= min_rows
    masks, counts = masks[keep].astype(float), counts[keep]
    desc = [d for d, k in zip(desc, keep) if k]
    regions: list[Region] = []
    zc, rawc = z.copy(), raw.copy()
    for _ in range(max_regions):
        scale = max(1.0, 1.4826 * float(np.median(np.abs(zc - np.median(zc)))))
        stat = masks @ zc / np.sqrt(counts)
        top = np.flatnonzero(np.abs(stat) >= np.abs(stat).max() * (1 - 1e-9))
        best = int(min(top, key=lambda i: (len(desc[i]), min(_PRIORITY.get(f, 9) for f in desc[i]))))
        if draw is None:
            draws = rng.normal(0.0, scale, size=(n_perm, zc.size))
        else:
            full = np.asarray(draw(rng, n_perm), dtype=float)
            if full.shape != (n_perm, ok.size):
                raise ValueError(f"locate: draw gave shape {full.shape}, expected {(n_perm, ok.size)}")
            draws = scale * full[:, ok]
        null = _max_abs_box_stat(draws, masks, np.sqrt(counts))
        p = (1 + np.sum(null >= abs(stat[best]))) / (n_perm + 1)
        if p > alpha:
            break
        m = masks[best] > 0
        vals = rawc[m]
        regions.append(Region(channel, desc[best], int(m.sum()), float(vals.mean()),
                              float(vals.std(ddof=1) / math.sqrt(m.sum())) if m.sum() > 1 else math.nan,
                              unit, float(stat[best]), float(p)))
        zc[m] -= zc[m].mean()
        rawc[m] -= rawc[m].mean()
    return regions


# ------------------------------------------------------------------------- fits
@dataclass(frozen=True)
class FitResult:
    """A least-squares fit of one or more candidates.

    Attributes
    ----------
    x : ndarray
        Parameters in reported units.
    std_errors : ndarray
        Standard errors (Gauss-Newton covariance scaled by max(1, chi2 / dof)); NaN where the
        data do not determine a parameter (a null direction of the Jacobian).
    chi2 : float
        In-sample sum of squared normalised residuals.
    z : ndarray
        Normalised residuals, rows x channels.
    jac : ndarray
        d z / d x at ``x`` (rows * channels, k).
    nfev : int
        Model evaluations (budget in evaluations, never seconds).
    covariance : ndarray or None
        Gauss-Newton covariance of ``x`` (pseudo-inverse over the determined directions,
        scaled like ``std_errors``).
    """

    x: NDArray[np.float64]
    std_errors: NDArray[np.float64]
    chi2: float
    z: NDArray[np.float64]
    jac: NDArray[np.float64]
    nfev: int
    covariance: NDArray[np.float64] | None = None


def fit(
    residual: Callable[[NDArray[np.float64]], NDArray[np.float64]], lower: NDArray[np.float64], upper: NDArray[np.float64],
    starts: Sequence[NDArray[np.float64]], n_channels: int, max_nfev: int = 30, tol: float | None = None,
) -> FitResult:
    """Bounded least squares (scipy trust-region reflective) from each start; the best wins.

    ``residual(x)`` returns the flattened normalised residuals. ``tol``: relative tolerance on
    the cost and on the step (scipy's ``ftol`` and ``xtol``; None: scipy's 1e-8), so a fit
    stops once the chi-square changes by less than ``tol`` of itself instead of spending its
    whole evaluation budget.
    """
    from scipy.optimize import least_squares

    if len(starts) == 0:
        raise ValueError("fit needs at least one starting point")
    best = None
    nfev = 0
    span = upper - lower
    for s in starts:
        x0 = np.clip(np.asarray(s, dtype=float), lower + 1e-6 * span, upper - 1e-6 * span)
        kw = {} if tol is None else {"ftol": tol, "xtol": tol}
        res = least_squares(residual, x0, bounds=(lower, upper), diff_step=1e-3, max_nfev=max_nfev, x_scale=0.1 * span, **kw)
        nfev += int(res.nfev) * (1 + x0.size)
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None  # starts is not empty (checked above)
    r = best.fun
    J = best.jac
    dof = max(r.size - J.shape[1], 1)
    s2 = max(float(r @ r) / dof, 1.0)
    JtJ = J.T @ J
    w, V = np.linalg.eigh(JtJ)
    tol = max(w.max(), 1e-300) * 1e-10
    se = np.full(J.shape[1], np.nan)
    good = w > tol
    cov = (V[:, good] / w[good]) @ V[:, good].T
    det = np.abs(V[:, ~good]).max(axis=1) < 1e-3 if (~good).any() else np.ones(J.shape[1], dtype=bool)
    se[det] = np.sqrt(np.clip(np.diag(cov)[det] * s2, 0, None))
    return FitResult(best.x, se, float(r @ r), r.reshape(-1, n_channels), J, nfev, cov * s2)


def _row_index(rows: NDArray[np.int_], n_channels: int) -> NDArray[np.int_]:
    return (rows[:, None] * n_channels + np.arange(n_channels)[None, :]).ravel()


def held_out(
    fitted: FitResult, residual_at: Callable[[NDArray[np.float64]], NDArray[np.float64]], folds: NDArray[np.int_],
    lower: NDArray[np.float64], upper: NDArray[np.float64], damping: float = 1e-3,
) -> NDArray[np.float64]:
    """Screening held-out chi-square of every row (summed over channels), K-fold by ``folds``.

    For each fold, the parameters are refitted on the other folds by one damped Gauss-Newton
    (Levenberg-Marquardt) step from the full-data fit,
    ``dx = -(J_tr' J_tr + damping I)^-1 J_tr' z_tr`` in column-normalised coordinates
    (clipped into the bounds), and the held-out rows are predicted by the nonlinear model at
    ``x + dx`` (``residual_at(x)`` returns the normalised residuals, rows x channels). Exact
    for a model linear in its parameters; optimistic for a threshold parameter that the
    full-data fit placed using the held-out rows, so candidates that pass on this score are
    scored again by :func:`refit_held_out`.
    """
    nc = fitted.z.shape[1]
    out = np.empty(fitted.z.shape[0])
    J, r = fitted.jac, fitted.z.ravel()
    colnorm = np.sqrt((J**2).sum(axis=0)) + 1e-300
    for f in np.unique(folds):
        tr = _row_index(np.flatnonzero(folds != f), nc)
        te_rows = np.flatnonzero(folds == f)
        Jt = J[tr] / colnorm
        A = Jt.T @ Jt + damping * np.eye(J.shape[1])
        dx = -np.linalg.solve(A, Jt.T @ r[tr]) / colnorm
        x = np.clip(fitted.x + dx, lower, upper)
        z = residual_at(x)
        out[te_rows] = (z[te_rows] ** 2).sum(axis=1)
    return out


def linear_held_out(
    z: NDArray[np.float64], jac: NDArray[np.float64], folds: NDArray[np.int_], damping: float = 1e-3,
) -> NDArray[np.float64]:
    """Held-out chi-square of every row of a model linearised at one point (no model evaluation).

    ``z`` are the normalised residuals (rows x channels) at the point and ``jac`` = d z / d x
    (rows * channels, k). For each fold the step ``dx`` is the damped Gauss-Newton step on the
    other folds (as in :func:`held_out`) and the held-out rows are predicted *linearly*,
    ``z_te + J_te dx``. This is the score test of a term added on top of a fitted explanation
    (forward selection): the term's own parameters start at their "no change" values, the
    explanation's parameters may move with it, and the held-out rows judge the move.
    """
    nc = z.shape[1]
    r = z.ravel()
    out = np.empty(z.shape[0])
    colnorm = np.sqrt((jac**2).sum(axis=0)) + 1e-300
    for f in np.unique(folds):
        tr = _row_index(np.flatnonzero(folds != f), nc)
        te_rows = np.flatnonzero(folds == f)
        te = _row_index(te_rows, nc)
        Jt = jac[tr] / colnorm
        dx = -np.linalg.solve(Jt.T @ Jt + damping * np.eye(jac.shape[1]), Jt.T @ r[tr]) / colnorm
        out[te_rows] = ((r[te] + jac[te] @ dx).reshape(-1, nc) ** 2).sum(axis=1)
    return out


def refit_held_out(
    residual_rows: Callable[[NDArray[np.float64], NDArray[np.int_]], NDArray[np.float64]], folds: NDArray[np.int_],
    lower: NDArray[np.float64], upper: NDArray[np.float64], starts: Sequence[NDArray[np.float64]], n_channels: int,
    max_nfev: int = 30, tol: float | None = None,
) -> tuple[NDArray[np.float64], int]:
    """Held-out chi-square of every row with a full refit on each training fold (``tol``: :func:`fit`).

    ``residual_rows(x, rows)`` returns the normalised residuals of ``rows`` (rows x
    channels). Each training fold is fitted from the same starts as the full-data fit (so a
    threshold is searched for again, not inherited), and its held-out rows are scored.

    Returns
    -------
    rows_chi2 : ndarray
    nfev : int
        Model evaluations spent.
    """
    n = folds.size
    out = np.empty(n)
    nfev = 0
    for f in np.unique(folds):
        out[folds == f], nf = refit_fold_held_out(residual_rows, folds, int(f), lower, upper, starts, n_channels,
                                                  max_nfev=max_nfev, tol=tol)
        nfev += nf
    return out, nfev


def refit_fold_held_out(
    residual_rows: Callable[[NDArray[np.float64], NDArray[np.int_]], NDArray[np.float64]], folds: NDArray[np.int_],
    fold: int, lower: NDArray[np.float64], upper: NDArray[np.float64], starts: Sequence[NDArray[np.float64]],
    n_channels: int, max_nfev: int = 30, tol: float | None = None,
) -> tuple[NDArray[np.float64], int]:
    """One fold of :func:`refit_held_out`: the fit on the other folds, the held-out chi-square of
    the rows of ``fold`` (in row order) and the model evaluations spent (the folds are
    independent: :func:`offline.discrepancy.parallel.map_tasks` runs them side by side)."""
    tr, te = np.flatnonzero(folds != fold), np.flatnonzero(folds == fold)
    res = fit(lambda x: residual_rows(x, tr).ravel(), lower, upper, starts, n_channels, max_nfev=max_nfev, tol=tol)
    return (residual_rows(res.x, te) ** 2).sum(axis=1), res.nfev + 1


def tangent_null(
    tangents: Sequence[Sequence[NDArray[np.float64]]], folds: NDArray[np.int_], n_channels: int, n_boot: int,
    rng: np.random.Generator,
    draw: Callable[[np.random.Generator, int, int], NDArray[np.float64]] | None = None,
    damping: float = 0.0,
) -> NDArray[np.float64]:
    """Null held-out improvements of each candidate, shape (n_candidates, n_boot).

    ``tangents[m]`` lists the Jacobians (rows * channels, k) of candidate m at several points
    of its parameter box. Under the null the normalised residuals are standard Gaussian
    noise ``e``; for each draw and each point the candidate's linearisation is fitted by
    least squares on the training folds and scored on the held-out fold, and the point with
    the largest in-sample reduction is kept (as the nonlinear fit would choose), giving
    ``sum_te e^2 - sum_te (e - D b)^2``. Candidates whose parameters are bounded on one side
    can do no better than this unconstrained fit, so the null is conservative for them.

    ``draw(rng, n, n_boot)`` replaces the independent standard-normal draws (rows x
    channels flattened row-major, one column per draw): the hook for correlated residuals
    (a time series needs block or whitened draws so a long recording does not make noise
    significant).

    ``damping``: the training-fold fits are damped as the observed score's step is
    (:func:`held_out`: ``(D_tr' D_tr + damping I)^-1 D_tr' e_tr`` in coordinates normalised by
    the columns of ``D``). 0 is the exact linear least squares; the observed score's 1e-3 keeps
    directions the data barely determine (a recalibration's trade-offs) from overfitting, so a
    null without it is far more negative than the score it is compared with and noise comes out
    significant (issue 24: a recalibration of 15 parameters at p_adj = 0.0005 on noise-only trials).
    """
    n = folds.size * n_channels
    E = rng.standard_normal((n, n_boot)) if draw is None else np.asarray(draw(rng, n, n_boot), dtype=float)
    if E.shape != (n, n_boot):
        raise ValueError(f"draw returned shape {E.shape}, expected ({n}, {n_boot})")
    out = np.empty((len(tangents), n_boot))
    fold_ids = np.unique(folds)
    idx = {f: (_row_index(np.flatnonzero(folds != f), n_channels), _row_index(np.flatnonzero(folds == f), n_channels))
           for f in fold_ids}
    for m, pts in enumerate(tangents):
        best_in = np.full(n_boot, -np.inf)
        best_cv = np.zeros(n_boot)
        for D in pts:
            Q, R = np.linalg.qr(D)
            keep = np.abs(np.diag(R)) > 1e-9 * max(np.abs(np.diag(R)).max(), 1e-300)
            if not keep.any():
                continue
            Qk = Q[:, keep]
            ins = ((Qk.T @ E) ** 2).sum(axis=0)
            cv = np.zeros(n_boot)
            Dk = D[:, keep]
            if damping > 0.0:
                Dk = Dk / (np.sqrt((Dk**2).sum(axis=0)) + 1e-300)
            for f in fold_ids:
                tr, te = idx[f]
                if damping > 0.0:
                    A = Dk[tr].T @ Dk[tr] + damping * np.eye(Dk.shape[1])
                    b = np.linalg.solve(A, Dk[tr].T @ E[tr])
                else:
                    b = np.linalg.pinv(Dk[tr]) @ E[tr]
                fit_te = Dk[te] @ b
                cv += (E[te] ** 2).sum(axis=0) - ((E[te] - fit_te) ** 2).sum(axis=0)
            better = ins > best_in
            best_in = np.where(better, ins, best_in)
            best_cv = np.where(better, cv, best_cv)
        out[m] = best_cv
    return out


def adjusted_p(observed: NDArray[np.float64], null: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Marginal and Westfall-Young min-P adjusted p-values of each candidate's held-out improvement.

    Parameters
    ----------
    observed : ndarray, shape (m,)
        Held-out improvement of each candidate on the data.
    null : ndarray, shape (m, B)
        Its null draws (:func:`tangent_null`).

    Returns
    -------
    p, p_adjusted : ndarray
        ``p_m = (1 + #{null_m >= obs_m}) / (B + 1)``; ``p_adj_m = (1 + #{min_j p*_j <= p_m}) / (B + 1)``
        where ``p*_j`` is the rank p-value of a null draw within its own null.
    """
    m, B = null.shape
    p = (1.0 + (null >= observed[:, None]).sum(axis=1)) / (B + 1.0)
    # rank p-value of each null draw within its own null (ties share the larger p)
    order = np.sort(null, axis=1)
    pstar = np.empty_like(null)
    for j in range(m):
        pstar[j] = (B - np.searchsorted(order[j], null[j], side="left")) / B
    minp = pstar.min(axis=0)
    p_adj = (1.0 + (minp[None, :] <= p[:, None]).sum(axis=1)) / (B + 1.0)
    return p, np.minimum(p_adj, 1.0)


def vuong(rows_a: NDArray[np.float64], rows_b: NDArray[np.float64], extra_parameters: int = 0) -> float:
    """Vuong's statistic that explanation ``a`` predicts held-out rows better than ``b``.

    ``d_i = rows_b,i - rows_a,i`` (held-out chi-square of b minus a, per row);
    ``V = (sum(d) - p ln n) / (sqrt(n) sd(d))``, standard normal when the two are equally good.
    ``p = extra_parameters`` (``a``'s parameters minus ``b``'s, default 0): Schwarz's correction of
    Vuong's adjusted statistic (1989; the chi-square as -2 log-likelihood), so that the more flexible
    explanation must beat the other by more than its extra parameters buy.

    References
    ----------
    Vuong, Q. H. (1989). Likelihood ratio tests for model selection and non-nested hypotheses.
    Econometrica 57(2), 307-333.
    """
    d = rows_b - rows_a
    sd = float(d.std(ddof=1)) if d.size > 1 else 0.0
    if sd == 0.0:
        return 0.0
    return float((d.sum() - extra_parameters * math.log(d.size)) / (math.sqrt(d.size) * sd))
