"""Continuation schedule of a table build: easiest points first, then along the grid's axes.

The former schedule (:func:`offline.rover.table_builder.chains`) solved chains along the slope
axis, each from the optimizer's automatic start (the nominal search, a continuation of the
failures from the nominal primitive, symmetric guesses, a mirror-image search, restarts and a
confirmation search), and every speed on its own. Measured on README's worked example (front-left
steering stuck, 252 points; ``tests/bench/results_new_failure.md``) most of that search was
spent where a better start or a cheaper verdict was available:

* the nominal primitive at the same operating point is already in a shipped table (a *seed*
  table, :func:`seed_tables`): the failure only adds constraints (a stuck angle fixes one
  variable), so a start from it with the failure imposed is one IPOPT run from the answer;
* the failure's own axis is a homotopy: the point nearest the seed (smallest violation of its
  bounds and rows at the seed start) is solved first, and its neighbours along the axis from it;
* (7.25) scales exactly with the travel speed (the speed twins' rule,
  :func:`~offline.rover.table_builder.twin_resolve`), so only the first speed is searched; the
  others are that solution scaled and verified by one warm IPOPT run and the independent check;
* where the seed table has no primitive at a (slope, cross slope), the relaxation of the
  scenario (the same point without the failures, :func:`~offline.rover.table_builder.relaxation_of`)
  is decided first with the optimizer's default budgets; if it is confirmed infeasible, so is
  every point of that (slope, cross slope) it covers, at every speed and failure value, and no
  search is spent there.

What is left (points none of this solved nor decided) goes to the builder's neighbour retries
and then to the full search (:func:`search_group`), one task per operating point of the other
axes, the first speed searched and the verdict carried to the other speeds by the twin rule.

Everything is deterministic: the order within a task is fixed by the grid and the seed, budgets
count iterations and attempts, and a phase uses only the results of the phases before it.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["SeedStart", "seed_tables", "seed_start", "family_seed_tables", "point_seed", "failure_tables", "former_table",
           "table_start", "group_points", "continuation_group", "search_group",
           "RELAXED_EVIDENCE", "TWIN_EVIDENCE", "hole_reason"]

RELAXED_EVIDENCE = ("the same operating point without the failures (a relaxation: the failures only add "
                    "constraints) is confirmed infeasible by the optimizer with its default budgets")
"""Evidence text of a point made ``infeasible`` by its relaxation's verdict."""

TWIN_EVIDENCE = ("the same NLP up to the exact speed scaling of (7.25) (speed twins) is confirmed infeasible at "
                 "another speed")
"""Evidence text of a point made ``infeasible`` by its speed twin's confirmed verdict."""


@dataclass(frozen=True)
class SeedStart:
    """A warm start (scaled variables) for one operating point, from a seed table.

    Attributes
    ----------
    x_scaled : ndarray
        The seed table's primitive at the same slope and cross slope, its wheel speeds scaled to
        this speed (exact speed scaling of (7.25)), divided by the layout's variable scales.
    source : str
        ``"<table name>@<content hash[:12]>"``.
    """

    x_scaled: NDArray[np.float64]
    source: str


def _normalised(sc: Any) -> str:
    """JSON of the scenario with the operating point, failures, trench and names removed: two
    scenarios with equal normalised forms have the same NLP (params, rover, world terms)."""
    from .table_builder import encode

    base = replace(sc, failures={}, trench=None, slope=0.0, cross_slope=0.0, speed=1.0, fy_offset=0.0, mz_offset=0.0,
                   name="", description="", source="")
    return json.dumps(encode(base), sort_keys=True)


@functools.lru_cache(maxsize=8)
def _load(path: str) -> Any:
    from rtctl.table import load_table

    return load_table(path)


