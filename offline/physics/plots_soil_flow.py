"""Figures of the soil-flow trench model: the shape phase map (Fig. 4.7) and the one-at-a-time sweep (Fig. 4.6).

Units at this edge: millimetres and degrees on the axes; the model is called in SI.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from .params import SOIL_DISSERTATION_T42, WHEEL_K10_MINI_T42, Soil, Wheel  # noqa: E402
from rtctl.physics.soil_flow import SHAPES, trench_profile, wheel_state_from_slip  # noqa: E402

__all__ = ["plot_phase_map", "plot_sweep"]

_COLORS = {"pointy": "#d95f02", "flat": "#1b9e77", "stepped": "#7570b3"}


def _profile(h0: float, beta_deg: float, s: float, v: float, wheel: Wheel, soil: Soil):
    omega, vx = wheel_state_from_slip(s, math.radians(beta_deg), v, wheel)
    return trench_profile(h0, math.radians(beta_deg), omega, vx, wheel, soil)


def plot_phase_map(
    path: str | Path,
    h0: float = 0.010,
    slip_ratios: Sequence[float] | None = None,
    slip_angles_deg: Sequence[float] | None = None,
    v: float = 0.03,
    wheel: Wheel = WHEEL_K10_MINI_T42,
    soil: Soil = SOIL_DISSERTATION_T42,
) -> Path:
    """Draw the trench-shape phase map over slip ratio x slip angle (dissertation Fig. 4.7).

    Each cell is coloured by :attr:`TrenchProfile.shape` (pointy / flat ``p > 0`` / stepped
    ``q > 0``); cells whose right side is clean (``h_R3 = 0``: one-sided pile) are hatched, and
    the regime switches (10 deg, 80 deg, tan rule) are drawn as lines.

    Parameters
    ----------
    path : str or Path
        Output PNG.
    h0 : float
        Sinkage, m (Fig. 4.7: 10 mm).
    slip_ratios : sequence of float, optional
        Slip ratios (eq. 5.2), default ``-1 .. 0.95``.
    slip_angles_deg : sequence of float, optional
        Slip angles in degrees, default ``0 .. 90``.
    v : float
        Travel speed, m/s (ch. 4 experiments: 0.03); ``v_x = v cos(beta)``.
    wheel, soil : Wheel, Soil
        Default: K10 mini wheel and soil of Table 4.2.

    Returns
    -------
    Path
        The written file.
    """
    s_grid = np.asarray(slip_ratios if slip_ratios is not None else np.linspace(-1.0, 0.95, 79), dtype=float)
    b_grid = np.asarray(slip_angles_deg if slip_angles_deg is not None else np.linspace(0.0, 90.0, 91), dtype=float)
    code = np.zeros((b_grid.size, s_grid.size))
    clean = np.zeros_like(code, dtype=bool)
    for i, b in enumerate(b_grid):
        for j, s in enumerate(s_grid):
            tp = _profile(h0, float(b), float(s), v, wheel, soil)
            code[i, j] = SHAPES.index(tp.shape)
            clean[i, j] = tp.h_R3 == 0.0
    fig, ax = plt.subplots(figsize=(7.0, 5.0), constrained_layout=True)
    cmap = ListedColormap([_COLORS[k] for k in SHAPES])
    ds = (s_grid[-1] - s_grid[0]) / max(s_grid.size - 1, 1)
    db = (b_grid[-1] - b_grid[0]) / max(b_grid.size - 1, 1)
    extent = (s_grid[0] - ds / 2, s_grid[-1] + ds / 2, b_grid[0] - db / 2, b_grid[-1] + db / 2)
    ax.imshow(code, origin="lower", aspect="auto", extent=extent, cmap=cmap, vmin=-0.5, vmax=2.5, interpolation="nearest")
    ax.contourf(s_grid, b_grid, clean.astype(float), levels=[0.5, 1.5], colors="none", hatches=["///"])
    for ang in (10.0, 80.0):
        ax.axhline(ang, color="k", lw=0.8, ls="--")
    from rtctl.physics.soil_flow import tan_rule_angle

    bt = math.degrees(float(tan_rule_angle(h0, wheel)))
    ax.axhline(bt, color="k", lw=0.8, ls=":")
    ax.text(s_grid[0] + 0.02, bt + 1.0, "tan rule", fontsize=8)
    ax.text(s_grid[0] + 0.02, 11.0, "10 deg", fontsize=8)
    ax.text(s_grid[0] + 0.02, 81.0, "80 deg", fontsize=8)
    handles = [Patch(color=_COLORS[k], label=k) for k in SHAPES]
    handles.append(Patch(facecolor="white", edgecolor="k", hatch="///", label="one-sided pile (h_R3 = 0)"))
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    ax.set_xlabel("slip ratio s")
    ax.set_ylabel("slip angle beta [deg]")
    ax.set_title(f"Trench shape, h0 = {h0 * 1e3:.0f} mm, v = {v * 100:.0f} cm/s ({wheel.name}, {soil.name})", fontsize=9)
    out = Path(path)
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out


def plot_sweep(
    path: str | Path,
    h0: float = 0.012,
    beta_deg: float = 45.0,
    s: float = 0.0,
    h0_values: Sequence[float] = (0.005, 0.012, 0.020, 0.025),
    beta_values_deg: Sequence[float] = (0.0, 22.5, 45.0, 67.5, 90.0),
    s_values: Sequence[float] = (-1.0, -0.5, 0.0, 0.5, 0.9),
    v: float = 0.03,
    wheel: Wheel = WHEEL_K10_MINI_T42,
    soil: Soil = SOIL_DISSERTATION_T42,
) -> Path:
    """Draw the one-at-a-time sweep of dissertation Fig. 4.6 as trench cross-sections.

    Nominal state ``h0 = 12 mm``, ``beta = 45 deg``, ``s = 0``; each panel varies one of
    ``h0``, ``beta``, ``s`` and keeps the other two nominal. Sections are seen from behind the
    wheel, turned right for ``beta > 0`` (the leading-edge soil goes left).

    Parameters
    ----------
    path : str or Path
        Output PNG.
    h0, beta_deg, s : float
        Nominal sinkage (m), slip angle (deg), slip ratio.
    h0_values, beta_values_deg, s_values : sequence of float
        The values swept in each panel (m, deg, -).
    v : float
        Travel speed, m/s.
    wheel, soil : Wheel, Soil

    Returns
    -------
    Path
        The written file.
    """
    panels = [
        ("sinkage h0", [(f"{x * 1e3:g} mm", _profile(x, beta_deg, s, v, wheel, soil)) for x in h0_values]),
        ("slip angle beta", [(f"{x:g} deg", _profile(h0, x, s, v, wheel, soil)) for x in beta_values_deg]),
        ("slip ratio s", [(f"{x:g}", _profile(h0, beta_deg, x, v, wheel, soil)) for x in s_values]),
    ]
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 8.5), sharex=True, constrained_layout=True)
    cmap = plt.get_cmap("viridis")
    for ax, (title, items) in zip(axes, panels):
        for k, (label, tp) in enumerate(items):
            color = cmap(k / max(len(items) - 1, 1))
            y, z = tp.polyline[:, 0] * 1e3, tp.polyline[:, 1] * 1e3
            ax.plot(y, z, color=color, lw=1.6, label=f"{label}: {tp.shape}, d = {tp.d * 1e3:.1f} mm")
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.set_ylabel("z [mm]")
        ax.set_title(
            f"varying {title} (nominal h0 = {h0 * 1e3:g} mm, beta = {beta_deg:g} deg, s = {s:g})", fontsize=9
        )
        ax.legend(fontsize=7, loc="lower left", frameon=False)
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("lateral position y [mm] (seen from behind the wheel)")
    out = Path(path)
    fig.savefig(out, dpi=130)
    plt.close(fig)
    return out
