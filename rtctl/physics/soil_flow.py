"""Closed-form soil-flow trench model (dissertation ch. 4) and the exit angle it implies (sec. 5.2.1).

The model follows soil through four phases (Fig. 4.2): separation of the displaced planar area
``A_tot`` into left/right piles (4.1)-(4.2), removal of the grouser-transported area ``A_rot``
(4.3), piling at the angle of repose (4.4), inward flow into the trench (4.5)-(4.10) and
redeposition of the transported soil (4.11)-(4.18).

One implementation, two uses (ARCHITECTURE.md, design point 1): the profile is computed by
:func:`_regime_profile`, written against :class:`offline.physics.backend.Backend`. :func:`trench_profile`
evaluates it with numpy for one state and returns a :class:`TrenchProfile` with a polyline;
:func:`exit_angle` evaluates it on any backend (numpy batches of shape ``(B, 1)`` or casadi ``SX``)
and blends the regimes so that the value is continuous everywhere.

Conventions and assumptions (where the code departs from the printed text it says so)
-------------------------------------------------------------------------------------
*Frame.* Cross-section perpendicular to the direction of travel, seen from behind the wheel
(Fig. 4.2): lateral position ``y`` [m] (positive to the right), height ``z`` [m] (``z = 0`` the
undisturbed surface, negative below). Everything is computed for ``beta >= 0`` ("the wheel is
turned to the right", sec. 4.2); a negative ``beta`` mirrors the profile, ``y -> -y``.

*Radius.* All wheel geometry uses the shearing radius ``r_s = r + h_g`` (grouser tips), because
the sinkage ``h0`` is measured at the shearing radius (sec. 5.2) and the exit angle is converted
with ``r_s`` (sec. 5.2.1). This includes ``A_el``, ``w``, the tan rule, ``m_max`` (4.15) and the
rim speed in ``A_rot`` (4.3), where the text writes ``r``.

*No compaction.* Soil is incompressible in the cross-section: the final profile satisfies
``integral z(y) dy = 0`` over the disturbed width, i.e. the area of the trench below ``z = 0``
equals the area of the piles above it once the transported soil ``A_rot`` is redeposited. At
every intermediate stage ``A_L2 + A_R2 + A_aside = A_tot`` and (piles - trench) ``= -A_aside``.

*Projected wheel section (4.1).* The submerged wheel, projected along the travel direction, is a
rectangle ``b cos(beta) x h0`` (the rim) plus the circular segment of depth ``h0`` of the wheel
face foreshortened by ``sin(beta)``; exactly,
``A_el = |sin beta| (r_s^2 acos(1 - h0/r_s) - (r_s - h0) sqrt(2 r_s h0 - h0^2))``,
and the width at the surface is ``w = b cos(beta) + 2 sin(beta) sqrt(2 r_s h0 - h0^2)`` (as printed).
The text calls it "semi-elliptical"; the exact segment is used (a semi-ellipse with the same
axes would overstate it by up to 18 %).

*A_rot (4.3).* ``A_rot = zeta mu h_g b r_s omega / v_x`` with ``omega`` in rad/s (the printed
``2 pi r`` carries rev/s), bounded by the soil the grousers meet: ``A_tot`` at low angle,
``A_R1`` otherwise. Reverse rotation (``omega < 0``): the grousers lift soil at the front of the
wheel and drop it ahead of it, where it rejoins the plowed soil; nothing is carried behind, so
``A_rot = 0`` (as for a locked wheel). This keeps ``A_rot`` continuous through ``omega = 0``.

*Regimes.* ``|beta| < 10 deg``: "low" (symmetric split, ``A_rot`` drawn from both piles and
deposited centred, (4.11)-(4.12)). Otherwise the tan rule ``tan(beta) > b / (2 sqrt(2 r_s h0 - h0^2))``
selects "high" (``A_rot`` added to the left pile) or "intermediate" (``A_rot`` deposited as a
step, (4.13)-(4.18)). The split is at the leading edge (4.2) for ``10 <= |beta| <= 80 deg`` and
symmetric (``A_tot / 2`` each side) outside.

*Bottom location.* (4.7) puts the deepest point under the leading corner, ``y = b cos(beta)/2``.
We use it whenever the split is at the leading edge; for the symmetric splits we put it on the
wheel centreline ``y = 0`` instead, because (4.7) at ``beta = 0`` would put the bottom under the
rim edge and make the "symmetric trench" of sec. 4.2 asymmetric.

*Inward flow, re-derived.* Toes of the piles are kept (4.6: the disturbed width is maintained)
and the flanks stand at the angle of repose. Writing ``P = (y_b - y_Ltoe) tan phi``,
``Q = (y_Rtoe - y_b) tan phi`` and ``u = p tan(phi) / 2``:
``2 h_L3 + d = P - u``, ``2 h_R3 + d = Q - u`` (4.6-4.7), and area conservation
``h_L3^2 + h_R3^2 - d^2 - 2 u d = -A_aside tan phi`` (4.5 with the flat-bottom term of 4.10).
Pointy: ``u = 0`` and ``d`` is the positive root of a quadratic. If ``d > h0`` the bottom is flat
at ``d = h0`` (the trench cannot be deeper than the wheel) and ``u`` is the smaller root of
``2u^2 - 2u(P + Q + 2 h0) + (P - h0)^2 + (Q - h0)^2 - 4 h0^2 + 4 A_aside tan phi = 0``; the flat
bottom is centred where the pointy bottom was, so p grows continuously from 0. (The printed
(4.8)-(4.9) carry a ``d/3`` term that does not follow from these constraints; (4.10) is the
area balance above and is reproduced.)

*Pile bounds (inward flow only).* Soil only flows down the steepest gradient, so a pile can
neither grow (``h_k3 <= h_k2``) nor go negative (``h_k3 >= 0``). When the formula above violates
a bound on one side, that side is clamped (peak on the pile's outer face at the bound) and the
bottom location (4.7) is released instead; if both sides are clamped and the trench cannot hold
the soil between the toes at depth ``<= h0``, both toes move outward by the same amount (the
undisturbed walls collapse). Consequence used by the clean-sided trench constraint (7.28):
``h_R2 = 0`` implies no soil above ``z = 0`` on the right. The converse fails only where the
right pile is entirely consumed by inward flow (then ``h_R3 = 0`` with ``h_R2 > 0``).

*Step (4.13)-(4.18), re-derived.* The printed step equations are mutually inconsistent ((4.14)
has ``+ q^2 tan(phi)/4``, (4.17) solves ``A = q m - q^2 tan(phi)/4``, (4.18) has ``2 + 4m/tan``
where ``2p`` is meant, and even with ``2p`` it balances triangles of slope ``tan(phi)/2``).
We keep the described mechanism and re-derive the areas: the transported soil forms a
flat-topped step leaning on the left flank with a vertical riser at the right edge of the
grousers, ``y_g = b cos(beta)/2`` (clipped to the trench bottom). (1) It grows upward:
``A = m (y_g - y_l) + m^2 / (2 tan phi)``; (2) at ``m_max`` it widens to the right,
``m_max = min((y_l - y_wL) tan phi, d)`` with ``y_wL = -(r_s sin beta + b cos(beta)/2)`` the
leftmost point of the wheel, which is (4.15) for a bottom centred at 0; (3) once the riser passes
the right bottom corner it climbs the right flank, ``A = m_max p + m_max^2/(2 tan phi) + m_max x -
x^2 tan(phi)/2``; (4) when it reaches the flank top the step covers the bottom and the rest fills
flat as (4.12). Every phase is continuous with the next.

*Low-angle fill (4.11)-(4.12).* Reproduced as printed: a flat fill of height
``e = -p tan(phi)/2 + sqrt((p tan(phi)/2)^2 + A_rot tan(phi))`` (``= sqrt(A_rot tan phi)`` for p = 0).

*Exit angle (sec. 5.2.1, Fig. 5.2 e-f).* The rear rim meets the final profile across the rim's
lateral footprint, half-width ``b cos(beta)/2`` (floored at ``1e-3 b`` so that it stays defined
at 90 deg), centred where the rear rim leaves the surface: displaced laterally by
``sqrt(2 r_s h0 - h0^2) sin|beta|`` toward the face-side pile (the plowing face looks forward;
the wheel's front swings away from it, so its rear swings toward it). The depth of the profile
is averaged over that band with uniform weights (exact integral of the piecewise-linear
profile), ``d_avg``; the rim height still in soil at the rear is ``h_c = max(h0 - d_avg, 0)``
and ``theta_r = max(-arccos(1 - h_c / r_s), -theta_f)`` (rad, <= 0, from the downward vertical).
Centring the band on the wheel centre instead (our first version) put it over the trench bottom
at high slip angles and drifted from Table 5.5's soil-flow rows by up to -20 / -23 points in
F_x / F_y at 60 deg; at the rear rim the 60 deg row matches the table (rms over 0-60 deg and the
three channels: 9.3 -> 3.0 points).

*Smoothing.* The regime rules at 10 deg, 80 deg and the tan rule switch the physics and make
the raw profile jump. :func:`exit_angle` evaluates both neighbouring regimes and blends their
exit angles linearly in ``|beta|`` over a window of ``smoothing_deg`` centred on each switch
(``smoothing_deg = 0`` gives the hard switch). Inside a regime everything (pointy/flat,
clamps, step phases) is continuous by construction, so no smoothing is applied there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from .backend import NUMPY, Backend
from .parameters import SoilLike as Soil, WheelLike as Wheel

__all__ = [
    "LOW_ANGLE",
    "HIGH_ANGLE",
    "SHAPES",
    "REGIMES",
    "TrenchProfile",
    "trench_profile",
    "exit_angle",
    "exit_angle_from_profile",
    "omega_from_slip",
    "wheel_state_from_slip",
    "tan_rule_angle",
    "trench_quantities",
]

LOW_ANGLE: float = math.radians(10.0)
"""Below this |beta| the soil splits evenly and A_rot is deposited centred (sec. 4.2)."""
HIGH_ANGLE: float = math.radians(80.0)
"""Above this |beta| the soil splits evenly again (sec. 4.2)."""
SHAPES: tuple[str, ...] = ("pointy", "flat", "stepped")
REGIMES: tuple[str, ...] = ("low", "intermediate", "high")

_SQ_FLOOR = 1e-24  # m^2: floor of every sqrt argument (finite derivatives, no NaN)
_LEN_TINY = 1e-12  # m: guard of divisions by a length
_ACOS_EPS = 1e-12  # guard of arccos arguments away from +-1
_BAND_FLOOR = 1e-3  # footprint half-width floor, fraction of b / 2
_BETA_EPS = 0.01  # rad: |beta| is evaluated as sqrt(beta^2 + eps^2) in exit_angle and
# trench_quantities, so the profile is smooth (not kinked) through beta = 0, where an optimizer
# balances symmetric wheels (IPOPT cycled on the kink). It departs from |beta| by at most eps
# (0.57 deg, at beta = 0) and by eps^2 / (2 |beta|) beyond: < 0.05 deg above 6 deg.

_Rot = Literal["low", "step", "left"]


# --------------------------------------------------------------------------------------------
# small backend helpers


def _sqrt(ops: Backend, x: Any) -> Any:
    return ops.sqrt(ops.fmax(x, _SQ_FLOOR))


def _ind(ops: Backend, cond: Any) -> Any:
    """Indicator 1.0 / 0.0 of a comparison (works for numpy bool arrays and casadi SX)."""
    return ops.where(cond, 1.0, 0.0)


def _sel(ops: Backend, flag: Any, a: Any, b: Any) -> Any:
    """``a`` where the 0/1 indicator ``flag`` is 1, else ``b``."""
    return ops.where(flag > 0.5, a, b)


# --------------------------------------------------------------------------------------------
# geometry


def _chord(ops: Backend, h0: Any, rs: float) -> Any:
    """Half chord of the wheel at the surface, sqrt(2 r_s h0 - h0^2)."""
    return _sqrt(ops, 2.0 * rs * h0 - h0 * h0)


def tan_rule_angle(h0: Any, wheel: Wheel, ops: Backend = NUMPY) -> Any:
    """Slip angle where the front and rear corners of the wheel align (sec. 4.2).

    ``beta_t = atan(b / (2 sqrt(2 r_s h0 - h0^2)))``; for ``|beta| > beta_t`` ("high angle") the
    transported soil joins the left pile.

    Parameters
    ----------
    h0 : float or array or casadi SX
        Sinkage, m.
    wheel : Wheel
    ops : Backend

    Returns
    -------
    beta_t : same type as ``h0``, rad.
    """
    return ops.arctan(wheel.width / (2.0 * _chord(ops, h0, wheel.shearing_radius)))


def _geometry(ops: Backend, h0: Any, a: Any, wheel: Wheel) -> dict[str, Any]:
    """Projected section of the submerged wheel, eq. (4.1), for ``a = |beta|``."""
    rs = wheel.shearing_radius
    b = wheel.width
    c = _chord(ops, h0, rs)
    ca = ops.clip(1.0 - h0 / rs, -1.0 + _ACOS_EPS, 1.0 - _ACOS_EPS)
    a_seg = rs * rs * ops.arccos(ca) - (rs - h0) * c
    sa, co = ops.sin(a), ops.cos(a)
    a_el = sa * a_seg
    a_rim = h0 * b * co
    return {
        "c": c,
        "sin": sa,
        "cos": co,
        "A_el": a_el,
        "A_rim": a_rim,
        "A_tot": a_el + a_rim,
        "w": b * co + 2.0 * sa * c,
    }


# --------------------------------------------------------------------------------------------
# inward flow (4.5)-(4.10) with the pile bounds


def _free(ops: Backend, yLt: Any, yRt: Any, AT: Any, ys: Any, h0: Any, T: float) -> dict[str, Any]:
    """Both toes kept, bottom at ``ys`` (4.5)-(4.7); flat at ``h0`` if too deep (4.8)-(4.10)."""
    P = (ys - yLt) * T
    Q = (yRt - ys) * T
    S = P + Q
    d_pt = 0.5 * (-S + _sqrt(ops, S * S + 2.0 * (P * P + Q * Q) + 8.0 * AT))
    flat = d_pt > h0
    a_ = P - h0
    b_ = Q - h0
    B = a_ + b_ + 4.0 * h0
    disc = B * B - 2.0 * (a_ * a_ + b_ * b_ - 4.0 * h0 * h0 + 4.0 * AT)
    u_f = ops.fmax(0.5 * (B - _sqrt(ops, disc)), 0.0)
    d = ops.where(flat, h0, d_pt)
    u = ops.where(flat, u_f, 0.0)
    feas = 1.0 - _ind(ops, flat) * _ind(ops, disc < 0.0)
    return {
        "d": d,
        "u": u,
        "hL": 0.5 * (P - u - d),
        "hR": 0.5 * (Q - u - d),
        "yl": ys - u / T,
        "yr": ys + u / T,
        "yLt": yLt,
        "yRt": yRt,
        "feas": feas,
    }


def _right_clamped(ops: Backend, yLt: Any, yRt: Any, AT: Any, hRc: Any, h0: Any, T: float) -> dict[str, Any]:
    """Right peak fixed at ``hRc``, both toes kept, bottom location free.

    From the two toe conditions, ``h_L3 = K - d - u`` with ``K = W/2 - h_Rc``; the area balance is
    then linear in ``d`` when pointy, ``d = (K^2 + h_Rc^2 + A T) / (2K)``, and quadratic in ``u``
    when flat, ``u = K - sqrt(2 K h0 - h_Rc^2 - A T)``.
    """
    W = (yRt - yLt) * T
    K = ops.fmax(0.5 * W - hRc, _LEN_TINY)
    d_pt = (K * K + hRc * hRc + AT) / (2.0 * K)
    flat = d_pt > h0
    disc = 2.0 * K * h0 - hRc * hRc - AT
    u_f = ops.fmax(K - _sqrt(ops, disc), 0.0)
    d = ops.where(flat, h0, d_pt)
    u = ops.where(flat, u_f, 0.0)
    yr = yRt - (2.0 * hRc + d) / T
    feas = 1.0 - _ind(ops, flat) * _ind(ops, disc < 0.0)
    return {"d": d, "u": u, "hL": K - d - u, "hR": hRc, "yl": yr - 2.0 * u / T, "yr": yr, "yLt": yLt, "yRt": yRt, "feas": feas}


def _mirror(s: dict[str, Any]) -> dict[str, Any]:
    """Mirror an inward-flow solution (y -> -y, left <-> right)."""
    out = dict(s)
    out["hL"], out["hR"] = s["hR"], s["hL"]
    out["yl"], out["yr"] = -s["yr"], -s["yl"]
    out["yLt"], out["yRt"] = -s["yRt"], -s["yLt"]
    return out


def _both_clamped(ops: Backend, yLt: Any, yRt: Any, AT: Any, hLc: Any, hRc: Any, h0: Any, T: float) -> dict[str, Any]:
    """Both peaks fixed; ``d + u = K2 = W/2 - h_Lc - h_Rc`` and ``d (2 K2 - d) = H``.

    ``H = h_Lc^2 + h_Rc^2 + A T``. If no ``d <= h0`` satisfies this between the toes, both toes move
    out by the same distance until it does (smallest ``K2`` with ``min(h0, K2)(2 K2 - min(h0, K2)) = H``).
    """
    W = (yRt - yLt) * T
    K2 = 0.5 * W - hLc - hRc
    H = hLc * hLc + hRc * hRc + AT
    k_min = ops.where(H <= h0 * h0, _sqrt(ops, H), 0.5 * (H / h0 + h0))
    K2e = ops.fmax(K2, k_min)
    d = K2e - _sqrt(ops, K2e * K2e - H)
    d = ops.fmin(d, h0)
    u = K2e - d
    delta = (K2e - K2) / T
    yLt2 = yLt - delta
    yRt2 = yRt + delta
    yl = yLt2 + (2.0 * hLc + d) / T
    return {"d": d, "u": u, "hL": hLc, "hR": hRc, "yl": yl, "yr": yl + 2.0 * u / T, "yLt": yLt2, "yRt": yRt2, "feas": 1.0 + 0.0 * d}


def _inward_flow(ops: Backend, yLt: Any, yRt: Any, hL2: Any, hR2: Any, AT: Any, ys: Any, h0: Any, T: float) -> dict[str, Any]:
    """Trench after inward flow, before redeposition of the set-aside soil (returns a case id too)."""

    def in_bounds(h: Any, hmax: Any) -> Any:
        return _ind(ops, h >= 0.0) * _ind(ops, h <= hmax)

    s0 = _free(ops, yLt, yRt, AT, ys, h0, T)
    vL0 = in_bounds(s0["hL"], hL2)
    vR0 = in_bounds(s0["hR"], hR2)
    ok0 = vL0 * vR0 * s0["feas"]
    hRc0 = ops.clip(s0["hR"], 0.0, hR2)
    hLc0 = ops.clip(s0["hL"], 0.0, hL2)

    s1r = _right_clamped(ops, yLt, yRt, AT, hRc0, h0, T)
    ok1r = in_bounds(s1r["hL"], hL2) * s1r["feas"]
    s1l = _mirror(_right_clamped(ops, -yRt, -yLt, AT, hLc0, h0, T))
    ok1l = in_bounds(s1l["hR"], hR2) * s1l["feas"]

    use_r = (1.0 - ok0) * vL0 * (1.0 - vR0)
    use_l = (1.0 - ok0) * vR0 * (1.0 - vL0)
    # clamp values of the both-clamped fallback
    hLc = _sel(ops, use_r, ops.clip(s1r["hL"], 0.0, hL2), hLc0)
    hRc = _sel(ops, use_l, ops.clip(s1l["hR"], 0.0, hR2), hRc0)
    s2 = _both_clamped(ops, yLt, yRt, AT, hLc, hRc, h0, T)

    case1r = use_r * ok1r
    case1l = use_l * ok1l
    case2 = (1.0 - ok0) * (1.0 - case1r) * (1.0 - case1l)
    out: dict[str, Any] = {}
    for k in ("d", "u", "hL", "hR", "yl", "yr", "yLt", "yRt"):
        v = _sel(ops, case2, s2[k], s0[k])
        v = _sel(ops, case1r, s1r[k], v)
        v = _sel(ops, case1l, s1l[k], v)
        out[k] = v
    out["case"] = case1r * 1.0 + case1l * 2.0 + case2 * 3.0
    return out


# --------------------------------------------------------------------------------------------
# one regime


def _regime_profile(
    ops: Backend,
    h0: Any,
    a: Any,
    omega: Any,
    vx: Any,
    wheel: Wheel,
    soil: Soil,
    sym_split: bool,
    rot: _Rot,
) -> dict[str, Any]:
    """Final profile for ``a = |beta| >= 0`` under one fixed regime (no switching on ``a``).

    ``sym_split``: even split ``A_tot / 2`` (|beta| < 10 or > 80 deg) instead of (4.2).
    ``rot``: ``"low"`` (A_rot from both piles, centred fill 4.11-4.12), ``"step"`` (A_rot from the
    right pile, step 4.13-4.18) or ``"left"`` (A_rot from the right pile onto the left pile).

    Returns a dict of scalars and ``ys``, ``zs``: the 8 vertices (left toe, left peak, A, B, C, D,
    right peak, right toe) with non-decreasing ``y``, some possibly coincident.
    """
    T = math.tan(soil.repose_angle)
    rs = wheel.shearing_radius
    b = wheel.width
    g = _geometry(ops, h0, a, wheel)
    a_tot, w = g["A_tot"], g["w"]

    # (4.3): rad/s, reverse rotation carries nothing behind the wheel
    a_rot_raw = (
        wheel.grouser_volume_fraction * wheel.grouser_area_ratio * wheel.grouser_height * b * rs
        * ops.fmax(omega, 0.0) / ops.fmax(vx, _LEN_TINY)
    )
    if sym_split:
        a_l1 = 0.5 * a_tot
        a_r1 = 0.5 * a_tot
        ys = 0.0 * h0
    else:  # (4.2): split about the leading edge; deepest point under the leading corner (4.7)
        a_l1 = g["A_el"]
        a_r1 = g["A_rim"]
        ys = 0.5 * b * g["cos"]
    if rot == "low":
        a_rot = ops.fmin(a_rot_raw, a_tot)
        a_l2 = 0.5 * (a_tot - a_rot)
        a_r2 = a_l2
        a_aside = a_rot
        a_r2_margin = 0.5 * (a_tot - a_rot_raw)
    elif rot == "step":
        a_rot = ops.fmin(a_rot_raw, a_r1)
        a_l2 = a_l1
        a_r2 = a_r1 - a_rot
        a_aside = a_rot
        a_r2_margin = a_r1 - a_rot_raw
    else:
        a_rot = ops.fmin(a_rot_raw, a_r1)
        a_l2 = a_l1 + a_rot
        a_r2 = a_r1 - a_rot
        a_aside = 0.0 * a_rot
        a_r2_margin = a_r1 - a_rot_raw
    a_r2 = ops.fmax(a_r2, 0.0)
    a_l2 = ops.fmax(a_l2, 0.0)

    # (4.4): triangles at the angle of repose against the wheel sides
    hL2 = ops.sqrt(ops.fmax(2.0 * a_l2 * T, 0.0) + _SQ_FLOOR) - math.sqrt(_SQ_FLOOR)
    hR2 = ops.sqrt(ops.fmax(2.0 * a_r2 * T, 0.0) + _SQ_FLOOR) - math.sqrt(_SQ_FLOOR)
    yLt = -0.5 * w - hL2 / T
    yRt = 0.5 * w + hR2 / T
    AT = a_aside * T
    fl = _inward_flow(ops, yLt, yRt, hL2, hR2, AT, ys, h0, T)
    d, yl, yr = fl["d"], fl["yl"], fl["yr"]
    p_pre = yr - yl
    zero = 0.0 * d

    # --- redeposition of the set-aside soil
    # flat fill (4.11)-(4.12)
    half = 0.5 * p_pre * T
    e = ops.fmin(ops.fmax(-half + _sqrt(ops, half * half + AT), 0.0), d)
    fill = {
        "A": (yl - e / T, -d + e),
        "B": (yr + e / T, -d + e),
        "C": (yr + e / T, -d + e),
        "D": (yr + e / T, -d + e),
        "d": d - e,
        "p": p_pre + 2.0 * e / T,
        "m": zero,
        "q": zero,
        "riser": zero,
    }
    if rot == "low":
        dep = fill
    elif rot == "left":
        dep = {
            "A": (yl, -d), "B": (yl, -d), "C": (yl, -d), "D": (yr, -d),
            "d": d, "p": p_pre, "m": zero, "q": zero, "riser": zero,
        }
    else:
        A = a_aside
        y_g = ops.clip(0.5 * b * g["cos"], yl, yr)  # riser under the right edge of the grousers
        y_wl = -(rs * g["sin"] + 0.5 * b * g["cos"])  # leftmost point of the wheel (4.15)
        mm = ops.fmax(ops.fmin((yl - y_wl) * T, d), 0.0)
        a1 = mm * (y_g - yl) + mm * mm / (2.0 * T)
        a2 = mm * p_pre + mm * mm / (2.0 * T)
        a3 = mm * p_pre + mm * mm / T
        ph1 = _ind(ops, A <= a1)
        ph2a = (1.0 - ph1) * _ind(ops, A <= a2)
        ph2b = (1.0 - ph1) * (1.0 - ph2a) * _ind(ops, A <= a3)
        ph3 = (1.0 - ph1) * (1.0 - ph2a) * (1.0 - ph2b)
        # phase 1: grows upward with the riser at y_g
        k1 = (y_g - yl) * T
        m1 = -k1 + _sqrt(ops, k1 * k1 + 2.0 * A * T)
        m1 = ops.fmax(m1, 0.0)
        # phase 2a: height m_max, riser moves right along the bottom
        y2a = yl + (A - mm * mm / (2.0 * T)) / ops.fmax(mm, _LEN_TINY)
        y2a = ops.clip(y2a, yl, yr)
        # phase 2b: riser on the right flank
        xb = (mm - _sqrt(ops, mm * mm - 2.0 * T * (A - a2))) / T
        xb = ops.clip(xb, 0.0, mm / T)
        m = _sel(ops, ph1, m1, mm)
        y2 = _sel(ops, ph1, y_g, _sel(ops, ph2a, y2a, yr + xb))
        foot = _sel(ops, ph2b, -d + xb * T, -d)
        top = -d + m
        step = {
            "A": (yl - m / T, top),
            "B": (y2, top),
            "C": (y2, foot),
            "D": (_sel(ops, ph2b, y2, yr), foot),
            "d": _sel(ops, ph2b, d - xb * T, d),
            "p": _sel(ops, ph2b, zero, yr - y2),
            "m": m,
            "q": y2 - (yl - m / T),
            "riser": top - foot,
        }
        dep = {}
        for k in step:
            if k in ("A", "B", "C", "D"):
                dep[k] = (_sel(ops, ph3, fill[k][0], step[k][0]), _sel(ops, ph3, fill[k][1], step[k][1]))
            else:
                dep[k] = _sel(ops, ph3, fill[k], step[k])

    hL3, hR3 = fl["hL"], fl["hR"]
    ys_v = [fl["yLt"], fl["yLt"] + hL3 / T, dep["A"][0], dep["B"][0], dep["C"][0], dep["D"][0], fl["yRt"] - hR3 / T, fl["yRt"]]
    zs_v = [zero, hL3, dep["A"][1], dep["B"][1], dep["C"][1], dep["D"][1], hR3, zero]
    return {
        "ys": ys_v,
        "zs": zs_v,
        "d": dep["d"],
        "p": dep["p"],
        "q": dep["q"],
        "m": dep["m"],
        "riser": dep["riser"],
        "h_L2": hL2,
        "h_R2": hR2,
        "h_L3": hL3,
        "h_R3": hR3,
        "A_tot": a_tot,
        "A_el": g["A_el"],
        "A_rot": a_rot,
        "A_L2": a_l2,
        "A_R2": a_r2,
        "A_R2_margin": a_r2_margin,
        "A_aside": a_aside,
        "w": w,
        "d_pre": d,
        "p_pre": p_pre,
        "case": fl["case"],
    }


def _band_mean_depth(ops: Backend, ys: list[Any], zs: list[Any], half: Any) -> Any:
    """Mean of ``-z(y)`` over ``|y| <= half`` for the piecewise-linear profile (exact)."""
    total = 0.0 * half
    for i in range(len(ys) - 1):
        y0, y1, z0, z1 = ys[i], ys[i + 1], zs[i], zs[i + 1]
        length = y1 - y0
        slope = ops.where(length > _LEN_TINY, (z1 - z0) / ops.fmax(length, _LEN_TINY), 0.0)
        s = ops.clip(y0, -half, half)
        e = ops.clip(y1, -half, half)
        total = total + (e - s) * (z0 + 0.5 * slope * (s + e - 2.0 * y0))
    return -total / (2.0 * half)


def _theta_from_depth(ops: Backend, h0: Any, d_avg: Any, rs: float) -> Any:
    h_c = ops.fmax(h0 - d_avg, 0.0)
    return -ops.arccos(ops.clip(1.0 - h_c / rs, -1.0 + _ACOS_EPS, 1.0 - _ACOS_EPS))


def _band_half(ops: Backend, a: Any, wheel: Wheel) -> Any:
    b = wheel.width
    return ops.fmax(0.5 * b * ops.cos(a), 0.5 * b * _BAND_FLOOR)


# --------------------------------------------------------------------------------------------
# public: numeric profile


@dataclass(frozen=True, eq=False)
class TrenchProfile:
    """Steady-state trench cross-section behind the wheel (ch. 4).

    Attributes
    ----------
    shape : str
        ``"pointy"``, ``"flat"`` (final bottom width ``p > 0``) or ``"stepped"`` (a step with a
        riser of positive height, ``q > 0``), as in Fig. 4.7.
    regime : str
        ``"low"`` (|beta| < 10 deg), ``"intermediate"`` or ``"high"`` (tan rule, sec. 4.2).
    split : str
        ``"symmetric"`` (|beta| < 10 or > 80 deg) or ``"leading_edge"`` (4.2).
    d : float
        Final maximum depth below the surface, m.
    p : float
        Final width of the flat bottom at depth ``d``, m (0 if pointy).
    q, m : float
        Step top width and step height above the trench bottom, m (0 without a step).
    h_L2, h_R2 : float
        Initial pile heights against the wheel, eq. (4.4), m.
    h_L3, h_R3 : float
        Pile heights after inward flow, m (>= 0, <= h_L2 / h_R2).
    A_tot, A_el, A_rot : float
        Displaced area (4.1), its face part, transported area (4.3, after bounding), m^2.
    A_L2, A_R2 : float
        Soil piled left / right before inward flow, m^2.
    w : float
        Wheel width at the surface, m.
    polyline : ndarray, shape (N, 2)
        ``(y, z)`` of the final section from the outer toe of the left pile to the outer toe of
        the right pile, m; consecutive duplicates removed (a step riser is two points with the
        same ``y``).
    h0, beta : float
        The inputs (m, rad).
    """

    shape: str
    regime: str
    split: str
    d: float
    p: float
    q: float
    m: float
    h_L2: float
    h_R2: float
    h_L3: float
    h_R3: float
    A_tot: float
    A_el: float
    A_rot: float
    A_L2: float
    A_R2: float
    w: float
    polyline: NDArray[np.float64]
    h0: float
    beta: float

    @property
    def net_area(self) -> float:
        """``integral z dy`` over the polyline, m^2 (zero: no compaction)."""
        y, z = self.polyline[:, 0], self.polyline[:, 1]
        return float(np.sum(np.diff(y) * 0.5 * (z[1:] + z[:-1])))

    @property
    def area_below(self) -> float:
        """Area of the trench below ``z = 0``, m^2."""
        return _signed_area_part(self.polyline, below=True)

    @property
    def area_above(self) -> float:
        """Area of the piles above ``z = 0``, m^2."""
        return _signed_area_part(self.polyline, below=False)


def _signed_area_part(poly: NDArray[np.float64], below: bool) -> float:
    total = 0.0
    for (y0, z0), (y1, z1) in zip(poly[:-1], poly[1:]):
        if y1 <= y0:
            continue
        if below:
            z0c, z1c = -z0, -z1
        else:
            z0c, z1c = z0, z1
        if z0c >= 0 and z1c >= 0:
            total += 0.5 * (z0c + z1c) * (y1 - y0)
        elif z0c > 0 or z1c > 0:  # crosses zero
            t = z0c / (z0c - z1c)
            yc = y0 + t * (y1 - y0)
            total += 0.5 * z0c * (yc - y0) if z0c > 0 else 0.5 * z1c * (y1 - yc)
    return total


def _check_scalar(name: str, value: Any) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return v


def _validate(h0: Any, beta: Any, omega: Any, vx: Any, wheel: Wheel) -> tuple[float, float, float, float]:
    h0 = _check_scalar("h0", h0)
    beta = _check_scalar("beta", beta)
    omega = _check_scalar("omega", omega)
    vx = _check_scalar("vx", vx)
    rs = wheel.shearing_radius
    if h0 <= 0.0:
        raise ValueError(f"h0 = {h0!r} m must be > 0 (sinkage below the undisturbed surface)")
    if h0 > 2.0 * rs:
        hint = " (h0 is in metres: did you pass millimetres?)" if h0 > 1.0 else ""
        raise ValueError(f"h0 = {h0!r} m exceeds the wheel diameter 2 r_s = {2 * rs!r} m{hint}")
    if abs(beta) > 0.5 * math.pi:
        hint = "; radians expected, did you pass degrees? use math.radians" if abs(beta) <= 360.0 else ""
        raise ValueError(f"beta = {beta!r} rad outside [-pi/2, pi/2]{hint}")
    if vx < 0.0:
        raise ValueError(f"vx = {vx!r} m/s must be >= 0 (the model is for forward travel; mirror a reversing wheel)")
    if omega > 0.0 and vx <= 0.0:
        raise ValueError(f"vx = {vx!r} m/s must be > 0 when omega > 0: A_rot (4.3) divides by v_x")
    return h0, beta, omega, vx


def _regime_of(a: float, h0: float, wheel: Wheel) -> tuple[bool, _Rot, str]:
    sym = a < LOW_ANGLE or a > HIGH_ANGLE
    if a < LOW_ANGLE:
        return sym, "low", "low"
    if a > float(tan_rule_angle(h0, wheel)):
        return sym, "left", "high"
    return sym, "step", "intermediate"


def trench_profile(h0: float, beta: float, omega: float, vx: float, wheel: Wheel, soil: Soil) -> TrenchProfile:
    """Steady-state trench behind a wheel, eqs. (4.1)-(4.18) (see the module notes for re-derivations).

    Parameters
    ----------
    h0 : float
        Sinkage at the shearing radius, m, ``0 < h0 <= 2 r_s``.
    beta : float
        Slip angle, rad, ``|beta| <= pi/2``; negative mirrors the profile.
    omega : float
        Wheel angular speed, rad/s (``<= 0``: nothing transported, see module notes).
    vx : float
        Wheel forward velocity along its heading, m/s (``> 0`` when ``omega > 0``).
    wheel : Wheel
    soil : Soil
        Only ``repose_angle`` is used.

    Returns
    -------
    TrenchProfile

    Raises
    ------
    ValueError
        Non-finite input, ``h0 <= 0`` or ``> 2 r_s``, ``|beta| > pi/2`` (likely degrees), ``vx < 0``,
        or ``vx == 0`` with ``omega > 0``.

    Examples
    --------
    >>> from offline.physics.params import WHEEL_K10_MINI_T42, SOIL_DISSERTATION_T42
    >>> tp = trench_profile(0.012, 0.7854, 0.5, 0.03, WHEEL_K10_MINI_T42, SOIL_DISSERTATION_T42)
    >>> tp.shape in SHAPES and abs(tp.net_area) < 1e-12
    True
    """
    h0, beta, omega, vx = _validate(h0, beta, omega, vx, wheel)
    a = abs(beta)
    sym, rot, regime = _regime_of(a, h0, wheel)
    col = lambda x: np.array([[x]], dtype=float)  # noqa: E731
    r = _regime_profile(NUMPY, col(h0), col(a), col(omega), col(vx), wheel, soil, sym, rot)
    f = lambda k: float(np.asarray(r[k]).ravel()[0])  # noqa: E731
    ys = np.array([float(np.asarray(v).ravel()[0]) for v in r["ys"]])
    zs = np.array([float(np.asarray(v).ravel()[0]) for v in r["zs"]])
    pts = [(ys[0], zs[0])]
    scale = max(wheel.width, h0)
    for y, z in zip(ys[1:], zs[1:]):
        if abs(y - pts[-1][0]) > 1e-12 * scale or abs(z - pts[-1][1]) > 1e-12 * scale:
            pts.append((y, z))
        elif len(pts) > 1:  # coincident: keep the later vertex so that the right toe survives
            pts[-1] = (y, z)
    poly = np.array(pts, dtype=float)
    if beta < 0.0:
        poly = poly[::-1].copy()
        poly[:, 0] = -poly[:, 0]
    tol = 1e-9 * scale
    if f("riser") > tol and f("A_aside") > 0.0:
        shape = "stepped"
    elif f("p") > tol:
        shape = "flat"
    else:
        shape = "pointy"
    stepped = shape == "stepped"
    return TrenchProfile(
        shape=shape,
        regime=regime,
        split="symmetric" if sym else "leading_edge",
        d=f("d"),
        p=f("p"),
        q=f("q") if stepped else 0.0,
        m=f("m") if stepped else 0.0,
        h_L2=f("h_L2"),
        h_R2=f("h_R2"),
        h_L3=f("h_L3"),
        h_R3=f("h_R3"),
        A_tot=f("A_tot"),
        A_el=f("A_el"),
        A_rot=f("A_rot"),
        A_L2=f("A_L2"),
        A_R2=f("A_R2"),
        w=f("w"),
        polyline=poly,
        h0=h0,
        beta=beta,
    )


# --------------------------------------------------------------------------------------------
# public: exit angle


def exit_angle_from_profile(profile: TrenchProfile, wheel: Wheel) -> float:
    """Exit angle theta_r from a computed profile (sec. 5.2.1, Fig. 5.2 e-f), numeric reference.

    Averages the depth of ``profile.polyline`` over the rear rim's footprint, half-width
    ``max(b cos(beta), 1e-3 b) / 2`` centred where the rear rim leaves the surface,
    ``y_c = -sqrt(2 r_s h0 - h0^2) sin(beta)``, and returns
    ``max(-arccos(1 - max(h0 - d_avg, 0) / r_s), -theta_f)``.

    Parameters
    ----------
    profile : TrenchProfile
    wheel : Wheel

    Returns
    -------
    theta_r : float
        rad, <= 0.
    """
    half = max(0.5 * wheel.width * math.cos(abs(profile.beta)), 0.5 * wheel.width * _BAND_FLOOR)
    rs = wheel.shearing_radius
    h0 = profile.h0
    # the rear rim leaves the surface displaced laterally toward the face-side pile
    yc = -math.sqrt(max(2.0 * rs * h0 - h0 * h0, 0.0)) * math.sin(profile.beta)
    area = 0.0
    for (y0, z0), (y1, z1) in zip(profile.polyline[:-1], profile.polyline[1:]):
        if y1 <= y0:  # vertical riser: no width
            continue
        s, e = max(y0, yc - half), min(y1, yc + half)
        if e <= s:
            continue
        zs = z0 + (z1 - z0) * (s - y0) / (y1 - y0)
        ze = z0 + (z1 - z0) * (e - y0) / (y1 - y0)
        area += 0.5 * (zs + ze) * (e - s)
    d_avg = -area / (2.0 * half)
    h_c = max(h0 - d_avg, 0.0)
    theta_f = math.acos(min(max(1.0 - h0 / rs, -1.0), 1.0))
    return max(-math.acos(min(max(1.0 - h_c / rs, -1.0), 1.0)), -theta_f)


def _blend_weight(ops: Backend, a: Any, switch: Any, window: float) -> Any:
    """0 below the switch, 1 above; linear over ``window`` rad centred on it (hard if window = 0)."""
    if window <= 0.0:
        return _ind(ops, a > switch)
    return ops.clip((a - switch) / window + 0.5, 0.0, 1.0)


def exit_angle(
    ops: Backend,
    h0: Any,
    beta: Any,
    omega: Any,
    vx: Any,
    wheel: Wheel | Any,
    soil: Soil | Any,
    smoothing_deg: float = 1.0,
) -> Any:
    """Exit angle theta_r from the soil-flow profile, sec. 5.2.1 (Fig. 5.2 e-f), any backend.

    ``wheel`` and ``soil`` are a :class:`Wheel` and a :class:`Soil`, or views with the same
    field names whose values may be symbolic (the casadi backend).

    The rear rim meets the final profile of :func:`trench_profile` across its lateral footprint
    (half-width ``b cos(beta) / 2``) centred where it leaves the surface,
    ``y = -sqrt(2 r_s h0 - h0^2) sin|beta|`` on the face-pile side; the mean depth there
    ``d_avg`` gives the rim height still in soil ``h_c = max(h0 - d_avg, 0)`` and

    .. math:: \\theta_r = \\max(-\\arccos(1 - h_c / r_s), -\\theta_f).

    Continuity: the regime switches at 10 deg, 80 deg and the tan rule (sec. 4.2) make the raw
    model jump; both neighbouring regimes are evaluated and their exit angles blended linearly
    in ``|beta|`` over ``smoothing_deg`` centred on each switch. Inside a regime the profile is
    continuous (pointy/flat/stepped and the pile clamps join continuously). Square roots and
    arccos are evaluated on floored arguments, so values and casadi derivatives are finite.

    Parameters
    ----------
    ops : Backend
        :data:`offline.physics.backend.NUMPY` (inputs of shape ``(B, 1)``, or broadcastable) or
        :data:`offline.physics.backend.CASADI` (scalar ``SX``/floats).
    h0 : array or SX
        Sinkage at the shearing radius, m (> 0).
    beta : array or SX
        Slip angle, rad; the result is even in ``beta``.
    omega : array or SX
        Angular speed, rad/s.
    vx : array or SX
        Forward velocity, m/s (> 0; floored at 1e-12 internally).
    wheel : Wheel
    soil : Soil
    smoothing_deg : float
        Width of the blending windows, deg (>= 0; 0 is the raw, discontinuous model).

    Returns
    -------
    theta_r : same type as the inputs, rad, <= 0.

    Raises
    ------
    ValueError
        If ``smoothing_deg`` is negative or not finite.
    """
    if not (isinstance(smoothing_deg, (int, float)) and math.isfinite(smoothing_deg) and smoothing_deg >= 0.0):
        raise ValueError(f"smoothing_deg must be a finite number >= 0 (degrees), got {smoothing_deg!r}")
    win = math.radians(float(smoothing_deg))
    rs = wheel.shearing_radius
    a = ops.sqrt(beta * beta + _BETA_EPS**2)  # smooth |beta| (see _BETA_EPS)
    half = _band_half(ops, a, wheel)
    # The rear rim leaves the surface displaced laterally by sqrt(2 r_s h0 - h0^2) sin|beta|
    # toward the face-side pile (the plowing face looks forward, the wheel's front swings
    # away from it, so its rear swings toward it): the band is centred there (Fig. 5.2 e:
    # "the region of the rear rim contacting the soil profile"), and theta_r >= -theta_f.
    y_rear = -_chord(ops, h0, rs) * ops.sin(a)
    theta_f = -ops.arccos(ops.clip(1.0 - h0 / rs, -1.0 + _ACOS_EPS, 1.0 - _ACOS_EPS))

    def theta(sym: bool, rot: _Rot) -> Any:
        r = _regime_profile(ops, h0, a, omega, vx, wheel, soil, sym, rot)
        ys = [y - y_rear for y in r["ys"]]
        return ops.fmax(_theta_from_depth(ops, h0, _band_mean_depth(ops, ys, r["zs"], half), rs), theta_f)

    a_t = tan_rule_angle(h0, wheel, ops)
    w_t = _blend_weight(ops, a, a_t, win)
    w_10 = _blend_weight(ops, a, LOW_ANGLE, win)
    w_80 = _blend_weight(ops, a, HIGH_ANGLE, win)
    mid_asym = (1.0 - w_t) * theta(False, "step") + w_t * theta(False, "left")
    mid_sym = (1.0 - w_t) * theta(True, "step") + w_t * theta(True, "left")
    upper = (1.0 - w_80) * mid_asym + w_80 * mid_sym
    return (1.0 - w_10) * theta(True, "low") + w_10 * upper


def trench_quantities(
    ops: Backend,
    h0: Any,
    beta: Any,
    omega: Any,
    vx: Any,
    wheel: Wheel,
    soil: Soil,
    smoothing_deg: float = 1.0,
) -> dict[str, Any]:
    """Trench dimensions for optimisation constraints (7.28)-(7.29), any backend, continuous.

    Returns the regime-blended (as in :func:`exit_angle`) trench depth ``d`` (m, > 0 below
    the surface), flat-bottom width ``p`` (m), and the rim-side pile ``A_R2`` (m^2) and its
    height ``h_R2`` (4.4). The rim side is the side the wheel is turned toward (the pile fed
    by the rim area and robbed by the grousers, eq. 4.2-4.3); it is the only side that can be
    left clean, so the clean-sided trench (7.28) is ``A_R2 = 0``, which is smooth where
    ``h_R2 = sqrt(2 A_R2 tan phi)`` is not.

    Parameters are those of :func:`exit_angle` (the result is even in ``beta``).
    """
    if not (isinstance(smoothing_deg, (int, float)) and math.isfinite(smoothing_deg) and smoothing_deg >= 0.0):
        raise ValueError(f"smoothing_deg must be a finite number >= 0 (degrees), got {smoothing_deg!r}")
    win = math.radians(float(smoothing_deg))
    a = ops.sqrt(beta * beta + _BETA_EPS**2)  # smooth |beta| (see _BETA_EPS)
    keys = ("d", "p", "A_R2", "h_R2", "A_R2_margin")

    def q(sym: bool, rot: _Rot) -> dict[str, Any]:
        r = _regime_profile(ops, h0, a, omega, vx, wheel, soil, sym, rot)
        return {k: r[k] for k in keys}

    a_t = tan_rule_angle(h0, wheel, ops)
    w_t = _blend_weight(ops, a, a_t, win)
    w_10 = _blend_weight(ops, a, LOW_ANGLE, win)
    w_80 = _blend_weight(ops, a, HIGH_ANGLE, win)
    low, sa, la, ss, ls = q(True, "low"), q(False, "step"), q(False, "left"), q(True, "step"), q(True, "left")
    out = {}
    for k in keys:
        mid_asym = (1.0 - w_t) * sa[k] + w_t * la[k]
        mid_sym = (1.0 - w_t) * ss[k] + w_t * ls[k]
        upper = (1.0 - w_80) * mid_asym + w_80 * mid_sym
        out[k] = (1.0 - w_10) * low[k] + w_10 * upper
    return out


# --------------------------------------------------------------------------------------------
# slip helpers (eq. 5.2)


def omega_from_slip(s: float, v: float, wheel: Wheel) -> float:
    """Wheel angular speed from the slip ratio, eq. (5.2) with ``r_s = r + h_g``.

    Slip (``0 <= s < 1``): ``s = (r_s w - v) / (r_s w)`` so ``w = v / (r_s (1 - s))``.
    Skid (``s < 0``): ``s = (r_s w - v) / v`` so ``w = v (1 + s) / r_s`` (``s = -1``: locked,
    ``s < -1``: reverse rotation).

    Parameters
    ----------
    s : float
        Slip ratio, ``< 1``.
    v : float
        Travel speed, m/s, ``> 0``.
    wheel : Wheel

    Returns
    -------
    omega : float
        rad/s.

    Raises
    ------
    ValueError
        ``s >= 1`` (the wheel spins in place: omega is unbounded), non-finite input or ``v <= 0``.
    """
    s = _check_scalar("s", s)
    v = _check_scalar("v", v)
    if v <= 0.0:
        raise ValueError(f"travel speed v = {v!r} m/s must be > 0")
    if s >= 1.0:
        raise ValueError(f"slip ratio s = {s!r} must be < 1 (s = 1 is spinning in place, omega unbounded)")
    rs = wheel.shearing_radius
    if s >= 0.0:
        return v / (rs * (1.0 - s))
    return v * (1.0 + s) / rs


def wheel_state_from_slip(s: float, beta: float, v: float, wheel: Wheel) -> tuple[float, float]:
    """``(omega, v_x)`` for slip ratio ``s``, slip angle ``beta`` (rad) and travel speed ``v``.

    ``v_x = v cos(beta)`` is the velocity along the wheel heading (Fig. 5.1) and ``omega`` comes
    from :func:`omega_from_slip`.

    Returns
    -------
    omega, vx : float
        rad/s, m/s.
    """
    beta = _check_scalar("beta", beta)
    if abs(beta) > 0.5 * math.pi:
        hint = "; radians expected, did you pass degrees? use math.radians" if abs(beta) <= 360.0 else ""
        raise ValueError(f"beta = {beta!r} rad outside [-pi/2, pi/2]{hint}")
    omega = omega_from_slip(s, v, wheel)
    return omega, max(v * math.cos(beta), 0.0)