def seed_tables(spec: Any, index: str | Path | None) -> tuple[str, ...]:
    """Paths of the tables in ``index`` that can seed ``spec``: tables without a failure and
    without a family axis, built for the same NLP (same parameters, rover and world terms,
    :func:`_normalised`, and the same layout), sorted by name; a table of ``spec``'s own name is
    never a seed (a rebuild must not depend on the file it replaces).

    ``index``: an ``index.json`` (or None: no seeds). A table that cannot be loaded is skipped.
    """
    from rtctl.table import TableError, load_index

    from .table_builder import _problem, scenario_from_header

    if index is None or not Path(index).is_file():
        return ()
    try:
        infos = load_index(index)
    except TableError:
        return ()
    want = _normalised(spec.scenario)
    lay = json.loads(_problem(spec.scenario, spec.solver).layout.to_json())
    out = []
    for name in sorted(infos):
        info = infos[name]
        if info.entry.get("family") is not None or name == spec.name:  # never seeded by its own former build
            continue
        try:
            t = _load(str(info.path))
            sc = scenario_from_header(t.header)
        except (TableError, OSError, ValueError, TypeError, KeyError):
            continue
        if sc.failures or sc.trench is not None or _normalised(sc) != want or t.header.get("layout") != lay:
            continue
        out.append(str(info.path))
    return tuple(out)


@functools.lru_cache(maxsize=8)
def _load_mirrored(path: str) -> Any:
    from rtctl.mirror import mirror_table

    return mirror_table(_load(path))


def _family_key(sc: Any, family: Mapping[str, Any]) -> str:
    """:func:`_normalised` with the failures kept, the family's own value set to 0 (same NLP and
    the same failures but for the value the table's axis varies)."""
    from .table_builder import encode, scenario_at

    base = scenario_at(sc, family, {family["axis"]: 0.0})
    base = replace(base, trench=None, slope=0.0, cross_slope=0.0, speed=1.0, fy_offset=0.0, mz_offset=0.0,
                   name="", description="", source="")
    return json.dumps(encode(base), sort_keys=True)


def family_seed_tables(spec: Any, index: str | Path | None) -> tuple[tuple[str, bool], ...]:
    """Tables in ``index`` of the same failure family as ``spec`` -- directly, or through the
    left-right mirror (:func:`rtctl.mirror.mirror_table`: a front-right stuck-steering table
    serves the front-left one) -- built for the same NLP, as ``(path, mirrored)`` sorted by name
    (direct before mirrored). Their primitives at the same slope, cross slope and failure value
    are exact starts (a mirrored optimum is the optimum of the mirrored scenario). A trench
    table is never mirrored; a table of ``spec``'s own name is never a seed."""
    from rtctl.mirror import MirrorError
    from rtctl.table import TableError, load_index

    from .table_builder import _problem, scenario_from_header

    if spec.family is None or spec.family["axis"] == "trench_depth" or index is None or not Path(index).is_file():
        return ()
    try:
        infos = load_index(index)
    except TableError:
        return ()
    want = _family_key(spec.scenario, spec.family)
    lay = json.loads(_problem(spec.scenario, spec.solver).layout.to_json())
    out = []
    for mirrored in (False, True):
        for name in sorted(infos):
            info = infos[name]
            fam = info.entry.get("family")
            if not isinstance(fam, dict) or fam.get("axis") != spec.family["axis"] or name == spec.name:
                continue
            try:
                t = _load_mirrored(str(info.path)) if mirrored else _load(str(info.path))
                sc = scenario_from_header(t.header)
                hf = t.header.get("family")
            except (TableError, MirrorError, OSError, ValueError, TypeError, KeyError):
                continue
            if (_family_core(hf) != _family_core(spec.family) or t.header.get("layout") != lay
                    or _family_key(sc, hf) != want):
                continue
            out.append((str(info.path), mirrored))
    return tuple(out)


