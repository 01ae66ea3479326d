"""EKF on heading, position, slip, crab angle and gyro bias (filterpy's ExtendedKalmanFilter, wrapped).

State (SI), :data:`STATE`:

* ``x``, ``y`` : world position, m;
* ``heading`` : yaw psi, rad, kept in (-pi, pi];
* ``slip`` : rover longitudinal slip s, so the travel speed is ``v = (1 - s) v_odo``, where
  ``v_odo`` is the wheel-odometry speed (below) -- the rover-level counterpart of the wheel
  slip ratio of eq. (5.2);
* ``crab`` : crab (lateral slip) angle alpha between the heading and the direction of travel,
  rad (positive: the rover moves to the left of where it points);
* ``gyro_bias`` : b, rad/s (the gyro reads ``r + b``).

Motion model (wheel odometry and yaw rate as inputs, per tick of length dt):

.. math::

    v &= (1 - s)\\,v_{odo}, \\qquad
    x^+ = x + dt\\,v\\cos(\\psi + \\alpha + \\alpha_c), \\qquad y^+ = y + dt\\,v\\sin(\\psi + \\alpha + \\alpha_c),\\\\
    \\psi^+ &= \\psi + dt\\,(r_{gyro} - b), \\qquad s^+ = s,\\ \\alpha^+ = \\alpha,\\ b^+ = b,

with the encoder and gyro noise mapped into the process noise through the input Jacobians, plus
random walks on slip, crab and bias. ``alpha_c`` is the crab the controller's own commands ask
for (an input, :attr:`Odometry.crab_cmd`: a lateral-force offset of eq. (7.27) makes the rover
crab until the soil's lateral resistance balances it), so the state ``crab`` is the rest: the
disturbance. Without it the commanded crab -- up to 4 deg within a tick after a sparse pose fix
moves the outer loop, measured in the simulator -- is model error no random walk of plausible
size covers. Its relative error ``crab_cmd_rel`` (the lateral resistance is a linearisation on
the believed soil) enters the process noise. The wheel-odometry speed is the least-squares travel speed
of the valid driven wheels: a wheel steered by beta and rolling at omega without slip moves the
rover at ``r_s omega / cos(beta)`` (eqs. (7.6)-(7.7) with zero lateral rover speed), so
``v_odo = sum(c_i r_s omega_i) / sum(c_i^2)`` with ``c_i = cos(beta_i)``.

Measurement: a pose fix ``(x, y, heading)`` with the heading residual wrapped (filterpy's
``residual=`` hook). A fix taken before the current tick is applied at the time it was taken
(the filter rewinds to the stored state before that time, predicts to the fix, updates and
re-predicts with the stored inputs); a fix older than the history is rejected with a counter.
Fixes whose squared Mahalanobis distance exceeds the gate are rejected; a run of rejected fixes
that agree with each other is a jump of the pose source and re-initialises the pose.
The covariance is symmetrised after every step; after every update (where round-off can
break it) it is checked by a Cholesky factorisation and repaired (eigenvalue floor) if it
stopped being positive definite; the repair is counted.

filterpy's ``predict_update`` is never called (it stores the wrong prior; STYLE.md point 4).

Import cost: ``from filterpy.kalman import ExtendedKalmanFilter`` runs ``filterpy.kalman``'s
package ``__init__``, which imports every filter of the package and, through ``filterpy.stats``,
``scipy.stats``: most of the controller's import time, for filters rtctl does not use. So the
class is taken from its own module file (``filterpy/kalman/EKF.py``, :func:`_filterpy_ekf`),
loaded under a private name with the two helpers it imports from ``filterpy.common``
(``filterpy/common/helpers.py``, numpy only) and a ``logpdf`` that imports ``filterpy.stats`` when
first called (only ``ExtendedKalmanFilter.log_likelihood`` calls it, which rtctl does not).
It is filterpy's own code, unchanged; where that layout is not found (another filterpy version)
the package import is used (:data:`FILTERPY_EKF_SOURCE` says which).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from numpy.typing import NDArray

from .config import ControllerConfig
from .inputs import finite_real
from .messages import Pose

__all__ = ["STATE", "EstimatorError", "EstimatorCounters", "Odometry", "wheel_odometry", "wrap_angle",
           "SlipHeadingEKF", "FILTERPY_EKF_SOURCE"]


def _filterpy_ekf() -> tuple[Any, str]:
    """filterpy's ``ExtendedKalmanFilter`` class and where it came from (module docstring):
    ``"module file"`` (filterpy/kalman/EKF.py without the package ``__init__``) or ``"package"``."""
    import importlib.util
    import sys
    import types
    from pathlib import Path

    if "filterpy.kalman" not in sys.modules:  # already imported: nothing to save
        placed: list[str] = []
        try:
            spec = importlib.util.find_spec("filterpy")
            root = Path(list(spec.submodule_search_locations or [])[0]) if spec is not None else None
            if root is not None and (root / "kalman" / "EKF.py").is_file() and (root / "common" / "helpers.py").is_file():
                hspec = importlib.util.spec_from_file_location("rtctl._filterpy_helpers", root / "common" / "helpers.py")
                espec = importlib.util.spec_from_file_location("rtctl._filterpy_ekf", root / "kalman" / "EKF.py")
                if hspec is not None and hspec.loader is not None and espec is not None and espec.loader is not None:
                    helpers = importlib.util.module_from_spec(hspec)
                    hspec.loader.exec_module(helpers)

                    def logpdf(*args: Any, **kwargs: Any) -> Any:
                        """filterpy.stats.logpdf, imported at the first call."""
                        from filterpy.stats import logpdf as real

                        return real(*args, **kwargs)

                    stand_ins = {"filterpy.stats": {"logpdf": logpdf},
                                 "filterpy.common": {"pretty_str": helpers.pretty_str, "reshape_z": helpers.reshape_z}}
                    for name, attrs in stand_ins.items():
                        if name not in sys.modules:  # the real module, if loaded, serves as is
                            mod = types.ModuleType(name)
                            mod.__dict__.update(attrs)
                            sys.modules[name] = mod
                            placed.append(name)
                    ekf = importlib.util.module_from_spec(espec)
                    espec.loader.exec_module(ekf)
                    return ekf.ExtendedKalmanFilter, "module file"
        except Exception:  # noqa: BLE001 - any surprise in another filterpy's layout: the package import below
            pass
        finally:
            for name in placed:  # the stand-ins served EKF.py's own imports only
                del sys.modules[name]
    from filterpy.kalman import ExtendedKalmanFilter

    return ExtendedKalmanFilter, "package"


if TYPE_CHECKING:
    from filterpy.kalman import ExtendedKalmanFilter
else:
    ExtendedKalmanFilter, FILTERPY_EKF_SOURCE = _filterpy_ekf()
FILTERPY_EKF_SOURCE: str
"""Where :class:`filterpy.kalman.ExtendedKalmanFilter` came from: ``"module file"`` or ``"package"``."""

STATE: tuple[str, ...] = ("x", "y", "heading", "slip", "crab", "gyro_bias")
"""Names of the EKF state entries, in order."""
_IX, _IY, _IPSI, _IS, _IA, _IB = range(6)
_EYE6 = np.eye(6)
_EYE6.flags.writeable = False  # copied where a transition matrix starts from it
_H = np.zeros((3, 6))
_H[0, _IX] = _H[1, _IY] = _H[2, _IPSI] = 1.0
_SLIP_LIMIT = 0.95  # |s| used in the motion model is clipped here (s -> 1 means no motion at all)
_MISSING_GYRO_SIGMA = 0.05  # rad/s: yaw-rate uncertainty while the gyro is out
_MAX_POSE = 1e6  # m, rad: a position or heading beyond this is garbage, not a place on a planet


class EstimatorError(ValueError):
    """Inconsistent estimator input (shapes, non-positive radius): a programming error upstream."""


def wrap_angle(a: float | NDArray[np.float64]) -> float | NDArray[np.float64]:
    """Wrap an angle (or array) to (-pi, pi]."""
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def _residual(z: NDArray[np.float64], hx: NDArray[np.float64]) -> NDArray[np.float64]:
    y = z - hx
    y[2] = wrap_angle(y[2])
    return y


@dataclass
class EstimatorCounters:
    """Counts of what the estimator did with its inputs (reported in the diagnostics)."""

    poses_accepted: int = 0
    poses_late_used: int = 0
    poses_too_old: int = 0
    poses_future: int = 0
    poses_gated: int = 0
    pose_resets: int = 0
    odometry_missing: int = 0
    gyro_missing: int = 0
    covariance_repairs: int = 0


@dataclass(frozen=True)
class Odometry:
    """Inputs of one prediction: odometry speed and its variance, gyro rate (nan if missing).

    Attributes
    ----------
    v_odo : float
        Wheel-odometry travel speed, m/s (nan: no usable wheel).
    var : float
        Variance of ``v_odo``, (m/s)^2.
    yaw_rate : float
        Gyro yaw rate, rad/s (nan: gyro reading rejected).
    crab_cmd : float
        Crab angle the commands active over the step ask for, rad (module docstring; 0: none).
    """

    v_odo: float
    var: float
    yaw_rate: float
    crab_cmd: float = 0.0


def wheel_odometry(wheel_speed: Sequence[float], steer: Sequence[float], valid: Sequence[bool],
                   wheel_radius: float | Sequence[float] | NDArray[np.float64], sigma_omega: float) -> tuple[float, float]:
    """Least-squares travel speed from the valid wheels and its variance (module docstring).

    ``wheel_radius``: one shearing radius, or one per wheel (a worn wheel: its rim moves the
    rover less per radian). Returns ``(nan, inf)`` when the valid wheels carry too little
    information (sum of cos^2 of their steering angles below 0.5, e.g. every usable wheel
    turned sideways).
    """
    if not isinstance(wheel_radius, (int, float)):
        radii = [float(r) for r in wheel_radius]
        num = den = var = 0.0
        for om, b, ok, r in zip(wheel_speed, steer, valid, radii):
            if ok:
                c = math.cos(b)
                num += c * r * om
                den += c * c
                var += (c * r * sigma_omega) ** 2
        if den < 0.5:
            return math.nan, math.inf
        return num / den, var / (den * den)
    num = den = 0.0
    for om, b, ok in zip(wheel_speed, steer, valid):
        if ok:
            c = math.cos(b)
            num += c * wheel_radius * om
            den += c * c
    if den < 0.5:
        return math.nan, math.inf
    return num / den, (sigma_omega * wheel_radius) ** 2 / den


class _Filter(ExtendedKalmanFilter):
    """filterpy's EKF with the nonlinear motion model in :meth:`predict_x`."""

    x: NDArray[np.float64]  # the state (filterpy keeps it as an attribute; typed here for mypy)

    def predict_x(self, u: Any = 0) -> None:
        """Eq. in the module docstring; ``u = (dt, v_odo, yaw_rate, crab_cmd)``."""
        dt, v_odo, r, a_cmd = u
        x: NDArray[np.float64] = self.x
        s = min(max(x[_IS], -_SLIP_LIMIT), _SLIP_LIMIT)
        v = (1.0 - s) * v_odo
        c = x[_IPSI] + x[_IA] + a_cmd
        x = x.copy()
        x[_IX] += dt * v * math.cos(c)
        x[_IY] += dt * v * math.sin(c)
        x[_IPSI] = wrap_angle(x[_IPSI] + dt * (r - x[_IB]))
        self.x = x


