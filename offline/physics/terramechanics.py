"""3D rigid-wheel terramechanics for any slip ratio and slip angle (dissertation ch. 5).

One implementation, two uses. :func:`wrench_core` is written against
:class:`offline.physics.backend.Backend`; with ``NUMPY`` it evaluates batched wheel states, with
``CASADI`` it builds an ``SX`` graph with exact derivatives. :class:`WheelModel` wraps both:
validated batched evaluation (:meth:`WheelModel.wrench`), casadi functions with Jacobians
(:meth:`WheelModel.casadi_function`), and sinkage from load, eq. (5.34)
(:meth:`WheelModel.sinkage_from_load`).

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
import hashlib
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from .backend import CASADI, NUMPY, Backend, gauss_legendre, smooth_abs
from .params import ContactTuning, ParameterError, ParameterSet, Soil, TuningTable, Wheel

__all__ = [
    "ModelOptions",
    "PhysParams",
    "Wrench",
    "SinkageResult",
    "WheelModel",
    "wrench_core",
    "state_from_slip",
    "bulldozing_resistance",
    "shear_kinematics",
    "WRENCH_NAMES",
    "STATE_NAMES",
    "COMPILE_FLAGS",
]

COMPILE_FLAGS: tuple[str, ...] = ("-O1",)
"""C compiler flags of the compiled wrench/Jacobian and sinkage functions, chosen by measurement
(gcc, the 1.2 MB generated wrench+Jacobian C, 2-core machine under load, 2026-11-22):
-O0 2.1 s CPU to build, 659 us per call; -O1 6.3 s, 168 us; -O2 12.7 s, 139 us. -O1 halves the
one-off build of -O2 for 20 % slower calls. ``OFFNOMINAL_CFLAGS`` (space separated) overrides
them; the flags are part of the cache key."""


def _compile_flags() -> tuple[str, ...]:
    env = os.environ.get("OFFNOMINAL_CFLAGS")
    return tuple(env.split()) if env else COMPILE_FLAGS

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
        :func:`offline.physics.soil_flow.exit_angle`).
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
    def from_sets(cls, soil: Soil, wheel: Wheel, tuning: ContactTuning | TuningTable) -> "PhysParams":
        """Collect the SI values of ``soil``, ``wheel`` and ``tuning``.

        A :class:`~offline.physics.params.TuningTable` has no single a0..b1 and raises its
        :class:`~offline.physics.params.ParameterError` saying to take ``tuning_at(abs_beta)``."""
        if isinstance(tuning, TuningTable):
            raise ParameterError(f"TuningTable {tuning.name!r} holds one tuning per slip angle, not a single a0..b1: "
                                 "build the model from tuning.tuning_at(abs_beta) (a ContactTuning)")
        return cls(
            soil.k, soil.n0, soil.n1, soil.n2, soil.friction_angle, soil.unit_weight, soil.cohesion,
            soil.shear_modulus, soil.repose_angle, wheel.radius, wheel.width, wheel.grouser_height,
            wheel.grouser_area_ratio, wheel.grouser_volume_fraction, tuning.a0, tuning.a1, tuning.b0,
            tuning.b1, tuning.a0_per_rad, tuning.a1_per_rad, tuning.b0_per_rad, tuning.b1_per_rad,
        )


def bulldozing_resistance(ops: Backend, h_b: Any, rho: Any, c: Any, phi: Any, form: str) -> Any:
    """Bulldozing resistance of a unit-width blade of depth ``h_b`` (section 5.2.4), N/m.

    .. math::
        R_b^{\\mathrm{pavlov}} = \\tfrac12 \\rho h_b^2 \\cot^2 X_c (1 + \\tfrac12 \\cot X_c \\tan\\phi) + 2 h_b c \\cot X_c

    (eq. (5.24) without its |sin beta| factor), ``hegedus`` [66] has ``(1 + cot X_c tan phi)``
    and ``ishigami`` [58] twice the first term of [66]. ``X_c = pi/4 - phi/2``.
    """
    cot_x = 1.0 / ops.tan(math.pi / 4 - phi / 2)
    tphi = ops.tan(phi)
    coh = 2.0 * h_b * c * cot_x
    if form == "pavlov":
        return 0.5 * rho * h_b**2 * cot_x**2 * (1.0 + 0.5 * cot_x * tphi) + coh
    if form == "hegedus":
        return 0.5 * rho * h_b**2 * cot_x**2 * (1.0 + cot_x * tphi) + coh
    if form == "ishigami":
        return rho * h_b**2 * cot_x**2 * (1.0 + cot_x * tphi) + coh
    raise ValueError(f"unknown bulldozing form {form!r}")


def _centre_of_pressure_depth(ops: Backend, h_b: Any, rho: Any, c: Any, phi: Any, form: str) -> Any:
    """Depth below the soil surface of the centre of bulldozing pressure, m.

    First moment of the linear pressure ``sigma_b(z) = A z + C`` over ``0 <= z <= h_b``:
    ``(A h^2 / 3 + C h / 2) / (A h / 2 + C)``; ``A``, ``C`` match the chosen R_b form so
    that the moment is consistent with the force. (5.33) as printed uses ``C / 2``.
    """
    cot_x = 1.0 / ops.tan(math.pi / 4 - phi / 2)
    tphi = ops.tan(phi)
    if form == "pavlov":
        a = rho * cot_x**2 * (1.0 + 0.5 * cot_x * tphi)
    elif form == "hegedus":
        a = rho * cot_x**2 * (1.0 + cot_x * tphi)
    else:
        a = 2.0 * rho * cot_x**2 * (1.0 + cot_x * tphi)
    cc = 2.0 * c * cot_x
    return (a * h_b**2 / 3.0 + cc * h_b / 2.0) / (a * h_b / 2.0 + cc + 1e-30)


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
    vjT = ops.where(front, vx * S - vct, rw - vct)
    vjL = -vy  # per state; broadcasts against the nodes
    jt_w = ops.where(front, (vx * S) * dth - vx * sin_f + vst, rw * (theta_0 - th) - vx * sin_0 + vst)
    jl_w = dth * vy
    return vjT, vjL, jt_w, jl_w


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
    rs = p.r + p.hg
    # Travel toward -x is the x-mirror image of travel toward +x (F_x, M_y, M_z flip sign).
    sgn = ops.where(vx < 0, -1.0, 1.0)
    vxp = sgn * vx
    wp = sgn * omega
    v = ops.sqrt(vxp * vxp + vy * vy + SPEED_FLOOR**2)
    beta = ops.arctan2(-vy, vxp)  # eq. (5.1)
    sin_b = -vy / v
    abs_b = smooth_abs(ops, beta, options.beta_smoothing)

    # Slip ratio, eq. (5.2) (denominator r_s w in slip, see module notes).
    rw = rs * wp
    skid = rw < v
    s_raw = ops.where(skid, (rw - v) / v, (rw - v) / ops.fmax(rw, SPEED_FLOOR))
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
    theta_m = ops.fmin(ops.fmax(theta_m, theta_r + 1e-6 * span), theta_f - 1e-6 * span)

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
    breaks = [theta_m, theta_0, theta_1, theta_star, -theta_star]
    breaks = [ops.fmin(ops.fmax(b_, theta_r), theta_f) for b_ in breaks]
    for i in range(len(breaks)):  # sorting network (bubble) of fmin/fmax: continuous, differentiable a.e.
        for j in range(len(breaks) - 1 - i):
            lo_, hi_ = ops.fmin(breaks[j], breaks[j + 1]), ops.fmax(breaks[j], breaks[j + 1])
            breaks[j], breaks[j + 1] = lo_, hi_
    x_gl, w_gl = _gauss_legendre_cached(options.nodes_per_segment)
    xn, wn = ops.nodes(x_gl), ops.nodes(w_gl)
    thetas, weights = [], []
    edges = [theta_r, *breaks, theta_f]
    for lo, hi in zip(edges[:-1], edges[1:]):
        half = 0.5 * (hi - lo)
        thetas.append(0.5 * (hi + lo) + half * xn)
        weights.append(half * wn)
    th = ops.cat(thetas)
    wq = ops.cat(weights)
    ct = ops.cos(th)
    st = ops.sin(th)

    # Normal stress, eqs. (5.7)-(5.9).
    theta_e = ops.where(th >= theta_m, th, theta_f - (th - theta_r) / (theta_m - theta_r) * (theta_f - theta_m))
    # floors keep second derivatives finite at quadrature nodes that coincide with theta_f
    # (zero-length segments): 1e-300 made log''/sqrt'' overflow to inf, and 0 * inf = NaN in
    # IPOPT's Hessian. sigma ~ base^n, so the 1e-12 floor changes stresses by < 1e-15 Pa.
    base = ops.fmax(ops.cos(theta_e) - cos_f, 1e-12)
    radial = p.mu * ops.exp(n * ops.log(rs)) + (1.0 - p.mu) * ops.exp(n * ops.log(p.r))
    sigma = p.k * radial * ops.exp(n * ops.log(base))

    # Shear velocities (5.13)-(5.19) and deformations (5.20)-(5.21), both multiplied by w.
    vjT, vjL, jt_w, jl_w = shear_kinematics(ops, th, ct, st, theta_f, theta_0, sin_f, sin_0, S, skid, vxp, rw, vy)
    j_w = ops.sqrt(jt_w * jt_w + jl_w * jl_w + 1e-24)  # floor 1e-12 m/s (w j), see above
    w_abs = ops.sqrt(wp * wp + OMEGA_FLOOR**2)
    shear_fraction = 1.0 - ops.exp(-j_w / (w_abs * p.K))
    eps_v = options.shear_direction_smoothing * (v + ops.fabs(rw))
    vj = ops.sqrt(vjT * vjT + vjL * vjL + eps_v * eps_v)
    tau_max = (p.c + sigma * ops.tan(p.phi)) * shear_fraction / vj
    tauT = vjT * tau_max
    tauL = vjL * tau_max

    # Sidewall bulldozing, eqs. (5.22)-(5.25).
    sin_r = ops.sin(theta_r)
    cos_r = ops.cos(theta_r)
    h_b = (st - sin_r) / (sin_f - sin_r + 1e-15) * (cos_r - cos_f) * rs - (cos_r - ct) * rs
    h_b = ops.fmax(h_b, 0.0)
    form = "pavlov" if options.bulldozing == "none" else options.bulldozing
    scale = 0.0 if options.bulldozing == "none" else options.bulldozing_scale
    if form == "ishigami":
        # eq. (5.29) with Ishigami 2007's blade depth: the local sinkage below the entry
        # height, h(theta) = r_s (cos(theta) - cos(theta_f)), used for R_b too.
        h_b = ops.fmax(rs * (ct - cos_f), 0.0)
        r_b = scale * bulldozing_resistance(ops, h_b, p.rho, p.c, p.phi, form)
        dfy_bull = (1.0 - h_b * ct / rs) * r_b * sin_b  # per unit theta, times r_s below
    else:
        r_b = scale * bulldozing_resistance(ops, h_b, p.rho, p.c, p.phi, form)
        # eq. (5.27) with R_b of (5.24) including its |sin beta| ("printed"), or the face
        # normal's single sin(beta) ("single")
        proj = ops.fabs(sin_b) * sin_b if options.sidewall_projection == "printed" else sin_b
        dfy_bull = r_b * proj * ct
    h_cop = _centre_of_pressure_depth(ops, h_b, p.rho, p.c, p.phi, form)
    arm_x = rs * ct - h_b + h_cop  # depth of the centre of pressure below the axle

    area = rs * p.b
    Fx = area * ops.qsum(wq * (-sigma * st + tauT * ct))  # (5.26)
    Fz = area * ops.qsum(wq * (sigma * ct + tauT * st))  # (5.28)
    Fy = area * ops.qsum(wq * tauL) + rs * ops.qsum(wq * dfy_bull)  # (5.27) / (5.29)
    My = -rs * area * ops.qsum(wq * tauT)  # (5.31)
    Mx = rs * area * ops.qsum(wq * tauL * ct) + rs * ops.qsum(wq * dfy_bull * arm_x)  # r x F, cf. (5.30)
    Mz = rs * area * ops.qsum(wq * tauL * st) + rs * ops.qsum(wq * dfy_bull * rs * st)  # r x F, cf. (5.32)

    wrench = (sgn * Fx, Fy, Fz, Mx, sgn * My, sgn * Mz)
    diag = {"slip": s_raw, "beta": beta, "theta_f": theta_f, "theta_m": theta_m, "theta_r": theta_r,
            "theta_0": theta_0, "n": n}
    return wrench, diag


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


@dataclass(frozen=True)
class Wrench:
    """Soil forces (N) and moments (N m) on the wheel, wheel frame (Fig. 5.1), plus diagnostics."""

    Fx: NDArray[np.float64]
    Fy: NDArray[np.float64]
    Fz: NDArray[np.float64]
    Mx: NDArray[np.float64]
    My: NDArray[np.float64]
    Mz: NDArray[np.float64]
    slip: NDArray[np.float64]
    beta: NDArray[np.float64]
    theta_f: NDArray[np.float64]
    theta_m: NDArray[np.float64]
    theta_r: NDArray[np.float64]
    theta_0: NDArray[np.float64]
    n: NDArray[np.float64]

    def as_array(self) -> NDArray[np.float64]:
        """Stack ``(Fx, Fy, Fz, Mx, My, Mz)`` as shape ``(..., 6)``."""
        return np.stack([self.Fx, self.Fy, self.Fz, self.Mx, self.My, self.Mz], axis=-1)


_STATUS_DTYPE = "<U32"
"""dtype of :attr:`SinkageResult.status`: wide enough for every status string."""


@dataclass(frozen=True)
class SinkageResult:
    """Sinkage that carries a given load, eq. (5.34).

    Attributes
    ----------
    h, h_zero_slip : ndarray
        Sinkage (m) and the zero-slip sinkage under the same load (NaN where failed).
    converged : ndarray of bool
    status : ndarray of str
        ``"ok"`` (load residual within tolerance), ``"load_exceeds_capacity"`` (the wheel
        cannot carry the load within the physical sinkage range), ``"load_below_resolution"``
        (carried at a sinkage below ``h_min``), ``"load_at_discontinuity"`` (``F_z(h)`` jumps
        across the load: no sinkage carries it within tolerance), ``"not_converged"``.
        Fixed-width strings wide enough for every status (never truncated).
    residual : ndarray
        ``F_z(h) - W``, N.
    iterations : int
    """

    h: NDArray[np.float64]
    h_zero_slip: NDArray[np.float64]
    converged: NDArray[np.bool_]
    status: NDArray[np.str_]
    residual: NDArray[np.float64]
    iterations: int
    h_max: float

    @property
    def ok(self) -> bool:
        """True when every state converged."""
        return bool(np.all(self.converged))

    def reasons(self) -> list[str]:
        """Human-readable reasons for every failed state."""
        out = []
        for i in np.flatnonzero(~self.converged):
            if self.status[i] == "load_exceeds_capacity":
                out.append(
                    f"state {i}: load exceeds what the wheel carries up to the maximum sinkage "
                    f"{self.h_max * 1e3:.1f} mm (short by {-self.residual[i]:.3g} N at best)"
                )
            else:
                out.append(f"state {i}: {self.status[i]} (residual {self.residual[i]:.3g} N)")
        return out


def state_from_slip(
    slip: NDArray[np.float64] | float, beta: NDArray[np.float64] | float, speed: NDArray[np.float64] | float, wheel: Wheel
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Wheel velocities (v_x, v_y, omega) from slip ratio, slip angle and travel speed.

    Inverts eqs. (5.1)-(5.2): ``v_x = v cos(beta)``, ``v_y = -v sin(beta)``,
    ``omega = v / (r_s (1 - s))`` in slip and ``v (1 + s) / r_s`` in skid.

    Raises
    ------
    ValueError
        Slip outside [-1, 1), |beta| > pi/2 (radians expected), non-positive speed or NaN.
    """
    s, b, v = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (slip, beta, speed)))
    for name, arr in (("slip", s), ("beta", b), ("speed", v)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr[~np.isfinite(arr)][:3]}")
    if np.any(s < -1.0) or np.any(s >= 1.0):
        raise ValueError(f"slip must lie in [-1, 1), got values in [{s.min()}, {s.max()}]")
    if np.any(np.abs(b) > math.pi / 2 + 1e-12):
        raise ValueError(
            f"beta must be in radians within [-pi/2, pi/2], got max |beta| = {np.abs(b).max():.4g} "
            "(did you pass degrees? use numpy.radians)"
        )
    if np.any(v <= 0):
        raise ValueError("speed must be > 0 m/s")
    rs = wheel.shearing_radius
    omega = np.where(s >= 0, v / (rs * (1.0 - s)), v * (1.0 + s) / rs)
    return v * np.cos(b), -v * np.sin(b), omega