def point_seed(spec: Any, seeds: Sequence[tuple[str, bool]], op: Mapping[str, float]) -> SeedStart | None:
    """The first family seed table's primitive (:func:`family_seed_tables`) at ``op``'s slope,
    cross slope and failure value (exact grid values, within 1e-9), from its lowest speed with
    a primitive, scaled to ``op``'s speed; None when none has one there."""
    for path, mirrored in seeds:
        t = _load_mirrored(path) if mirrored else _load(path)
        s = _exact(spec, t, op, ("slope", "cross_slope", spec.family["axis"]))
        if s is not None:
            return SeedStart(s.x_scaled, ("mirror of " if mirrored else "") + s.source)
    return None


def _exact(spec: Any, t: Any, op: Mapping[str, float], keys: Sequence[str]) -> SeedStart | None:
    """``t``'s primitive at ``op``'s values of ``keys`` (every other axis searched, lowest index
    first), wheel speeds scaled to ``op``'s speed (exact speed scaling of (7.25))."""
    from .table_builder import _problem

    lay = _problem(spec.scenario, spec.solver).layout
    om = [lay.var("omega", w) for w in lay.wheels]
    sc0 = spec.scenario
    want = {k: float(op[k]) if k in op else float(getattr(sc0, k)) for k in keys}
    sel: list[list[int]] = []
    for k in t.axis_order:
        ax = np.asarray(t.axes[k], dtype=float)
        if k in want:
            hit = np.flatnonzero(np.abs(ax - want[k]) <= 1e-9)
            if not hit.size:
                return None
            sel.append([int(hit[0])])
        else:
            sel.append(list(range(len(ax))))
    for idx in (tuple(int(i) for i in c) for c in np.array(np.meshgrid(*sel, indexing="ij")).reshape(len(sel), -1).T):
        if t.status_at(idx) != "optimal":
            continue
        x = np.array(t.arrays["x"][idx], dtype=float)
        v_seed = t.grid_point(idx).get("speed", float(t.header["scenario"]["speed"]))
        x[om] *= float(op.get("speed", sc0.speed)) / v_seed
        return SeedStart(x / lay.variable_scale, f"{t.name}@{t.header['content_hash'][:12]}")
    return None


def seed_start(spec: Any, seeds: Sequence[str], op: Mapping[str, float]) -> SeedStart | None:
    """The first seed table's primitive at ``op``'s slope and cross slope (exact grid values,
    within 1e-9 rad), from its lowest speed with a primitive, scaled to ``op``'s speed: omega of
    every wheel times the speed ratio, everything else unchanged (exact speed scaling of
    (7.25)); None when no seed has a primitive there."""
    for path in seeds:
        s = _exact(spec, _load(path), op, ("slope", "cross_slope"))
        if s is not None:
            return s
    return None


