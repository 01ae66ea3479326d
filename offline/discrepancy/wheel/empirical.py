"""Empirical terms for what the single-wheel library lacks (issue 24, "model the unknown").

When no library term explains a set of testbed trials (the engine's verdict is
``unexplained``, ``partly_explained`` or ``ambiguous``), :func:`search_wheel_empirical` builds a
term from what the data locate, out of a small family of generic, physically interpretable
terms, and accepts it only by a held-out test whose null is the same search run on noise.

What it is told: the recording (conditions, measured channels, their noise), the model as
given (its predictions at those conditions) and the engine's dispersion and folds. What it is
not told: anything of the truth (no effect, channel, condition, threshold or law is given to it).
Its family holds no mechanism: a term says *where* (which conditions) and *how much* (which law)
a force or a sinkage is missing, never *why*; the report says which experiment would tell.

The family (:class:`WheelTerm`)
-------------------------------
A term is a *direction* times a *localisation* times a *magnitude* ``m``, added to the model's
prediction of every row (a testbed row is a steady state, so a term acts on its own row only and
needs no re-simulation):

=============  ====================================================================  =====
direction      what acts                                                             unit
=============  ====================================================================  =====
``drag``       a force against the wheel's travel (F_x, F_y along ``-v / |v|``)      N
``Fx``         a force along the wheel's x axis (its heading)                        N
``Fy``         a force along the wheel's y axis (lateral)                            N
``sinkage``    extra sinkage                                                         m
=============  ====================================================================  =====

localised in an operating-point feature of the recording (``slip``, ``abs_beta_deg``,
``sinkage_mm`` measured, ``load_N``, ``rim_speed_mm_s``) or a force of the model as given
(``model_abs_Fx_N``, ``model_abs_Fy_N``: a threshold or saturation in a state variable) with the
shape

- ``constant``: everywhere (1 parameter);
- ``above`` / ``below``: a step, where the feature is above / below ``lo`` (2);
- ``hinge_above`` / ``hinge_below``: ``m (v - lo)`` above ``lo`` / ``m (lo - v)`` below it,
  a ramp that starts at the threshold (2; ``m`` per unit of the feature);
- ``box``: where ``lo <= v < hi`` (3).

Thresholds are the midpoints between the feature's distinct levels (values within 1 % of the
feature's span are one level; at most 14 thresholds, by quantile, for a continuous feature), and
the levels themselves for hinges; a localised term must cover at least ``min_rows`` rows.

How a term is found
-------------------
1. **Columns.** Every direction x feature x shape x threshold is a column ``a`` of the change of
   the normalised residual (the engine's ``(measured - predicted) / (noise s)``, per row and
   channel) per unit magnitude: the effect is exactly linear in ``m``.
2. **Selection by sparsity.** Within a set of rows, each column gets its least-squares
   magnitude and an AIC-type score, the chi-square improvement ``(a.r)^2 / (a.a)`` minus 2 per
   parameter; the best column wins.
3. **Held-out test** on the engine's folds (:meth:`SingleWheelRecording.folds`, every slip level
   at every angle in every fold): for each fold the selection runs on the other folds, the chosen
   column's magnitude is fitted there, and the term is scored on the held-out fold; ``D`` is the
   summed held-out improvement. Its null is the same nested search on ``ceil(2 / alpha)`` draws
   of independent unit-variance noise in the same units (conservative where the dispersion
   ``s`` exceeds one), so the multiplicity of the whole family is paid for. Accepted at
   ``p < alpha``.
4. **A second term** is searched on what the first leaves, with the same test.

Verdict (:class:`WheelEmpiricalResult`): ``explained`` by the empirical term(s) when they remove at
least half of the held-out excess chi-square (the engine's ``explained_fraction`` definition) and
no channel misfits beyond noise after them (the engine's lack-of-fit test); ``partly_explained``
when a term passes its test but either condition fails; ``none`` otherwise. An empirical term never
names library physics: the engine's status is kept and the report adds the term with its law,
localisation, held-out improvement and the experiment that would confirm its physics. It is not
written to ``accepted_truth.toml`` (a testbed term lives in the testbed's measurement space; the
rover simulator has no hook for it); the report writer puts it in ``empirical_terms.json``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["WheelTerm", "WheelEmpiricalResult", "search_wheel_empirical", "term_columns", "with_model_features", "DIRECTIONS",
           "FEATURES", "SHAPES"]

DIRECTIONS: dict[str, tuple[str, str]] = {
    "drag": ("force against the wheel's travel", "N"),
    "Fx": ("force along the wheel's x axis", "N"),
    "Fy": ("force along the wheel's y axis", "N"),
    "sinkage": ("sinkage", "mm"),
}
"""``direction -> (what acts, report unit)``."""

FEATURES: dict[str, tuple[str, str]] = {
    "slip": ("slip ratio", ""),
    "abs_beta_deg": ("|slip angle|", "deg"),
    "sinkage_mm": ("measured sinkage", "mm"),
    "load_N": ("load", "N"),
    "rim_speed_mm_s": ("rim speed", "mm/s"),
    "model_abs_Fx_N": ("|F_x| of the model as given", "N"),
    "model_abs_Fy_N": ("|F_y| of the model as given", "N"),
}
"""Localisation features: ``key -> (name, unit)``. The first five are the recording's own
``features``; the last two are state variables of the model as given at each row
(:func:`with_model_features`), where a saturation of a force (a load cell's range, a rig's
compliance) is localised."""

SHAPES: dict[str, int] = {"constant": 1, "above": 2, "below": 2, "hinge_above": 2, "hinge_below": 2, "box": 3}
"""Shape -> number of fitted parameters (magnitude and edges), the AIC penalty's ``k``."""

