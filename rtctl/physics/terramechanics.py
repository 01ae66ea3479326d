"""3D rigid-wheel terramechanics for any slip ratio and slip angle (dissertation ch. 5).

One implementation, two uses. :func:`wrench_core` is written against
:class:`rtctl.physics.backend.Backend`; with ``NUMPY`` it evaluates batched wheel states (on the
ground and on the rover, for each tick's exact residual), with the ground side's ``CASADI`` it
builds an ``SX`` graph with exact derivatives. ``offline.physics.terramechanics.WheelModel``
wraps both (validated batched evaluation, casadi functions with Jacobians, sinkage from load).
:func:`normal_force` is :func:`wrench_core`'s ``F_z`` alone, bit for bit (the two share the contact
stage), for the sinkage solve of eq. (5.34), which uses nothing else.

Frame and signs (Fig. 5.1): x forward along the wheel heading, y out of the wheel face,
z up; forces and moments are exerted by the soil on the wheel, moments about the wheel
centre. ``beta = -atan(v_y / v_x)`` (5.1); slip ratio (5.2) with ``r_s = r + h_g``; rim
angles measured from the downward vertical, positive toward the front. ``M_y`` is the soil
torque about +y (eq. 5.31): the motor must supply ``-M_y``.

Departures from the printed text (each also noted where it happens)
-------------------------------------------------------------------
* (5.2) prints ``(r_s w - v) / (r w)`` for slip; the denominator is ``r_s w`` (published code).
* (5.17) is garbled (``v_jT = v_y``). Rear skid region (theta < theta_0) has the slip shear
  velocity (5.13) (as the text says), and the front region (5.18) follows from (5.16) with
  ``K_v`` fixed by ``j_T(theta_0) = 0``; both integrate to (5.20) (pinned by a test).
* (5.30), (5.32) print the lateral-shear moment with the opposite sign to the bulldozing
  moment, although both forces act in +y below the axle. Moments here are ``r x F`` about
  the wheel centre for every stress, which reproduces (5.31) exactly. The bulldozing lever
  arm is the true depth of the centre of pressure below the axle,
  ``r_s cos(theta) - h_b + h_COP``, with ``h_COP`` the first moment of the pressure (5.22)-(5.23)
  over the blade depth; (5.33) as printed halves the cohesive terms of that ratio.
* Locked wheel (w = 0): the deformations (5.20)-(5.21) diverge as 1/w. They are evaluated
  as ``w j`` (finite) and ``1 - exp(-|w j| / (|w| K))`` with ``|w|`` floored at
  ``OMEGA_FLOOR``, which gives the analytic limit ``tau = c + sigma tan(phi)`` with no
  division by zero, in value and derivative.
* Counter-rotation (w r_s < 0 while travelling forward, s < -1): outside the model's
  domain. Numeric evaluation raises; the symbolic graph clips s to -1 in the empirical
  terms (n, theta_0) and keeps the exact kinematics.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from .backend import Backend, gauss_legendre, smooth_abs
from .parameters import ParameterError, SoilLike, TuningLike, WheelLike

__all__ = ["ModelOptions", "PhysParams", "wrench_core", "normal_force", "bulldozing_resistance", "shear_kinematics", "WRENCH_NAMES",
           "STATE_NAMES", "DIAG_NAMES", "OMEGA_FLOOR", "SPEED_FLOOR", "SHEAR_VELOCITY_REL_EPS"]

WRENCH_NAMES = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")
STATE_NAMES = ("vx", "vy", "omega", "h", "h_zero_slip")
DIAG_NAMES = ("slip", "beta", "theta_f", "theta_m", "theta_r", "theta_0", "n")

OMEGA_FLOOR = 1e-9
"""rad/s; |omega| is evaluated as sqrt(omega^2 + OMEGA_FLOOR^2) in the shear-deformation
exponent only. At the testbed's slowest driven rim speed (3 mm/s, omega = 0.05 rad/s) the
relative change is 2e-16."""

SPEED_FLOOR = 1e-12
"""m/s; guards v = |(v_x, v_y)| in the slip-ratio denominator (a wheel at rest)."""

SHEAR_VELOCITY_REL_EPS = 1e-6
"""Relative floor of |v_j| in the shear-direction ratio of eq. (5.11), scaled by
(v + |r_s w|): removes the 0/0 where both shear velocities vanish. Changes tau by less than
5e-13 relative wherever |v_j| > 1e-3 (v + |r_s w|)."""


@dataclass(frozen=True)
class ModelOptions:
    """Model variant switches.

    Parameters
    ----------
    exit_angle : {"classic", "soil_flow"}
        theta_r from eq. (5.4) with b0, b1, or from the soil-flow trench (section 5.2.1).
    bulldozing : {"pavlov", "hegedus", "ishigami"}
        ``pavlov``: R_b of eq. (5.24), integrated by (5.27) (the dissertation's model);
        ``hegedus``: the [66] form of R_b (times |sin beta|), integrated by (5.27);
        ``ishigami``: the [58] form, integrated by (5.29) (Ishigami 2007 sidewall);
        ``none``: no sidewall force (to study what the term contributes).
    bulldozing_scale : float
        Multiplier on the sidewall bulldozing resistance (1 = the published form); used by
        the discrepancy tool to fit how much sidewall force the data ask for.
    sidewall_projection : {"printed", "single"}
        The inclination factor of the sidewall force in (5.27): ``|sin b| sin b`` as printed
        (R_b of (5.24) already holds |sin b|), or a single ``sin b`` (the face normal is the
        wheel's y axis, so the second factor only carries the sign). Ignored for ishigami.
    nodes_per_segment : int
        Gauss-Legendre nodes on each of the six segments between theta_r, theta_f and the
        sorted breakpoints theta_m, theta_0 and the zeros of the tangential shear velocity
        (the kinks and jumps of the integrand).
    beta_smoothing : float
        rad; |beta| in the tuning (7.8)-(7.9) is sqrt(beta^2 + eps^2) so the linear a(beta)
        fit has no kink at beta = 0. Only matters when the tuning has beta slopes.
    soil_flow_smoothing_deg : float
        Width of the blend across soil-flow regime switches (passed to
        :func:`rtctl.physics.soil_flow.exit_angle`).
    shear_direction_smoothing : float
        Relative floor ``eps`` of the shear-velocity magnitude in the direction ratio of
        eq. (5.11), ``v_ji / sqrt(v_jT^2 + v_jL^2 + (eps (v + |r_s w|))^2)``. The ratio makes the
        shear direction switch abruptly where a shear velocity crosses zero (near free rolling
        a tiny slip angle turns most of the shear sideways), which is a near-discontinuity for
        an optimizer; a larger ``eps`` rounds it over that velocity width.
    """

    exit_angle: Literal["classic", "soil_flow"] = "classic"
    bulldozing: Literal["pavlov", "hegedus", "ishigami", "none"] = "pavlov"
    bulldozing_scale: float = 1.0
    sidewall_projection: Literal["printed", "single"] = "printed"
    nodes_per_segment: int = 8
    beta_smoothing: float = 1e-3
    soil_flow_smoothing_deg: float = 1.0
    shear_direction_smoothing: float = SHEAR_VELOCITY_REL_EPS

    def __post_init__(self) -> None:
        if self.exit_angle not in ("classic", "soil_flow"):
            raise ValueError(f"ModelOptions.exit_angle must be 'classic' or 'soil_flow', got {self.exit_angle!r}")
        if self.bulldozing not in ("pavlov", "hegedus", "ishigami", "none"):
            raise ValueError(
                f"ModelOptions.bulldozing must be 'pavlov', 'hegedus', 'ishigami' or 'none', got {self.bulldozing!r}"
            )
        if self.sidewall_projection not in ("printed", "single"):
            raise ValueError(f"ModelOptions.sidewall_projection must be 'printed' or 'single', got {self.sidewall_projection!r}")
        if not (math.isfinite(self.bulldozing_scale) and 0.0 <= self.bulldozing_scale <= 100.0):
            raise ValueError(f"ModelOptions.bulldozing_scale must be in [0, 100], got {self.bulldozing_scale!r}")
        if not (isinstance(self.nodes_per_segment, int) and 2 <= self.nodes_per_segment <= 200):
            raise ValueError(f"ModelOptions.nodes_per_segment must be an int in [2, 200], got {self.nodes_per_segment!r}")
        if not 0.0 < self.shear_direction_smoothing < 0.5:
            raise ValueError(f"ModelOptions.shear_direction_smoothing must be in (0, 0.5), got {self.shear_direction_smoothing!r}")
        if not 0.0 <= self.beta_smoothing < 0.1:
            raise ValueError(f"ModelOptions.beta_smoothing must be in [0, 0.1) rad, got {self.beta_smoothing!r}")


class PhysParams(NamedTuple):
    """Flat parameter vector of the physics; entries may be floats or casadi symbols.

    Built from the dataclasses by :meth:`from_sets`; calibration replaces entries by
    symbols to differentiate with respect to them.
    """

    k: Any
    n0: Any
    n1: Any
    n2: Any
    phi: Any
    rho: Any
    c: Any
    K: Any
    repose: Any
    r: Any
    b: Any
    hg: Any
    mu: Any
    zeta: Any
    a0: Any
    a1: Any
    b0: Any
    b1: Any
    a0_beta: Any
    a1_beta: Any
    b0_beta: Any
    b1_beta: Any

    @classmethod
    def from_sets(cls, soil: SoilLike, wheel: WheelLike, tuning: TuningLike | Any) -> "PhysParams":
        """Collect the SI values of ``soil``, ``wheel`` and ``tuning``.

        A :class:`~offline.physics.params.TuningTable` has no single a0..b1 and raises its
        :class:`~rtctl.physics.parameters.ParameterError` saying to take ``tuning_at(abs_beta)``."""
        if hasattr(tuning, "tuning_at"):  # offline.physics.params.TuningTable: one tuning per slip angle
            raise ParameterError(f"TuningTable {getattr(tuning, 'name', '?')!r} holds one tuning per slip angle, not a single a0..b1: "
                                 "build the model from tuning.tuning_at(abs_beta) (a ContactTuning)")
        return cls(
            soil.k, soil.n0, soil.n1, soil.n2, soil.friction_angle, soil.unit_weight, soil.cohesion,
            soil.shear_modulus, soil.repose_angle, wheel.radius, wheel.width, wheel.grouser_height,
            wheel.grouser_area_ratio, wheel.grouser_volume_fraction, tuning.a0, tuning.a1, tuning.b0,
            tuning.b1, tuning.a0_per_rad, tuning.a1_per_rad, tuning.b0_per_rad, tuning.b1_per_rad,
        )


def _parameter_terms(ops: Backend, phi: Any) -> tuple[Any, Any]:
    """``(cot X_c, tan phi)`` with ``X_c = pi/4 - phi/2`` (eqs. (5.24)-(5.25)): terms of the
    parameters alone. With numpy and a number ``phi`` they are computed once per value (the
    same numpy functions on the same number, so the same values), not at every evaluation."""
    if ops.name == "numpy" and isinstance(phi, float):
        return _parameter_terms_of(phi)
    return 1.0 / ops.tan(math.pi / 4 - phi / 2), ops.tan(phi)


@functools.lru_cache(maxsize=64)
def _parameter_terms_of(phi: float) -> tuple[Any, Any]:
    return 1.0 / np.tan(math.pi / 4 - phi / 2), np.tan(phi)


def _log_of(ops: Backend, v: Any) -> Any:
    """``log(v)`` of a parameter (a wheel radius): once per value with numpy and a number."""
    if ops.name == "numpy" and isinstance(v, float):
        return _log_of_number(v)
    return ops.log(v)


@functools.lru_cache(maxsize=64)
def _log_of_number(v: float) -> Any:
    return np.log(v)


def _scaled(scale: float, v: Any) -> Any:
    """``scale * v``; ``v`` itself when ``scale`` is 1.0 (the same value, one array operation less)."""
    return v if scale == 1.0 else scale * v


def bulldozing_resistance(ops: Backend, h_b: Any, rho: Any, c: Any, phi: Any, form: str) -> Any:
    """Bulldozing resistance of a unit-width blade of depth ``h_b`` (section 5.2.4), N/m.

    .. math::
        R_b^{\\mathrm{pavlov}} = \\tfrac12 \\rho h_b^2 \\cot^2 X_c (1 + \\tfrac12 \\cot X_c \\tan\\phi) + 2 h_b c \\cot X_c

    (eq. (5.24) without its |sin beta| factor), ``hegedus`` [66] has ``(1 + cot X_c tan phi)``
    and ``ishigami`` [58] twice the first term of [66]. ``X_c = pi/4 - phi/2``.
    """
    cot_x, tphi = _parameter_terms(ops, phi)
    coh = 2.0 * h_b * c * cot_x
    if form == "pavlov":
        return 0.5 * rho * h_b**2 * cot_x**2 * (1.0 + 0.5 * cot_x * tphi) + coh
    if form == "hegedus":
        return 0.5 * rho * h_b**2 * cot_x**2 * (1.0 + cot_x * tphi) + coh
    if form == "ishigami":
        return rho * h_b**2 * cot_x**2 * (1.0 + cot_x * tphi) + coh
    raise ValueError(f"unknown bulldozing form {form!r}")


def _pressure_coefficients(ops: Backend, rho: Any, c: Any, phi: Any, form: str) -> tuple[Any, Any]:
    """``(A, C)`` of the linear bulldozing pressure ``sigma_b(z) = A z + C`` at depth ``z`` below
    the soil surface whose integral over the blade depth is the chosen R_b form,
    ``R_b = A h_b^2 / 2 + C h_b`` (section 5.2.4, eqs. (5.22)-(5.25); ``C = 2 c cot X_c``)."""
    cot_x, tphi = _parameter_terms(ops, phi)
    if form == "pavlov":
        a = rho * cot_x**2 * (1.0 + 0.5 * cot_x * tphi)
    elif form == "hegedus":
        a = rho * cot_x**2 * (1.0 + cot_x * tphi)
    elif form == "ishigami":
        a = 2.0 * rho * cot_x**2 * (1.0 + cot_x * tphi)
    else:
        raise ValueError(f"unknown bulldozing form {form!r}")
    return a, 2.0 * c * cot_x


@functools.lru_cache(maxsize=8)
def _gauss_legendre_cached(n: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return gauss_legendre(n)


def shear_kinematics(
    ops: Backend, th: Any, ct: Any, st: Any, theta_f: Any, theta_0: Any, sin_f: Any, sin_0: Any, S: Any,
    skid: Any, vx: Any, rw: Any, vy: Any,
) -> tuple[Any, Any, Any, Any]:
    """Shear velocities and ``omega``-scaled deformations at rim angles ``th``.

    Tangential shear velocity (soil relative to rim), eqs. (5.13), (5.16)-(5.18):

    * slip, and skid rear region ``theta < theta_0``: ``v_jT = r_s w - v_x cos(theta)``
      (the printed (5.17) ``v_jT = v_y`` is garbled; the text says the rear region is as in slip);
    * skid front region ``theta > theta_0``: ``v_jT = v_x (S - cos(theta))`` with
      ``S = (sin theta_f - sin theta_0) / (theta_f - theta_0)``, i.e. (5.16) with
      ``K_v v_x = S v_x - r_s w`` fixed by ``j_T(theta_0) = 0``;
    * lateral, (5.14): ``v_jL = -v_y``.

    Deformations from (5.12) with ``d theta = -w dt``, multiplied by ``w`` so a locked
    wheel stays finite (5.20)-(5.21):

    * rear: ``w j_T = r_s w (theta_0 - theta) - v_x (sin theta_0 - sin theta)``
      (slip: theta_0 = theta_f),
    * front: ``w j_T = v_x (S (theta_f - theta) - (sin theta_f - sin theta))``,
    * ``w j_L = (theta_f - theta) v_y`` (sign irrelevant: only |j| enters (5.11)).

    So ``d(w j_T)/d theta = -v_jT`` in each region, ``j_T(theta_f) = 0`` and ``j_T`` is
    continuous (zero) at ``theta_0`` (tests pin all three).

    Returns
    -------
    vjT, vjL, jt_w, jl_w
    """
    front = skid * (th > theta_0)  # logical and, valid for numpy bools and casadi 0/1
    vct = vx * ct  # shared node arrays (fewer temporaries on the numpy path)
    vst = vx * st
    dth = theta_f - th
    vxs = vx * S  # per state
    # each region's last operation (- vct, + vst) taken out of the select: the same values, bit
    # for bit, with one node-array operation less in each
    vjT = ops.where(front, vxs, rw) - vct
    vjL = -vy  # per state; broadcasts against the nodes
    jt_w = ops.where(front, vxs * dth - vx * sin_f, rw * (theta_0 - th) - vx * sin_0) + vst
    jl_w = dth * vy
    return vjT, vjL, jt_w, jl_w


class _Contact(NamedTuple):
    """What the integrals of :func:`wrench_core` need from the contact (numpy arrays or SX)."""

    rs: Any
    sgn: Any
    sin_b: Any
    beta: Any
    s_raw: Any
    n: Any
    theta_f: Any
    theta_m: Any
    theta_r: Any
    theta_0: Any
    sin_f: Any
    cos_f: Any
    th: Any
    wq: Any
    ct: Any
    st: Any
    sigma: Any
    tau_max: Any
    tauT: Any
    vjL: Any


def _contact(ops: Backend, vx: Any, vy: Any, omega: Any, h: Any, h_zero_slip: Any, p: PhysParams,
             options: ModelOptions) -> _Contact:
    """Kinematics, contact angles, quadrature nodes and the rim stresses of :func:`wrench_core`
    (eqs. (5.1)-(5.21)): the part :func:`wrench_core` and :func:`normal_force` share."""
    rs = p.r + p.hg
    # Travel toward -x is the x-mirror image of travel toward +x (F_x, M_y, M_z flip sign).
    sgn = ops.where(vx < 0, -1.0, 1.0)
    vxp = sgn * vx
    wp = sgn * omega
    vy2 = vy * vy  # shared sub-expressions (the same values, fewer array operations)
    nvy = -vy
    v = ops.sqrt(vxp * vxp + vy2 + SPEED_FLOOR**2)
    beta = ops.arctan2(nvy, vxp)  # eq. (5.1)
    sin_b = nvy / v
    abs_b = smooth_abs(ops, beta, options.beta_smoothing)

    # Slip ratio, eq. (5.2) (denominator r_s w in slip, see module notes).
    rw = rs * wp
    skid = rw < v
    rw_v = rw - v
    s_raw = ops.where(skid, rw_v / v, rw_v / ops.fmax(rw, SPEED_FLOOR))
    s = ops.fmax(s_raw, -1.0)

    # Sinkage exponent, eq. (5.6).
    n = p.n0 + ops.where(skid, -p.n2 * s, p.n1 * s)

    # Contact angles, eqs. (5.3)-(5.4).
    theta_f = ops.arccos(1.0 - h / rs)
    theta_f0 = ops.arccos(1.0 - h_zero_slip / rs)
    a0 = p.a0 + p.a0_beta * abs_b
    a1 = p.a1 + p.a1_beta * abs_b
    b0 = p.b0 + p.b0_beta * abs_b
    b1 = p.b1 + p.b1_beta * abs_b
    theta_m = ops.where(skid, a0 * theta_f0, theta_f * (a0 + a1 * s))
    if options.exit_angle == "classic":
        theta_r = ops.where(skid, b0 * theta_f0, theta_f * (b0 + b1 * s))
    else:
        from .soil_flow import exit_angle  # local: soil flow is only needed for this variant

        theta_r = exit_angle(
            ops, h, beta, wp, vxp, _WheelView(p), _SoilView(p), smoothing_deg=options.soil_flow_smoothing_deg
        )
    theta_r = ops.fmin(theta_r, 0.0)
    # Keep theta_r < theta_m < theta_f (a tuning can push theta_m0 past a shallower skid theta_f).
    span = theta_f - theta_r
    margin = 1e-6 * span
    theta_m = ops.fmin(ops.fmax(theta_m, theta_r + margin), theta_f - margin)

    # Skid transition angle, eq. (5.15): theta_0 = theta_f (1 + (w r_s - v) / (2 v)).
    theta_0 = ops.where(skid, theta_f * (1.0 + 0.5 * s), theta_f)
    d0 = theta_f - theta_0
    sin_f = ops.sin(theta_f)
    sin_0 = ops.sin(theta_0)
    cos_f = ops.cos(theta_f)
    # S = (sin theta_f - sin theta_0) / (theta_f - theta_0) of (5.18); -> cos theta_f as d0 -> 0.
    big = d0 > 1e-7
    S = ops.where(big, (sin_f - sin_0) / ops.where(big, d0, 1.0), cos_f + 0.5 * sin_f * d0)  # mean of cos: > cos_f

    # Quadrature: Gauss-Legendre segments split at every kink and jump of the integrand:
    # theta_m (5.8), theta_0 (5.15), and the zeros of v_jT, where tau_T ~ v_jT / |v_j|
    # changes sign (a jump when v_y = 0): acos(S) in the skid front region and
    # +/- acos(r_s w / v_x) in the rear region (absent in slip, where r_s w > v_x).
    one = 1.0 - 1e-12
    theta_1 = ops.where(skid, ops.arccos(ops.clip(S, -one, one)), theta_f)
    ratio = rw / ops.fmax(vxp, SPEED_FLOOR)
    theta_star = ops.arccos(ops.clip(ratio, -one, one))
    # sorted and clamped into [theta_r, theta_f] by a network of fmin/fmax (Backend.segment_nodes)
    x_gl, w_gl = _gauss_legendre_cached(options.nodes_per_segment)
    th, wq = ops.segment_nodes(theta_r, theta_f, [theta_m, theta_0, theta_1, theta_star, -theta_star], x_gl, w_gl)
    ct = ops.cos(th)
    st = ops.sin(th)

    # Normal stress, eqs. (5.7)-(5.9). The rear region's equivalent angle (5.9) is linear in
    # theta with the slope k_e fixed per state: theta_e = (theta_f + k_e theta_r) - k_e theta
    # (per-state terms first: two node-array operations instead of four; the same function,
    # rounding apart).
    k_e = (theta_f - theta_m) / (theta_m - theta_r)
    theta_e = ops.where(th >= theta_m, th, (theta_f + k_e * theta_r) - th * k_e)
    # floors keep second derivatives finite at quadrature nodes that coincide with theta_f
    # (zero-length segments): 1e-300 made log''/sqrt'' overflow to inf, and 0 * inf = NaN in
    # IPOPT's Hessian. sigma ~ base^n, so the 1e-12 floor changes stresses by < 1e-15 Pa.
    base = ops.fmax(ops.cos(theta_e) - cos_f, 1e-12)
    radial = p.mu * ops.exp(n * _log_of(ops, rs)) + (1.0 - p.mu) * ops.exp(n * _log_of(ops, p.r))
    sigma = (p.k * radial) * ops.exp(n * ops.log(base))  # base^n (exp and log: fewer instructions than pow)

    # Shear velocities (5.13)-(5.19) and deformations (5.20)-(5.21), both multiplied by w.
    vjT, vjL, jt_w, jl_w = shear_kinematics(ops, th, ct, st, theta_f, theta_0, sin_f, sin_0, S, skid, vxp, rw, vy)
    j_w = ops.sqrt(jt_w * jt_w + jl_w * jl_w + 1e-24)  # floor 1e-12 m/s (w j), see above
    w_abs = ops.sqrt(wp * wp + OMEGA_FLOOR**2)
    # eq. (5.10): 1 - exp(-j / K) with j = (w j) / |w|; the per-state factor -1 / (|w| K) first
    shear_fraction = 1.0 - ops.exp(j_w * (-1.0 / (w_abs * p.K)))
    eps_v = options.shear_direction_smoothing * (v + ops.fabs(rw))
    vj = ops.sqrt(vjT * vjT + (vy2 + eps_v * eps_v))  # v_jL = -v_y is per state: its terms first
    tau_max = (p.c + sigma * _parameter_terms(ops, p.phi)[1]) * shear_fraction / vj
    tauT = vjT * tau_max
    return _Contact(rs, sgn, sin_b, beta, s_raw, n, theta_f, theta_m, theta_r, theta_0, sin_f, cos_f, th, wq, ct, st,
                    sigma, tau_max, tauT, vjL)


def wrench_core(
    ops: Backend,
    vx: Any,
    vy: Any,
    omega: Any,
    h: Any,
    h_zero_slip: Any,
    p: PhysParams,
    options: ModelOptions,
) -> tuple[tuple[Any, ...], dict[str, Any]]:
    """Six-component soil wrench on a rigid wheel, eqs. (5.1)-(5.33), backend-generic.

    Parameters
    ----------
    ops : Backend
        :data:`offline.physics.backend.NUMPY` (arguments of shape ``(B, 1)``) or ``CASADI``
        (scalar ``SX``).
    vx, vy : array or SX
        Wheel-frame velocity of the wheel centre, m/s.
    omega : array or SX
        Wheel angular speed, rad/s (positive rolls the wheel toward +x).
    h : array or SX
        Sinkage at the shearing radius, m (theta_f = acos(1 - h / r_s)).
    h_zero_slip : array or SX
        Sinkage the wheel would have at zero slip under the same load; fixes
        ``theta_f0`` and hence theta_m0 and theta_r0 in skid (eqs. 5.3-5.4).
    p : PhysParams
        Parameters (floats or casadi symbols).
    options : ModelOptions

    Returns
    -------
    wrench : tuple
        ``(Fx, Fy, Fz, Mx, My, Mz)`` in N and N m.
    diagnostics : dict
        ``slip``, ``beta``, ``theta_f``, ``theta_m``, ``theta_r``, ``theta_0``, ``n``.
    """
    c = _contact(ops, vx, vy, omega, h, h_zero_slip, p, options)
    rs, sgn, sin_b, beta, s_raw, n, theta_f, theta_m, theta_r, theta_0, sin_f, cos_f, th, wq, ct, st, sigma, tau_max, \
        tauT, vjL = c
    form = "pavlov" if options.bulldozing == "none" else options.bulldozing
    scale = 0.0 if options.bulldozing == "none" else options.bulldozing_scale
    area = rs * p.b
    wct = wq * ct  # quadrature weights times the rim trigonometry, shared by the integrals
    wst = wq * st
    qsum = ops.qsum
    Fx = area * (qsum(tauT * wct) - qsum(sigma * wst))  # (5.26)
    Fz = area * ops.qsum(wq * (sigma * ct + tauT * st))  # (5.28), as normal_force writes it (bit for bit)
    My = -rs * area * qsum(wq * tauT)  # (5.31)
    shear = area * vjL  # tau_L = v_jL tau_max, v_jL per state: taken out of the integrals
    Fy = shear * qsum(wq * tau_max)  # (5.27) / (5.29)
    Mx = rs * shear * qsum(tau_max * wct)  # r x F, cf. (5.30)
    Mz = rs * shear * qsum(tau_max * wst)  # r x F, cf. (5.32)
    if scale != 0.0:
        # Sidewall bulldozing, eqs. (5.22)-(5.25) and (5.27)/(5.29): per unit theta the force
        # r_s R_b(h_b) f(theta) m (f = cos theta and m = |sin b| sin b (printed) or sin b
        # (single) for (5.27); f = 1 - h_b cos(theta) / r_s and m = sin b for Ishigami's (5.29)),
        # at the centre of pressure, depth r_s cos(theta) - h_b + h_COP below the axle. With the
        # linear pressure A z + C of the form (_pressure_coefficients), R_b = A h^2 / 2 + C h and
        # R_b h_COP = A h^3 / 3 + C h^2 / 2 (the first moment), so R_b (r_s cos - h_b + h_COP)
        # = R_b r_s cos - h_b^2 (A h_b / 6 + C / 2): no division by the resultant.
        sin_r = ops.sin(theta_r)
        cos_r = ops.cos(theta_r)
        rs_ct = rs * ct
        if form == "ishigami":
            # Ishigami 2007's blade depth: the local sinkage below the entry height,
            # h(theta) = r_s (cos(theta) - cos(theta_f)), used for R_b too.
            h_b = ops.fmax(rs_ct - rs * cos_f, 0.0)
            fac = 1.0 - h_b * ct / rs
            proj = sin_b
        else:
            # blade depth (5.22)-(5.23): the chord from the exit point to the entry point
            # minus the rim, (sin th - sin r) / (sin f - sin r) (cos r - cos f) r_s - (cos r - cos th) r_s
            chord = (cos_r - cos_f) / (sin_f - sin_r + 1e-15) * rs
            h_b = ops.fmax((st - sin_r) * chord + (rs_ct - rs * cos_r), 0.0)
            fac = ct
            proj = ops.fabs(sin_b) * sin_b if options.sidewall_projection == "printed" else sin_b
        a_p, c_p = _pressure_coefficients(ops, p.rho, p.c, p.phi, form)
        r_b = (h_b * (scale * 0.5 * a_p) + scale * c_p) * h_b
        lever = r_b * rs_ct - (h_b * h_b) * (h_b * (scale * a_p / 6.0) + scale * 0.5 * c_p)
        wg = wq * (r_b * fac)
        side = rs * proj
        Fy = Fy + side * qsum(wg)
        Mx = Mx + side * qsum(wq * (lever * fac))
        Mz = Mz + (rs * side) * qsum(wg * st)

    wrench = (sgn * Fx, Fy, Fz, Mx, sgn * My, sgn * Mz)
    diag = {"slip": s_raw, "beta": beta, "theta_f": theta_f, "theta_m": theta_m, "theta_r": theta_r,
            "theta_0": theta_0, "n": n}
    return wrench, diag


def normal_force(ops: Backend, vx: Any, vy: Any, omega: Any, h: Any, h_zero_slip: Any, p: PhysParams,
                 options: ModelOptions) -> Any:
    """The normal force ``F_z`` of eq. (5.28) alone: :func:`wrench_core`'s ``F_z`` (the same
    operations on the same values, so the same number bit for bit) without the sidewall
    bulldozing and the other five integrals, which ``F_z`` does not depend on. For the sinkage
    that carries a load, eq. (5.34), where only ``F_z`` is used (about half the operations).

    Parameters and shapes as :func:`wrench_core`; returns ``F_z`` in N.
    """
    c = _contact(ops, vx, vy, omega, h, h_zero_slip, p, options)
    area = c.rs * p.b
    return area * ops.qsum(c.wq * (c.sigma * c.ct + c.tauT * c.st))  # (5.28)


class _WheelView:
    """Duck-typed Wheel whose fields may be symbolic (for the soil-flow exit angle)."""

    def __init__(self, p: PhysParams) -> None:
        self.radius, self.width, self.grouser_height = p.r, p.b, p.hg
        self.grouser_area_ratio, self.grouser_volume_fraction = p.mu, p.zeta
        self.shearing_radius = p.r + p.hg


class _SoilView:
    """Duck-typed Soil whose fields may be symbolic (for the soil-flow exit angle)."""

    def __init__(self, p: PhysParams) -> None:
        self.repose_angle, self.friction_angle, self.cohesion = p.repose, p.phi, p.c
        self.unit_weight = p.rho