def _family_core(family: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """A family record without the description ``offnominal tables describe`` adds (``declares``):
    the shipped headers carry it, a spec's family does not."""
    return None if family is None else {k: v for k, v in family.items() if k != "declares"}


def _failure_key(sc: Any, family: Mapping[str, Any] | None) -> str:
    """JSON of what makes two tables' failures the same: the failures (kinds and values, the
    family's own value set to 0: the table's axis varies it), the trench goal, the rover (and rover
    file) and the family; parameters, world terms and the operating point are left out (a sibling
    soil, e.g. ``rr_trench_clean`` for ``rr_trench_clean_mu01``, has the same failures)."""
    from .table_builder import encode, scenario_at

    base = scenario_at(sc, family, {family["axis"]: 0.0}) if family is not None else sc
    return json.dumps(encode({"failures": dict(base.failures), "trench": base.trench, "rover": base.rover,
                              "rover_file": base.rover_file, "family": _family_core(family)}), sort_keys=True)


def failure_tables(spec: Any, index: str | Path | None) -> tuple[str, ...]:
    """Paths of the tables in ``index`` with ``spec``'s failures (:func:`_failure_key`: the same
    failure kinds and values, trench goal, rover and family axis) and layout; their parameters
    may differ. A table of ``spec``'s own name (the former build) comes first, the others by name.

    Their primitives at a point's very slope, cross slope and failure value (:func:`table_start`)
    are the starts with which the builder re-checks a search's verdict there
    (:func:`~offline.rover.table_builder._recheck_from_tables`).

    Unlike :func:`seed_tables` and :func:`family_seed_tables` this admits the former build of the
    table itself. The rule "a rebuild must not depend on the file it replaces" keeps a rebuild's
    *answers* from resting on the old file; a start does not: it only adds a candidate, and the
    candidate is kept only if IPOPT converges from it on today's NLP and the result passes the
    optimizer's independent check, i.e. it is an optimum of today's problem whatever produced the
    start. What the rebuild does depend on is the set of points where it finds a primitive (a
    search's "infeasible" is not a proof): issue 22/23's from-scratch rr_steer_stuck called (0 deg,
    +45 deg stuck) infeasible at both speeds, while the shipped primitive there passes today's
    check and a warm run converges from it in 6-7 iterations. Refusing the former file would
    throw that evidence away; using it, the dependency is recorded (the header's continuation
    record names the table and its content hash, the point's ``continued_from`` says so), and
    ``--seed-index none`` still builds from scratch.

    ``index``: an ``index.json`` (or None: none). A table that cannot be loaded is skipped.
    """
    from rtctl.table import TableError, load_index

    from .table_builder import _problem, scenario_from_header

    if index is None or not Path(index).is_file():
        return ()
    try:
        infos = load_index(index)
    except TableError:
        return ()
    want = _failure_key(spec.scenario, spec.family)
    lay = json.loads(_problem(spec.scenario, spec.solver).layout.to_json())
    out = []
    for name in sorted(infos, key=lambda n: (n != spec.name, n)):
        info = infos[name]
        try:
            t = _load(str(info.path))
            sc = scenario_from_header(t.header)
            key = _failure_key(sc, t.header.get("family"))
        except (TableError, OSError, ValueError, TypeError, KeyError):
            continue
        if key == want and t.header.get("layout") == lay:
            out.append(str(info.path))
    return tuple(out)


def former_table(spec: Any, index: str | Path | None) -> str | None:
    """The path of the table of ``spec``'s own name in ``index`` (the file a rebuild replaces) if it
    poses the same NLP (same parameters, rover, world terms, failures, family and layout); else
    None. Its optimum at each point is a candidate of the builder's neighbour pass
    (:func:`~offline.rover.table_builder._polish`), taken only if strictly better and verified."""
    from .table_builder import scenario_from_header

    for path in failure_tables(spec, index):
        t = _load(path)
        if t.name != spec.name:
            continue
        try:
            sc = scenario_from_header(t.header)
        except (ValueError, TypeError, KeyError):
            return None
        same = (_normalised(sc) == _normalised(spec.scenario)
                and _family_core(t.header.get("family")) == _family_core(spec.family))
        return path if same else None
    return None


def table_start(spec: Any, path: str, op: Mapping[str, float]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], str] | None:
    """The table at ``path``'s primal-dual point at ``op``'s slope, cross slope and failure value
    (exact grid values, within 1e-9; its lowest speed with a primitive) scaled exactly to ``op``'s
    speed, in the layout's scaled variables: ``(x, lam_x, lam_g, "<name>@<hash[:12]>")``, or None
    when the table has no primitive there. Omega and its bound multipliers move by the speed ratio
    (:func:`~offline.rover.table_builder.twin_resolve`)."""
    from .table_builder import _problem

    t = _load(path)
    lay = _problem(spec.scenario, spec.solver).layout
    om = [lay.var("omega", w) for w in lay.wheels]
    keys = ("slope", "cross_slope") + ((spec.family["axis"],) if spec.family is not None else ())
    want = {k: float(op[k]) if k in op else float(getattr(spec.scenario, k)) for k in keys}
    sel: list[list[int]] = []
    for k in t.axis_order:
        ax = np.asarray(t.axes[k], dtype=float)
        if k in want:
            hit = np.flatnonzero(np.abs(ax - want[k]) <= 1e-9)
            if not hit.size:
                return None
            sel.append([int(hit[0])])
        else:
            sel.append(list(range(len(ax))))
    for idx in (tuple(int(i) for i in c) for c in np.array(np.meshgrid(*sel, indexing="ij")).reshape(len(sel), -1).T):
        if t.status_at(idx) != "optimal":
            continue
        ratio = float(op.get("speed", spec.scenario.speed)) / t.grid_point(idx).get("speed", float(t.header["scenario"]["speed"]))
        x = np.array(t.arrays["x"][idx], dtype=float)
        x[om] *= ratio
        lam_x = np.array(t.arrays["lam_x"][idx], dtype=float) * lay.variable_scale
        lam_x[om] /= ratio
        lam_g = np.array(t.arrays["lam_g"][idx], dtype=float) * lay.constraint_scale
        return x / lay.variable_scale, lam_x, lam_g, f"{t.name}@{t.header['content_hash'][:12]}"
    return None


