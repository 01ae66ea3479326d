"""Empirical terms for what the drive library lacks (issue 24, "model the unknown").

When no library term explains a drive (the engine's verdict is ``unexplained``, ``ambiguous``
or ``partly_explained``), :func:`search_empirical` builds a term from what the data locate,
out of a small family of generic, physically interpretable terms, and accepts it only by a
held-out test with a null of the same search. What it is told: the recording, the believed
model (scenario, world, actuators, sensors) and the engine's verdict (its residuals, noise,
dispersion and folds). What it is not told: anything of the truth (no effect, wheel, place,
time or law is given to it).

The family (:class:`EmpiricalTerm`)
-----------------------------------
A term is a *direction* times a *localisation* times a *magnitude*:

================  ==============================================================  ========
direction         what acts                                                       unit
================  ==============================================================  ========
``drag.body``     a force at the centre of mass against the rover's travel         N
``drag.<W>``      a force at wheel W's contact against that contact's travel       N
``drag.each``     the same force on every wheel, each by its own localisation       N
``torque.<W>``    a torque resisting wheel W's spin                                N m
``torque.each``   the same torque on every wheel, each by its own localisation      N m
``speed_loss.<W>``  the fraction of wheel W's rim-speed command its servo misses   -
``offset.<ch>``   an offset of the ``yaw_rate``, ``roll`` or ``pitch`` reading      rad/s, rad
================  ==============================================================  ========

localised (``where``, ``shape``) as

- ``everywhere`` / ``constant``;
- in ``time`` (s from the drive's start): ``box`` [lo, hi) or ``step`` (from lo on);
- in position ``x`` or ``y`` (m, the recording's pose frame; of the point where the force
  acts: the wheel's contact or the centre of mass): ``box`` [lo, hi) -- a patch;
- in a state variable of the wheel (``sinkage`` m, ``slip``, ``slip_angle`` |rad|, from the
  believed model's re-simulation): ``step`` (above the threshold lo) or ``hinge``
  (``magnitude (v - lo)`` above lo: magnitude per unit of v);
- in the wheel's commanded rim speed (``command``, m/s; ``speed_loss`` only): ``saturation``
  -- the servo reaches ``|c|`` up to ``lo`` and only ``lo + (1 - magnitude) (|c| - lo)`` above
  it (``magnitude`` 1: a hard limit at ``lo``; ``lo`` 0: a constant fraction).

How a term is found (:func:`search_empirical`)
----------------------------------------------
1. **Sensitivities.** The believed model re-simulates the drive once with a state logger
   (sinkage, slip, slip angle per wheel and tick) and once per direction with a constant unit
   term (13 re-simulations on the mini rover). At drive speeds the plant is quasi-static, so a
   term's effect on a tick is its magnitude there times that tick's sensitivity: every
   localised term is then a column ``a`` of normalised residual changes (the engine's noise x
   dispersion units), with no further simulation. Columns: every direction x every
   localisation on a grid (time edges every ``time_step`` segments, position edges at 16
   quantiles of the visited positions, state thresholds at 10 quantiles, command thresholds at
   the commanded speeds).
2. **Selection by sparsity.** Within a training set of rows each column gets its least-squares
   magnitude and an AIC-type score: in-sample chi-square improvement minus 2 per parameter
   (1 for a constant, 2 for a step, hinge or saturation, 3 for a box). The best column wins.
3. **Held-out test** (the engine's held-out blocks, :meth:`DriveRecording.folds`): for each
   fold the selection runs on the other folds and the chosen term, with the magnitude fitted
   there, is scored on the held-out fold; ``D`` is the summed held-out improvement. Its null
   is the same nested search run on draws of the drive's correlated noise
   (:meth:`DriveRecording.null_draw`, unit variance in the normalised units, which is
   conservative where the dispersion exceeds one), so the multiplicity of the whole family is
   paid for. Accepted at ``p < alpha`` (the drive's family-wise level,
   :data:`~offline.discrepancy.drive.diagnosis.DRIVE_ALPHA`), with ``ceil(2 / alpha)`` draws.
4. **Confirmed by the simulator.** The accepted term is refined on the full data (edges at
   tick resolution around the grid's best, magnitude by least squares), its magnitude
   corrected by one re-simulation (the real column replaces the linear one), and the held-out
   improvement is measured again by re-simulating each fold's term (fitted without that fold):
   the reported held-out improvement is the simulator's, not the linearisation's.
5. **A second term** is searched on the residuals the first leaves, with the same test.

Verdict (:class:`EmpiricalResult`): ``explained`` by the empirical term(s) when they remove at
least half of the held-out excess chi-square (the engine's ``explained_fraction`` definition)
and no misfit above noise is left (the engine's lack-of-fit test at its after-level);
``partly_explained`` when a term passes the test but either condition fails; ``none``
otherwise. An empirical term never names library physics: the engine's status is kept, the
report adds the term with its law, localisation, held-out improvement and the experiment that
would confirm its physics.

What the simulator can apply: the re-simulation applies force and torque terms as a disturbance
hook (:meth:`EmpiricalTerms.hook`, contract C5), speed losses in the commands the servos follow
(:meth:`EmpiricalTerms.commands`) and reading offsets in the readings, all through
:class:`~offline.discrepancy.drive.diagnosis.DriveModel`. The simulator itself takes a truth file:
force and torque terms are written to ``accepted_truth.toml`` as ``[[empirical_force]]`` tables
(:func:`truth_entries`; :func:`offline.sim.truth.load_truth` reads them and
:func:`offline.discrepancy.drive.candidates.disturbance_from_truth` makes the simulator's hook of them,
localised by the simulator's own time and pose). Speed losses (the servo commands) and reading
offsets (the sensor chain) are not part of the world a truth file describes: the report says so
for each (:func:`simulator_applies`), and every term is in ``empirical_terms.json``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.physics.hub_drag import SPEED_SMOOTHING, SPIN_SMOOTHING

from ...sim.simulator import DisturbanceForces
from ...sim.truth import WHEELS
from ..significance import fail_floor, normalised

__all__ = ["EmpiricalTerm", "EmpiricalTerms", "EmpiricalResult", "search_empirical", "search_drives", "interleaved_folds",
           "DIRECTIONS", "simulator_applies", "truth_entries", "terms_from_truth", "direction_text", "wheel_names"]

DIRECTIONS: dict[str, tuple[str, str]] = {
    "drag.body": ("resisting force at the centre of mass against the rover's travel", "N"),
    **{f"drag.{w}": (f"resisting force at the {w} wheel's contact against its travel", "N") for w in WHEELS},
    "drag.each": ("resisting force at each wheel's contact against its travel", "N per wheel"),
    **{f"torque.{w}": (f"torque resisting the {w} wheel's spin", "N m") for w in WHEELS},
    "torque.each": ("torque resisting each wheel's spin", "N m per wheel"),
    **{f"speed_loss.{w}": (f"{w} wheel-speed servo short of its command", "fraction") for w in WHEELS},
    "offset.yaw_rate": ("offset of the yaw-rate (gyro) reading", "deg/s"),
    "offset.roll": ("offset of the roll reading", "deg"),
    "offset.pitch": ("offset of the pitch reading", "deg"),
}
"""Directions of the empirical family: ``name -> (what acts, report unit)`` (module table)."""

_REPORT_SCALE = {"offset.yaw_rate": 180 / math.pi, "offset.roll": 180 / math.pi, "offset.pitch": 180 / math.pi}
_WHERE_UNIT = {"time": ("s", 1.0), "x": ("m", 1.0), "y": ("m", 1.0), "sinkage": ("mm", 1e3), "slip": ("", 1.0),
               "slip_angle": ("deg", 180 / math.pi), "command": ("m/s", 1.0), "everywhere": ("", 1.0)}
_SHAPES = ("constant", "box", "step", "hinge", "saturation")
_STATE = ("sinkage", "slip", "slip_angle")


_PER_WHEEL_KINDS = ("drag", "torque", "speed_loss")


def _wheel_xy(rover: Any) -> NDArray[np.float64]:
    """Body-frame contact positions (x forward, y left), m: FR, FL, RR, RL of the mini rover, or
    a rover file's wheels in its order (:func:`~offline.discrepancy.drive.candidates.wheel_plan_positions`)."""
    from .candidates import wheel_plan_positions

    return wheel_plan_positions(rover)


