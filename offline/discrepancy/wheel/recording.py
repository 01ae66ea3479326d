"""The single-wheel testbed adapter of the discrepancy engine: one row per condition.

:class:`SingleWheelRecording` exposes the :class:`~offline.discrepancy.observations.Observations`
protocol over the testbed's trials (repeat means, pooled repeat noise, operating-point features).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ...fit.dataset import DatasetError, TrialSet
from ...fit.validation import average_conditions, trial_states
from ..observations import Probe

__all__ = ["SingleWheelRecording"]


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
    channels: tuple[str, ...] = ("Fx", "Fy", "sinkage")
    units: Mapping[str, str] = None  # type: ignore[assignment]
    scale_out: Mapping[str, float] = None  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.units is None:
            object.__setattr__(self, "units", {"Fx": "N", "Fy": "N", "sinkage": "mm"})
        if self.scale_out is None:
            object.__setattr__(self, "scale_out", {"Fx": 1.0, "Fy": 1.0, "sinkage": 1e3})

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
        except DatasetError:
            med = float(np.median(trials.Fz))
            nz = {"Fx": 0.05 * med, "Fy": 0.05 * med, "sinkage": 2e-3}
            src = "no repeats: assumed 5 % of the median load for forces and 2 mm for sinkage"
        vx, vy, w = trial_states(avg)
        return cls(
            vx=vx, vy=vy, omega=w, load=avg.Fz.copy(),
            measured={"Fx": avg.Fx.copy(), "Fy": avg.Fy.copy(), "sinkage": avg.sinkage.copy()},
            noise={ch: np.full(len(avg), nz[ch]) / np.sqrt(nrep) for ch in ("Fx", "Fy", "sinkage")},
            features={
                "slip": avg.slip.copy(),
                "abs_beta_deg": np.abs(np.degrees(avg.beta_cmd)),
                "sinkage_mm": avg.sinkage * 1e3,
                "load_N": avg.Fz.copy(),
                "rim_speed_mm_s": avg.rim_speed * 1e3,
            },
            beta_cmd=avg.beta_cmd.copy(), travel=avg.vx * window_time, noise_source=src, source=str(trials.source),
        )

    @property
    def beta(self) -> NDArray[np.float64]:
        """Slip angle of each row from the wheel-frame velocity, rad (``v_y = -V sin(beta)``)."""
        return np.arctan2(-self.vy, self.vx)

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

    def folds(self, k: int) -> NDArray[np.int_]:
        """Fold of each row for ``k``-fold held-out scoring, stratified by commanded slip angle
        and, within an angle, interleaved in slip (so every fold spans the slip range).

        The ``j``-th angle (in increasing order) starts its interleave at fold ``j mod k``, so
        the rows at one slip rank (the locked wheel, the free-rolling wheel...) are spread over
        ``min(k, n_angles)`` folds rather than all falling in one: with at least ``k`` angles
        every fold holds every slip level (a fold of only zero-slip rows, or one holding every
        locked-wheel row, would test a term on conditions it was never fitted on)."""
        fold = np.empty(len(self), dtype=int)
        for j, b in enumerate(np.unique(self.beta_cmd)):
            idx = np.flatnonzero(self.beta_cmd == b)
            order = idx[np.argsort(self.features["slip"][idx], kind="stable")]
            fold[order] = (np.arange(order.size) + j) % k
        return fold

    def _state(self, beta: NDArray[np.float64], load: NDArray[np.float64], travel_scale: float = 1.0) -> "SingleWheelRecording":
        v = np.hypot(self.vx, self.vy)
        return replace(self, vx=v * np.cos(beta), vy=-v * np.sin(beta), load=load, beta_cmd=beta,
                       travel=self.travel * travel_scale,
                       features={**self.features, "abs_beta_deg": np.abs(np.degrees(beta)), "load_N": load})

    def probes(self) -> list[Probe]:
        """What-if variants of these conditions that could separate two explanations: load
        x0.6 and x1.5, the slip angle mirrored (-beta), the slip angle +20 deg (at most 90),
        and a three times longer run (travel x3)."""
        b = self.beta
        return [
            Probe("vary the load: the same conditions at 0.6 x the load", self._state(b, 0.6 * self.load)),
            Probe("vary the load: the same conditions at 1.5 x the load", self._state(b, 1.5 * self.load)),
            Probe("mirror the slip angle (run -beta as well as +beta)", self._state(-b, self.load)),
            Probe("change the slip angle by +20 deg", self._state(np.clip(b + math.radians(20.0), -math.pi / 2, math.pi / 2), self.load)),
            Probe("run three times longer (record after 3 x the travel)", self._state(b, self.load, 3.0)),
        ]