def group_points(grid: Any) -> list[list[int]]:
    """Flat indices grouped by the operating point of the axes other than speed and the
    family axis (slope, cross slope), each group in flat order (speed-major within it when
    speed precedes the family axis, as in the default grid); groups in flat order."""
    shape = grid.shape
    keep = [i for i, n in enumerate(grid.names) if n in ("slope", "cross_slope")]
    groups: dict[tuple[int, ...], list[int]] = {}
    for f in range(grid.size):
        idx = np.unravel_index(f, shape)
        groups.setdefault(tuple(int(idx[i]) for i in keep), []).append(f)
    return [groups[k] for k in sorted(groups, key=lambda k: groups[k][0])]


def _speed_index(grid: Any, flat: int) -> int:
    if "speed" not in grid.names:
        return 0
    return int(np.unravel_index(flat, grid.shape)[grid.names.index("speed")])


def _family_index(spec: Any, flat: int) -> int:
    if spec.family is None:
        return 0
    return int(np.unravel_index(flat, spec.grid.shape)[spec.grid.names.index(spec.family["axis"])])


def _accept(spec: Any, flat: int, r: Mapping[str, Any], source: str, its: int) -> dict[str, Any]:
    from .table_builder import point_data, scenario_at

    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    x, lx, lg = (np.asarray(r[k], dtype=float) for k in ("x", "lam_x", "lam_g"))
    return {"flat": flat, "status": "optimal", "iterations": its, "evidence": None, "continued_from": source,
            "x_scaled": x, "lam_x": lx, "lam_g": lg, "data": point_data(spec, sc, x, lx, lg)}


def _try_starts(spec: Any, flat: int, starts: Sequence[tuple[str, NDArray[np.float64], Any, Any]]
                ) -> tuple[dict[str, Any] | None, list[str], int]:
    """One IPOPT run (the solver's ``max_iter``) from each start in turn; the first that converges
    and passes the optimizer's independent check is the point's primitive."""
    from .table_builder import first_checked_start

    r, label, tried, its = first_checked_start(spec, flat, [(lb, lb, x0, lx, lg) for lb, x0, lx, lg in starts])
    return (_accept(spec, flat, r, label, its) if r is not None else None), tried, its