@dataclass
class _Snapshot:
    t: float
    x: NDArray[np.float64]
    P: NDArray[np.float64]
    u: Odometry | None = None  # input used from t to the next snapshot


class SlipHeadingEKF:
    """The controller's EKF (module docstring). Deterministic: state is ``(x, P, t)`` plus the
    short history used for late pose fixes; no clock, no randomness.

    Memory is bounded: the history holds at most ``ceil(max_pose_delay / period) + 2`` snapshots
    (12 with the defaults), the innovations of rejected pose fixes at most
    ``reset_after_rejections`` (5; only the last ones decide a pose jump), and the counters are
    a fixed set of integers.

    Parameters
    ----------
    config : ControllerConfig
        Noise levels and estimator settings.
    wheel_radius : float
        Shearing radius r_s, m (rim speed = omega r_s).
    """

    def __init__(self, config: ControllerConfig, wheel_radius: float) -> None:
        if not (math.isfinite(wheel_radius) and wheel_radius > 0):
            raise EstimatorError(f"wheel_radius must be finite and > 0, got {wheel_radius}")
        self.config = config
        self.wheel_radius = float(wheel_radius)
        n = config.noise
        self._R = np.diag([n.pose_xy ** 2, n.pose_xy ** 2, n.pose_heading ** 2])
        self._history_len = int(math.ceil(config.estimator.max_pose_delay / config.period)) + 2
        self.counters = EstimatorCounters()
        self.last_mahalanobis = math.nan
        self._rejected: deque[NDArray[np.float64]] = deque(maxlen=config.estimator.reset_after_rejections)
        self.reset(0.0)

    # ------------------------------------------------------------------ state
    def reset(self, t: float, x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> None:
        """Restart at a pose with the configured initial uncertainty; clears counters and history."""
        e = self.config.estimator
        self.ekf = _Filter(dim_x=6, dim_z=3)
        self.ekf.x = np.array([x, y, float(wrap_angle(heading)), e.initial_slip, 0.0, 0.0])
        self.ekf.P = np.diag([e.initial_sigma_xy ** 2, e.initial_sigma_xy ** 2, e.initial_sigma_heading ** 2,
                              e.initial_sigma_slip ** 2, e.initial_sigma_crab ** 2, e.initial_sigma_bias ** 2])
        self.ekf.R = self._R.copy()
        self.t = float(t)
        self.counters = EstimatorCounters()
        self.last_mahalanobis = math.nan
        self._rejected.clear()
        self._history: list[_Snapshot] = [_Snapshot(self.t, self.ekf.x.copy(), self.ekf.P.copy())]
        self._v_last = 0.0
        self._r_last = 0.0

    def rebase_time(self, t: float) -> None:
        """Move the filter's time to ``t`` keeping its state and covariance (the rover's clock
        was stepped or restarted, :mod:`rtctl.inputs`): the history of past steps is dropped,
        since pose fixes time-stamped on the old clock cannot be placed on the new one."""
        self.t = float(t)
        self._history = [_Snapshot(self.t, self.ekf.x.copy(), self.ekf.P.copy())]

    @property
    def x(self) -> NDArray[np.float64]:
        """State estimate (copy), in :data:`STATE` order."""
        return np.array(self.ekf.x, dtype=float)

    @property
    def P(self) -> NDArray[np.float64]:
        """State covariance (copy)."""
        return np.array(self.ekf.P, dtype=float)

    # ------------------------------------------------------------------ prediction
    def _transition(self, dt: float, u: Odometry) -> None:
        """Set F and Q for one step of length ``dt`` and run filterpy's predict."""
        n = self.config.noise
        x = self.ekf.x
        s = min(max(x[_IS], -_SLIP_LIMIT), _SLIP_LIMIT)
        ds_active = 1.0 if abs(x[_IS]) < _SLIP_LIMIT else 0.0
        v_odo, r = u.v_odo, u.yaw_rate
        var_v = u.var
        if not math.isfinite(v_odo):
            v_odo, var_v = self._v_last, max(self._v_last ** 2, 0.01 ** 2)
        var_r = n.gyro ** 2
        if not math.isfinite(r):
            r, var_r = self._r_last + x[_IB], _MISSING_GYRO_SIGMA ** 2
        v = (1.0 - s) * v_odo
        a_cmd = u.crab_cmd if math.isfinite(u.crab_cmd) else 0.0
        c = x[_IPSI] + x[_IA] + a_cmd
        cc, sc = math.cos(c), math.sin(c)
        F = _EYE6.copy()
        F[_IX, _IPSI] = F[_IX, _IA] = -dt * v * sc
        F[_IY, _IPSI] = F[_IY, _IA] = dt * v * cc
        F[_IX, _IS] = -dt * v_odo * cc * ds_active
        F[_IY, _IS] = -dt * v_odo * sc * ds_active
        F[_IPSI, _IB] = -dt
        # Q = g_v g_v' var_v + g_a g_a' (crab_cmd_rel a_cmd)^2 + the random walks, with
        # g_v = d x+ / d v_odo and g_a = d x+ / d crab_cmd (the same as d x+ / d crab): both are
        # zero outside (x, y), so the two outer products fill the (x, y) block only; written
        # entry by entry on floats (the same IEEE products and sums as the array form, so the
        # same values bit for bit, in a few dozen float operations instead of ten array ones)
        gx, gy = dt * (1 - s) * cc, dt * (1 - s) * sc
        ax, ay = float(F[_IX, _IA]), float(F[_IY, _IA])
        k_a = (n.crab_cmd_rel * a_cmd) ** 2
        Q = np.zeros((6, 6))
        Q[_IX, _IX] = (gx * gx) * var_v + (ax * ax) * k_a + dt * n.position_walk ** 2
        Q[_IY, _IY] = (gy * gy) * var_v + (ay * ay) * k_a + dt * n.position_walk ** 2
        Q[_IX, _IY] = Q[_IY, _IX] = (gx * gy) * var_v + (ax * ay) * k_a
        Q[_IPSI, _IPSI] = dt * dt * var_r
        Q[_IS, _IS] = dt * n.slip_walk ** 2
        Q[_IA, _IA] = dt * n.crab_walk ** 2
        Q[_IB, _IB] = dt * n.gyro_bias_walk ** 2
        self.ekf.F = F
        self.ekf.Q = Q
        self.ekf.predict(u=np.array([dt, v_odo, r, a_cmd]))
        # F P F' + Q with Q >= 0 stays positive definite: symmetrise only (checked after updates)
        P = self.ekf.P
        self.ekf.P = 0.5 * (P + P.T)

    def predict(self, t: float, u: Odometry) -> None:
        """Propagate to time ``t`` with the tick's odometry (``t`` after the filter's time); a
        step longer than ``config.max_gap`` is propagated as ``max_gap``."""
        dt = float(t) - self.t
        if not (math.isfinite(dt) and dt > 0):
            raise EstimatorError(f"predict to t = {t} from t = {self.t}: time must increase")
        if not math.isfinite(u.v_odo):
            self.counters.odometry_missing += 1
        if not math.isfinite(u.yaw_rate):
            self.counters.gyro_missing += 1
        self._history[-1].u = u
        # a dropout longer than max_gap is propagated as max_gap: the inputs over it are unknown,
        # and an unbounded dt would overflow the covariance (the controller counts the gap)
        self._transition(min(dt, self.config.max_gap), u)
        if math.isfinite(u.v_odo):
            self._v_last = u.v_odo
        if math.isfinite(u.yaw_rate):
            self._r_last = u.yaw_rate - float(self.ekf.x[_IB])
        self.t = float(t)
        self._history.append(_Snapshot(self.t, self.ekf.x.copy(), self.ekf.P.copy()))
        if len(self._history) > self._history_len:
            del self._history[0]

    # ------------------------------------------------------------------ pose fixes
    def update_pose(self, pose: Pose) -> str:
        """Use a pose fix; returns what happened: ``accepted``, ``late``, ``too_old``, ``future``,
        ``gated``, ``reset`` or ``invalid``.

        The fix must have finite fields, and position and heading below 1e6 in magnitude (else
        ``invalid``; the time stamp may be any finite rover clock value); it is used at
        ``pose.t`` (see the module docstring).
        """
        vals = tuple(finite_real(getattr(pose, k, None)) for k in ("t", "x", "y", "heading"))
        if not (all(math.isfinite(v) for v in vals) and all(abs(v) < _MAX_POSE for v in vals[1:])):
            return "invalid"
        pose = Pose(*vals)
        if pose.t > self.t + 1e-9:
            self.counters.poses_future += 1
            return "future"
        if pose.t < self._history[0].t - 1e-9 or self.t - pose.t > self.config.estimator.max_pose_delay + 1e-9:
            self.counters.poses_too_old += 1
            return "too_old"
        z = np.array([pose.x, pose.y, float(wrap_angle(pose.heading))])
        if pose.t >= self.t - 1e-9:
            return self._update_now(z)
        # late fix: rewind to the last snapshot at or before pose.t
        j = max(i for i, s in enumerate(self._history) if s.t <= pose.t + 1e-9)
        snap = self._history[j]
        saved = (self.ekf.x.copy(), self.ekf.P.copy())
        self.ekf.x, self.ekf.P = snap.x.copy(), snap.P.copy()
        u = snap.u
        if u is None:  # pragma: no cover - only the last snapshot has no input, and pose.t < self.t
            self.ekf.x, self.ekf.P = saved
            self.counters.poses_too_old += 1
            return "too_old"
        dt1 = pose.t - snap.t
        if dt1 > 1e-9:
            self._transition(dt1, u)
        verdict = self._update_now(z, count=False)
        if verdict not in ("accepted", "reset"):
            self.ekf.x, self.ekf.P = saved
            return verdict
        # re-predict: rest of interval j, then every later stored interval
        t_cur = pose.t
        for k in range(j, len(self._history) - 1):
            t_next = self._history[k + 1].t
            if k > j:
                self._history[k].x, self._history[k].P = self.ekf.x.copy(), self.ekf.P.copy()
            uk = self._history[k].u
            if uk is not None and t_next - t_cur > 1e-12:  # every snapshot but the last has its input
                self._transition(t_next - t_cur, uk)
            t_cur = t_next
        self._history[-1].x, self._history[-1].P = self.ekf.x.copy(), self.ekf.P.copy()
        if verdict == "accepted":
            self.counters.poses_late_used += 1
        return "late" if verdict == "accepted" else verdict

    def _update_now(self, z: NDArray[np.float64], count: bool = True) -> str:
        x, P = self.ekf.x, self.ekf.P
        y = _residual(z, _H @ x)
        S = _H @ P @ _H.T + self._R
        d2 = float(y @ np.linalg.solve(S, y))
        self.last_mahalanobis = d2
        if d2 > self.config.estimator.gate_chi2:
            self.counters.poses_gated += 1
            self._rejected.append(y)
            if self._pose_jump():
                self._reinitialise_pose(z)
                self.counters.pose_resets += 1
                self._rejected.clear()
                return "reset"
            return "gated"
        self._rejected.clear()
        self.ekf.update(z, lambda _x: _H, lambda xx: _H @ xx, R=self._R, residual=_residual)
        self.ekf.x[_IPSI] = wrap_angle(self.ekf.x[_IPSI])
        self._keep_pd()
        self.counters.poses_accepted += 1
        if count:
            self._history[-1].x, self._history[-1].P = self.ekf.x.copy(), self.ekf.P.copy()
        return "accepted"

    def _pose_jump(self) -> bool:
        """True when the last ``reset_after_rejections`` rejected innovations agree (a jump)."""
        k = self.config.estimator.reset_after_rejections
        if len(self._rejected) < k:
            return False
        last = list(self._rejected)[-k:]
        ref = last[-1]
        n = self.config.noise
        tol = np.array([4 * n.pose_xy + 0.02, 4 * n.pose_xy + 0.02, 4 * n.pose_heading + 0.02])
        return all(bool(np.all(np.abs(_residual(r.copy(), ref)) <= tol)) for r in last)

    def initialise_pose(self, pose: Pose) -> None:
        """Take a pose fix as the pose (the first fix of a drive), whatever the current estimate;
        the pose covariance becomes the fix's, slip, crab and bias keep theirs."""
        self._reinitialise_pose(np.array([pose.x, pose.y, float(wrap_angle(pose.heading))]))

    def _reinitialise_pose(self, z: NDArray[np.float64]) -> None:
        x, P = self.ekf.x, self.ekf.P
        x[_IX], x[_IY], x[_IPSI] = z
        P[:3, :] = 0.0
        P[:, :3] = 0.0
        P[:3, :3] = self._R
        self.ekf.x, self.ekf.P = x, P
        self._history[-1].x, self._history[-1].P = x.copy(), P.copy()

    def _keep_pd(self) -> None:
        P = 0.5 * (self.ekf.P + self.ekf.P.T)
        try:
            np.linalg.cholesky(P)
        except np.linalg.LinAlgError:
            w, V = np.linalg.eigh(P)
            P = (V * np.maximum(w, 1e-12)) @ V.T
            P = 0.5 * (P + P.T)
            self.counters.covariance_repairs += 1
        self.ekf.P = P
