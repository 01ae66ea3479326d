"""Calibrate the terramechanics model on single-wheel trials (dissertation section 5.3.2).

Two procedures, both weighted least squares with exact derivatives from the casadi graph of
the same physics (:func:`offline.physics.terramechanics.wrench_core`):

* :func:`fit_per_angle` -- the dissertation's procedure: a0, a1, b0, b1 for one slip angle
  with the *measured sinkage imposed*, residuals in F_x, F_y, F_z. The linear constraints
  ``a0 + a1 <= 1`` and ``b0 + b1 >= -1`` are kept by the reparametrisation
  ``a1 = u (1 - a0)``, ``b1 = -t (1 + b0)`` with ``u, t`` in [0, 1].
  :func:`fit_linear_in_beta` then fits the lines a0(beta), a1(beta) of Fig. 5.7 / Table 7.2.
* :func:`fit_joint` -- soil parameters together with contact-angle lines in |beta|, *given
  the load*: every trial's sinkage solves ``F_z(h) = W`` (5.34), and derivatives of the
  predictions flow through that solve by the implicit function theorem (for skidding
  trials also through the zero-slip sinkage that fixes theta_m0, theta_r0). The calibrated
  model therefore predicts sinkage as well as forces.

Residuals are normalised by the measurement noise: the pooled repeat spread of each
channel (:meth:`offline.fit.dataset.TrialSet.noise`). The dissertation normalised by the
measured values, which is undefined where a force crosses zero (F_y at beta = 0, F_x at
free rolling).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from ..physics.backend import CASADI
from .dataset import DatasetError, TrialSet, check_force_units
from ..physics.params import ContactTuning, ParameterError, Soil, Wheel
from ..physics.terramechanics import ModelOptions, PhysParams, WheelModel, wrench_core
from .validation import trial_states

__all__ = [
    "CalibrationError",
    "check_fit_data",
    "MOST_FAILED_FRACTION",
    "FitResult",
    "fit_per_angle",
    "fit_linear_in_beta",
    "fit_joint",
    "JOINT_PARAMETERS",
    "DEFAULT_BOUNDS",
    "leave_one_angle_out",
]

class CalibrationError(ValueError):
    """The data cannot give a calibration (too few trials, loads the model cannot carry,
    a fitted tuning outside the contact patch); the message says why and what to do."""


MOST_FAILED_FRACTION = 0.5
"""A fit whose final model carries the measured load on fewer than this fraction of the
trials is an error, never a calibration."""

UNDETERMINED_REL_SINGULAR_VALUE = 1e-8
"""A direction of the (column-normalised) Jacobian whose singular value is below this
fraction of the largest is not determined by the data; parameters with a component above
0.1 in such a direction are reported as not determined (NaN standard error)."""


# PhysParams field -> (lower, upper) bounds used by the fits
DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {
    "k": (1.0e6, 5.0e7),
    "n0": (0.5, 2.5),
    "n1": (0.0, 2.0),
    "n2": (0.0, 2.0),
    "c": (0.0, 5.0e3),
    "K": (1.0e-3, 0.1),
    "a0": (0.0, 1.0),
    "a1": (0.0, 1.0),
    "b0": (-1.0, 0.0),
    "b1": (-1.0, 0.0),
    "a0_beta": (-0.6, 0.6),
    "a1_beta": (-0.6, 0.6),
    "b0_beta": (-0.6, 0.6),
    "b1_beta": (-0.6, 0.6),
    "zeta": (0.0, 1.0),
}

JOINT_PARAMETERS: tuple[str, ...] = (
    "n0", "n1", "n2", "c", "K", "a0", "a0_beta", "a1", "a1_beta", "b0", "b0_beta", "b1", "b1_beta",
)
"""Default free parameters of :func:`fit_joint` (k is added when the plate tests support it)."""

_TUNING_FIELDS = {"a0": "a0", "a1": "a1", "b0": "b0", "b1": "b1", "a0_beta": "a0_per_rad",
                  "a1_beta": "a1_per_rad", "b0_beta": "b0_per_rad", "b1_beta": "b1_per_rad"}
_WHEEL_FIELDS = {"zeta": "grouser_volume_fraction"}
_SOIL_FIELDS = {"k": "k", "n0": "n0", "n1": "n1", "n2": "n2", "c": "cohesion", "K": "shear_modulus",
                "phi": "friction_angle", "rho": "unit_weight"}


@dataclass(frozen=True)
class FitResult:
    """Outcome of a least-squares calibration.

    Attributes
    ----------
    names : tuple of str
        Free parameters (PhysParams field names).
    values, std_errors : ndarray
        Estimates and their standard errors from ``(J^T J)^-1`` scaled by the residual
        variance (a local, Gaussian-noise estimate).
    soil, tuning : Soil, ContactTuning
        The calibrated sets.
    wheel : Wheel or None
        The wheel, with any calibrated field (zeta) replaced.
    cost, rms : float
        Final ``0.5 sum r^2`` and the rms of the normalised residuals.
    n_residuals, n_iterations : int
    seconds : float
    success : bool
    message : str
    """

    names: tuple[str, ...]
    values: NDArray[np.float64]
    std_errors: NDArray[np.float64]
    soil: Soil
    tuning: ContactTuning
    cost: float
    rms: float
    n_residuals: int
    n_iterations: int
    seconds: float
    success: bool
    message: str
    wheel: Wheel | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    determined: tuple[bool, ...] = ()

    @property
    def not_determined(self) -> tuple[str, ...]:
        """Free parameters the data cannot determine (no effect on the residuals, or only in
        a combination with others): their value is the start value, not an estimate."""
        if not self.determined:
            return ()
        return tuple(n for n, d in zip(self.names, self.determined) if not d)

    def table(self) -> str:
        """Parameter table as text (parameters the data cannot determine say so)."""
        und = set(self.not_determined)
        return "\n".join(
            f"  {n:>8} = {v: .5g}  not determined by the data (left at its start value)" if n in und
            else f"  {n:>8} = {v: .5g} ± {e:.2g}" for n, v, e in zip(self.names, self.values, self.std_errors))


def _apply(
    soil: Soil, tuning: ContactTuning, names: Sequence[str], values: Sequence[float], wheel: Wheel | None = None
) -> tuple[Soil, ContactTuning, Wheel | None]:
    s_kw: dict[str, Any] = {}
    t_kw: dict[str, Any] = {}
    w_kw: dict[str, Any] = {}
    for n, v in zip(names, values):
        if n in _TUNING_FIELDS:
            t_kw[_TUNING_FIELDS[n]] = float(v)
        elif n in _SOIL_FIELDS:
            s_kw[_SOIL_FIELDS[n]] = float(v)
        elif n in _WHEEL_FIELDS and wheel is not None:
            w_kw[_WHEEL_FIELDS[n]] = float(v)
        else:
            raise ValueError(f"parameter {n!r} cannot be calibrated; choose from {sorted(DEFAULT_BOUNDS)}")
    return replace(soil, **s_kw), replace(tuning, **t_kw), (replace(wheel, **w_kw) if wheel is not None else None)


class _Jacobians:
    """casadi evaluation of (F_x, F_y, F_z) and d/d(h, h_zero_slip, free params), mapped over states."""

    def __init__(self, base: PhysParams, names: Sequence[str], options: ModelOptions) -> None:
        import casadi as ca

        self._ca = ca
        x = ca.SX.sym("x", 5)
        p = ca.SX.sym("p", len(names))
        pp = base._replace(**{n: p[i] for i, n in enumerate(names)})
        wr, _ = wrench_core(CASADI, x[0], x[1], x[2], x[3], x[4], pp, options)
        f = ca.vertcat(wr[0], wr[1], wr[2])
        jac = ca.jacobian(f, ca.vertcat(x[3], x[4], p))
        self.fun = ca.Function("fj", [x, p], [f, jac])
        self._maps: dict[int, Any] = {}
        self.m = len(names)

    def __call__(self, X: NDArray[np.float64], p: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        n = X.shape[0]
        if n not in self._maps:
            self._maps[n] = self.fun.map(n)
        f, j = self._maps[n](X.T, np.repeat(p.reshape(-1, 1), n, axis=1))
        f = np.asarray(f).T  # (n, 3)
        # the mapped Jacobian is 3 x (n (2 + m)): one 3 x (2 + m) block per state
        jj = np.asarray(j).reshape(3, n, 2 + self.m).transpose(1, 0, 2)  # (n, 3, 2 + m)
        return f, jj


def _noise_scales(trials: TrialSet, noise: Mapping[str, float] | None) -> dict[str, float]:
    """Per-channel noise: given, else the pooled repeat spread (5 % of the load and 2 mm when
    there are no repeats). A channel whose spread is zero (not measured, or quantised to one
    value) cannot normalise residuals: that is an error naming the channel."""
    if noise is not None:
        sc = dict(noise)
    else:
        try:
            sc = trials.noise()
        except DatasetError:  # no repeats: documented fallback
            med = float(np.median(trials.Fz))
            sc = {"Fx": 0.05 * med, "Fy": 0.05 * med, "Fz": 0.05 * med, "sinkage": 2e-3}
    for ch in ("Fx", "Fy", "Fz", "sinkage"):
        if ch in sc and not (np.isfinite(sc[ch]) and sc[ch] > 0):
            raise ValueError(
                f"channel {ch} has noise {sc[ch]!r} (zero repeat spread: not measured or constant); pass "
                f"noise={{'{ch}': <sd>, ...}} explicitly, or remove the channel's trials"
            )
    return sc


def _zero_slip_sinkage(trials: TrialSet) -> NDArray[np.float64]:
    """Per trial: mean measured sinkage of the condition at the same slip angle whose slip
    is closest to zero (the measured stand-in for h_zero_slip when sinkage is imposed)."""
    out = np.empty(len(trials))
    for b in np.unique(trials.beta_cmd):
        idx = np.flatnonzero(trials.beta_cmd == b)
        s = trials.slip[idx]
        best = np.abs(s) <= np.abs(s).min() + 1e-9
        out[idx] = trials.sinkage[idx][best].mean()
    return out


def _least_squares(fun: Callable, x0: NDArray[np.float64], lb: NDArray[np.float64], ub: NDArray[np.float64], max_nfev: int) -> Any:
    from scipy.optimize import least_squares

    cache: dict[bytes, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}

    def both(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        key = x.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = fun(x)
        return cache[key]

    return least_squares(lambda x: both(x)[0], x0, jac=lambda x: both(x)[1], bounds=(lb, ub), x_scale="jac",
                         method="trf", max_nfev=max_nfev, xtol=1e-10, ftol=1e-10, gtol=1e-10)


def _determined(J: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which parameters the data determine: a column with no effect on the residuals, or a
    component above 0.1 in a direction of the column-normalised Jacobian whose singular
    value is below :data:`UNDETERMINED_REL_SINGULAR_VALUE` of the largest, is not."""
    norms = np.linalg.norm(J, axis=0)
    big = float(norms.max()) if norms.size else 0.0
    det = norms > UNDETERMINED_REL_SINGULAR_VALUE * max(big, 1e-300)
    if det.sum() >= 2:
        Js = J[:, det] / norms[det]
        try:
            _, sv, vt = np.linalg.svd(Js, full_matrices=False)
        except np.linalg.LinAlgError:
            return det
        weak = sv < UNDETERMINED_REL_SINGULAR_VALUE * sv[0]
        if weak.any():
            involved = np.any(np.abs(vt[weak]) > 0.1, axis=0)
            idx = np.flatnonzero(det)
            det[idx[involved]] = False
    return det


