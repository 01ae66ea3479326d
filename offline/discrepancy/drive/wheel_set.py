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
  are left out of the candidates -- the re-simulation's hooks
  (:func:`offline.discrepancy.drive.candidates.disturbance_from_terms`) are the mini rover's
  four wheels -- and the channels a term acts on (for the report) are the file's;
* :func:`truth_disturbance`: the simulator's disturbance hook of a truth file's hook sections
  (``[tether_anchor]``, ``[hub_contact]``, ``[[empirical_force]]``) on the scenario's wheel set,
  so a world with hub contact, a tether or a body drag is simulated on a rover file's plant as on
  the mini rover's (:class:`WheelSetHubContact`: the hub contact at the file's wheel positions).

A per-wheel candidate is renamed, not rewritten: its ``build`` is the template's with the rover
terms ``<term>.FR`` renamed ``<term>.<wheel>`` (:data:`~offline.discrepancy.drive.candidates.PER_WHEEL_TERMS`),
so the physics, bounds and starting points are the mini rover's, in SI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ...physics.params import ParameterSet
from rtctl.physics.hub_drag import SPEED_SMOOTHING, SPIN_SMOOTHING

from ...rover.scenario import Scenario
from ...sim.simulator import DisturbanceForces, TruthState
from ...sim.truth import WHEELS, Truth
from ..wheel.candidates import Candidate
from .candidates import AnchoredTether, DriveCandidateError, HubContact, RoverExtension, disturbance_from_truth

__all__ = ["tick_channels", "channel_unit", "library_for", "HOOK_CANDIDATES", "truth_disturbance",
           "WheelSetHubContact", "WheelSetHooks"]

HOOK_CANDIDATES = ("hub_contact", "tether_anchor")
"""Candidates that act through the simulator's disturbance hook (contract C5): their re-simulation
builds the mini rover's four-wheel hooks (:func:`~offline.discrepancy.drive.candidates.disturbance_from_terms`),
so :func:`library_for` leaves them out of a rover file's library (the rover file's simulator takes
a hook: :func:`truth_disturbance`)."""

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
        ``candidates`` itself (as a tuple) for the mini rover; for a rover file, the library on its wheels.

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
        if c.key in HOOK_CANDIDATES:
            continue
        w = _wheel_of(c.key, names)
        if w is None:
            out.append(replace(c, channels=_channels(c.channels, wheels)))
            continue
        stem = c.key[:-len(w)]
        if stem in done:
            continue
        done.add(stem)
        members = family[stem]
        if all(m in wheels for _, m in members):  # already the rover's own wheels
            out += [m for m, _ in members]
            continue
        tpl = next((m for m, x in members if x == _TEMPLATE), None) or templates.get(stem + _TEMPLATE)
        if tpl is None:
            raise DriveCandidateError(f"candidate {c.key}: no {stem}{_TEMPLATE} template to make it for the wheels of "
                                      f"{rf.name} ({', '.join(wheels)})")
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


@dataclass(frozen=True)
class WheelSetHubContact(HubContact):
    """:class:`~offline.discrepancy.drive.candidates.HubContact` (the same passive-pressure drag and
    hub torque per wheel, :meth:`HubContact.force`) at the wheels of a rover file: ``rover`` is a
    :class:`rtctl.physics.rover_file.RoverSpec`, whose wheel positions (body frame of the plant:
    the travel frame of a backward drive) and order the forces take."""

    def __call__(self, t: float, s: TruthState) -> DisturbanceForces:
        """The forces over the next step (contract C5), one per wheel of the rover file."""
        f = self.force(np.array(s.sinkage))
        spec: Any = self.rover  # a RoverSpec here (HubContact's field is typed for the mini rover's Rover)
        xs = np.array([w.position[0] for w in spec.wheels])
        ys = np.array([w.position[1] for w in spec.wheels])
        if len(f) != len(xs):
            raise DriveCandidateError(f"hub contact on {spec.name}: the state has {len(f)} wheels, the rover file "
                                      f"{len(xs)}")
        vx, vy = s.u - s.yaw_rate * ys, s.v + s.yaw_rate * xs
        norm = np.sqrt(vx * vx + vy * vy + SPEED_SMOOTHING ** 2)
        om = np.array(s.omega)
        torque = f * self.arm * om / np.sqrt(om * om + SPIN_SMOOTHING ** 2)
        return DisturbanceForces(wheel_force=tuple((float(-fi * a / n), float(-fi * b / n)) for fi, a, b, n in zip(f, vx, vy, norm)),
                                 wheel_torque=tuple(float(x) for x in torque))


@dataclass(frozen=True)
class WheelSetHooks:
    """Several disturbance hooks on a rover of ``wheels`` wheels acting together (their forces add;
    the mini rover's :class:`~offline.discrepancy.drive.candidates.Hooks` for any wheel count)."""

    hooks: tuple[Any, ...]
    wheels: int

    def __call__(self, t: float, s: TruthState) -> DisturbanceForces:
        """The summed forces over the next step (contract C5)."""
        n = self.wheels
        v = sum(h(t, s).vector(n) for h in self.hooks)
        return DisturbanceForces(body_force=(v[0], v[1]), body_moment_z=v[2],
                                 wheel_force=tuple(zip(v[3:3 + n], v[3 + n:3 + 2 * n])), wheel_torque=tuple(v[3 + 2 * n:]))


def truth_disturbance(truth: Truth, scenario: Scenario) -> Any:
    """The simulator's disturbance hook of a truth's hook sections on the scenario's rover; None
    without any.

    The mini rover (no rover file): :func:`~offline.discrepancy.drive.candidates.disturbance_from_truth`,
    as before. A rover file: ``[tether_anchor]`` an
    :class:`~offline.discrepancy.drive.candidates.AnchoredTether` (a body force, any rover),
    ``[hub_contact]`` a :class:`WheelSetHubContact` at the file's wheels (the believed soil of the
    truth's parameter set), ``[[empirical_force]]`` the empirical family's hook of its body terms
    (:func:`offline.sim.truth.load_truth` admits only ``drag.body`` on a rover file).

    Parameters
    ----------
    truth : Truth
        The simulated world (:func:`offline.sim.truth.load_truth` with the rover file).
    scenario : Scenario

    Raises
    ------
    DriveCandidateError
        A per-wheel empirical term on a rover file (a truth not read with the rover file).
    """
    rf = getattr(scenario, "rover_file", None)
    if rf is None:
        return disturbance_from_truth(truth, scenario.rover)
    hooks: list[Any] = []
    if truth.anchor is not None:
        a = truth.anchor
        hooks.append(AnchoredTether(a["tension"], a.get("bearing", math.pi), a.get("inverse_distance", 0.0),
                                    a.get("attach_x", 0.0), a.get("spring_rate", 0.0)))
    if truth.hub is not None:
        hooks.append(WheelSetHubContact(truth.hub["clearance"], truth.hub.get("face_width", 0.0), truth.hub.get("arm", 0.0),
                                        truth.params.soil, rf))
    if truth.empirical:
        bad = [e["direction"] for e in truth.empirical if e["direction"] != "drag.body"]
        if bad:
            raise DriveCandidateError(f"empirical terms {bad} act on the mini rover's wheels; on the rover file {rf.name} "
                                      "an empirical term acts on the body only (drag.body)")
        from .empirical import EmpiricalTerms, terms_from_truth

        hooks.append(EmpiricalTerms(terms_from_truth(truth.empirical), scenario.rover).hook())
    if not hooks:
        return None
    return hooks[0] if len(hooks) == 1 else WheelSetHooks(tuple(hooks), len(scenario.wheels))