def _order(spec: Any, flats: Sequence[int], seed: SeedStart | None) -> list[tuple[int, int | None]]:
    """Solve order of the points of one speed along the family axis: ``(flat, flat of the
    neighbour to continue from)``. The first point is the one whose bounds and rows the seed
    start violates least (the easiest, e.g. the stuck angle nearest the nominal primitive's
    steering angle); then outward along the axis, each from the previous one."""
    from .table_builder import _problem, scenario_at

    if len(flats) <= 1:  # none: the relaxation decided every point of the group (e.g. one speed, no family axis)
        return [(f, None) for f in flats]
    if seed is None:
        k0 = 0
    else:
        viol = []
        for f in flats:
            sc = scenario_at(spec.scenario, spec.family, spec.grid.point(f))
            pb = _problem(sc, spec.solver)
            b = pb.bounds(sc)
            x0 = np.clip(seed.x_scaled, b["lbx"], b["ubx"])
            g = np.asarray(pb.eval_g(x0, b["p"])[0]).ravel()
            move = float(np.max(np.abs(x0 - seed.x_scaled)))  # bound moves (a stuck angle imposed)
            viol.append(max(move, pb.violation(b, x0, g)))
        k0 = int(np.argmin(viol))
    out: list[tuple[int, int | None]] = [(flats[k0], None)]
    out += [(flats[k], flats[k - 1]) for k in range(k0 + 1, len(flats))]
    out += [(flats[k], flats[k + 1]) for k in range(k0 - 1, -1, -1)]
    return out


def continuation_group(spec: Any, flats: Sequence[int], seed: SeedStart | None, decide_relaxation: bool,
                       point_seeds: Mapping[int, SeedStart] | None = None) -> list[dict[str, Any]]:
    """Solve the points of one (slope, cross slope) group (module docstring): every speed and
    failure value. Returns one record per point: ``optimal`` (with ``continued_from``: the
    seed table, a neighbour on the family axis or the speed twin), ``infeasible`` (relaxation
    evidence), or ``not_found`` with ``pending`` set (left to the builder's later passes).

    Parameters
    ----------
    spec : TableSpec
        The table's spec.
    flats : sequence of int
        The group's grid points (:func:`group_points`).
    seed : SeedStart or None
        A seed table's primitive at the group's slope and cross slope (:func:`seed_start`).
    decide_relaxation : bool
        Decide the relaxation first (no seed table has a primitive here).
    point_seeds : mapping or None
        Per first-speed point, a family seed table's primitive at that very point
        (:func:`point_seed`, e.g. the mirror of the other side's table), tried first.

    Returns
    -------
    list of dict
        One record per point of ``flats``, in that order.
    """
    from .table_builder import (_solve_point, relaxation_of, relaxation_verdict, scenario_at, speed_twin,
                                twin_resolve)

    grid = spec.grid
    recs: dict[int, dict[str, Any]] = {}
    rel: dict[str, Any] | None = None
    if decide_relaxation:
        relaxable = [f for f in flats if relaxation_of(scenario_at(spec.scenario, spec.family, grid.point(f))) is not None]
        if relaxable:
            rel = relaxation_verdict(spec, grid.point(relaxable[0]))
            if rel["status"] == "infeasible":
                for f in relaxable:
                    recs[f] = {"flat": f, "status": "infeasible", "iterations": 0,
                               "evidence": {"relaxation": RELAXED_EVIDENCE, "relaxation evidence": rel["evidence"],
                                            "table search": "not run: the relaxation decides this point"}}
    first = [f for f in flats if _speed_index(grid, f) == 0 and f not in recs]
    first.sort(key=lambda f: _family_index(spec, f))
    for f, nb in _order(spec, first, seed):
        starts: list[tuple[str, NDArray[np.float64], Any, Any]] = []
        ps = (point_seeds or {}).get(f)
        if ps is not None:
            starts.append((f"seed table {ps.source}", ps.x_scaled, None, None))
        if nb is not None and recs.get(nb, {}).get("status") == "optimal":
            starts.append((f"neighbour {nb} on the failure axis", recs[nb]["x_scaled"], recs[nb]["lam_x"], recs[nb]["lam_g"]))
        if seed is not None:
            starts.append((f"seed table {seed.source}", seed.x_scaled, None, None))
        if not starts:  # no seed and nothing solved yet: the optimizer's automatic start, as chains do
            auto = _solve_point(spec, f, None)
            recs[f] = {**auto, "continued_from": "automatic start"} if auto["status"] == "optimal" else \
                {**auto, "pending": auto["status"] != "infeasible"}
            continue
        rec, tried, its = _try_starts(spec, f, starts)
        recs[f] = rec if rec is not None else {"flat": f, "status": "not_found", "iterations": its, "pending": True,
                                               "evidence": {"continuation": tried},
                                               # the neighbours whose primal-dual point was a start (the
                                               # builder's retries and re-checks do not repeat that run)
                                               "tried_neighbours": [nb] if nb is not None and recs.get(nb, {}).get(
                                                   "status") == "optimal" else []}
    # the other speeds: the first speed's primitive scaled exactly and verified (speed twins)
    for f in flats:
        if f in recs:
            continue
        t = speed_twin(grid, f)
        tw = recs.get(t) if t is not None else None
        if tw is not None and tw["status"] == "optimal":
            r = twin_resolve(spec, f, tw)
            if r is not None:
                recs[f] = {**r, "continued_from": f"speed twin {t}"}
                continue
        recs[f] = {"flat": f, "status": "not_found", "iterations": 0, "pending": True,
                   "evidence": {"continuation": f"speed twin {t}: {'no primitive' if tw is None or tw['status'] != 'optimal' else 'scaled primitive did not verify'}"}}
    known = "optimal" if seed is not None else (rel["status"] if rel is not None else None)
    for f in flats:
        if recs[f]["status"] != "optimal" and known is not None:
            recs[f]["relaxation_status"] = known
    return [recs[f] for f in flats]