def wheel_names(rover: Any) -> tuple[str, ...]:
    """The wheel names of ``rover``: the mini rover's (:data:`~offline.sim.truth.WHEELS`) or a
    rover file's (:attr:`rtctl.physics.rover_file.RoverSpec.wheel_names`, issue 23)."""
    return tuple(getattr(rover, "wheel_names", WHEELS))


def direction_text(direction: str, wheels: Sequence[str] = WHEELS) -> tuple[str, str]:
    """``(what acts, report unit)`` of a direction on a wheel set: :data:`DIRECTIONS` (the mini
    rover's wheels), or a per-wheel direction (``drag``, ``torque``, ``speed_loss``) of a rover
    file's wheel (``drag.LM`` on the MER-class rover), worded as the mini rover's.

    Raises
    ------
    ValueError
        An unknown direction, or a wheel not in ``wheels``.
    """
    kind, dot, w = direction.partition(".")
    mini = tuple(wheels) == WHEELS
    if direction in DIRECTIONS and (mini or not (kind in _PER_WHEEL_KINDS and w not in ("body", "each"))):
        return DIRECTIONS[direction]
    if kind in _PER_WHEEL_KINDS and w in wheels:
        what, unit = DIRECTIONS[f"{kind}.FR"]
        return what.replace("FR", w), unit
    raise ValueError(f"empirical term: unknown direction {direction!r} on the wheels {', '.join(wheels)}; known: "
                     f"{[d for d in DIRECTIONS if d.partition('.')[0] not in _PER_WHEEL_KINDS or d.partition('.')[2] in ('body', 'each')]} "
                     f"and {list(_PER_WHEEL_KINDS)} of a wheel: <kind>.<wheel>")