def _std_errors(J: NDArray[np.float64], r: NDArray[np.float64], n_par: int) -> NDArray[np.float64]:
    """Standard errors from ``s^2 (J^T J)^-1``, with the columns scaled to unit norm first so
    parameters of very different magnitude (k ~ 1e7, a0 ~ 1) do not fall below the
    pseudo-inverse's cut-off. Parameters the data do not determine (:func:`_determined`)
    get NaN, never a zero error; the others' errors are conditional on those held fixed."""
    dof = max(r.size - n_par, 1)
    s2 = float(r @ r) / dof
    det = _determined(J)
    out = np.full(n_par, np.nan)
    if not det.any():
        return out
    Jd = J[:, det]
    norms = np.linalg.norm(Jd, axis=0)
    Js = Jd / norms
    try:
        cov = np.linalg.pinv(Js.T @ Js) * s2
    except np.linalg.LinAlgError:
        return out
    out[det] = np.sqrt(np.clip(np.diag(cov), 0, None)) / norms
    return out


def check_fit_data(trials: TrialSet, names: Sequence[str], wheel: Wheel | None = None) -> None:
    """Refuse, before any fitting, data that cannot give a calibration.

    Parameters
    ----------
    trials : TrialSet
    names : sequence of str
        The free parameters.
    wheel : Wheel, optional
        When given, the loads are checked against it (:func:`offline.fit.dataset.check_force_units`).

    Raises
    ------
    CalibrationError
        Fewer than two trials, or fewer residuals (three per trial) than free parameters + 1.
    DatasetError
        Force columns in the wrong unit.
    """
    src = trials.source or "trials"
    n = len(trials)
    if n < 2:
        raise CalibrationError(
            f"{src}: {n} trial(s): a calibration needs several trials (repeats of several slip ratios and slip angles); "
            "a single trial cannot determine soil and contact parameters. Add trials, or use 'offnominal validate' "
            "to score a parameter file on it"
        )
    m = len(tuple(names))
    if 3 * n <= m:
        raise CalibrationError(
            f"{src}: {n} trials give {3 * n} residuals (F_x, F_y, sinkage per trial) for {m} free parameters; "
            f"need at least {m // 3 + 1} trials, or free fewer parameters"
        )
    if wheel is not None:
        check_force_units(trials, wheel)