_EXPERIMENT = {
    "drag": ("run the conditions where it acts again at 0.6 x and 1.5 x the load (a soil reaction scales with the "
             "load, a rig or sensor force does not) and once with the wheel lifted clear of the soil (a reading then "
             "is the rig's)"),
    "Fx": ("run the conditions where it acts again at 0.6 x and 1.5 x the load and once with the wheel lifted clear "
           "of the soil; mirror the slip angle (a sensor axis effect keeps its sign in the wheel frame)"),
    "Fy": ("run the conditions where it acts at the mirrored slip angle (a soil force changes sign, a sensor's "
           "saturation or cross-talk does not) and at 0.6 x and 1.5 x the load"),
    "sinkage": ("measure the sinkage at those conditions a second way (rut depth after the run, a laser on the "
                "carriage) and record the transient at the start of each run"),
}


@dataclass(frozen=True)
class WheelTerm:
    """One empirical term: ``magnitude x shape(feature; lo, hi)`` in ``direction``.

    Attributes
    ----------
    direction, feature, shape : str
        Keys of :data:`DIRECTIONS`, :data:`FEATURES`, :data:`SHAPES`.
    lo, hi : float
        Threshold(s) in the feature's units (NaN where the shape has none).
    magnitude, std_error : float
        SI (N or m; per unit of the feature for a hinge); the error from the least-squares fit
        on all rows in the engine's units (noise x dispersion).
    rows : int
        Rows where the term is non-zero.
    """

    direction: str
    feature: str
    shape: str
    lo: float
    hi: float
    magnitude: float
    std_error: float
    rows: int

    @property
    def k(self) -> int:
        """Fitted parameters."""
        return SHAPES[self.shape]

    def weight(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """The localisation's value at feature values ``v`` (0 where the term does not act)."""
        return _shape(self.shape, v, self.lo, self.hi)

    def apply(self, obs: Any, pred: dict[str, NDArray[np.float64]]) -> dict[str, NDArray[np.float64]]:
        """``pred`` with this term added (physical units, every channel of ``obs``; a term
        localised in a model force needs ``obs`` from :func:`with_model_features`)."""
        if self.feature not in obs.features:
            raise KeyError(f"feature {self.feature!r} is not in these observations: pass with_model_features(obs, pred) "
                           "for a term localised in a force of the model")
        out = {ch: np.asarray(p, dtype=float).copy() for ch, p in pred.items()}
        w = self.magnitude * self.weight(np.asarray(obs.features[self.feature], dtype=float))
        for ch, d in _direction_vectors(obs, self.direction).items():
            out[ch] = out[ch] + d * w
        return out

    def localisation(self) -> str:
        """``where slip < -0.1``, ``for 15 <= |slip angle| < 45 deg``..."""
        name, unit = FEATURES[self.feature]
        u = f" {unit}" if unit else ""
        if self.shape == "constant":
            return "at every condition"
        if self.shape in ("above", "hinge_above"):
            return f"where {name} > {self.lo:.3g}{u}"
        if self.shape in ("below", "hinge_below"):
            return f"where {name} < {self.lo:.3g}{u}"
        return f"where {self.lo:.3g} <= {name} < {self.hi:.3g}{u}"

    def law(self) -> str:
        """The term as a sentence, in report units."""
        what, unit = DIRECTIONS[self.direction]
        f = 1e3 if self.direction == "sinkage" else 1.0
        m, e = self.magnitude * f, self.std_error * f
        name, funit = FEATURES[self.feature]
        if self.shape.startswith("hinge"):
            side = "above" if self.shape == "hinge_above" else "below"
            per = f"{funit} of {name}" if funit else f"unit of {name}"
            return f"extra {what} of {m:.3g} ± {e:.2g} {unit} per {per} {side} {self.lo:.3g}"
        return f"extra {what} of {m:.3g} ± {e:.2g} {unit} {self.localisation()}"

    def experiment(self) -> str:
        """What experiment would confirm (or refute) the physics behind the term."""
        return f"to confirm: {_EXPERIMENT[self.direction]}; the term acts {self.localisation()}"

    def to_json(self) -> dict[str, Any]:
        """SI fields, the law and the experiment."""
        return {"direction": self.direction, "feature": self.feature, "shape": self.shape, "lo": self.lo, "hi": self.hi,
                "magnitude_si": self.magnitude, "std_error_si": self.std_error, "rows": self.rows, "law": self.law(),
                "experiment": self.experiment()}


@dataclass
class WheelEmpiricalResult:
    """What :func:`search_wheel_empirical` found.

    Attributes
    ----------
    status : {"explained", "partly_explained", "none"}
    terms : list of WheelTerm
        Accepted terms (at most two), in order of acceptance.
    held_out : list of float
        Each accepted term's held-out improvement ``D`` (engine units), and its p-value in ``p``.
    tried : list of (WheelTerm, float, float)
        Every search's best term with its ``D`` and p, accepted or not (the report's audit trail).
    excess_fraction : float
        Share of the held-out excess chi-square the accepted terms remove (the units of the test:
        noise x dispersion; what the status decision uses).
    noise_chi2 : tuple (before, after, values, k)
        Residual chi-square in noise units (s = 1) without and with the terms
        (:attr:`excess_removed` is reported in these units, beside the misfit lines).
    misfit_after : list
        Channels misfitting beyond noise with the terms (the engine's lack-of-fit test).
    library_held_out : float
        The library's best explanation's held-out improvement (NaN: none), for comparison.
    lookalikes : list of list of WheelTerm
        For each accepted term, the terms localised in another feature that fit the data as
        well (penalised in-sample score within 2): where it acts is then not determined between
        them, and the report says so.
    simulator : str
        Whether the rover simulator can apply the terms (it cannot: measurement space).
    """

    status: str
    terms: list[WheelTerm]
    held_out: list[float]
    p: list[float]
    tried: list[tuple[WheelTerm, float, float]]
    excess_fraction: float
    chi2_base: float
    values: int
    misfit_after: list[tuple[str, float, int, float]] = field(default_factory=list)
    n_null: int = 0
    library_held_out: float = math.nan
    lookalikes: list[list[WheelTerm]] = field(default_factory=list)
    noise_chi2: tuple[float, float, int, int] = (math.nan, math.nan, 0, 0)
    simulator: str = ("not written to accepted_truth.toml: a testbed term acts in the testbed's measurement space "
                      "and the rover simulator has no hook for it (empirical_terms.json holds it)")

    def summary_lines(self) -> list[str]:
        """Report lines (appended to the engine's summary)."""
        if not self.terms:
            best = (f"; best try: {self.tried[0][0].law()}, held-out improvement {self.tried[0][1]:.1f}, "
                    f"p = {self.tried[0][2]:.3g}") if self.tried else ""
            return [f"empirical terms: none passes the held-out test against its null ({self.n_null} noise draws){best}"]
        head = {"explained": "EXPLAINED by empirical term(s) (no library physics named)",
                "partly_explained": "PARTLY EXPLAINED by empirical term(s) (no library physics named)"}[self.status]
        out = [f"empirical: {head}"]
        for i, (t, d, p) in enumerate(zip(self.terms, self.held_out, self.p)):
            out.append(f"  - {t.law()} ({t.rows} rows); held-out improvement {d:.1f} (p = {p:.3g}, "
                       f"{self.n_null} noise draws of the same search)")
            out.append(f"    {t.experiment()}")
            for a in (self.lookalikes[i] if i < len(self.lookalikes) else []):
                out.append(f"    equally well localised (these conditions cannot tell them apart): {a.law()}")
        lib = ""
        if math.isfinite(self.library_held_out):
            lib = f"; the library's best explanation: {self.library_held_out:.1f}"
        out.append(f"  held-out chi2 in noise x dispersion units (the units of the test): {self.chi2_base:.1f} -> "
                   f"{self.chi2_base - sum(self.held_out):.1f} for {self.values} values{lib}")
        out.append(f"  {self.noise_units_line()}")
        for ch, c2, n, p in self.misfit_after:
            out.append(f"  misfit left in {ch} after the empirical terms: chi2 {c2:.0f} for {n} rows in noise units (p = {p:.2g})")
        out.append(f"  {self.simulator}")
        return out

    @property
    def excess_removed(self) -> float:
        """Share (0..1) of the excess residual chi-square over the noise that the terms remove, in
        noise units (s = 1, the units of the misfit lines); NaN without terms or excess."""
        before, after, n, k = self.noise_chi2
        if not self.terms or not before > n:
            return math.nan
        return float(min(1.0, max(0.0, 1.0 - (after - (n - k)) / (before - n))))

    def noise_units_line(self) -> str:
        """The residual chi-square in noise units before and after, and the share of the excess
        removed (never rounded up to 100 % beside a remaining misfit)."""
        before, after, n, k = self.noise_chi2
        frac = self.excess_removed
        if not math.isfinite(frac):
            share = "no excess over noise to remove"
        elif self.misfit_after:
            share = f"{math.floor(1000 * min(frac, 0.999)) / 10:.1f} % of the excess over noise removed, a misfit above noise remains"
        else:
            share = f"{100 * frac:.0f} % of the excess over noise removed"
        return (f"residual chi2 in noise units (the units of the misfit lines): {before:.0f} -> {after:.0f} for {n} values, "
                f"{n - k} expected from noise alone: {share}")

    def to_json(self) -> dict[str, Any]:
        """JSON-able result."""
        return {"status": self.status, "noise_chi2": list(self.noise_chi2), "excess_removed_noise_units": self.excess_removed, "terms": [t.to_json() for t in self.terms], "held_out_improvement": self.held_out,
                "p": self.p, "lookalikes": [[a.to_json() for a in al] for al in self.lookalikes], "excess_fraction": self.excess_fraction, "chi2_cv_base": self.chi2_base, "values": self.values,
                "null_draws": self.n_null, "library_held_out_improvement": self.library_held_out,
                "misfit_after": [list(m) for m in self.misfit_after], "simulator": self.simulator,
                "tried": [{**t.to_json(), "held_out_improvement": d, "p": p} for t, d, p in self.tried]}


# ----------------------------------------------------------------------------------- columns
def _shape(shape: str, v: NDArray[np.float64], lo: float, hi: float) -> NDArray[np.float64]:
    if shape == "constant":
        return np.ones_like(v)
    if shape == "above":
        return (v > lo).astype(float)
    if shape == "below":
        return (v < lo).astype(float)
    if shape == "hinge_above":
        return np.maximum(v - lo, 0.0)
    if shape == "hinge_below":
        return np.maximum(lo - v, 0.0)
    if shape == "box":
        return ((v >= lo) & (v < hi)).astype(float)
    raise ValueError(f"shape {shape!r}: expected one of {sorted(SHAPES)}")


def _direction_vectors(obs: Any, direction: str) -> dict[str, NDArray[np.float64]]:
    """Per-channel change of the prediction per unit magnitude (SI) for each row."""
    n = len(obs)
    if direction == "drag":
        v = np.hypot(obs.vx, obs.vy)
        v = np.where(v > 0, v, 1.0)
        return {"Fx": -np.asarray(obs.vx, dtype=float) / v, "Fy": -np.asarray(obs.vy, dtype=float) / v}
    if direction in ("Fx", "Fy", "sinkage"):
        return {direction: np.ones(n)}
    raise ValueError(f"direction {direction!r}: expected one of {sorted(DIRECTIONS)}")


def _levels(v: NDArray[np.float64], max_thresholds: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Distinct levels (values within 1 % of the span of a level's first value are that level)
    and the midpoints between them (at most ``max_thresholds`` of each, by quantile)."""
    u = np.sort(v[np.isfinite(v)])
    if u.size == 0:
        return np.empty(0), np.empty(0)
    tol = 0.01 * float(u[-1] - u[0])
    groups: list[list[float]] = [[float(u[0])]]
    for x in u[1:]:
        if x - groups[-1][0] > tol:
            groups.append([float(x)])
        else:
            groups[-1].append(float(x))
    levels = [float(np.mean(g)) for g in groups]
    lev = np.array(levels)
    mids = 0.5 * (lev[1:] + lev[:-1])

    def thin(a: NDArray[np.float64]) -> NDArray[np.float64]:
        if a.size <= max_thresholds:
            return a
        idx = np.unique(np.round(np.linspace(0, a.size - 1, max_thresholds)).astype(int))
        return a[idx]

    return thin(lev), thin(mids)


def with_model_features(obs: Any, pred: dict[str, NDArray[np.float64]]) -> Any:
    """``obs`` with the model-state features of :data:`FEATURES` (``|F_x|``, ``|F_y|`` of the
    model as given, ``pred``) added to its ``features``."""
    from dataclasses import replace

    return replace(obs, features={**obs.features, "model_abs_Fx_N": np.abs(np.asarray(pred["Fx"], dtype=float)),
                                  "model_abs_Fy_N": np.abs(np.asarray(pred["Fy"], dtype=float))})


def term_columns(obs: Any, scale: dict[str, float], min_rows: int = 3, max_thresholds: int = 14
                 ) -> tuple[list[tuple[str, str, str, float, float]], NDArray[np.float64]]:
    """Every term of the family on these conditions.

    Returns
    -------
    specs : list of (direction, feature, shape, lo, hi)
    A : ndarray (rows, channels, columns)
        Change of the normalised residual's prediction per unit magnitude (``a`` in the module
        notes; the residual of the model with the term is ``z - m a``).
    """
    chans = list(obs.channels)
    n = len(obs)
    dirs = {d: _direction_vectors(obs, d) for d in DIRECTIONS}
    dirs = {d: vec for d, vec in dirs.items() if all(ch in chans for ch in vec)}
    denom = {ch: np.asarray(obs.noise[ch], dtype=float) * scale[ch] for ch in chans}
    specs: list[tuple[str, str, float, float]] = []
    weights: list[NDArray[np.float64]] = []
    for feat in FEATURES:
        if feat not in obs.features:
            continue
        v = np.asarray(obs.features[feat], dtype=float)
        lev, mids = _levels(v, max_thresholds)
        shapes: list[tuple[str, float, float]] = []
        if feat == "slip":
            shapes.append(("constant", math.nan, math.nan))
        for lo in mids:
            shapes += [("above", float(lo), math.nan), ("below", float(lo), math.nan)]
        for lo in lev:
            shapes += [("hinge_above", float(lo), math.nan), ("hinge_below", float(lo), math.nan)]
        edges = np.concatenate([[-np.inf], mids, [np.inf]])
        for i in range(edges.size - 1):
            for j in range(i + 1, edges.size):
                if i == 0 and j == edges.size - 1:
                    continue
                shapes.append(("box", float(edges[i]), float(edges[j])))
        for shape, lo, hi in shapes:
            w = _shape(shape, v, lo, hi)
            w = np.where(np.isfinite(w), w, 0.0)
            if shape != "constant" and np.count_nonzero(w) < min_rows:
                continue
            if shape == "box" and (math.isinf(lo) or math.isinf(hi)):
                continue  # a half-open box is a step
            specs.append((feat, shape, lo, hi))
            weights.append(w)
    W = np.stack(weights, axis=1) if weights else np.empty((n, 0))
    cols: list[NDArray[np.float64]] = []
    out_specs: list[tuple[str, str, str, float, float]] = []
    for d, vec in dirs.items():
        a = np.zeros((n, len(chans), W.shape[1]))
        for ch, dv in vec.items():
            a[:, chans.index(ch), :] = (dv / denom[ch])[:, None] * W
        cols.append(a)
        out_specs += [(d, f, s, lo, hi) for f, s, lo, hi in specs]
    A = np.concatenate(cols, axis=2) if cols else np.empty((n, len(chans), 0))
    A = np.where(np.isfinite(A), A, 0.0)
    return out_specs, A


# ------------------------------------------------------------------------------------ search
def _select(ar: NDArray[np.float64], aa: NDArray[np.float64], penalty: NDArray[np.float64]) -> int:
    """Index of the best column by ``(a.r)^2 / (a.a) - 2 k`` (columns with no weight excluded)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.where(aa > 0, ar**2 / np.where(aa > 0, aa, 1.0), -np.inf) - penalty
    return int(np.argmax(score))


def _held_out(Z: NDArray[np.float64], A_rows_aa: NDArray[np.float64], A: NDArray[np.float64], folds: NDArray[np.int_],
              penalty: NDArray[np.float64]) -> float:
    """Nested held-out improvement ``D`` of the search on residuals ``Z`` (rows x channels)."""
    ar_rows = np.einsum("rcj,rc->rj", A, Z)
    ar_all, aa_all = ar_rows.sum(axis=0), A_rows_aa.sum(axis=0)
    d = 0.0
    for f in np.unique(folds):
        held = folds == f
        ar_tr = ar_all - ar_rows[held].sum(axis=0)
        aa_tr = aa_all - A_rows_aa[held].sum(axis=0)
        j = _select(ar_tr, aa_tr, penalty)
        if not aa_tr[j] > 0:
            continue
        m = ar_tr[j] / aa_tr[j]
        d += float(2.0 * m * ar_rows[held, j].sum() - m * m * A_rows_aa[held, j].sum())
    return d


def _one_term(Z: NDArray[np.float64], A: NDArray[np.float64], specs: Sequence[tuple[str, str, str, float, float]],
              folds: NDArray[np.int_], rng: np.random.Generator, n_null: int, obs: Any
              ) -> tuple[WheelTerm, float, float, NDArray[np.float64], list[WheelTerm]]:
    """The best term on ``Z``, its held-out improvement, its p-value, its column and its
    look-alikes in other features."""
    aa_rows = np.einsum("rcj,rcj->rj", A, A)
    penalty = np.array([2.0 * SHAPES[s[2]] for s in specs])
    d = _held_out(Z, aa_rows, A, folds, penalty)
    exceed = 0
    for _ in range(n_null):
        if _held_out(rng.standard_normal(Z.shape), aa_rows, A, folds, penalty) >= d:
            exceed += 1
    p = (1 + exceed) / (1 + n_null)
    ar = np.einsum("rcj,rc->j", A, Z)
    aa = aa_rows.sum(axis=0)
    j = _select(ar, aa, penalty)
    term = _term(specs, j, ar, aa, obs)
    # look-alikes: the best term localised in each other feature whose penalised score is within
    # 2 of the chosen one's (the data cannot tell where the effect acts between these)
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.where(aa > 0, ar**2 / np.where(aa > 0, aa, 1.0), -np.inf) - penalty
    alike: list[WheelTerm] = []
    for feat in FEATURES:
        if feat == term.feature:
            continue
        idx = [i for i, sp in enumerate(specs) if sp[1] == feat]
        if idx:
            i = idx[int(np.argmax(score[idx]))]
            if score[i] >= score[j] - 2.0:
                alike.append(_term(specs, i, ar, aa, obs))
    return term, d, p, A[:, :, j], alike


def _term(specs: Sequence[tuple[str, str, str, float, float]], j: int, ar: NDArray[np.float64], aa: NDArray[np.float64],
          obs: Any) -> WheelTerm:
    direction, feat, shape, lo, hi = specs[j]
    w = _shape(shape, np.asarray(obs.features[feat], dtype=float), lo, hi)
    return WheelTerm(direction, feat, shape, lo, hi, float(ar[j] / aa[j]), float(1.0 / math.sqrt(aa[j])), int(np.count_nonzero(w)))


def search_wheel_empirical(v: Any, alpha: float = 0.01, seed: int = 0, k_folds: int = 5, max_terms: int = 2,
                           min_rows: int = 3) -> WheelEmpiricalResult:
    """Model what the library lacks with the generic empirical family (module notes).

    Parameters
    ----------
    v : Verdict
        A single-wheel verdict of :func:`offline.discrepancy.engine.diagnose` (its observations,
        the model as given's predictions ``pred_before`` and the dispersion ``scale``).
    alpha : float
        Level of each term's held-out test (``ceil(2 / alpha)`` null draws).
    seed : int
        Seed of the null draws.
    k_folds : int
        Folds (the recording's own stratified folds).
    max_terms : int
        At most this many terms, each with its own test.
    min_rows : int
        A localised term covers at least this many rows.

    Returns
    -------
    WheelEmpiricalResult
    """
    from ..engine import _lack_of_fit
    from ..significance import fail_floor, normalised

    if not 0.0 < alpha < 0.5:
        raise ValueError(f"alpha = {alpha}: expected 0 < alpha < 0.5")
    obs = with_model_features(v.observations, v.pred_before)
    rng = np.random.default_rng(seed)
    n_null = int(math.ceil(2.0 / alpha))
    # a row the model as given cannot predict counts its worst row on the channel, as in the engine
    # (significance.fail_floor), not a fixed FAIL_Z
    Z = normalised(obs, v.pred_before, v.scale, fail_floor(obs, v.pred_before, v.scale))
    specs, A = term_columns(obs, v.scale, min_rows=min_rows)
    folds = obs.folds(k_folds)
    chi2_base = float((Z**2).sum())
    nvals = int(Z.size)
    terms: list[WheelTerm] = []
    held: list[float] = []
    ps: list[float] = []
    tried: list[tuple[WheelTerm, float, float]] = []
    lookalikes: list[list[WheelTerm]] = []
    for _ in range(max_terms):
        if A.shape[2] == 0:
            break
        term, d, p, col, alike = _one_term(Z, A, specs, folds, rng, n_null, obs)
        tried.append((term, d, p))
        if not (p < alpha and d > 0):
            break
        terms.append(term)
        lookalikes.append(alike)
        held.append(d)
        ps.append(p)
        Z = Z - term.magnitude * col
    pred = {ch: np.asarray(p, dtype=float) for ch, p in v.pred_before.items()}
    for t in terms:
        pred = t.apply(obs, pred)
    k = sum(t.k for t in terms)
    misfit = _lack_of_fit(obs, pred, k, alpha) if terms else []
    excess = chi2_base - nvals
    frac = float(min(1.0, sum(held) / excess)) if terms and excess > 0 else 0.0
    if not terms:
        status = "none"
    elif frac >= 0.5 and not misfit:
        status = "explained"
    else:
        status = "partly_explained"
    lib = float(v.chi2_cv_base - v.chosen.chi2_cv) if getattr(v, "chosen", None) is not None else math.nan
    zb = np.concatenate([(obs.measured[ch] - v.pred_before[ch]) / obs.noise[ch] for ch in obs.channels])
    za = np.concatenate([(obs.measured[ch] - pred[ch]) / obs.noise[ch] for ch in obs.channels])
    fin = np.isfinite(zb) & np.isfinite(za)
    noise_chi2 = (float(zb[fin] @ zb[fin]), float(za[fin] @ za[fin]), int(fin.sum()), k)
    return WheelEmpiricalResult(status, terms, held, ps, tried, frac, chi2_base, nvals, misfit, n_null, lib, lookalikes,
                                noise_chi2)
