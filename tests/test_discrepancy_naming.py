"""When the engine may name an explanation: only over a misfit beyond the noise (issue 24, fast).

README's closed-loop drive with no concealed effect (bench ``sparse_negatives``, operational seed
33) named an FL radius of +0.53 % at p = 3.3e-4 while its own report said "no excess over noise":
the candidate test's null draws noise around fixed commands, but there the commands react to the
noise. An adapter that sets ``name_needs_excess`` (drives) now names a significant explanation only
when the believed model's residual chi-square in noise units exceeds the number of values.

The toy here reproduces the situation in a second: a recording whose declared noise is larger
than the noise it carries (the drives' segment noise is over-estimated: 0.7-0.9 of the values in
every negative control) with a small effect the candidate test finds. The old rule named it
("explained"); the new one reports it as not named.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from offline.discrepancy.wheel.candidates import Candidate
from offline.discrepancy.engine import CandidateScore, diagnose, withhold_without_excess

N_ROWS = 200


@dataclass(frozen=True)
class _Shift:
    """The toy model's extension: ``a`` times the row's covariate is added to the prediction."""

    a: float = 0.0

    def merge(self, other: "_Shift") -> "_Shift":
        return _Shift(self.a + other.a)


@dataclass(frozen=True)
class _ToyRecording:
    """One channel ``y``; the covariate ``x`` (+-1, not a locating feature, so no region test can
    see the effect: the decision rests on the candidate test alone, as on seed 33)."""

    x: NDArray[np.float64]
    y: NDArray[np.float64]
    sigma: float
    name_needs_excess: bool = True
    channels: tuple[str, ...] = ("y",)
    units: dict[str, str] = field(default_factory=lambda: {"y": "u"})
    scale_out: dict[str, float] = field(default_factory=lambda: {"y": 1.0})
    noise_source: str = "declared"
    source: str = "toy"

    @property
    def measured(self) -> dict[str, NDArray[np.float64]]:
        return {"y": self.y}

    @property
    def noise(self) -> dict[str, NDArray[np.float64]]:
        return {"y": np.full(len(self.y), self.sigma)}

    @property
    def features(self) -> dict[str, NDArray[np.float64]]:
        return {"time_s": np.arange(len(self.y), dtype=float)}

    def __len__(self) -> int:
        return len(self.y)

    def subset(self, idx: NDArray[np.int_]) -> "_ToyRecording":
        return replace(self, x=self.x[idx], y=self.y[idx])

    def with_measured(self, measured: dict[str, NDArray[np.float64]]) -> "_ToyRecording":
        return replace(self, y=np.asarray(measured["y"], dtype=float))

    def folds(self, k: int) -> NDArray[np.int_]:
        return np.arange(len(self.y)) * k // len(self.y)

    def probes(self) -> list[Any]:
        return []


class _ToyModel:
    params = None

    def predict(self, obs: _ToyRecording, ext: _Shift | None = None) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
        a = ext.a if ext is not None else 0.0
        return {"y": a * obs.x}, np.ones(len(obs), dtype=bool)

    def empty_extension(self) -> _Shift:
        return _Shift()


TERM = Candidate("shift", "a term proportional to the covariate", (("a", "u", -5.0, 5.0, 0.0, 1.0),),
                 lambda th, ps: _Shift(float(th[0])), channels=("y",), null=(0.0,))


def _toy(effect: float, name_needs_excess: bool = True) -> _ToyRecording:
    rng = np.random.default_rng(5)
    x = rng.choice([-1.0, 1.0], size=N_ROWS)
    y = effect * x + 0.8 * rng.standard_normal(N_ROWS)  # carried noise 0.8, declared 1.0 below
    return _ToyRecording(x, y, 1.0, name_needs_excess)


def _diagnose(obs: _ToyRecording) -> Any:
    return diagnose(obs, _ToyModel(), candidates=[TERM], recalibrate=False, n_boot=400, n_points=2, max_terms=1, seed=1)


def test_a_significant_term_is_not_named_without_a_misfit_beyond_noise():
    v = _diagnose(_toy(0.45))
    before, _, n, _ = v.noise_chi2
    assert before < n  # no excess over the declared noise
    assert v.withheld is not None and v.withheld.significant and v.withheld.keys == ("shift",)
    assert v.status == "agree" and v.chosen is None and v.missing_physics == []
    assert "not named" in v.summary() and "no misfit beyond the noise" in v.summary()
    assert v.to_json()["withheld"]["terms"] == ["shift"]
    # the old rule (no such adapter flag, as the single-wheel tool keeps) named it
    old = _diagnose(_toy(0.45, name_needs_excess=False))
    assert old.status == "explained" and old.missing_physics == ["shift"]


def test_a_term_over_a_misfit_beyond_noise_is_still_named():
    v = _diagnose(_toy(1.2))
    before, _, n, _ = v.noise_chi2
    assert before > n
    assert v.status == "explained" and v.missing_physics == ["shift"] and v.withheld is None
    assert math.isclose(v.chosen.values[0], 1.2, rel_tol=0.2)


def _score(delta: float, p_adj: float) -> CandidateScore:
    return CandidateScore(("wheel_radius_FL",), ("worn wheel",), ("term",), ("radius_change",), ("%",), (0.53,), (0.15,), 1,
                          0.0, 0.0, delta, p_adj, p_adj, True, np.zeros(1))


def test_the_rule_on_the_bench_statistics():
    """Seed 33 (no effect): withheld; README's drive with a worn FL wheel (bench ``sparse``): named."""
    reason = withhold_without_excess(_score(11.2, 3.3e-4), 600.0, 700)
    assert "wheel_radius_FL" in reason and "no misfit beyond the noise" in reason and "600 for 700" in reason
    assert withhold_without_excess(_score(1957.0, 1e-3), 2548.0, 700) == ""
    assert withhold_without_excess(None, 600.0, 700) == ""
    assert withhold_without_excess(_score(11.2, 3.3e-4), 700.0, 700) != ""  # exactly the noise: nothing to explain


def test_noise_alone_agrees_with_nothing_withheld_and_the_summary_renders():
    v = _diagnose(_toy(0.0))
    assert v.status == "agree" and v.chosen is None and v.withheld is None
    assert "no candidate and no region is significant" in v.summary() and "not named" not in v.summary()