def fit_per_angle(
    trials: TrialSet,
    soil: Soil,
    wheel: Wheel,
    start: ContactTuning,
    options: ModelOptions | None = None,
    noise: Mapping[str, float] | None = None,
    max_nfev: int = 200,
) -> FitResult:
    """Fit a0, a1, b0, b1 for the trials of one slip angle with the measured sinkage imposed.

    The dissertation's procedure (section 5.3.2): residuals in F_x, F_y, F_z; bounds
    ``0 <= a0, a1 <= 1``, ``-1 <= b0, b1 <= 0``; ``a0 + a1 <= 1``, ``b0 + b1 >= -1``.

    Parameters
    ----------
    trials : TrialSet
        Trials of one commanded slip angle (use :meth:`TrialSet.subset`).
    soil, wheel : Soil, Wheel
        The soil and wheel held fixed while the tuning is fitted.
    start : ContactTuning
        Starting point; beta slopes are ignored (set to zero).
    options : ModelOptions, optional
        Terramechanics variant (default :class:`ModelOptions()`).
    noise : mapping, optional
        Per-channel noise (N); defaults to the pooled repeat spread of ``trials``.
    max_nfev : int
        Residual-evaluation budget of the least-squares solver.
    """
    options = options or ModelOptions()
    t0 = time.perf_counter()
    sc = _noise_scales(trials, noise)
    base_t = replace(start, a0_per_rad=0.0, a1_per_rad=0.0, b0_per_rad=0.0, b1_per_rad=0.0)
    base = PhysParams.from_sets(soil, wheel, base_t)
    names = ("a0", "a1", "b0", "b1")
    jac = _Jacobians(base, names, options)
    vx, vy, w = trial_states(trials)
    rmax = 1.5 * wheel.radius + wheel.grouser_height
    h = np.clip(trials.sinkage, 1e-4 * wheel.shearing_radius, rmax)
    h0 = np.clip(_zero_slip_sinkage(trials), 1e-4 * wheel.shearing_radius, rmax)
    X = np.stack([vx, vy, w, h, h0], axis=1)
    meas = np.stack([trials.Fx, trials.Fy, trials.Fz], axis=1)
    scale = np.array([sc["Fx"], sc["Fy"], sc["Fz"]])

    def unpack(z: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        a0, u, b0, t = z
        p = np.array([a0, u * (1 - a0), b0, -t * (1 + b0)])
        dp = np.array([[1, 0, 0, 0], [-u, 1 - a0, 0, 0], [0, 0, 1, 0], [0, 0, -t, -(1 + b0)]], dtype=float)
        return p, dp

    def fun(z: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        p, dp = unpack(z)
        f, jj = jac(X, p)
        r = ((f - meas) / scale).ravel()
        J = (jj[:, :, 2:] @ dp / scale[None, :, None]).reshape(-1, 4)
        return r, J

    a0 = min(max(start.a0, 0.0), 1.0)
    b0 = min(max(start.b0, -1.0), 0.0)
    u = min(max(start.a1 / max(1 - a0, 1e-9), 0.0), 1.0)
    t = min(max(-start.b1 / max(1 + b0, 1e-9), 0.0), 1.0)
    z0 = np.array([a0, u, b0, t])
    lb, ub = np.array([0.0, 0.0, -1.0, 0.0]), np.array([1.0, 1.0, 0.0, 1.0])
    res = _least_squares(fun, np.clip(z0, lb + 1e-9, ub - 1e-9), lb, ub, max_nfev)
    p, dp = unpack(res.x)
    r, J = fun(res.x)
    se_z = _std_errors(J, r, 4)
    se = np.sqrt(np.diag(dp @ np.diag(se_z**2) @ dp.T))  # NaN propagates from an undetermined z
    tuning = replace(base_t, a0=float(p[0]), a1=float(p[1]), b0=float(p[2]), b1=float(p[3]),
                     name=f"per_angle_{math.degrees(float(np.median(trials.beta_cmd))):.0f}",
                     source="offline.fit.calibration.fit_per_angle (measured sinkage imposed)")
    return FitResult(names, p, se, soil, tuning, float(res.cost), float(np.sqrt(np.mean(r**2))), r.size,
                     int(res.nfev), time.perf_counter() - t0, bool(res.success), str(res.message),
                     determined=tuple(bool(x) for x in np.isfinite(se)))


def fit_linear_in_beta(per_angle: Mapping[float, ContactTuning], base: ContactTuning | None = None) -> ContactTuning:
    """Least-squares lines ``a0 = a_c + a_cb beta``, ``a1 = a_s + a_sb beta`` (7.8)-(7.9)
    through per-angle tunings (Fig. 5.7); b0, b1 are averaged (the chapter-7 model takes
    the exit angle from soil flow). Angles in degrees as keys; slopes stored per radian."""
    betas = np.radians(np.array(sorted(per_angle)))
    if betas.size < 2:
        raise ValueError("a line in beta needs per-angle tunings at two or more slip angles")
    A = np.stack([np.ones_like(betas), betas], axis=1)
    a0 = np.array([per_angle[b].a0 for b in sorted(per_angle)])
    a1 = np.array([per_angle[b].a1 for b in sorted(per_angle)])
    c0, *_ = np.linalg.lstsq(A, a0, rcond=None)
    c1, *_ = np.linalg.lstsq(A, a1, rcond=None)
    b0 = float(np.mean([per_angle[b].b0 for b in per_angle]))
    b1 = float(np.mean([per_angle[b].b1 for b in per_angle]))
    return ContactTuning(
        a0=float(c0[0]), a1=float(c1[0]), b0=b0, b1=b1, a0_per_rad=float(c0[1]), a1_per_rad=float(c1[1]),
        name="linear_in_beta", source="offline.fit.calibration.fit_linear_in_beta over per-angle fits",
    )


def _predict_with_sensitivities(
    jac: _Jacobians, model: WheelModel, trials: TrialSet, p: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Predictions (n, 3: F_x, F_y, h) given the load, and d/dp through the sinkage solves."""
    vx, vy, w = trial_states(trials)
    W = trials.Fz
    sol = model.sinkage_from_load(W, vx, vy, w)
    ok = sol.converged
    n, m = len(trials), jac.m
    pred = np.full((n, 3), np.nan)
    dpred = np.zeros((n, 3, m))
    if not ok.any():
        return pred, dpred, ok
    idx = np.flatnonzero(ok)
    h, h0 = sol.h[idx], sol.h_zero_slip[idx]
    rs = model.wheel.shearing_radius
    v = np.hypot(vx[idx], vy[idx])
    skid = rs * np.abs(w[idx]) < v
    # zero-slip states (for the skidding trials): omega = v / r_s, h = h0
    X0 = np.stack([vx[idx], vy[idx], np.sign(np.where(vx[idx] == 0, 1, vx[idx])) * v / rs, h0, h0], axis=1)
    X = np.stack([vx[idx], vy[idx], w[idx], h, h0], axis=1)
    f, J = jac(X, p)
    dh0 = np.zeros((idx.size, m))
    if skid.any():
        _, J0 = jac(X0[skid], p)
        dfz0_dh = J0[:, 2, 0] + J0[:, 2, 1]
        dh0[skid] = -J0[:, 2, 2:] / dfz0_dh[:, None]
    # slip trials: h_zero_slip is h itself
    dfz_dh = np.where(skid, J[:, 2, 0], J[:, 2, 0] + J[:, 2, 1])
    rhs = J[:, 2, 2:] + np.where(skid[:, None], J[:, 2, 1][:, None] * dh0, 0.0)
    dh = -rhs / dfz_dh[:, None]
    dh0 = np.where(skid[:, None], dh0, dh)
    for k in (0, 1):
        dpred[idx, k] = J[:, k, 2:] + J[:, k, 0][:, None] * dh + J[:, k, 1][:, None] * dh0
    dpred[idx, 2] = dh
    pred[idx, 0], pred[idx, 1], pred[idx, 2] = f[:, 0], f[:, 1], h
    return pred, dpred, ok


def fit_joint(
    trials: TrialSet,
    soil: Soil,
    wheel: Wheel,
    start: ContactTuning,
    names: Sequence[str] = JOINT_PARAMETERS,
    options: ModelOptions | None = None,
    noise: Mapping[str, float] | None = None,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    max_nfev: int = 100,
    progress: Callable[[int, float], None] | None = None,
    priors: Mapping[str, tuple[float, float]] | None = None,
) -> FitResult:
    """Fit soil parameters and contact-angle lines in |beta| jointly, given each trial's load.

    Residuals ``(F_x - F_x,meas) / s_Fx``, ``(F_y - F_y,meas) / s_Fy``,
    ``(h - h_meas) / s_h`` with the predicted sinkage solving ``F_z(h) = W`` (5.34); a trial
    whose load the model cannot carry gets the residual of the maximum sinkage and no
    gradient (it pushes the fit only through its value).

    Parameters
    ----------
    trials : TrialSet
        The trials fitted (every slip angle at once).
    soil, wheel : Soil, Wheel
        Starting soil and wheel; their fields not in ``names`` stay fixed.
    start : ContactTuning
        Starting contact-angle tuning (eqs. (7.8)-(7.9): lines in |beta|).
    names : sequence of str
        Free parameters (PhysParams field names, see :data:`DEFAULT_BOUNDS`).
    options : ModelOptions, optional
        Terramechanics variant (default :class:`ModelOptions()`).
    noise : mapping, optional
        Per-channel noise scales (N, m); defaults to the pooled repeat spread of ``trials``.
    bounds : mapping, optional
        ``name -> (low, high)`` in SI, overriding :data:`DEFAULT_BOUNDS`.
    max_nfev : int
        Residual-evaluation budget of the least-squares solver.
    progress : callable, optional
        Called as ``progress(evaluation, cost)``.
    priors : mapping, optional
        ``name -> (mean, sd)`` in SI: independent evidence on a parameter (e.g. k from the
        static plate tests, :mod:`offline.fit.bekker`), added as residuals ``(x - mean) / sd``.

    Returns
    -------
    FitResult
        Parameters the data cannot determine (e.g. zeta with the soil-flow exit angle on a
        wheel without grousers) are listed in ``not_determined`` with a NaN standard error.

    Raises
    ------
    CalibrationError
        Too few trials (:func:`check_fit_data`), the fitted model carries fewer than half of
        the measured loads, or the fitted tuning leaves the contact patch.
    DatasetError
        Force columns in the wrong unit for this wheel.
    """
    options = options or ModelOptions()
    t0 = time.perf_counter()
    check_fit_data(trials, names, wheel)
    sc = _noise_scales(trials, noise)
    bnd = dict(DEFAULT_BOUNDS)
    bnd.update(bounds or {})
    names = tuple(names)
    fittable = set(_TUNING_FIELDS) | set(_SOIL_FIELDS) | set(_WHEEL_FIELDS)
    unknown = [n for n in names if n not in bnd or n not in fittable]
    if unknown:
        raise ValueError(f"parameter(s) {unknown} cannot be calibrated; choose from {sorted(set(bnd) & fittable)}")
    base = PhysParams.from_sets(soil, wheel, start)
    jac = _Jacobians(base, names, options)
    meas = np.stack([trials.Fx, trials.Fy, trials.sinkage], axis=1)
    scale = np.array([sc["Fx"], sc["Fy"], sc["sinkage"]])
    rmax = 1.5 * wheel.radius + wheel.grouser_height
    lb = np.array([bnd[n][0] for n in names])
    ub = np.array([bnd[n][1] for n in names])
    x0 = np.clip(np.array([getattr(base, n) for n in names], dtype=float), lb, ub)
    x0 = np.clip(x0, lb + 1e-9 * (ub - lb), ub - 1e-9 * (ub - lb))
    count = [0]
    prior_idx = []
    for pname, (m, sd) in (priors or {}).items():
        if pname not in names:
            raise ValueError(f"prior on {pname!r}, which is not a free parameter ({list(names)})")
        if not (math.isfinite(m) and math.isfinite(sd) and sd > 0):
            raise ValueError(f"prior on {pname!r} needs a finite mean and sd > 0, got ({m}, {sd})")
        prior_idx.append((names.index(pname), (float(m), float(sd))))

    last_ok = [np.ones(len(trials), dtype=bool)]

    def fun(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        # the physics reads PhysParams only: set the free entries directly, so an iterate
        # whose tuning lines leave the contact patch at some untested slip angle does not
        # stop the fit (the final tuning is checked below)
        model = WheelModel(soil, wheel, start, options)
        model.params = base._replace(**{n: float(v) for n, v in zip(names, x)})
        pred, dpred, ok = _predict_with_sensitivities(jac, model, trials, x)
        last_ok[0] = ok
        pred = np.where(ok[:, None], pred, np.array([np.nan, np.nan, rmax]))
        if (~ok).any():  # value at the maximum sinkage for trials the wheel cannot carry
            bad = np.flatnonzero(~ok)
            vx, vy, w = trial_states(trials.subset(bad))
            wr = model.wrench(vx, vy, w, np.full(bad.size, rmax), np.full(bad.size, rmax))
            pred[bad, 0], pred[bad, 1] = wr.Fx, wr.Fy
        r = ((pred - meas) / scale).ravel()
        J = (dpred / scale[None, :, None]).reshape(-1, len(names))
        if prior_idx:
            rp = np.array([(x[i] - m) / sd for i, (m, sd) in prior_idx])
            Jp = np.zeros((len(prior_idx), len(names)))
            for row, (i, (_, sd)) in enumerate(prior_idx):
                Jp[row, i] = 1.0 / sd
            r, J = np.concatenate([r, rp]), np.vstack([J, Jp])
        count[0] += 1
        if progress is not None:
            progress(count[0], 0.5 * float(r @ r))
        return r, J

    res = _least_squares(fun, x0, lb, ub, max_nfev)
    r, J = fun(res.x)
    n_ok = int(last_ok[0].sum())
    if n_ok < MOST_FAILED_FRACTION * len(trials):
        raise CalibrationError(
            f"{trials.source or 'trials'}: at the fitted parameters the model carries the measured load on only {n_ok} "
            f"of {len(trials)} trials (the others exceed what the {wheel.name!r} wheel carries within its sinkage "
            "range, or fall below its resolution): no calibration. Check the force units, the wheel file "
            "(radius, width) and the starting soil"
        )
    se = _std_errors(J, r, len(names))
    try:
        s_, t_, w_ = _apply(soil, start, names, res.x, wheel)
    except ParameterError as exc:
        raise CalibrationError(
            f"the fitted parameters are outside their physical range: {exc}. Fit fewer slip angles' worth of slope "
            "(--max-beta-deg), or tighten the bounds of the per-degree slopes"
        ) from None
    t_ = replace(t_, name="joint_linear_in_beta", source="offline.fit.calibration.fit_joint (load given)")
    s_ = replace(s_, source=f"offline.fit.calibration.fit_joint from {soil.name}", name=f"{soil.name}_calibrated")
    if w_ is not None and any(n in _WHEEL_FIELDS for n in names):
        fitted = ", ".join(n for n in names if n in _WHEEL_FIELDS)
        w_ = replace(w_, name=f"{wheel.name}_calibrated", source=f"{wheel.source}; {fitted} from offline.fit.calibration.fit_joint")
    return FitResult(names, res.x.copy(), se, s_, t_, float(res.cost), float(np.sqrt(np.mean(r**2))), r.size,
                     int(res.nfev), time.perf_counter() - t0, bool(res.success), str(res.message), wheel=w_,
                     extra={"n_carried": n_ok}, determined=tuple(bool(x) for x in np.isfinite(se)))


def leave_one_angle_out(
    trials: TrialSet,
    soil: Soil,
    wheel: Wheel,
    start: ContactTuning,
    names: Sequence[str] = JOINT_PARAMETERS,
    options: ModelOptions | None = None,
    angles_deg: Sequence[float] | None = None,
    max_nfev: int = 40,
) -> dict[float, FitResult]:
    """Refit :func:`fit_joint` without each slip angle in turn (out-of-sample check).

    Returns
    -------
    dict
        Held-out angle (deg) -> the fit made without it; predict the held-out trials with
        ``result.soil`` and ``result.tuning``.
    """
    out = {}
    betas = np.round(np.degrees(np.unique(trials.beta_cmd)), 6)
    for b in angles_deg if angles_deg is not None else betas:
        keep = np.abs(np.degrees(trials.beta_cmd) - b) > 0.5
        out[float(b)] = fit_joint(trials.subset(keep), soil, wheel, start, names, options, max_nfev=max_nfev)
    return out
