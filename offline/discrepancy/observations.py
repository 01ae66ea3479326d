"""Observations for the discrepancy engine: what was recorded, how noisy, where in the operating space.

The engine (:mod:`offline.discrepancy.engine`) never looks inside a recording; it uses the
:class:`Observations` protocol: rows with channels, a per-row noise level, operating-point
features for locating regions, fold labels for held-out scoring, row subsets, and
*probe designs* (what-if variants of the experiment used to say which measurement would
separate two explanations). :class:`SingleWheelRecording` is the single-wheel testbed
adapter (:mod:`offline.discrepancy.wheel.recording`, one row per condition); rover drive
recordings plug in with their own adapter exposing the same members
(:mod:`offline.discrepancy.drive.diagnosis`: rows = time segments, features = time, wheel,
speed...).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Protocol, Sequence

import numpy as np
from numpy.typing import NDArray


__all__ = ["Observations", "Probe", "FEATURE_LABELS"]

FEATURE_LABELS = {"slip": "slip", "abs_beta_deg": "|beta| (deg)", "sinkage_mm": "sinkage (mm)", "load_N": "load (N)",
                  "rim_speed_mm_s": "rim speed (mm/s)"}
"""Report names of the single-wheel features (other adapters may add their own; unknown names print as is)."""


@dataclass(frozen=True)
class Probe:
    """A what-if experiment: the same rows under changed conditions (for separating candidates).

    Attributes
    ----------
    description : str
        What to do on the testbed (report text).
    observations : Observations
        The changed rows (their ``measured`` values are not used).
    """

    description: str
    observations: "Observations"


class Observations(Protocol):
    """What the discrepancy engine needs from a recording (see module docstring)."""

    # read-only attributes (a frozen dataclass's fields satisfy them)
    @property
    def channels(self) -> tuple[str, ...]: ...
    @property
    def units(self) -> Mapping[str, str]: ...
    @property
    def scale_out(self) -> Mapping[str, float]: ...
    @property
    def measured(self) -> dict[str, NDArray[np.float64]]: ...
    @property
    def noise(self) -> dict[str, NDArray[np.float64]]: ...
    @property
    def features(self) -> dict[str, NDArray[np.float64]]: ...
    @property
    def noise_source(self) -> str: ...
    @property
    def source(self) -> str: ...

    def __len__(self) -> int: ...

    def subset(self, idx: NDArray[np.int_]) -> "Observations": ...

    def with_measured(self, measured: Mapping[str, NDArray[np.float64]]) -> "Observations": ...

    def folds(self, k: int) -> NDArray[np.int_]: ...

    def probes(self) -> Sequence[Probe]: ...

    # Optional: ``null_draw(rng, n, n_boot)`` -> (n, n_boot) correlated noise draws for the
    # significance test (time series); without it rows are independent.