@dataclass(frozen=True)
class EmpiricalTerm:
    """One generic term: ``magnitude x weight(localisation variable)`` along a direction (module table).

    Parameters
    ----------
    direction : str
        A key of :data:`DIRECTIONS`.
    where : str
        ``everywhere``, ``time``, ``x``, ``y``, ``sinkage``, ``slip``, ``slip_angle`` or ``command``.
    shape : str
        ``constant``, ``box`` ([lo, hi)), ``step`` (from / above lo), ``hinge`` ((v - lo) above lo)
        or ``saturation`` (``command`` only: the fraction of the command above lo that is lost).
    lo, hi : float
        Edges or threshold (SI: s, m, m, -, rad, m/s).
    magnitude : float
        SI (N, N m, fraction, rad/s, rad); for ``hinge`` per unit of the variable.
    wheels : tuple of str
        The wheel set a per-wheel direction names a wheel of (default the mini rover's; a rover
        file's wheels, issue 23). Not compared.

    Raises
    ------
    ValueError
        An unknown direction, localisation or shape, or a combination the family does not have.
    """

    direction: str
    where: str = "everywhere"
    shape: str = "constant"
    lo: float = -math.inf
    hi: float = math.inf
    magnitude: float = 0.0
    wheels: tuple[str, ...] = field(default=WHEELS, compare=False, repr=False)

    def __post_init__(self) -> None:
        direction_text(self.direction, self.wheels)  # raises on an unknown direction
        if self.where not in _WHERE_UNIT:
            raise ValueError(f"empirical term: unknown localisation {self.where!r}; known: {list(_WHERE_UNIT)}")
        if self.shape not in _SHAPES:
            raise ValueError(f"empirical term: unknown shape {self.shape!r}; known: {list(_SHAPES)}")
        kind = self.direction.split(".")[0]
        if (self.where == "command") != (self.shape == "saturation") or (self.where == "command" and kind != "speed_loss"):
            raise ValueError(f"empirical term {self.direction}: a saturation is in the commanded speed of a speed loss only")
        if kind == "offset" and self.where not in ("everywhere", "time"):
            raise ValueError(f"empirical term {self.direction}: a reading offset is localised in time only")
        if self.where in _STATE and (self.direction == "drag.body" or kind in ("offset", "speed_loss")):
            raise ValueError(f"empirical term {self.direction}: a wheel state localises a wheel's drag or torque only")

    @property
    def kind(self) -> str:
        """``drag``, ``torque``, ``speed_loss`` or ``offset``."""
        return self.direction.split(".")[0]

    @property
    def target(self) -> str:
        """``body``, a wheel name, ``each`` or a reading channel."""
        return self.direction.split(".", 1)[1]

    @property
    def on_wheel(self) -> bool:
        """Whether the term acts on one named wheel (``drag.<W>``, ``torque.<W>``, ``speed_loss.<W>``)."""
        return self.kind in _PER_WHEEL_KINDS and self.target not in ("body", "each")

    @property
    def n_params(self) -> int:
        """Fitted parameters (magnitude plus the localisation's)."""
        return {"constant": 1, "step": 2, "hinge": 2, "saturation": 2, "box": 3}[self.shape]

    def weight(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        """The localisation's weight at the values ``v`` of its variable (magnitude 1)."""
        v = np.asarray(v, dtype=float)
        if self.shape == "constant":
            return np.ones_like(v)
        if self.shape == "box":
            return ((v >= self.lo) & (v < self.hi)).astype(float)
        if self.shape == "step":
            return (v >= self.lo).astype(float)
        if self.shape == "hinge":
            return np.maximum(v - self.lo, 0.0)
        a = np.abs(v)
        return np.where(a > self.lo, (a - self.lo) / np.maximum(a, 1e-12), 0.0)

    def with_(self, **kw: Any) -> "EmpiricalTerm":
        """A copy with fields replaced."""
        return dataclasses.replace(self, **kw)

    def localisation_text(self) -> str:
        """Where / when / above what the term acts, in report units."""
        u, f = _WHERE_UNIT[self.where]
        name = {"time": "t", "x": "x", "y": "y", "sinkage": "sinkage", "slip": "slip", "slip_angle": "|slip angle|",
                "command": "|command|"}.get(self.where, "")
        whose = (" of each wheel" if self.target == "each" else f" of the {self.target} wheel"
                 if self.where in _STATE or (self.where in ("x", "y") and self.kind != "drag" or self.on_wheel)
                 and self.where not in ("time",) else " of the centre of mass" if self.where in ("x", "y") else "")
        if self.shape == "constant":
            return "throughout the drive"
        if self.shape == "box":
            return f"for {name}{whose} in [{f * self.lo:.3g}, {f * self.hi:.3g}) {u}".rstrip()
        if self.shape == "step":
            return (f"from t = {f * self.lo:.3g} s on" if self.where == "time"
                    else f"where {name}{whose} exceeds {f * self.lo:.3g} {u}".rstrip())
        if self.shape == "hinge":
            return f"growing linearly with {name}{whose} above {f * self.lo:.3g} {u}".rstrip()
        return f"above {self.lo:.3g} m/s of command"

    def law(self) -> str:
        """The term as one report line (e.g. ``extra resisting force 0.4 N per wheel for x in [1.0, 1.6) m``)."""
        what, unit = direction_text(self.direction, self.wheels)
        m = self.magnitude * _REPORT_SCALE.get(self.direction, 1.0)
        if self.kind == "speed_loss":
            w = self.target
            if self.shape == "saturation" and self.lo > 0:
                if self.magnitude >= 0.95:
                    return (f"{w} wheel speed limited to {self.lo:.3g} m/s: it follows its command below and loses "
                            f"{self.magnitude:.2f} of the command's excess above")
                return (f"{w} wheel speed saturates: it follows its command up to {self.lo:.3g} m/s and only "
                        f"{1 - self.magnitude:.2f} of the command's excess beyond")
            return (f"{w} wheel speed reaches {1 - self.magnitude:.2f} of its command "
                    f"{self.localisation_text() if self.shape != 'saturation' else 'at every speed'}")
        sign = "" if m >= 0 else "negative (assisting) "
        if self.shape == "hinge":
            u, f = _WHERE_UNIT[self.where]
            return f"extra {sign}{what}: {abs(m) / f:.3g} {unit} per {u or 'unit'} of {self.where} {self.localisation_text()}"
        return f"extra {sign}{what}: {abs(m):.3g} {unit} {self.localisation_text()}"

    def experiment(self) -> str:
        """What experiment would confirm the physics behind the term."""
        k, t = self.kind, self.target
        if k == "offset":
            return (f"log the {t.replace('_', ' ')} sensor at rest before and after the suspected change "
                    "(and its temperature): an offset that steps with no motion is the sensor's")
        if k == "speed_loss":
            return (f"command the {t} wheel alone, lifted, at a ladder of speeds up to the drive's highest, and log its "
                    "encoder: a servo limit shows with no soil load")
        if self.where in ("x", "y"):
            return ("drive across the same place again, at another heading and speed; inspect the ground there "
                    "(sinkage tracks, a penetrometer or a bevameter plate): a patch of other soil stays where it is")
        if self.where == "time":
            return ("repeat the drive on fresh ground: an effect tied to the time (something caught or dragged, a "
                    "thermal change) does not return at the same place")
        if self.where in _STATE:
            return (f"drive a slip / sinkage sweep (single-wheel testbed or rover drawbar-pull steps) and log "
                    f"{'each wheel' if t == 'each' else f'the {t} wheel'}'s motor torque against {self.where}: the term "
                    "predicts where it sets in")
        return (f"lift the {'rover' if t == 'body' else t + ' wheel'} and spin / push it free of the soil: a drag that "
                "remains is in the hardware (hub, seal, bearing), one that goes is the soil's")

    def to_json(self) -> dict[str, Any]:
        """Machine-readable term (SI)."""
        return {"direction": self.direction, "where": self.where, "shape": self.shape,
                "lo": self.lo if math.isfinite(self.lo) else None, "hi": self.hi if math.isfinite(self.hi) else None,
                "magnitude_SI": self.magnitude, "law": self.law(), "confirm_by": self.experiment()}


@dataclass(frozen=True)
class EmpiricalTerms:
    """Terms the believed simulator applies on top of an extension
    (:meth:`offline.discrepancy.drive.diagnosis.DriveModel.simulate`'s ``extra``).

    Parameters
    ----------
    terms : tuple of EmpiricalTerm
    rover : Rover or RoverSpec
        Wheel names and positions: the mini rover (rocker length, track width; FR, FL, RR, RL) or
        a rover file (its wheels, in its order; issue 23).
    logger : list, optional
        When given, the disturbance hook appends each truth state it sees (``(t, state)``)
        and the hook is installed even without a force term (forces zero).
    """

    terms: tuple[EmpiricalTerm, ...]
    rover: Any
    logger: list[Any] | None = field(default=None, compare=False)

    def key(self) -> Any:
        """Cache key of the re-simulation (a logger is never cached)."""
        if self.logger is not None:
            return ("log", id(self.logger))
        return tuple((t.direction, t.where, t.shape, t.lo, t.hi, t.magnitude) for t in self.terms)

    def hook(self, time_of: Callable[[], float] | None = None,
             pose_of: Callable[[float], tuple[float, float, float]] | None = None) -> Any:
        """The disturbance hook of the drag and torque terms (None without them and without a logger).

        ``time_of()`` and ``pose_of(t) -> (x, y, heading)`` give the time and pose the terms are
        localised by: the re-simulation's recorded ones (:class:`~offline.discrepancy.drive.diagnosis.DriveModel`
        solves the plant at the recorded heading, skipping ticks); None: the simulator's own (the
        hook's time argument and the truth state's pose, as a truth file's ``[[empirical_force]]``
        is applied, :func:`offline.discrepancy.drive.candidates.disturbance_from_truth`).
        """
        forces = [t for t in self.terms if t.kind in ("drag", "torque")]
        if not forces and self.logger is None:
            return None
        xy = _wheel_xy(self.rover)
        names = wheel_names(self.rover)
        nw = len(names)
        from .candidates import backward_rover_file

        back = backward_rover_file(self.rover)
        log = self.logger

        def hook(tt: float, s: Any) -> DisturbanceForces:
            now = tt if time_of is None else time_of()
            if log is not None:
                log.append((now, s))
            bf = np.zeros(2)
            wf = np.zeros((nw, 2))
            wt = np.zeros(nw)
            if forces:
                X, Y, H = (s.x, s.y, s.heading) if pose_of is None else pose_of(now)
                if pose_of is not None and back:
                    H += math.pi  # a recorded (body) heading; the plant and the wheel positions are in the travel frame
                c, sn = math.cos(H), math.sin(H)
                vx, vy = s.u - s.yaw_rate * xy[:, 1], s.v + s.yaw_rate * xy[:, 0]
                state = {"sinkage": np.asarray(s.sinkage, float), "slip": np.asarray(s.slip, float),
                         "slip_angle": np.abs(np.asarray(s.slip_angle, float))}
                for t in forces:
                    if t.target == "body":
                        v = {"time": now, "x": X, "y": Y}.get(t.where, 0.0)
                        g = float(t.weight(np.array([v]))[0]) * t.magnitude
                        sp = math.sqrt(s.u * s.u + s.v * s.v + SPEED_SMOOTHING ** 2)
                        bf += (-g * s.u / sp, -g * s.v / sp)
                        continue
                    idx = range(nw) if t.target == "each" else [names.index(t.target)]
                    for i in idx:
                        if t.where == "time":
                            v = now
                        elif t.where in ("x", "y"):
                            v = (X + c * xy[i, 0] - sn * xy[i, 1]) if t.where == "x" else (Y + sn * xy[i, 0] + c * xy[i, 1])
                        elif t.where in _STATE:
                            v = float(state[t.where][i])
                        else:
                            v = 0.0
                        g = float(t.weight(np.array([v]))[0]) * t.magnitude
                        if g == 0.0:
                            continue
                        if t.kind == "drag":
                            n = math.sqrt(vx[i] ** 2 + vy[i] ** 2 + SPEED_SMOOTHING ** 2)
                            wf[i] += (-g * vx[i] / n, -g * vy[i] / n)
                        else:
                            om = float(s.omega[i])
                            wt[i] += g * om / math.sqrt(om * om + SPIN_SMOOTHING ** 2)
            return DisturbanceForces(body_force=(float(bf[0]), float(bf[1])),
                                     wheel_force=tuple((float(a), float(b)) for a, b in wf),
                                     wheel_torque=tuple(float(x) for x in wt))

        return hook

    def commands(self, rim: NDArray[np.float64], steer: NDArray[np.float64], t: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The rim-speed commands the servos really follow under the speed-loss terms."""
        rim = np.array(rim, dtype=float)
        for term in self.terms:
            if term.kind != "speed_loss":
                continue
            i = wheel_names(self.rover).index(term.target)
            v = {"time": t, "command": rim[:, i]}.get(term.where, np.zeros(len(t)))
            rim[:, i] = rim[:, i] * (1.0 - term.magnitude * term.weight(v))
        return rim, np.asarray(steer, dtype=float)

    def readings(self, ticks: dict[str, NDArray[np.float64]], t: NDArray[np.float64]) -> dict[str, NDArray[np.float64]]:
        """Readings with the offset terms added."""
        out = dict(ticks)
        for term in self.terms:
            if term.kind == "offset":
                v = t if term.where == "time" else np.zeros(len(t))
                out[term.target] = out[term.target] + term.magnitude * term.weight(v)
        return out


def simulator_applies(term: EmpiricalTerm) -> str:
    """Empty when a truth file's ``[[empirical_force]]`` carries the term to the simulator,
    otherwise why not (module notes)."""
    if term.kind in ("drag", "torque"):
        return ""
    if term.kind == "speed_loss":
        return ("a speed loss acts on the commands a wheel's servo follows; the truth format describes the world, "
                "and the simulator's actuators take no per-wheel command law from it")
    return "a reading offset belongs to the sensor chain (SensorConfig), not to the simulated world"


def truth_entries(terms: Sequence[EmpiricalTerm]) -> list[dict[str, Any]]:
    """The ``[[empirical_force]]`` tables (:func:`offline.sim.truth.load_truth`) of the terms the
    simulator applies (:func:`simulator_applies`), SI, in file keys."""
    out = []
    for t in terms:
        if simulator_applies(t):
            continue
        e: dict[str, Any] = {"direction": t.direction, "where": t.where, "shape": t.shape}
        if math.isfinite(t.lo):
            e["lo_si"] = t.lo
        if math.isfinite(t.hi):
            e["hi_si"] = t.hi
        e["magnitude_si"] = t.magnitude
        out.append(e)
    return out


def terms_from_truth(entries: Sequence[dict[str, Any]], wheels: Sequence[str] = WHEELS) -> tuple[EmpiricalTerm, ...]:
    """The terms of :attr:`offline.sim.truth.Truth.empirical` (SI dicts) on a wheel set (default the
    mini rover's; a rover file's wheels, issue 23).

    Raises
    ------
    ValueError
        A combination the family does not have (e.g. a body drag localised in a wheel's sinkage).
    """
    return tuple(EmpiricalTerm(e["direction"], e["where"], e["shape"], e["lo"], e["hi"], e["magnitude"], tuple(wheels))
                 for e in entries)


@dataclass
class EmpiricalResult:
    """What the empirical search found (module notes).

    Attributes
    ----------
    status : str
        ``explained``, ``partly_explained`` or ``none``.
    terms : list of EmpiricalTerm
        Accepted terms, in the order found.
    p_values : list of float
        Held-out test of each accepted term (and of the first rejected one, last, when any).
    held_out_linear : list of float
        Nested held-out improvement of each search (linearised), noise x dispersion units.
    chi2_cv_base, chi2_cv_after : float
        Held-out chi-square of the believed model and with the accepted terms (each fold's terms
        fitted without that fold, re-simulated), over ``values`` values.
    explained_fraction : float
        ``(chi2_cv_base - chi2_cv_after) / (chi2_base - values)``: share of the held-out excess removed.
    misfit_after : list
        Channels still above noise with the terms (the engine's lack-of-fit test).
    fold_terms : list of list of EmpiricalTerm
        The terms fitted without each fold (their spread says how well the data fix them).
    simulations, seconds : int, float
    """

    status: str
    terms: list[EmpiricalTerm]
    p_values: list[float]
    held_out_linear: list[float]
    chi2_cv_base: float
    chi2_cv_after: float
    values: int
    explained_fraction: float
    misfit_after: list[tuple[str, float, int, float]]
    fold_terms: list[list[EmpiricalTerm]]
    simulations: int
    seconds: float
    n_columns: int
    n_boot: int
    alpha: float

    def summary_lines(self) -> list[str]:
        """Report lines (appended to the engine's summary)."""
        head = {"explained": "EXPLAINED BY AN EMPIRICAL TERM (not library physics)",
                "partly_explained": "PARTLY EXPLAINED BY AN EMPIRICAL TERM (not library physics)",
                "none": "no empirical term passes the held-out test"}[self.status]
        out = [f"empirical model of what the library lacks: {head}"]
        for t, p in zip(self.terms, self.p_values):
            out.append(f"  - {t.law()} (held-out test p = {p:.2g})")
            out.append(f"    to confirm the physics: {t.experiment()}")
        if self.terms:
            out.append(f"  held-out chi2 (each fold's term fitted without it, re-simulated): {self.chi2_cv_base:.1f} -> "
                       f"{self.chi2_cv_after:.1f} for {self.values} values: {100 * self.explained_fraction:.0f} % of the "
                       "held-out excess removed")
            for ch, c2, n, p in self.misfit_after:
                out.append(f"  misfit left with the term in {ch}: chi2 {c2:.0f} for {n} rows in noise units (p = {p:.2g})")
            for t in self.terms:
                why = simulator_applies(t)
                out.append(f"  {t.direction} {t.where}: " + ("written to accepted_truth.toml ([[empirical_force]]), which "
                                                             "the simulator applies as a disturbance hook" if not why else
                                                             f"not written to accepted_truth.toml: {why}"))
        out.append(f"  searched {self.n_columns} localised terms; null: the same nested search on {self.n_boot} draws of "
                   f"the drive's correlated noise, level {self.alpha:g}; {self.simulations} re-simulations, {self.seconds:.1f} s")
        return out

    def to_json(self) -> dict[str, Any]:
        """Machine-readable result."""
        return {"status": self.status, "terms": [t.to_json() for t in self.terms], "p_values": self.p_values,
                "held_out_linear": self.held_out_linear, "held_out_chi2_before": self.chi2_cv_base,
                "held_out_chi2_after": self.chi2_cv_after, "values": self.values,
                "explained_fraction": self.explained_fraction,
                "misfit_after": [{"channel": c, "chi2_noise_units": x, "rows": n, "p": p} for c, x, n, p in self.misfit_after],
                "fold_terms": [[t.to_json() for t in ts] for ts in self.fold_terms],
                "simulations": self.simulations, "seconds": self.seconds, "columns_searched": self.n_columns,
                "null_draws": self.n_boot, "alpha": self.alpha,
                "accepted_truth_toml": [simulator_applies(t) or "written ([[empirical_force]])" for t in self.terms]}


# --------------------------------------------------------------------------- the linear family

@dataclass
class _Family:
    """Columns of the search: terms (magnitude 1) and their normalised responses ``A`` (columns x values)."""

    terms: list[EmpiricalTerm]
    A: NDArray[np.float64]
    k: NDArray[np.float64]


def _tick_contributions(obs: Any, drive: int, dticks: dict[str, NDArray[np.float64]], dbody: NDArray[np.float64] | None,
                        base_body: NDArray[np.float64], scale: dict[str, float]) -> NDArray[np.float64]:
    """Per-tick contribution (ticks x channels) of a per-tick change to the drive's segment rows, in
    normalised units: tick channels average over their segment; pose increments sum the change of
    the body velocity turned by the believed model's heading within the segment (first order)."""
    d, seg = obs.drives[drive], obs.segments[drive]
    rows = np.flatnonzero(obs.drive == drive)
    rows = rows[np.argsort(obs.segment[rows])]
    n = len(d.t)
    out = np.zeros((n, len(obs.channels)))
    for j, (a, b) in enumerate(seg.bounds):
        r = rows[j] if j < rows.size else None
        if r is None:
            continue
        L = b - a
        ks = np.arange(a + 1, b + 1)
        if dbody is not None:
            rr = base_body[ks, 2]
            hm = np.cumsum(rr) * d.period - 0.5 * rr * d.period
        for c, ch in enumerate(obs.channels):
            den = obs.noise[ch][r] * scale[ch]
            if ch in dticks:
                out[ks, c] = dticks[ch][ks] / L / den
            elif ch in ("dx_body", "dy_body", "dheading") and dbody is not None:
                du, dv, dr = dbody[ks].T
                if ch == "dx_body":
                    out[ks, c] = d.period * (du * np.cos(hm) - dv * np.sin(hm)) / den
                elif ch == "dy_body":
                    out[ks, c] = d.period * (du * np.sin(hm) + dv * np.cos(hm)) / den
                else:
                    out[ks, c] = d.period * dr / den
    return np.nan_to_num(out)


def _aggregate(obs: Any, drive: int, G: NDArray[np.float64], C: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rows of columns ``G`` (columns x ticks weights) through contributions ``C`` (ticks x channels):
    ``(columns, rows of this drive in obs order, channels)``."""
    seg = obs.segments[drive]
    m, L = len(seg.bounds), int(seg.bounds[0, 1] - seg.bounds[0, 0])
    ks = slice(1, m * L + 1)
    g = G[:, ks].reshape(G.shape[0], m, L)
    c = C[ks].reshape(m, L, C.shape[1])
    return np.einsum("kml,mlh->kmh", g, c, optimize=True)


def _edges(v: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    """``n`` distinct quantile edges of the finite values (ends included)."""
    v = v[np.isfinite(v)]
    if v.size == 0:
        return np.zeros(0)
    e = np.unique(np.quantile(v, np.linspace(0.0, 1.0, n)))
    e[-1] = np.nextafter(e[-1], np.inf)
    return e


def _box_terms(direction: str, where: str, edges: NDArray[np.float64], min_span: int = 1,
               wheels: tuple[str, ...] = WHEELS) -> list[EmpiricalTerm]:
    out = []
    for i in range(len(edges)):
        for j in range(i + min_span, len(edges)):
            if i == 0 and j == len(edges) - 1:
                continue  # the whole range: the constant term
            out.append(EmpiricalTerm(direction, where, "box", float(edges[i]), float(edges[j]), 1.0, wheels))
    return out


def _rover_of(model: Any) -> Any:
    """The rover the empirical terms act on: the believed scenario's rover file (its wheels, in the
    plant's frame: a backward drive's file is turned) or the mini rover."""
    sc = model.scenario
    rf = getattr(sc, "rover_file", None)
    return sc.rover if rf is None else rf


def _unit_scales(model: Any) -> tuple[float, float]:
    """Force and torque scales of the unit terms: 1 on the mini rover; on a rover file its weight
    (and weight x wheel radius) over the mini rover's
    (:func:`~offline.discrepancy.drive.wheel_set.rover_scales`), so a unit term moves a heavy
    rover's readings as much as the mini rover's (the sensitivities are linear in the term; its
    size keeps the re-simulation's change well above the plant solver's tolerance)."""
    from .wheel_set import rover_scales

    force, length = rover_scales(model.scenario)
    return force, force * length


class _Search:
    """The linearised family over one set of observations (module notes, steps 1-2)."""

    def __init__(self, obs: Any, model: Any, scale: dict[str, float], time_step: int = 2, n_position: int = 16,
                 n_state: int = 10) -> None:
        self.obs, self.model, self.scale = obs, model, scale
        rover = _rover_of(model)
        self.rover = rover
        self.wheels = names = wheel_names(rover)
        nd = len(obs.drives)
        chans = obs.channels
        self.values = len(obs) * len(chans)
        # step 1: the base re-simulation with a state logger and one per direction
        sims0 = model.simulations
        base, states, contrib = [], [], []
        # unit terms: the mini rover's sizes, forces and torques scaled by the rover's weight (x wheel radius)
        f, m = _unit_scales(model)
        unit = {"drag.body": 0.5 * f, **{f"drag.{w}": 0.3 * f for w in names}, **{f"torque.{w}": 0.02 * m for w in names},
                **{f"speed_loss.{w}": 0.1 for w in names}}
        for k in range(nd):
            d = obs.drives[k]
            log: list[Any] = []
            ticks0, body0, ok = model.simulate(d, None, obs.heading_offset, EmpiricalTerms((), rover, log))
            if not ok:
                raise ValueError(f"{d.source}: the believed model cannot re-simulate the drive with a state logger")
            base.append((ticks0, body0))
            tt = np.array([a for a, _ in log])
            order = np.argsort(tt, kind="stable")
            tt = tt[order]
            st = {}
            for name in _STATE:
                vals = np.array([np.asarray(getattr(s, name), float) for _, s in log])[order]
                if name == "slip_angle":
                    vals = np.abs(vals)
                st[name] = np.stack([np.interp(d.t, tt, vals[:, i]) for i in range(len(names))], axis=1) if tt.size else \
                    np.full((len(d.t), len(names)), np.nan)
            states.append(st)
            cd: dict[str, NDArray[np.float64]] = {}
            for direction, m0 in unit.items():
                ext_terms = EmpiricalTerms((EmpiricalTerm(direction, magnitude=m0, wheels=names),), rover)
                ticks1, body1, ok1 = model.simulate(d, None, obs.heading_offset, ext_terms)
                if not ok1:
                    cd[direction] = np.zeros((len(d.t), len(chans)))
                    continue
                dt_ = {ch: (ticks1[ch] - ticks0[ch]) / m0 for ch in chans if ch in ticks1}
                cd[direction] = _tick_contributions(obs, k, dt_, (body1 - body0) / m0, body0, scale)
            for ch in ("yaw_rate", "roll", "pitch"):
                if ch in chans:
                    cd[f"offset.{ch}"] = _tick_contributions(obs, k, {ch: np.ones(len(d.t))}, None, body0, scale)
            contrib.append(cd)
        self.sims = model.simulations - sims0
        self.states, self.contrib, self.base = states, contrib, base
        # per-tick localisation variables
        xy = _wheel_xy(rover)
        self.var: list[dict[str, NDArray[np.float64]]] = []
        for k in range(nd):
            d = obs.drives[k]
            X, Y, H = d.pose[:, 0], d.pose[:, 1], d.pose[:, 2]
            c, s = np.cos(H), np.sin(H)
            v = {"time": d.t, "x.body": X, "y.body": Y}
            for i, w in enumerate(names):
                v[f"x.{w}"] = X + c * xy[i, 0] - s * xy[i, 1]
                v[f"y.{w}"] = Y + s * xy[i, 0] + c * xy[i, 1]
                for name in _STATE:
                    v[f"{name}.{w}"] = states[k][name][:, i]
                cmd = np.concatenate([d.rim_cmd[:1, i], d.rim_cmd[:-1, i]])  # the command acting on each tick
                v[f"command.{w}"] = cmd
            self.var.append(v)
        self.has_pose = all(np.all(np.isfinite(d.pose[:, :2])) for d in obs.drives)
        self.time_step, self.n_position, self.n_state = time_step, n_position, n_state
        self.family = self._family()

    def variable(self, k: int, term: EmpiricalTerm, wheel: str) -> NDArray[np.float64]:
        """The localisation variable of ``term`` at each tick of drive ``k``, for ``wheel`` (or body)."""
        v = self.var[k]
        if term.where == "everywhere":
            return np.zeros(len(v["time"]))
        if term.where == "time":
            return v["time"]
        return v[f"{term.where}.{wheel}"]

    def response(self, terms: Sequence[EmpiricalTerm]) -> NDArray[np.float64]:
        """Normalised responses (columns x values, rows x channels row-major) of ``terms`` at magnitude 1."""
        nc = len(self.obs.channels)
        out = np.zeros((len(terms), len(self.obs), nc))
        groups: dict[tuple[str, str], list[int]] = {}
        for j, t in enumerate(terms):
            groups.setdefault((t.direction, t.where), []).append(j)
        for (direction, where), idx in groups.items():
            kind, target = direction.split(".", 1)
            parts = [direction] if target != "each" else [f"{kind}.{w}" for w in self.wheels]
            for k in range(len(self.obs.drives)):
                rows = np.flatnonzero(self.obs.drive == k)
                rows = rows[np.argsort(self.obs.segment[rows])]
                acc = None
                for part in parts:
                    wheel = part.split(".", 1)[1] if kind in ("drag", "torque", "speed_loss") else "body"
                    G = np.stack([terms[j].weight(self.variable(k, terms[j], wheel)) for j in idx])
                    C = self.contrib[k][part]
                    a = _aggregate(self.obs, k, G, C)
                    acc = a if acc is None else acc + a
                assert acc is not None
                out[np.ix_(np.asarray(idx, dtype=int), rows[:acc.shape[1]])] = acc[:, :rows.size]
        return out.reshape(len(terms), -1)

    def _family(self) -> _Family:
        obs = self.obs
        terms: list[EmpiricalTerm] = []
        dirs = list(self.contrib[0])
        t_all = np.concatenate([v["time"] for v in self.var])
        seg_t = np.unique(np.concatenate([d.t[s.bounds[:, 0]] for d, s in zip(obs.drives, obs.segments)]))
        tedges = np.append(seg_t[::self.time_step], np.nextafter(t_all.max(), np.inf))
        for direction in dirs + ["drag.each", "torque.each"]:
            terms.append(EmpiricalTerm(direction, wheels=self.wheels))
            terms += _box_terms(direction, "time", tedges, wheels=self.wheels) if direction not in ("drag.each", "torque.each") else []
            if direction not in ("drag.each", "torque.each"):
                terms += [EmpiricalTerm(direction, "time", "step", float(e), math.inf, 1.0, self.wheels) for e in tedges[1:-1]]
        if self.has_pose:
            for direction in ("drag.body", "drag.each"):
                for axis in ("x", "y"):
                    keys = [f"{axis}.body"] if direction == "drag.body" else [f"{axis}.{w}" for w in self.wheels]
                    vals = np.concatenate([v[key] for v in self.var for key in keys])
                    terms += _box_terms(direction, axis, _edges(vals, self.n_position), wheels=self.wheels)
        q = np.linspace(0.05, 0.95, self.n_state)
        for name in _STATE:
            for w in [*self.wheels, "each"]:
                ws = self.wheels if w == "each" else [w]
                vals = np.concatenate([v[f"{name}.{x}"] for v in self.var for x in ws])
                vals = vals[np.isfinite(vals)]
                if vals.size == 0:
                    continue
                for thr in np.unique(np.quantile(vals, q)):
                    for kind in ("drag", "torque"):
                        for shape in ("step", "hinge"):
                            terms.append(EmpiricalTerm(f"{kind}.{w}", name, shape, float(thr), math.inf, 1.0, self.wheels))
        for w in self.wheels:
            cm = np.unique(np.round(np.abs(np.concatenate([v[f"command.{w}"] for v in self.var])), 6))
            thr = np.unique(np.concatenate([[0.0], 0.5 * (cm[1:] + cm[:-1]), cm[cm > 0] * 0.999]))
            terms += [EmpiricalTerm(f"speed_loss.{w}", "command", "saturation", float(c), math.inf, 1.0, self.wheels) for c in thr
                      if c < cm.max()]
        A = self.response(terms)
        norm = np.einsum("ij,ij->i", A, A)
        keep = norm > 1e-12
        terms = [t for t, kk in zip(terms, keep) if kk]
        return _Family(terms, A[keep], np.array([t.n_params for t in terms], dtype=float))


def _nested(fam: _Family, R: NDArray[np.float64], fold_of_value: NDArray[np.int_], folds: int,
            penalty: float = 2.0) -> tuple[NDArray[np.float64], list[NDArray[np.int_]], list[NDArray[np.float64]]]:
    """Nested held-out improvement of the sparsity-selected column for each column of ``R``
    (values x draws): per fold, the best column on the other folds (LS magnitude, AIC-type score),
    scored on the fold. Returns ``(D per draw, chosen column per fold, magnitude per fold)``."""
    A = fam.A
    D = np.zeros(R.shape[1])
    tot_ar = A @ R
    tot_aa = np.einsum("ij,ij->i", A, A)
    picks, mags = [], []
    for f in range(folds):
        m = fold_of_value == f
        Af = A[:, m]
        ar_h = Af @ R[m]
        aa_h = np.einsum("ij,ij->i", Af, Af)
        ar_t = tot_ar - ar_h
        aa_t = np.maximum(tot_aa - aa_h, 1e-300)
        # a column (almost) absent from the training folds cannot be fitted there
        gain = np.where((aa_t > 1e-3 * tot_aa)[:, None], ar_t ** 2 / aa_t[:, None] - penalty * fam.k[:, None], -np.inf)
        j = np.argmax(gain, axis=0)
        cols = np.arange(R.shape[1])
        mag = ar_t[j, cols] / aa_t[j]
        D += 2.0 * mag * ar_h[j, cols] - mag ** 2 * aa_h[j]
        picks.append(j)
        mags.append(mag)
    return D, picks, mags


def _refine(search: _Search, term: EmpiricalTerm, r: NDArray[np.float64]) -> EmpiricalTerm:
    """The term with its edges / threshold moved on a finer grid around the grid's best (full data,
    in-sample LS) and its magnitude fitted."""
    cands = [term]
    if term.where == "time":
        t = np.unique(np.concatenate([v["time"] for v in search.var]))
        step = 2 * search.time_step * int(search.obs.segments[0].bounds[0, 1] - search.obs.segments[0].bounds[0, 0])
        def near(e: float) -> NDArray[np.float64]:
            i = int(np.searchsorted(t, e))
            return t[max(0, i - step):i + step + 1] if math.isfinite(e) else np.array([e])
        cands += [term.with_(lo=float(a), hi=float(b)) for a in near(term.lo) for b in near(term.hi) if b > a]
    elif term.where in ("x", "y") and term.shape == "box":
        w = term.hi - term.lo
        grid = np.linspace(-0.5, 0.5, 21) * w
        cands += [term.with_(lo=term.lo + a, hi=term.hi + b) for a in grid for b in grid if term.hi + b > term.lo + a]
    elif term.shape in ("step", "hinge", "saturation") and term.where != "time":
        span = abs(term.lo) if term.lo != 0 else 0.01
        cands += [term.with_(lo=max(0.0, term.lo + a * span)) for a in np.linspace(-0.5, 0.5, 21)]
    cands = [c.with_(magnitude=1.0) for c in cands]
    A = search.response(cands)
    aa = np.einsum("ij,ij->i", A, A)
    ok = aa > 1e-12
    ar = A @ r
    gain = np.where(ok, ar ** 2 / np.maximum(aa, 1e-300), -np.inf)
    j = int(np.argmax(gain))
    return cands[j].with_(magnitude=float(ar[j] / aa[j]))


def _fit_real(model: Any, obs: Any, scale: dict[str, float], done: Sequence[EmpiricalTerm], term: EmpiricalTerm,
              rows: NDArray[np.bool_] | None = None, lost: dict[str, float] | None = None) -> EmpiricalTerm:
    """One simulator correction of the term's magnitude: the response re-simulated at the linear
    fit replaces the linear column (a secant step), on ``rows`` (default all). ``lost``: what a
    lost (not simulated) row counts per channel, the engine's
    :func:`~offline.discrepancy.significance.fail_floor` of the model as given (default: computed
    here from the re-simulation without terms), so a step that loses the drive is never taken for
    one that fits it better."""
    if term.kind == "offset" or term.magnitude == 0.0:
        return term
    rover = _rover_of(model)
    if lost is None:
        lost = fail_floor(obs, model.predict(obs, None)[0], scale)
    p0, _ = model.predict(obs, None, EmpiricalTerms(tuple(done), rover) if done else None)
    p1, _ = model.predict(obs, None, EmpiricalTerms((*done, term), rover))
    z0, z1 = normalised(obs, p0, scale, lost), normalised(obs, p1, scale, lost)
    sel = np.ones(len(obs), bool) if rows is None else rows
    a = (z0 - z1)[sel].ravel() / term.magnitude
    r = z0[sel].ravel()
    aa = float(a @ a)
    if not (aa > 0) or not np.all(np.isfinite(a)):
        return term
    m = float(a @ r) / aa
    lim = 1.0 if term.kind == "speed_loss" else math.inf
    m = float(np.clip(m, -lim, lim))
    # the secant step is accepted only where it lowers the simulated chi-square
    p2, _ = model.predict(obs, None, EmpiricalTerms((*done, term.with_(magnitude=m)), rover))
    z2 = normalised(obs, p2, scale, lost)
    return term.with_(magnitude=m) if float((z2[sel] ** 2).sum()) < float((z1[sel] ** 2).sum()) else term


def interleaved_folds(obs: Any, k: int) -> NDArray[np.int_]:
    """Held-out folds of the empirical search: segment ``j`` of each drive in fold ``j mod k``.

    The engine's contiguous time blocks cannot validate an effect that happens once (a patch
    crossed in the first seconds lies in one block: fitted without it, nothing predicts it). With
    interleaved segments every localised effect longer than ``k`` segments is seen in training
    and predicted on held-out segments between. Adjacent segments share correlated noise; the
    null draws carry the drive's segment-to-segment correlation
    (:meth:`~offline.discrepancy.drive.diagnosis.DriveRecording.null_draw`) through the same folds, so
    the test keeps its level."""
    return (np.asarray(obs.segment) % k).astype(int)


def search_empirical(v: Any, alpha: float | None = None, n_boot: int | None = None, seed: int = 0, max_terms: int = 2,
                     time_step: int = 2, k_folds: int = 5, progress: Callable[[str], None] | None = None,
                     alpha_after: float | None = None) -> EmpiricalResult:
    """Model what the library lacks with the generic family (module notes).

    Parameters
    ----------
    v : Verdict
        The engine's drive verdict (:func:`~offline.discrepancy.drive.diagnosis.diagnose_drives`):
        its observations, model and dispersion are used; nothing of the truth.
    alpha : float, optional
        Level of each term's held-out test (default the observations' ``family_alpha``).
    n_boot : int, optional
        Null draws (default ``ceil(2 / alpha)``).
    seed : int
        Seed of the null draws.
    max_terms : int
        At most this many terms (each with its own test).
    time_step : int
        Time edges every this many segments.
    k_folds : int
        Held-out folds (the engine's contiguous time blocks).
    alpha_after : float, optional
        Level of the lack-of-fit check with the terms (default 0.01, the drive's after-level).
    progress : callable, optional

    Returns
    -------
    EmpiricalResult
    """
    from ..engine import _lack_of_fit

    t0 = time.perf_counter()
    say = progress or (lambda s: None)
    obs, model, scale = v.observations, v.model, v.scale
    alpha = float(getattr(obs, "family_alpha", 0.001) if alpha is None else alpha)
    alpha_after = 0.01 if alpha_after is None else alpha_after
    n_boot = int(math.ceil(2.0 / alpha)) if n_boot is None else int(n_boot)
    sims0 = model.simulations
    say("empirical terms: sensitivities")
    search = _Search(obs, model, scale, time_step=time_step)
    fam = search.family
    nc = len(obs.channels)
    folds = interleaved_folds(obs, k_folds)
    fold_of_value = np.repeat(folds, nc)
    rng = np.random.default_rng(seed + 24)
    rover = _rover_of(model)
    pred0, _ = model.predict(obs, None)
    # a lost row (a term whose re-simulation fails) counts the worst the model as given does on
    # the channel, as in the engine (significance.fail_floor), not a fixed FAIL_Z
    lost = fail_floor(obs, pred0, scale)
    z_base = normalised(obs, pred0, scale, lost)
    chi2_base = float((z_base ** 2).sum())
    accepted: list[EmpiricalTerm] = []
    fold_terms: list[list[EmpiricalTerm]] = [[] for _ in range(k_folds)]
    pvals, dlin = [], []
    r = z_base.ravel()
    for _ in range(max_terms):
        say(f"empirical terms: nested search over {len(fam.terms)} terms, null of {n_boot} draws")
        D_obs, picks, mags = _nested(fam, r[:, None], fold_of_value, k_folds)
        exceed = 0
        for b0 in range(0, n_boot, 250):
            nb = min(250, n_boot - b0)
            Rn = obs.null_draw(rng, len(obs) * nc, nb)
            Dn, _, _ = _nested(fam, Rn, fold_of_value, k_folds)
            exceed += int((Dn >= D_obs[0]).sum())
        p = (1 + exceed) / (n_boot + 1)
        pvals.append(p)
        dlin.append(float(D_obs[0]))
        say(f"empirical terms: nested held-out improvement {D_obs[0]:.1f}, p = {p:.3g}")
        if not (p < alpha and D_obs[0] > 0):
            break
        # the full-data term: sparsity-selected, refined, its magnitude corrected by the simulator
        ar = fam.A @ r
        aa = np.einsum("ij,ij->i", fam.A, fam.A)
        j = int(np.argmax(ar ** 2 / aa - 2.0 * fam.k))
        term = _refine(search, fam.terms[j], r)
        say(f"empirical terms: {term.law()}")
        term = _fit_real(model, obs, scale, accepted, term, lost=lost)
        # each fold's term (selected and fitted without the fold) for the simulator's held-out score
        for f in range(k_folds):
            tf = fam.terms[int(picks[f][0])].with_(magnitude=float(mags[f][0]))
            fold_terms[f].append(_fit_real(model, obs, scale, fold_terms[f][:len(accepted)], tf, rows=folds != f,
                                           lost=lost))
        accepted.append(term)
        pa, _ = model.predict(obs, None, EmpiricalTerms(tuple(accepted), rover))
        r = normalised(obs, pa, scale, lost).ravel()
    cv_after = chi2_base
    misfit: list[tuple[str, float, int, float]] = []
    if accepted:
        rows_cv = np.zeros(len(obs))
        for f in range(k_folds):
            pf, _ = model.predict(obs, None, EmpiricalTerms(tuple(fold_terms[f]), rover))
            zf = normalised(obs, pf, scale, lost)
            rows_cv[folds == f] = (zf[folds == f] ** 2).sum(axis=1)
        cv_after = float(rows_cv.sum())
        pa, _ = model.predict(obs, None, EmpiricalTerms(tuple(accepted), rover))
        misfit = _lack_of_fit(obs, pa, sum(t.n_params for t in accepted), alpha_after)
    excess = chi2_base - len(obs) * nc
    frac = float(min(1.0, (chi2_base - cv_after) / excess)) if excess > 0 else 0.0
    if not accepted:
        status = "none"
    elif frac >= 0.5 and not misfit:
        status = "explained"
    else:
        status = "partly_explained"
    return EmpiricalResult(status, accepted, pvals, dlin, chi2_base, cv_after, len(obs) * nc, frac, misfit,
                           fold_terms if accepted else [], model.simulations - sims0, time.perf_counter() - t0,
                           len(fam.terms), n_boot, alpha)


@dataclass(frozen=True)
class _Inputs:
    """What :func:`search_empirical` reads of a verdict (for :func:`search_drives`)."""

    observations: Any
    model: Any
    scale: dict[str, float]


def search_drives(paths: Sequence[Any], scenario: Any, segment: int = 5, alpha: float | None = None,
                  **kw: Any) -> EmpiricalResult:
    """The empirical search alone on recorded drives, without the library's diagnosis: the drives
    are segmented, their noise and dispersion estimated as
    :func:`~offline.discrepancy.drive.diagnosis.diagnose_drives` does, and :func:`search_empirical`
    runs on the believed model's residuals (``kw`` passed on).

    Parameters
    ----------
    paths : sequence of path
        MCAP recordings or folders of them.
    scenario : Scenario
        The believed rover, parameter set and declared failures (flat nominal world).
    segment : int
        Ticks per row.
    alpha : float, optional
        Level (default :data:`~offline.discrepancy.drive.diagnosis.DRIVE_ALPHA`).
    **kw
        Passed to :func:`search_empirical` (``seed``, ``n_boot``, ``max_terms``, ...).
    """
    from dataclasses import replace as _replace

    from .diagnosis import DRIVE_ALPHA, DriveModel, DriveRecording, load_drives

    model = DriveModel(scenario)
    a = DRIVE_ALPHA if alpha is None else float(alpha)
    obs = _replace(DriveRecording.build(load_drives(paths), model, segment), family_alpha=a)
    pred, _ = model.predict(obs, None)
    return search_empirical(_Inputs(obs, model, obs.dispersion(pred)), alpha=a, **kw)
