"""Declared failures as data: the rover's reader of the failure descriptions in table headers.

rtctl has no list of failure kinds of its own. Every table header written by the table builder
carries, as data written by the optimizer's own failure-kind objects
(:meth:`offline.rover.failures.FailureKind.rover_description`):

* ``failure_kinds``: every kind the builder knew, by the name the rover declares it with
  (:class:`rtctl.messages.FailureDeclaration.kind`): its declared value (name, unit, plausible
  range, whether NaN is allowed), its *rules* (what it constrains), whether the wheel still
  serves the odometry, and the factor its value takes on the mirror-image wheel;
* ``failures``: the table's own failures (wheel, kind, value), i.e. what the table was built
  for (its signature; a record marked ``with_task`` is a constraint of the task, not a declared
  failure), and ``task`` (a task's kind and wheel, and the task kind as data in its
  ``description``: value name, unit, range, odometry; :func:`read_task_kinds`).

A rule is one constraint in this small vocabulary, which is all the rover interprets:

==============  ==========================================================================
``on``          ``omega`` (rad/s), ``beta`` (rad), ``W`` (N), ``h``, ``h0`` (m): the wheel's
                variables; ``rim_speed`` (m/s): omega times the command radius; ``torque``
                (N m): the wheel-torque row; ``contact`` (1 / 0) and ``pivot_locked`` (0 / 1):
                parameters of the steady-state model
``fix``         both bounds set to the expression (overrides what was there)
``lo``, ``hi``  a bound tightened to the expression (the intersection)
``free``        both bounds removed
expression      ``{"const": c, "value": a, "speed": b, "value_speed": d}`` meaning
                ``c + a v + b V + d v V`` (v the declared value, V the travel speed; missing
                keys are 0), or ``{"bound": "lo"}``: the target's own lower bound
``frame``       ``"encoder"``: on ``beta``, the expression is an encoder angle (the wheel's
                steering offset is added)
``prefer_measured``  on ``beta``: a measured steering angle replaces the expression
==============  ==========================================================================

:func:`apply_rules` imposes a kind's rules on one wheel's bounds. The optimizer's ``apply`` and
these rules are checked against each other for every kind (``tests/test_failure_descriptions.py``).
A header whose description breaks the vocabulary raises :class:`FailureDescriptionError` (the
controller then treats that table as unavailable, flagged).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any, Mapping

__all__ = ["FailureDescriptionError", "Rule", "KindSpec", "TableFailures", "VARIABLES", "TARGETS", "read_kinds",
           "read_table_failures", "apply_rules", "rule_text", "KIND_NAME"]

VARIABLES: tuple[str, ...] = ("omega", "beta", "W", "h", "h0")
"""Wheel variables a rule may constrain (the layout's per-wheel variables)."""
TARGETS: tuple[str, ...] = (*VARIABLES, "rim_speed", "torque", "contact", "pivot_locked")
"""Every target of a rule."""
KIND_NAME = re.compile(r"^[a-z][a-z0-9_]{0,47}$")
"""What a failure kind's name looks like (checked at the input boundary, :mod:`rtctl.inputs`)."""
_EXPR_KEYS = ("const", "value", "speed", "value_speed")


class FailureDescriptionError(ValueError):
    """A table header's failure description that breaks the vocabulary (the message names it)."""


@dataclass(frozen=True)
class Expr:
    """``const + value v + speed V + value_speed v V``, or the target's own lower bound."""

    const: float = 0.0
    value: float = 0.0
    speed: float = 0.0
    value_speed: float = 0.0
    own_lower: bool = False

    @property
    def uses_value(self) -> bool:
        """Whether the declared value enters."""
        return self.value != 0.0 or self.value_speed != 0.0

    def __call__(self, v: float, speed: float, lower: float) -> float:
        if self.own_lower:
            return lower
        out = self.const + self.speed * speed
        if self.uses_value:
            out += self.value * v + self.value_speed * v * speed
        return out

    def text(self) -> str:
        if self.own_lower:
            return "its lower bound"
        terms: list[str] = []
        for c, name in ((self.const, ""), (self.value, "v"), (self.speed, "V"), (self.value_speed, "v V")):
            if c != 0.0 or (not name and not terms and self.value == self.speed == self.value_speed == 0.0):
                terms.append(f"{c:g}" if not name else (name if c == 1.0 else ("-" + name if c == -1.0 else f"{c:g} {name}")))
        return " + ".join(terms).replace("+ -", "- ") or "0"


@dataclass(frozen=True)
class Rule:
    """One constraint of a failure kind (module docstring)."""

    on: str
    fix: Expr | None = None
    lo: Expr | None = None
    hi: Expr | None = None
    free: bool = False
    encoder: bool = False
    prefer_measured: bool = False

    @property
    def uses_value(self) -> bool:
        """Whether the declared value enters the rule."""
        return any(e is not None and e.uses_value for e in (self.fix, self.lo, self.hi))

    @property
    def fixes(self) -> bool:
        """Whether the rule fixes its target."""
        return self.fix is not None


@dataclass(frozen=True)
class KindSpec:
    """One failure kind as the rover knows it from a table header."""

    kind: str
    text: str
    value_name: str | None
    value_unit: str
    value_lo: float
    value_hi: float
    value_required: bool
    rules: tuple[Rule, ...]
    odometry: bool
    mirror_value: float | None
    source: str = ""

    def same_physics(self, other: "KindSpec") -> bool:
        """Whether two descriptions say the same (the text and source may differ)."""
        keys = ("value_name", "value_unit", "value_lo", "value_hi", "value_required", "rules", "odometry", "mirror_value")
        return all(getattr(self, k) == getattr(other, k) for k in keys)

    def check_value(self, v: float) -> str:
        """Why a declared value is not acceptable ("" when it is)."""
        if self.value_name is None:
            return ""
        if math.isnan(v):
            return "" if not self.value_required else f"{self.kind} needs its {self.value_name} ({self.value_unit})"
        if not self.value_lo <= v <= self.value_hi:
            return (f"{self.kind} {self.value_name} {v:.6g} {self.value_unit} outside "
                    f"[{self.value_lo:.6g}, {self.value_hi:.6g}]")
        return ""


@dataclass(frozen=True)
class TableFailures:
    """What a table was built for: its failures ``{(wheel, kind): value}`` and task."""

    failures: tuple[tuple[str, str, float], ...]
    task: tuple[str, str] | None

    def signature(self) -> frozenset[tuple[str, str]]:
        """``{(wheel, kind), ...}`` plus ``(wheel, task kind)``."""
        out = {(w, k) for w, k, _ in self.failures}
        if self.task is not None:
            out.add((self.task[1], self.task[0]))
        return frozenset(out)


def _num(d: Mapping[str, Any], key: str, where: str, default: float | None = None) -> float:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(float(v)):
        raise FailureDescriptionError(f"{where}: {key} must be a number, got {v!r}")
    return float(v)


def _expr(e: Any, where: str) -> Expr:
    if not isinstance(e, Mapping):
        raise FailureDescriptionError(f"{where}: an expression must be a mapping, got {e!r}")
    if "bound" in e:
        if e.get("bound") != "lo" or len(e) != 1:
            raise FailureDescriptionError(f"{where}: {{'bound': 'lo'}} is the only bound expression, got {dict(e)!r}")
        return Expr(own_lower=True)
    bad = set(e) - set(_EXPR_KEYS)
    if bad:
        raise FailureDescriptionError(f"{where}: unknown expression terms {sorted(bad)} (known: {list(_EXPR_KEYS)})")
    c, a, b, d = (_num(e, k, where, 0.0) for k in _EXPR_KEYS)
    if not all(math.isfinite(v) for v in (c, a, b, d)):
        raise FailureDescriptionError(f"{where}: expression terms must be finite, got {dict(e)!r}")
    return Expr(const=c, value=a, speed=b, value_speed=d)


def _rule(r: Any, where: str) -> Rule:
    if not isinstance(r, Mapping):
        raise FailureDescriptionError(f"{where}: a rule must be a mapping, got {r!r}")
    on = r.get("on")
    if on not in TARGETS:
        raise FailureDescriptionError(f"{where}: rule target {on!r} is not in the rover's vocabulary {list(TARGETS)}")
    bad = set(r) - {"on", "fix", "lo", "hi", "free", "frame", "prefer_measured"}
    if bad:
        raise FailureDescriptionError(f"{where}: unknown rule keys {sorted(bad)}")
    ops = [k for k in ("fix", "lo", "hi") if k in r] + (["free"] if r.get("free") else [])
    if not ops or ("fix" in ops and len(ops) > 1) or ("free" in ops and len(ops) > 1):
        raise FailureDescriptionError(f"{where}: a rule has 'fix', or 'lo' and/or 'hi', or 'free'; got {sorted(r)}")
    frame = r.get("frame", "physical")
    if frame not in ("physical", "encoder") or (frame == "encoder" and on != "beta"):
        raise FailureDescriptionError(f"{where}: frame {frame!r} (only 'encoder', on beta)")
    pm = r.get("prefer_measured", False)
    if not isinstance(pm, bool) or (pm and on != "beta"):
        raise FailureDescriptionError(f"{where}: prefer_measured is a bool, on beta only")
    return Rule(on=str(on), fix=_expr(r["fix"], where) if "fix" in r else None,
                lo=_expr(r["lo"], where) if "lo" in r else None, hi=_expr(r["hi"], where) if "hi" in r else None,
                free=bool(r.get("free", False)), encoder=frame == "encoder", prefer_measured=pm)


def _kind(name: str, d: Any, source: str) -> KindSpec:
    where = f"{source}: failure_kinds.{name}"
    if not (isinstance(name, str) and KIND_NAME.match(name)):
        raise FailureDescriptionError(f"{where}: a kind's name is lower case letters, digits and _")
    if not isinstance(d, Mapping):
        raise FailureDescriptionError(f"{where}: expected a mapping")
    val = d.get("value")
    if val is not None and not isinstance(val, Mapping):
        raise FailureDescriptionError(f"{where}: value must be a mapping or null")
    rules = d.get("rules")
    if not isinstance(rules, list):
        raise FailureDescriptionError(f"{where}: rules must be a list")
    parsed = tuple(_rule(r, f"{where}.rules[{i}]") for i, r in enumerate(rules))
    if val is None and any(r.uses_value for r in parsed):
        raise FailureDescriptionError(f"{where}: a rule uses the declared value but the kind takes none")
    odo = d.get("odometry", True)
    mv = d.get("mirror_value")
    if not isinstance(odo, bool) or not (mv is None or (isinstance(mv, (int, float)) and not isinstance(mv, bool)
                                                         and math.isfinite(mv))):
        raise FailureDescriptionError(f"{where}: odometry must be a bool and mirror_value a number or null")
    if val is None:
        return KindSpec(name, str(d.get("text", "")), None, "", -math.inf, math.inf, False, parsed, odo, None, source)
    lo, hi = _num(val, "lo", where), _num(val, "hi", where)
    if lo > hi:
        raise FailureDescriptionError(f"{where}: value range lo > hi")
    return KindSpec(name, str(d.get("text", "")), str(val.get("name", "value")), str(val.get("unit", "")), lo, hi,
                    bool(val.get("required", True)), parsed, odo, float(mv) if mv is not None else None, source)


def read_kinds(header: Mapping[str, Any], source: str = "table") -> dict[str, KindSpec]:
    """The failure kinds a table header describes (empty for a header without ``failure_kinds``).

    Raises
    ------
    FailureDescriptionError
        A description outside the vocabulary (module docstring), naming the kind and key.
    """
    fk = header.get("failure_kinds")
    if fk is None:
        return {}
    if not isinstance(fk, Mapping):
        raise FailureDescriptionError(f"{source}: failure_kinds must be a mapping")
    return {name: _kind(name, d, source) for name, d in sorted(fk.items())}


def read_task_kinds(header: Mapping[str, Any], source: str = "table") -> dict[str, KindSpec]:
    """The task kind a table header describes (its ``task`` entry's ``description``, written by
    the task's own class offline, e.g. ``offline.rover.failures.TrenchGoal``): ``{kind: spec}``
    with the value's name, unit and range and whether the task's wheel still serves the
    odometry; empty for a table without a task (or a task without a description).

    Raises
    ------
    FailureDescriptionError
        A description outside the vocabulary, or a task kind with rules (a task is served by its
        own table, never imposed on another).
    """
    task = header.get("task")
    if not isinstance(task, Mapping) or task.get("description") is None:
        return {}
    name = str(task.get("kind"))
    spec = _kind(name, task.get("description"), f"{source}: task")
    if spec.rules:
        raise FailureDescriptionError(f"{source}: task {name!r}: a task kind has no rules")
    return {str(name): spec}


def read_table_failures(header: Mapping[str, Any], wheels: tuple[str, ...], source: str = "table") -> TableFailures | None:
    """The failures and task a table was built for, from its header's ``failures`` and ``task``;
    None for a header without them that has failures or a task in its scenario (built before the
    descriptions: ``offnominal tables describe`` adds them). A header with neither is nominal.

    Raises
    ------
    FailureDescriptionError
        Malformed records.
    """
    fl = header.get("failures")
    task = header.get("task")
    if fl is None:
        sc = header.get("scenario") or {}
        fails = sc.get("failures") if isinstance(sc, Mapping) else None
        has = bool(fails) if isinstance(fails, Mapping) else False
        has = has or (isinstance(sc, Mapping) and isinstance(sc.get("trench"), Mapping))
        return None if has else TableFailures((), None)
    if not isinstance(fl, list):
        raise FailureDescriptionError(f"{source}: failures must be a list")
    out = []
    for i, r in enumerate(fl):
        if not (isinstance(r, Mapping) and r.get("wheel") in wheels and isinstance(r.get("kind"), str)
                and KIND_NAME.match(r["kind"])):
            raise FailureDescriptionError(f"{source}: failures[{i}] must name a wheel of {list(wheels)} and a kind")
        if r.get("with_task") is True:  # a constraint of the task (e.g. a trenching wheel's steer range)
            continue
        v = r.get("value")
        v = float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan
        out.append((str(r["wheel"]), str(r["kind"]), v))
    tk = None
    if task is not None:
        if not (isinstance(task, Mapping) and task.get("wheel") in wheels and isinstance(task.get("kind"), str)):
            raise FailureDescriptionError(f"{source}: task must name a kind and a wheel of {list(wheels)}")
        if task.get("description") is None:  # built before task kinds were data: undescribed
            return None
        tk = (str(task["kind"]), str(task["wheel"]))
    return TableFailures(tuple(sorted(out)), tk)


def apply_rules(spec: KindSpec, value: float, speed: float, rim_radius: float, lo: dict[str, float],
                hi: dict[str, float], offset: float = 0.0, measured_beta: float = math.nan) -> set[str]:
    """Impose a kind's rules on one wheel's physical bounds, in place.

    Parameters
    ----------
    spec, value
        The kind and its declared value (NaN: none; a rule that needs it is then skipped, and
        ``prefer_measured`` rules use ``measured_beta``).
    speed, rim_radius
        Travel speed (m/s) and the command radius (m): ``rim_speed = omega x rim_radius``.
    lo, hi
        Bounds by target: the wheel variables, ``torque`` (the wheel-torque row), ``contact`` and
        ``pivot_locked`` (parameters: ``fix`` sets both), ``rim_speed`` is read and written as
        ``omega``. Missing targets are unbounded.
    offset
        The wheel's steering offset (true minus encoder angle, rad), added to ``encoder`` rules.
    measured_beta
        The measured (physical) steering angle, used by ``prefer_measured`` rules when finite.

    Returns
    -------
    set of str
        The targets the rules fixed (both bounds equal).
    """
    fixed: set[str] = set()
    for r in spec.rules:
        tgt = "omega" if r.on == "rim_speed" else r.on
        k = 1.0 / rim_radius if r.on == "rim_speed" else 1.0
        cur_lo, cur_hi = lo.get(tgt, -math.inf), hi.get(tgt, math.inf)
        if r.free:
            lo[tgt], hi[tgt] = -math.inf, math.inf
            continue
        if r.uses_value and math.isnan(value) and not (r.prefer_measured and math.isfinite(measured_beta)):
            continue
        off = offset if r.encoder else 0.0
        if r.fix is not None:
            if r.prefer_measured and math.isfinite(measured_beta):
                v = measured_beta
            else:
                v = k * (r.fix(value, speed, cur_lo) + off)
            lo[tgt] = hi[tgt] = v
            fixed.add(tgt)
            continue
        if r.lo is not None:
            lo[tgt] = max(cur_lo, k * (r.lo(value, speed, cur_lo) + off))
        if r.hi is not None:
            hi[tgt] = min(cur_hi, k * (r.hi(value, speed, cur_lo) + off))
    return fixed


def rule_text(spec: KindSpec) -> str:
    """The rules in words, for the flags (``beta fixed at the measured angle, else v``)."""
    parts = []
    for r in spec.rules:
        if r.free:
            parts.append(f"{r.on} unbounded")
        elif r.fix is not None:
            parts.append(f"{r.on} fixed at " + ("the measured angle, else " if r.prefer_measured else "")
                         + r.fix.text() + (" (encoder)" if r.encoder else ""))
        else:
            b = []
            if r.lo is not None:
                b.append(f">= {r.lo.text()}")
            if r.hi is not None:
                b.append(f"<= {r.hi.text()}")
            parts.append(f"{r.on} " + " and ".join(b) + (" (encoder)" if r.encoder else ""))
    unit = f" {spec.value_unit}" if spec.value_unit else ""
    v = f" (v = its {spec.value_name}{',' + unit if unit else ''}; V = travel speed)" if spec.value_name else ""
    return "; ".join(parts) + v
