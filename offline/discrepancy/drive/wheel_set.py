"""The drive discrepancy tool on any rover's wheel set (issue 23): the mini rover's four wheels or a rover file's.

The drive tool was written for the mini rover's wheels (FR, FL, RR, RL): its per-wheel channels
(``omega_<W>``, ``torque_<W>``) and its per-wheel candidates (``wheel_radius_<W>``,
``steer_offset_<W>``, the per-wheel actuator terms) name them. A recording of another rover
carries its own wheel set (:attr:`rtctl.recording.Recording.wheels`, the rover file's names and
order); here the channels and the library follow it:

* :func:`tick_channels`, :func:`channel_unit`: the per-tick channels of a wheel set;
* :func:`library_for`: a candidate library for the rover of a scenario. For the mini rover (no
  rover file) it is the library as given, so the mini rover's diagnoses are unchanged. For a
  rover file, each per-wheel candidate family of the library (its ``FR`` member is the
  template) is made for each of the file's wheels (steering terms only for steerable wheels),
  the terms acting through the simulator's disturbance hook (hub contact, an anchored tether)
  are kept -- their re-simulation builds the hook on the file's wheels
  (:func:`offline.discrepancy.drive.candidates.disturbance_from_terms` with the scenario's
  ``rover_file``: the hub drag at each of its wheels, the tether in the plant's frame) -- and the
  channels a term acts on (for the report) are the file's;
* :func:`truth_disturbance`: the simulator's disturbance hook of a truth file's hook sections
  (``[tether_anchor]``, ``[hub_contact]``, ``[[empirical_force]]``) on the scenario's wheel set,
  so a world with hub contact, a tether or an empirical drag or torque is simulated on a rover
  file's plant as on the mini rover's (the hub contact and the per-wheel empirical terms at the
  file's wheel positions).

The mini rover's bounds and starting points of a force are sized for its weight (a drawbar
pull of +-10 N is a quarter of the mini rover's 34 N, under 2 % of the MER-class rover's 646 N):
on a rover file they are scaled by :func:`rover_scales` -- forces (N) and spring rates (N/m) by
the weight ratio, torques (N m) by the weight x wheel-radius ratio, the hub contact's face width
and lever arm (mm) by the wheel-radius ratio (its clearance, a depth compared with the sinkage,
is kept) -- so a candidate spans the same physical range relative to the
rover. Other units (angles, fractions, speeds, time constants) are kept.

A per-wheel candidate is renamed, not rewritten: its ``build`` is the template's with the rover
terms ``<term>.FR`` renamed ``<term>.<wheel>`` (:data:`~offline.discrepancy.drive.candidates.PER_WHEEL_TERMS`),
so the physics, bounds and starting points are the mini rover's, in SI.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ...physics.params import ParameterSet
from ...rover.scenario import Scenario
from ...sim.truth import WHEELS, Truth
from ..wheel.candidates import Candidate
from .candidates import DriveCandidateError, Hooks, HubContact, RoverExtension, disturbance_from_truth

__all__ = ["tick_channels", "channel_unit", "library_for", "HOOK_CANDIDATES", "truth_disturbance", "rover_scales",
           "WheelSetHubContact", "WheelSetHooks"]

HOOK_CANDIDATES = ("hub_contact", "tether_anchor")
"""Candidates that act through the simulator's disturbance hook (contract C5): their re-simulation
builds the hook on the believed rover's wheels (:func:`~offline.discrepancy.drive.candidates.disturbance_from_terms`
with the scenario's ``rover_file``); :func:`library_for` keeps them, with the file's channels."""

_TEMPLATE = "FR"
"""The mini rover's wheel whose per-wheel candidates are the templates of a rover file's."""


def tick_channels(wheels: Sequence[str]) -> tuple[str, ...]:
    """Per-tick readings averaged over a segment, for a wheel set (the mini rover's:
    :data:`offline.discrepancy.drive.diagnosis.TICK_CHANNELS`)."""
    return (*(f"omega_{w}" for w in wheels), *(f"torque_{w}" for w in wheels), "yaw_rate", "roll", "pitch")


def channel_unit(channel: str, units: dict[str, tuple[str, float]]) -> tuple[str, float]:
    """``(unit, factor from SI)`` of a channel: ``units`` (the mini rover's table) or, for a
    rover file's wheel, that of the same channel kind (``omega_<W>`` rad/s, ``torque_<W>`` N m)."""
    if channel in units:
        return units[channel]
    kind = channel.partition("_")[0]
    if kind in ("omega", "torque"):
        return units[f"{kind}_{_TEMPLATE}"]
    raise KeyError(f"no unit for channel {channel!r}; channels are omega_<wheel>, torque_<wheel> and {sorted(units)}")


def _wheel_of(key: str, names: Sequence[str] = WHEELS) -> str | None:
    """The wheel of ``names`` a per-wheel candidate key ends with (``wheel_radius_RR``: RR), or None."""
    for w in sorted(names, key=len, reverse=True):
        if key.endswith(f"_{w}"):
            return w
    return None


def _renamed_build(build: Callable[[NDArray[np.float64], ParameterSet], Any], old: str, new: str, key: str
                   ) -> Callable[[NDArray[np.float64], ParameterSet], Any]:
    """``build`` with its per-wheel rover terms of wheel ``old`` renamed to wheel ``new``."""
    def renamed(t: NDArray[np.float64], p: ParameterSet) -> RoverExtension:
        e = build(t, p)
        terms = {}
        for k, v in e.terms.items():
            term, dot, w = k.partition(".")
            terms[f"{term}.{new}" if dot and w == old else k] = v
        if not any(k.endswith(f".{new}") for k in terms):
            raise DriveCandidateError(f"candidate {key}: its template's extension {dict(e.terms)} names no per-wheel term "
                                      f"of {old} to rename to {new}; a per-wheel candidate sets <term>.{old}")
        return RoverExtension(e.soil, terms)
    return renamed


def _channels(channels: Sequence[str], wheels: Sequence[str], old: str | None = None, new: str | None = None
              ) -> tuple[str, ...]:
    """A candidate's report channels on a wheel set: one wheel's channel renamed (``old`` -> ``new``),
    or, where they name a mini rover wheel the set lacks, the four ``omega_`` / ``torque_`` channels
    replaced by the wheel set's (channels already on the set are kept)."""
    if old is None and not any(c.partition("_")[0] in ("omega", "torque") and c.partition("_")[2] in WHEELS
                               and c.partition("_")[2] not in wheels for c in channels):
        return tuple(channels)
    out: list[str] = []
    for c in channels:
        kind, _, w = c.partition("_")
        if kind in ("omega", "torque") and w in WHEELS:
            if old is not None:
                out.append(f"{kind}_{new}" if w == old else c)
            elif w == WHEELS[0]:
                out += [f"{kind}_{x}" for x in wheels]
            continue
        out.append(c)
    return tuple(out)


def rover_scales(scenario: Scenario) -> tuple[float, float]:
    """``(force, length)`` scales of a scenario's rover against the mini rover of Table 7.2: its
    weight over the mini rover's 34.3 N and its wheel radius over the ``dissertation-ch7`` set's
    58 mm; ``(1, 1)`` for the mini rover (no rover file)."""
    if getattr(scenario, "rover_file", None) is None:
        return 1.0, 1.0
    from ...physics.params import ROVER_MINI_T72
    from ...rover.scenario import PARAM_PRESETS

    return (scenario.rover.weight / ROVER_MINI_T72.weight,
            scenario.params.wheel.radius / PARAM_PRESETS["dissertation-ch7"].wheel.radius)


_SCALED_GEOMETRY = {"hub_contact": ("face_width", "arm")}
"""Millimetre parameters that are the wheel's size (scaled by the wheel radius); the hub contact's
clearance is a depth compared with the sinkage, which does not grow with the wheel: kept."""


def _rescaled(c: Candidate, force: float, length: float) -> Candidate:
    """``c`` with its force, spring-rate, torque (and hub geometry) bounds and starts scaled (module notes)."""
    factors = [force if unit in ("N", "N/m") else force * length if unit == "N m"
               else length if unit == "mm" and name in _SCALED_GEOMETRY.get(c.key, ()) else 1.0
               for name, unit, *_ in c.params]
    if all(f == 1.0 for f in factors):
        return c
    params = tuple((name, unit, lo * f, hi * f, start * f, si) for (name, unit, lo, hi, start, si), f in zip(c.params, factors))
    starts = tuple(tuple(x * f for x, f in zip(st, factors)) for st in c.starts)
    return replace(c, params=params, starts=starts)


def library_for(candidates: Sequence[Candidate], scenario: Scenario) -> tuple[Candidate, ...]:
    """The candidate library for the rover of ``scenario`` (module notes).

    Parameters
    ----------
    candidates : sequence of Candidate
        A library written for the mini rover (:data:`~offline.discrepancy.drive.candidates.DRIVE_CANDIDATES`
        or a selection of it), or one already made for this rover (kept: the function is
        idempotent). A per-wheel family (candidates whose keys differ only in the wheel name at
        the end) with a member naming a wheel the rover lacks is the mini rover's: it is made for
        each of the rover file's wheels (its ``FR`` member is the template). A family whose
        members all name the rover's own wheels is kept as given (MER's ``RR`` is its right rear
        wheel: ``wheel_radius_RR`` alone is that wheel's).
    scenario : Scenario

    Returns
    -------
    tuple of Candidate
        ``candidates`` itself (as a tuple) for the mini rover; for a rover file, the library on its
        wheels, a candidate whose parameters are still the mini rover library's with its force,
        torque and hub-geometry bounds scaled to the rover (:func:`rover_scales`; module notes).

    Raises
    ------
    DriveCandidateError
        A per-wheel family of ``candidates`` has no ``FR`` member among the library's per-wheel
        templates (:data:`~offline.discrepancy.drive.candidates.DRIVE_CANDIDATES_WITH_ACTUATORS`).
    """
    rf = getattr(scenario, "rover_file", None)
    if rf is None:
        return tuple(candidates)
    from .candidates import DRIVE_CANDIDATES_WITH_ACTUATORS

    wheels = tuple(scenario.wheels)
    names = (*WHEELS, *(w for w in wheels if w not in WHEELS))
    force, length = rover_scales(scenario)
    mini = {c.key: c.params for c in DRIVE_CANDIDATES_WITH_ACTUATORS}

    def sized(c: Candidate, template: str) -> Candidate:
        # only a candidate still at the mini rover's bounds (idempotent: one made for the rover is kept)
        return _rescaled(c, force, length) if mini.get(template) == c.params else c

    steerable = {w.name for w in rf.wheels if w.steerable}
    templates = {c.key: c for c in DRIVE_CANDIDATES_WITH_ACTUATORS if _wheel_of(c.key) == _TEMPLATE}
    family: dict[str, list[tuple[Candidate, str]]] = {}
    for c in candidates:
        w = _wheel_of(c.key, names)
        if w is not None:
            family.setdefault(c.key[:-len(w)], []).append((c, w))
    out: list[Candidate] = []
    done: set[str] = set()
    for c in candidates:
        w = _wheel_of(c.key, names)
        if w is None:
            out.append(replace(sized(c, c.key), channels=_channels(c.channels, wheels)))
            continue
        stem = c.key[:-len(w)]
        if stem in done:
            continue
        done.add(stem)
        members = family[stem]
        if all(m in wheels for _, m in members):  # already the rover's own wheels
            out += [sized(m, stem + _TEMPLATE) for m, _ in members]
            continue
        tpl = next((m for m, x in members if x == _TEMPLATE), None) or templates.get(stem + _TEMPLATE)
        if tpl is None:
            raise DriveCandidateError(f"candidate {c.key}: no {stem}{_TEMPLATE} template to make it for the wheels of "
                                      f"{rf.name} ({', '.join(wheels)})")
        tpl = sized(tpl, stem + _TEMPLATE)
        for new in wheels:
            if stem.startswith("steer_") and new not in steerable:
                continue  # a wheel that does not steer has no steering offset or steering servo
            if new == _TEMPLATE:
                out.append(tpl)
                continue
            out.append(replace(tpl, key=stem + new, physics=tpl.physics.replace(f" {_TEMPLATE} ", f" {new} "),
                               build=_renamed_build(tpl.build, _TEMPLATE, new, stem + new),
                               channels=_channels(tpl.channels, wheels, _TEMPLATE, new),
                               family=tpl.family[:-len(_TEMPLATE)] + new if tpl.family.endswith(f"_{_TEMPLATE}") else tpl.family))
    return tuple(out)


WheelSetHubContact = HubContact
""":class:`~offline.discrepancy.drive.candidates.HubContact`, which takes a rover file
(:class:`rtctl.physics.rover_file.RoverSpec`) as its ``rover``: the drag at the file's wheels."""

WheelSetHooks = Hooks
""":class:`~offline.discrepancy.drive.candidates.Hooks` with its ``wheels`` count (a rover file's)."""


def truth_disturbance(truth: Truth, scenario: Scenario) -> Any:
    """The simulator's disturbance hook of a truth's hook sections on the scenario's rover; None
    without any.

    :func:`~offline.discrepancy.drive.candidates.disturbance_from_truth` on the scenario's rover: the
    mini rover's, or its rover file (``[hub_contact]`` and the per-wheel ``[[empirical_force]]``
    terms at the file's wheels, in the plant's frame; ``[tether_anchor]`` a body force).

    Parameters
    ----------
    truth : Truth
        The simulated world (:func:`offline.sim.truth.load_truth` with the rover file).
    scenario : Scenario

    Raises
    ------
    ValueError
        An ``[[empirical_force]]`` combination the empirical family does not have.
    """
    rf = getattr(scenario, "rover_file", None)
    return disturbance_from_truth(truth, scenario.rover if rf is None else rf)