def search_group(spec: Any, flats: Sequence[int], lead: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """The full search (:func:`~offline.rover.primitives.solve_primitive` from its automatic
    start, the table's budgets) for still-unsolved points of one operating point that differ
    only in speed (ascending). The first is searched; an optimum is carried to the others by
    the speed scaling (:func:`~offline.rover.table_builder.twin_resolve`), a confirmed
    ``infeasible`` verdict too (the same NLP); where the carried point does not verify, or the
    first is ``not_found``, the next is searched as well (another start). ``lead``: a solved
    member of the same speed group (e.g. solved by the neighbour retries), carried first."""
    from .table_builder import _solve_point, twin_resolve

    out: dict[int, dict[str, Any]] = {}
    for f in flats:
        if lead is not None and lead["status"] == "optimal":
            r = twin_resolve(spec, f, lead)
            if r is not None:
                out[f] = {**r, "continued_from": f"speed twin {lead['flat']}"}
                continue
        if lead is not None and lead["status"] == "infeasible":
            out[f] = {"flat": f, "status": "infeasible", "iterations": 0,
                      "evidence": {"speed twin": TWIN_EVIDENCE, "twin": int(lead["flat"]),
                                   "twin evidence": lead["evidence"]}}
            continue
        rec = _solve_point(spec, f, None)
        if rec["status"] == "optimal":
            rec["continued_from"] = "automatic start"
        out[f] = rec
        if lead is None or rec["status"] in ("optimal", "infeasible"):
            lead = rec
    return [out[f] for f in flats]


def hole_reason(spec: Any, flat: int, relaxation_status: str | None) -> str:
    """Why a point left ``not_found`` is neither solved nor proven infeasible (for its evidence)."""
    from .table_builder import relaxation_of, scenario_at

    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    if relaxation_of(sc) is None:
        why = ("no relaxation applies (a stuck angle beyond the free steering range of +-89 deg lies outside the "
               "nominal problem's bounds, a raised wheel changes the equations, or the failure kind is not known to "
               "only add constraints), so the infeasibility of the same point without the failures is no evidence")
    elif relaxation_status == "optimal":
        why = ("the same point without the failures has a primitive, so no relaxation decides it; the failure's "
               "constraints are what the search could not satisfy within the table's budgets")
    else:
        why = (f"the relaxation's verdict is '{relaxation_status or 'not computed'}' (not a confirmed infeasibility), "
               "and the search spent the table's budgets")
    return why + "; examine it with the optimizer's full budgets: offnominal primitive"