class _DirectCall:
    """Call a casadi-generated C function through ctypes with preallocated buffers.

    The casadi Python call costs about 25 us of overhead per call; the generated C for the
    wrench and its Jacobian runs in a few microseconds. Generated-code interface:
    ``int f(const double** arg, double** res, casadi_int* iw, double* w, int mem)`` and
    ``int f_work(casadi_int*, casadi_int*, casadi_int*, casadi_int*)``.
    """

    def __init__(self, so: Path, name: str, reference: Any) -> None:
        import ctypes

        lib = ctypes.CDLL(str(so))
        self._fn = getattr(lib, name)
        work = getattr(lib, f"{name}_work")
        ci = ctypes.c_longlong
        sz = [ci(0) for _ in range(4)]
        work(*[ctypes.byref(v) for v in sz])
        n_arg, n_res, n_iw, n_w = (int(v.value) for v in sz)
        self._x = np.zeros(5)
        self._w6 = np.zeros(6)
        sp = reference.sparsity_out(1)
        self._jnz = np.zeros(sp.nnz())
        rows, cols = sp.get_triplet()
        self._rows, self._cols = np.asarray(rows, dtype=int), np.asarray(cols, dtype=int)
        dp = ctypes.POINTER(ctypes.c_double)
        self._arg = (dp * max(n_arg, 1))()
        self._res = (dp * max(n_res, 2))()
        self._arg[0] = self._x.ctypes.data_as(dp)
        self._res[0] = self._w6.ctypes.data_as(dp)
        self._res[1] = self._jnz.ctypes.data_as(dp)
        self._iw = (ci * max(n_iw, 1))()
        self._wbuf = (ctypes.c_double * max(n_w, 1))()
        self._fn.argtypes = [ctypes.POINTER(dp), ctypes.POINTER(dp), ctypes.POINTER(ci), ctypes.POINTER(ctypes.c_double),
                             ctypes.c_int]
        self._fn.restype = ctypes.c_int

    def __call__(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        self._x[:] = x
        if self._fn(self._arg, self._res, self._iw, self._wbuf, 0) != 0:
            raise RuntimeError("compiled wheel wrench function returned an error")
        J = np.zeros((6, 5))
        J[self._rows, self._cols] = self._jnz
        return self._w6.copy(), J


class WheelModel:
    """The terramechanics model of one wheel on one soil, evaluated numerically or symbolically.

    Parameters
    ----------
    soil : Soil
    wheel : Wheel
    tuning : ContactTuning
    options : ModelOptions, optional

    Examples
    --------
    >>> from offline.physics.params import (SOIL_DISSERTATION_T53_GROUSERED as soil,
    ...     WHEEL_GROUSERED_PUBLISHED_CODE as wheel, TUNING_T72_LINEAR as tuning)
    >>> m = WheelModel(soil, wheel, tuning)
    >>> w = m.wrench(vx=0.01, vy=0.0, omega=0.01 / 0.063, h=0.015)
    >>> bool(abs(w.Fy[0]) < 1e-9)
    True
    """

    def __init__(self, soil: Soil, wheel: Wheel, tuning: ContactTuning | TuningTable, options: ModelOptions | None = None) -> None:
        self.soil = soil
        self.wheel = wheel
        self.tuning = tuning
        self.options = options or ModelOptions()
        self.params = PhysParams.from_sets(soil, wheel, tuning)
        self._cas: dict[str, Any] = {}
        self._so_paths: dict[str, Path] = {}
        self._direct: Any = None

    @classmethod
    def from_parameter_set(cls, ps: ParameterSet, options: ModelOptions | None = None) -> "WheelModel":
        """Build from a :class:`offline.physics.params.ParameterSet` (e.g. a calibration TOML)."""
        return cls(ps.soil, ps.wheel, ps.tuning, options)

    # ---- limits -----------------------------------------------------------------------
    @property
    def h_max(self) -> float:
        """Largest sinkage accepted, ``1.5 r + h_g`` (eq. 7.5), m."""
        return 1.5 * self.wheel.radius + self.wheel.grouser_height

    @property
    def h_min(self) -> float:
        """Smallest sinkage used by the load solve, ``1e-4 r_s``, m."""
        return 1e-4 * self.wheel.shearing_radius

    # ---- numeric ------------------------------------------------------------------------
    def _validate(self, vx: Any, vy: Any, omega: Any, h: Any, h0s: Any) -> tuple[NDArray[np.float64], ...]:
        arrays = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (vx, vy, omega, h, h0s)))
        shape = arrays[0].shape
        out = [a.reshape(-1) for a in arrays]
        for name, a in zip(STATE_NAMES, out):
            bad = ~np.isfinite(a)
            if np.any(bad):
                raise ValueError(f"{name} must be finite; got {a[bad][:3]} at index {np.flatnonzero(bad)[:3]}")
        vxa, vya, wa, ha, h0a = out
        rs = self.wheel.shearing_radius
        for name, a in (("h", ha), ("h_zero_slip", h0a)):
            if np.any(a <= 0) or np.any(a > self.h_max + 1e-12):
                i = int(np.flatnonzero((a <= 0) | (a > self.h_max + 1e-12))[0])
                raise ValueError(
                    f"{name} must be in (0, {self.h_max:.4g}] m (sinkage, metres); got {a[i]!r} at index {i}"
                    + (" (did you pass millimetres?)" if a[i] > self.h_max else "")
                )
        counter = (np.sign(wa) * np.sign(vxa) < 0) & (np.abs(wa * rs) > 1e-9 * (np.abs(vxa) + 1e-12))
        if np.any(counter):
            i = int(np.flatnonzero(counter)[0])
            raise ValueError(
                f"omega opposes the travel direction at index {i} (omega={wa[i]!r}, vx={vxa[i]!r}): "
                "slip ratio < -1 is outside the model's domain [-1, 1)"
            )
        return vxa, vya, wa, ha, h0a, shape  # type: ignore[return-value]

    def wrench(
        self,
        vx: Any,
        vy: Any,
        omega: Any,
        h: Any,
        h_zero_slip: Any | None = None,
        *,
        chunk: int = 1024,
    ) -> Wrench:
        """Evaluate the wrench for a batch of wheel states (numpy backend).

        Parameters
        ----------
        vx, vy, omega, h : array_like
            Broadcastable wheel states (m/s, m/s, rad/s, m).
        h_zero_slip : array_like, optional
            Zero-slip sinkage for theta_m0, theta_r0 in skid; defaults to ``h`` (the
            state's own sinkage), which is exact at s = 0.
        chunk : int
            States per vectorised block (keeps temporaries in cache).

        Returns
        -------
        Wrench
            Arrays of the broadcast shape.

        Raises
        ------
        ValueError
            NaN or infinite state, sinkage outside (0, 1.5 r + h_g], counter-rotation.
        """
        vxa, vya, wa, ha, h0a, shape = self._validate(vx, vy, omega, h, h if h_zero_slip is None else h_zero_slip)
        return self._wrench_unchecked(vxa, vya, wa, ha, h0a, shape, chunk)

    def _wrench_unchecked(self, vxa: Any, vya: Any, wa: Any, ha: Any, h0a: Any, shape: Any, chunk: int = 1024) -> Wrench:
        nb = vxa.size
        cols = {k: np.empty(nb) for k in WRENCH_NAMES + DIAG_NAMES}
        with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
            for start in range(0, nb, chunk):
                sl = slice(start, min(nb, start + chunk))
                vx_, vy_, w_, h_, h0_ = (a[sl, None] for a in (vxa, vya, wa, ha, h0a))
                wr, dg = wrench_core(NUMPY, vx_, vy_, w_, h_, h0_, self.params, self.options)
                for k, val in zip(WRENCH_NAMES, wr):
                    cols[k][sl] = np.broadcast_to(val, (sl.stop - sl.start, 1))[:, 0]
                for k in DIAG_NAMES:
                    cols[k][sl] = np.broadcast_to(dg[k], (sl.stop - sl.start, 1))[:, 0]
        return Wrench(**{k: v.reshape(shape) for k, v in cols.items()})

    # ---- symbolic -----------------------------------------------------------------------
    def expressions(self, vx: Any, vy: Any, omega: Any, h: Any, h_zero_slip: Any, params: PhysParams | None = None) -> tuple[tuple[Any, ...], dict[str, Any]]:
        """casadi ``SX`` wrench and diagnostics of symbolic states (for an NLP)."""
        return wrench_core(CASADI, vx, vy, omega, h, h_zero_slip, params or self.params, self.options)

    def casadi_function(self, jacobian: bool = False) -> Any:
        """``casadi.Function`` ``f(x[5]) -> w[6]`` (and ``J[6x5]`` if ``jacobian``).

        ``x = (v_x, v_y, omega, h, h_zero_slip)``. Built once per model and cached.
        """
        key = "jac" if jacobian else "val"
        if key not in self._cas:
            import casadi as ca

            x = ca.SX.sym("x", 5)
            wr, _ = self.expressions(x[0], x[1], x[2], x[3], x[4])
            w = ca.vertcat(*wr)
            if jacobian:
                self._cas[key] = ca.Function("wheel_wrench_jac", [x], [w, ca.jacobian(w, x)], ["x"], ["w", "J"])
            else:
                self._cas[key] = ca.Function("wheel_wrench", [x], [w], ["x"], ["w"])
        return self._cas[key]

    def compiled_function(self, jacobian: bool = True, cache_dir: str | Path | None = None) -> Any:
        """The casadi function compiled to C (casadi code generation + the system C compiler).

        The shared library is cached under ``cache_dir`` (default
        ``$XDG_CACHE_HOME/offnominal`` or ``~/.cache/offnominal``), keyed by a hash of the
        parameters and options, so only the first call pays the ~6 s compile. Falls back to
        the interpreted casadi function, with a warning, when no C compiler is found.
        """
        key = "cjac" if jacobian else "cval"
        if key not in self._cas:
            self._cas[key] = self._compile(self.casadi_function(jacobian), key, cache_dir)
        return self._cas[key]

    def _compile(self, f: Any, tag: str, cache_dir: str | Path | None = None) -> Any:
        """Generate C for casadi function ``f``, compile it once (cached on disk, keyed by a
        hash of parameters, options and ``tag``) and load it; the interpreted function,
        with a warning, when no C compiler is found."""
        import casadi as ca

        # the serialised graph covers parameters, options and the code that built it
        flags = _compile_flags()
        version = str(getattr(ca, "__version__", ""))  # casadi ships no type stubs
        digest = hashlib.sha256((f.serialize() + tag + version + " ".join(flags)).encode()).hexdigest()[:16]
        root = Path(cache_dir) if cache_dir else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "offnominal"
        so = root / f"{f.name()}_{digest}.so"
        cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
        if not so.exists():
            if cc is None:
                warnings.warn("no C compiler found: using the interpreted casadi function (slower)", stacklevel=3)
                return f
            try:
                self._build_so(f, root, so, cc, flags)
            except (OSError, subprocess.CalledProcessError) as exc:
                warnings.warn(f"could not compile {f.name()} into {root} ({exc}): using the interpreted casadi "
                              "function (slower); set XDG_CACHE_HOME to a writable folder", stacklevel=3)
                return f
        self._so_paths[f.name()] = so
        return ca.external(f.name(), str(so))

    @staticmethod
    def _build_so(f: Any, root: Path, so: Path, cc: str, flags: tuple[str, ...] = COMPILE_FLAGS) -> None:
        """Generate C for ``f`` and compile it to ``so`` (atomic rename), saying on screen
        (stderr) what is being built, where, and how long it took: a cold build takes
        seconds to tens of seconds of CPU and happens once per parameter set."""
        root.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(dir=root) as tmp:
            cwd = os.getcwd()
            try:
                os.chdir(tmp)
                f.generate(f"{f.name()}.c")
            finally:
                os.chdir(cwd)
            src = Path(tmp) / f"{f.name()}.c"
            print(f"offnominal: building the compiled {f.name()} ({src.stat().st_size / 1e6:.1f} MB of generated C, "
                  f"{Path(cc).name} {' '.join(flags)}) into {root}; one-off, cached for later runs ...",
                  file=sys.stderr, flush=True)
            tmp_so = Path(tmp) / so.name
            subprocess.run([cc, *flags, "-fPIC", "-shared", str(src), "-o", str(tmp_so)], check=True, capture_output=True)
            os.replace(tmp_so, so)  # atomic: an interrupted build leaves no half file
        print(f"offnominal: built {so.name} in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)

    def wrench_and_jacobian(self, x: NDArray[np.float64], compiled: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Wrench (6,) and its Jacobian (6, 5) at one state ``x = (vx, vy, omega, h, h_zero_slip)``.

        Exact derivatives from the casadi graph; ``compiled`` uses the C-compiled function
        (:meth:`compiled_function`). The state is checked (finite, sinkage range).

        At ``v_x = v_y = 0`` (a wheel spinning in place, or at rest) the slip angle (5.1) is
        undefined and the wrench is not differentiable in ``(v_x, v_y)``: its derivative
        along v_y grows like 1 / |v| (about 1.5e8 N s/m at |v| = 1e-9 m/s). That state is
        refused with a :class:`ValueError` (documented choice: a clear error rather than a
        finite number that depends on an arbitrary direction); evaluate at a small travel
        speed in the direction of interest instead. The wrench value itself is finite there
        (:meth:`wrench`). Any other non-finite Jacobian is refused the same way.

        Raises
        ------
        ValueError
            Wrong shape, non-finite state, sinkage out of range, counter-rotation,
            ``v_x = v_y = 0``, or a non-finite result.
        """
        xa = np.asarray(x, dtype=float).reshape(-1)
        if xa.size != 5:
            raise ValueError(f"state must have 5 entries {STATE_NAMES}, got shape {np.shape(x)}")
        if not (np.isfinite(xa).all() and 0.0 < xa[3] <= self.h_max and 0.0 < xa[4] <= self.h_max):
            self._validate(*xa)  # raises with a message naming the bad entry
        if xa[0] * xa[2] < 0 and abs(xa[2]) * self.wheel.shearing_radius > 1e-9 * abs(xa[0]):
            self._validate(*xa)
        if xa[0] == 0.0 and xa[1] == 0.0:
            raise ValueError(
                f"wrench Jacobian at v_x = v_y = 0 (omega = {xa[2]!r} rad/s: "
                f"{'spinning in place' if xa[2] != 0 else 'at rest'}) is undefined: the slip angle of eq. (5.1) "
                "has no value at zero travel speed, so d wrench / d(v_x, v_y) does not exist; evaluate at a small "
                "travel speed (e.g. v_x = 1e-6 m/s) in the direction of interest"
            )
        w_out, J_out = self._wrench_and_jacobian_raw(xa, compiled)
        if not (np.all(np.isfinite(w_out)) and np.all(np.isfinite(J_out))):
            bad = [STATE_NAMES[j] for j in range(5) if not np.all(np.isfinite(J_out[:, j]))]
            raise ValueError(f"wrench or Jacobian is not finite at state {dict(zip(STATE_NAMES, xa.tolist()))} "
                             f"(non-finite columns: {bad}); the state is at a singularity of the model")
        return w_out, J_out

    def _wrench_and_jacobian_raw(self, xa: NDArray[np.float64], compiled: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Wrench and Jacobian at a checked state, unchecked result (see :meth:`wrench_and_jacobian`)."""
        if compiled:
            if self._direct is None:
                f = self.compiled_function(True)
                so = self._so_paths.get(f.name())
                self._direct = _DirectCall(so, f.name(), self.casadi_function(True)) if so else False
            if self._direct:
                return self._direct(xa)
        f = self.compiled_function(True) if compiled else self.casadi_function(True)
        w, J = f(xa)
        return np.asarray(w).reshape(6), np.asarray(J)

    # ---- sinkage from load (5.34) ---------------------------------------------------------
    SCAN_POINTS = 12
    """Sinkages (geometric grid over [h_min, h_max]) scanned to bracket the first root."""

    def sinkage_from_load(
        self,
        load: Any,
        vx: Any,
        vy: Any,
        omega: Any,
        *,
        rtol: float = 1e-9,
        max_iter: int = 80,
    ) -> SinkageResult:
        """Sinkage at which ``F_z(h) = W``, eq. (5.34), by a vectorised bracketing solve.

        A wheel in skid needs theta_m0, theta_r0 from the zero-slip sinkage under the same
        load, so skidding states are solved twice: first at zero slip (same v_x, v_y,
        ``omega = v / r_s``), then in skid with that ``h_zero_slip``. Each solve is the
        Illinois variant of regula falsi on ``F_z(h) - W`` inside the bracket of the first
        sign change found by a coarse scan of ``[h_min, h_max]`` (F_z is not monotonic once
        theta_f passes 90 deg); it never leaves the bracket and converges superlinearly.

        Returns
        -------
        SinkageResult
            ``status`` is ``"load_exceeds_capacity"`` where ``F_z(h_max) < W``: the wheel
            cannot carry the load within the physical sinkage range. Never a silent wrong
            answer: failed states have ``h = NaN`` and ``converged = False``; ``"ok"`` only
            where ``|F_z(h) - W| <= rtol W``. An empty batch gives empty arrays.

        Raises
        ------
        ValueError
            Non-positive or non-finite load, NaN states, counter-rotation.
        """
        W = np.asarray(load, dtype=float)
        arrays = np.broadcast_arrays(W, *(np.asarray(a, dtype=float) for a in (vx, vy, omega)))
        shape = arrays[0].shape
        Wf, vxa, vya, wa = (a.reshape(-1).astype(float) for a in arrays)
        if Wf.size == 0:  # empty batch: empty answer, same shape
            empty = np.empty(shape)
            return SinkageResult(empty, empty.copy(), np.empty(shape, dtype=bool), np.empty(shape, dtype=_STATUS_DTYPE),
                                 empty.copy(), 0, self.h_max)
        if not np.all(np.isfinite(Wf)):
            raise ValueError("load must be finite (N)")
        if np.any(Wf <= 0):
            raise ValueError(f"load must be > 0 N, got {Wf[Wf <= 0][:3]}")
        ones = np.full_like(Wf, 0.5 * self.h_max)
        self._validate(vxa, vya, wa, ones, ones)
        rs = self.wheel.shearing_radius
        v = np.sqrt(vxa**2 + vya**2)
        skid = rs * np.abs(wa) < v
        w0 = np.sign(np.where(vxa == 0, 1.0, vxa)) * v / rs
        # zero-slip solve (h_zero_slip = h): needed for every skidding state
        h0, ok0, st0, res0, it0 = self._illinois(Wf, vxa, vya, np.where(skid, w0, wa), None, rtol, max_iter)
        h0s = np.where(skid, h0, np.nan)
        need = skid & ok0
        h = h0.copy()
        ok, status, res = ok0.copy(), st0.copy(), res0.copy()
        it = it0
        if np.any(need):
            idx = np.flatnonzero(need)
            h1, ok1, st1, r1, it1 = self._illinois(Wf[idx], vxa[idx], vya[idx], wa[idx], h0[idx], rtol, max_iter)
            h[idx], ok[idx], status[idx], res[idx] = h1, ok1, st1, r1
            it = max(it, it1)
        h0s = np.where(skid, h0s, h)
        h = np.where(ok, h, np.nan)
        h0s = np.where(ok, h0s, np.nan)
        return SinkageResult(h.reshape(shape), h0s.reshape(shape), ok.reshape(shape), status.reshape(shape),
                             res.reshape(shape), it, self.h_max)

    def _single_sinkage_function(self) -> Any:
        """casadi function ``[W, vx, vy, w] -> [h, h_zero_slip, g, g0, dg, dg0]`` by unrolled,
        bracketed Newton on ``g(u) = log F_z(e^u) - log W`` (nearly linear in u = log h),
        first at zero slip then (for skid) with that h_zero_slip. C-compiled when possible."""
        key = "sink1"
        if key in self._cas:
            return self._cas[key]
        import casadi as ca

        rs = self.wheel.shearing_radius
        u = ca.SX.sym("u")
        q = ca.SX.sym("q", 5)  # W, vx, vy, omega, h_zero_slip (<= 0: the state's own h)
        h = ca.exp(u)
        wr, _ = self.expressions(q[1], q[2], q[3], h, ca.if_else(q[4] > 0, q[4], h))
        g = ca.log(ca.fmax(wr[2], 1e-12)) - ca.log(q[0])
        fz = ca.Function("fz_log", [u, q], [g, ca.jacobian(g, u)])
        P = ca.MX.sym("P", 4)
        v = ca.sqrt(P[1] ** 2 + P[2] ** 2)
        skid = rs * ca.fabs(P[3]) < v
        w_first = ca.if_else(skid, ca.if_else(P[1] < 0, -1, 1) * v / rs, P[3])

        def newton(qv: Any) -> tuple[Any, Any, Any]:
            lo, hi = ca.MX(math.log(self.h_min)), ca.MX(math.log(self.h_max))
            uu = ca.MX(math.log(0.25 * rs))
            for _ in range(self.SINGLE_NEWTON_STEPS):
                gv, dg = fz(uu, qv)
                un = uu - gv / dg
                lo = ca.if_else(gv < 0, uu, lo)
                hi = ca.if_else(gv < 0, hi, uu)
                # a converged step lands on the bracket end it just set: accept it (>=, <=)
                inside = (un >= lo) * (un <= hi) * (dg > 0)
                uu = ca.if_else(inside, un, 0.5 * (lo + hi))
            gv, dg = fz(uu, qv)
            return uu, gv, dg

        u0, g0, d0 = newton(ca.vertcat(P[0], P[1], P[2], w_first, -1.0))
        u1, g1, d1 = newton(ca.vertcat(P[0], P[1], P[2], P[3], ca.exp(u0)))
        outs = [ca.if_else(skid, ca.exp(u1), ca.exp(u0)), ca.exp(u0), ca.if_else(skid, g1, g0), g0,
                ca.if_else(skid, d1, d0), d0]
        f = ca.Function("sinkage_single", [P], outs)
        self._cas[key] = self._compile(f, "sink1")
        return self._cas[key]

    SINGLE_NEWTON_STEPS = 12
    """Unrolled Newton steps per solve in :meth:`sinkage_from_load_single`."""

    def sinkage_from_load_single(self, load: float, vx: float, vy: float, omega: float, rtol: float = 1e-9) -> SinkageResult:
        """Sinkage carrying ``load`` for one wheel state, fast (compiled) path of
        :meth:`sinkage_from_load`.

        Safeguarded Newton in ``log h`` (bracket-keeping, bisection when a step leaves the
        bracket or the slope is not positive), compiled to C. The answer is accepted only
        if the load residual is below ``rtol`` and ``F_z`` rises with ``h`` there (the
        physical, first root); otherwise the robust scan-and-bracket solve of
        :meth:`sinkage_from_load` answers, so a hard case is slower but never wrong.
        """
        vals = [float(load), float(vx), float(vy), float(omega)]
        if not all(math.isfinite(x) for x in vals):
            raise ValueError(f"load and state must be finite, got {vals}")
        if vals[0] <= 0:
            raise ValueError(f"load must be > 0 N, got {vals[0]!r}")
        if vals[1] * vals[3] < 0 and abs(vals[3]) * self.wheel.shearing_radius > 1e-9 * abs(vals[1]):
            self._validate(vals[1], vals[2], vals[3], 0.5 * self.h_max, 0.5 * self.h_max)
        h, h0, g, g0, d, d0 = (float(x) for x in self._single_sinkage_function()(vals))
        tol = math.log1p(rtol)
        if abs(g) <= tol and abs(g0) <= tol and d > 0 and d0 > 0 and self.h_min < h < self.h_max:
            one = lambda x: np.array([x])  # noqa: E731
            return SinkageResult(one(h), one(h0), one(True), np.array(["ok"], dtype=_STATUS_DTYPE), one(g * vals[0]), self.SINGLE_NEWTON_STEPS,
                                 self.h_max)
        return self.sinkage_from_load(np.array([vals[0]]), np.array([vals[1]]), np.array([vals[2]]), np.array([vals[3]]),
                                      rtol=rtol)

    def _fz(self, vx: Any, vy: Any, w: Any, h: Any, h0s: Any | None) -> NDArray[np.float64]:
        return self._wrench_unchecked(vx, vy, w, h, h if h0s is None else h0s, h.shape).Fz

    def _illinois(self, W: Any, vx: Any, vy: Any, w: Any, h0s: Any | None, rtol: float, max_iter: int) -> tuple[Any, ...]:
        nb = W.size
        # Coarse scan first: F_z(h) is not monotonic once theta_f passes 90 deg (the rim's
        # far side pushes down), so bracket the *first* sinkage that carries the load.
        grid = np.geomspace(self.h_min, self.h_max, self.SCAN_POINTS)
        rep = lambda a: np.repeat(a, grid.size)  # noqa: E731
        hg = np.tile(grid, nb)
        fg = (self._fz(rep(vx), rep(vy), rep(w), hg, None if h0s is None else rep(h0s)) - rep(W)).reshape(nb, -1)
        above = fg >= 0
        first = np.where(above.any(axis=1), above.argmax(axis=1), -1)
        status = np.full(nb, "ok", dtype=object)
        cap = first < 0
        status[cap] = "load_exceeds_capacity"
        light = first == 0
        status[light] = "load_below_resolution"  # carried at h < h_min: not resolved
        active = first > 0
        i_hi = np.clip(first, 1, grid.size - 1)
        rows = np.arange(nb)
        lo, hi = grid[i_hi - 1], grid[i_hi]
        flo, fhi = fg[rows, i_hi - 1].copy(), fg[rows, i_hi].copy()
        lo, hi = lo.copy(), hi.copy()
        h = np.where(active, 0.5 * (lo + hi), np.nan)
        fh = np.full(nb, np.nan)
        side = np.zeros(nb, dtype=int)
        tol_f = rtol * W + 1e-12
        it = 0
        for it in range(1, max_iter + 1):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            # Illinois regula falsi step, with bisection when the secant leaves the bracket
            denom = fhi[idx] - flo[idx]
            hn = np.where(denom > 0, lo[idx] - flo[idx] * (hi[idx] - lo[idx]) / np.where(denom > 0, denom, 1.0), 0.5 * (lo[idx] + hi[idx]))
            bad = ~((hn > lo[idx]) & (hn < hi[idx]))
            hn[bad] = 0.5 * (lo[idx][bad] + hi[idx][bad])
            fn = self._fz(vx[idx], vy[idx], w[idx], hn, None if h0s is None else h0s[idx]) - W[idx]
            h[idx], fh[idx] = hn, fn
            done = (np.abs(fn) <= tol_f[idx]) | ((hi[idx] - lo[idx]) < 1e-13)
            pos = fn > 0
            # update bracket; halve the stale endpoint's value when the same side repeats
            li, hi_i = idx[~pos], idx[pos]
            lo[li], flo[li] = hn[~pos], fn[~pos]
            fhi[li] = np.where(side[li] == -1, 0.5 * fhi[li], fhi[li])
            side[li] = -1
            hi[hi_i], fhi[hi_i] = hn[pos], fn[pos]
            flo[hi_i] = np.where(side[hi_i] == 1, 0.5 * flo[hi_i], flo[hi_i])
            side[hi_i] = 1
            active[idx[done]] = False
        status[active] = "not_converged"
        res = np.where(np.isnan(fh), np.where(cap, fg.max(axis=1), np.nan), fh)
        # "ok" only within tolerance: a bracket that collapsed onto a jump of F_z(h) (the
        # soil-flow exit angle switches regime with sinkage) leaves a residual above tol_f
        jump = (status == "ok") & ~(np.abs(res) <= tol_f)
        status[jump] = "load_at_discontinuity"
        ok = status == "ok"
        return h, ok, status.astype(_STATUS_DTYPE), res, it
