"""The chapter-7 reference numbers of the dissertation, in one table, and how to compute ours.

Every number the dissertation reports for the steady-state optimizer (section 7.3, Fig. 7.12,
section 7.2.7) is one :class:`Reference` in :data:`CHAPTER7`: what it is, its value and unit,
where it is printed, how our optimizer computes the same quantity (:func:`compute`), and the
tolerance within which ours must agree, or, where it does not, the reason and the band our
value is known to lie in (so a change in either is noticed). ``offnominal chapter7`` prints
the table beside our numbers; ``tests/test_primitives.py`` checks the cheap ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["Reference", "CHAPTER7", "compute", "compare", "QUICK"]


@dataclass(frozen=True)
class Reference:
    """One dissertation number and the rule comparing ours with it.

    Attributes
    ----------
    key : str
        Identifier (e.g. ``"nominal_flat_mean_slip"``).
    quantity : str
        What is measured.
    value : float
        The dissertation's number, in ``unit``.
    unit : str
    source : str
        Where it is printed.
    tolerance : float
        Largest accepted ``|ours - value|`` (in ``unit``) when ``matched``.
    matched : bool
        Whether our model is expected to reproduce it.
    ours_band : tuple of float
        When not matched: the range our value is known to lie in (checked, so drift is seen).
    why : str
        Why a number is not matched (or how the tolerance was chosen).
    """

    key: str
    quantity: str
    value: float
    unit: str
    source: str
    tolerance: float
    matched: bool = True
    ours_band: tuple[float, float] = (-math.inf, math.inf)
    why: str = ""


CHAPTER7: tuple[Reference, ...] = (
    Reference("nominal_flat_mean_slip", "nominal driving, flat ground: mean slip", 15.0, "%", "sec. 7.3.4, Fig. 7.12",
              2.0, matched=False, ours_band=(7.5, 10.0),
              why="the Table 5.3 soil with the published wheel code and linear a(beta) gives 8.6 %; the dissertation's "
                  "15 % comes from its own code state (tuning not recoverable from the text)"),
    Reference("nominal_steepest_slope", "nominal driving: steepest feasible slope", 24.0, "deg", "sec. 7.3.4", 2.0,
              why="bracketed by the envelope to 2.5/2^5 deg; 2 deg covers the dissertation's 1 deg sweep step"),
    Reference("nominal_slip50_slope", "nominal driving: slope where mean slip reaches 50 %", 12.5, "deg", "sec. 7.3.4",
              2.5, why="measured 14.4 deg: the lower flat-ground slip (8.6 % vs 15 %) delays the rise; 2.5 deg is one "
                       "sweep step of the envelope"),
    Reference("stuck50_flat_mean_slip", "RR steering stuck at -50 deg, flat: mean slip of unaffected wheels", 40.0, "%",
              "sec. 7.3.4, Fig. 7.12", 10.0, matched=False, ours_band=(28.0, 36.0),
              why="same soil/tuning difference as the nominal slip; the rise over nominal (x3.7 here, x2.7 there) agrees"),
    Reference("speedcap_flat_mean_slip", "RR rim speed <= v/2, flat: mean slip of unaffected wheels", 69.0, "%",
              "sec. 7.3.4, Fig. 7.12", 10.0, matched=False, ours_band=(55.0, 63.0),
              why="59 % here: the same soil/tuning difference as the nominal slip (6.4 points lower there)"),
    Reference("speedcap_flat_max_slip", "RR rim speed <= v/2, flat: max slip", 76.0, "%", "sec. 7.3.4, Fig. 7.12", 10.0,
              matched=False, ours_band=(64.0, 72.0), why="68 % here, lower for the same reason as the mean slip"),
    Reference("lowest_rim_speed_cap", "lowest reachable rim-speed cap on RR", 1.5, "cm/s", "sec. 7.2.7", 0.3,
              matched=False, ours_band=(0.0, 1.5),
              why="the dissertation stopped its hand continuation at 1.5 cm/s; the automated bisection goes lower "
                  "(a lower cap that solves is a better answer, not a contradiction)"),
    Reference("trench_depth", "clean-sided trench with RR, depth >= b/2: predicted depth", 2.6, "cm", "sec. 7.3.1",
              0.3, matched=False, ours_band=(2.4, 2.6),
              why="the optimizer meets the depth constraint b/2 = 2.5 cm at its bound (the objective favours the "
                  "shallowest trench); the dissertation's 2.6 cm was the depth of its chosen (not minimal) solution"),
)
"""The chapter-7 numbers (section 7.3.4, Fig. 7.12; section 7.2.7; section 7.3.1)."""

QUICK: tuple[str, ...] = ("nominal_flat_mean_slip", "stuck50_flat_mean_slip", "speedcap_flat_mean_slip",
                          "speedcap_flat_max_slip", "trench_depth")
"""Keys computed by single solves (seconds); the others need slope envelopes or bisections."""


def _shipped(name: str) -> Any:
    from .scenario import example_scenarios, load_scenario

    return load_scenario(next(p for p in example_scenarios() if p.stem == name))


def _flat(name: str, what: str, options: Any) -> float:
    from .primitives import solve_primitive

    r = solve_primitive(_shipped(name), options)
    if not r.ok:
        return math.nan
    return 100 * (r.mean_slip() if what == "mean" else r.max_slip())


def _envelope(what: str, options: Any, step_deg: float) -> float:
    from .primitives import envelope

    e = envelope(_shipped("nominal"), 0.5, options, step_deg=step_deg, max_deg=30.0)
    return float(e["steepest_slope_deg"] if what == "steepest" else e["slip_limit_slope_deg"])


def _lowest_cap(options: Any) -> float:
    from .primitives import lowest_speed_cap

    cap, _ = lowest_speed_cap(_shipped("rr_speed_cap_half"), "RR", options)
    return 100 * cap


def _trench(options: Any) -> float:
    from .primitives import solve_primitive

    r = solve_primitive(_shipped("rr_trench_clean"), options)
    return 100 * r.trench.d if r.ok else math.nan


_COMPUTE: dict[str, Callable[[Any, float], float]] = {
    "nominal_flat_mean_slip": lambda o, s: _flat("nominal", "mean", o),
    "nominal_steepest_slope": lambda o, s: _envelope("steepest", o, s),
    "nominal_slip50_slope": lambda o, s: _envelope("slip50", o, s),
    "stuck50_flat_mean_slip": lambda o, s: _flat("rr_steer_stuck_50", "mean", o),
    "speedcap_flat_mean_slip": lambda o, s: _flat("rr_speed_cap_half", "mean", o),
    "speedcap_flat_max_slip": lambda o, s: _flat("rr_speed_cap_half", "max", o),
    "lowest_rim_speed_cap": lambda o, s: _lowest_cap(o),
    "trench_depth": lambda o, s: _trench(o),
}


def compute(key: str, options: Any = None, step_deg: float = 2.5) -> float:
    """Our value of reference ``key``, in its unit (NaN when the scenario has no primitive)."""
    if key not in _COMPUTE:
        raise KeyError(f"no chapter-7 reference {key!r}; known: {sorted(_COMPUTE)}")
    return _COMPUTE[key](options, step_deg)


def compare(ref: Reference, ours: float) -> tuple[bool, str]:
    """Does ``ours`` meet the reference's rule? Returns (passed, explanation)."""
    if not math.isfinite(ours):
        return False, "no value computed"
    if ref.matched:
        ok = abs(ours - ref.value) <= ref.tolerance
        return ok, f"|{ours:.2f} - {ref.value:g}| {'<=' if ok else '>'} {ref.tolerance:g} {ref.unit}"
    lo, hi = ref.ours_band
    ok = lo <= ours <= hi
    return ok, f"not matched ({ref.why}); ours {ours:.2f} {'inside' if ok else 'OUTSIDE'} the known band [{lo:g}, {hi:g}]"


