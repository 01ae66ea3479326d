"""Table builder: driving primitives and the online QP's data over a grid of operating conditions.

For one scenario file (rover + parameter file + failure) and a grid over slope, cross-slope,
speed and, for a family, the failure's own parameter (stuck steering angle, rim-speed cap as a
fraction of the travel speed, trench depth target), solve the steady-state NLP (7.25) at every
grid point and store what the on-rover QP needs to be one exact SQP step of it
(:mod:`rtctl.table` describes the file):

* the primitive and IPOPT's multipliers; the constraint values and exact Jacobians in the
  decision variables and the parameters; the objective gradient; the Hessian of the Lagrangian
  ``f + lam_g' g``; bounds and active sets;
* the parametric sensitivity ``dx*/dp`` from the KKT system of the active set (the
  Fiacco sensitivity system ``[H A'; A 0] [dx; dlam] = -[H_xp; A_p - b_p]``), bounds that move
  with a parameter (the motor limit and a rim-speed cap scale with the speed) included;
* each wheel's wrench and its exact Jacobian in ``(v_x, v_y, omega, h, h0)`` from the AD graph;
* the steering controllers of section 7.2.4: re-solves with +-yaw-moment (7.26) and
  +-lateral-force (7.27) offsets minus the primitive, per unit offset (the first-order
  sensitivity column where a re-solve fails, flagged in ``controller_source``).

Schedule (deterministic, so the file is byte-identical whatever the worker count or the order
in which workers finish): the grid is cut into *chains* along the slope axis (all other axes
fixed), solved from flat ground upward, each point warm-started from the last solved point of
its chain (the first from the optimizer's automatic start). Chains are independent tasks for a
local process pool or a Dask cluster. Points left unsolved (``not_found``/``solver_failure``)
are then retried from each solved grid neighbour in a fixed order; still unsolved, they are
``not_found`` (distinct from ``infeasible``, which carries the optimizer's evidence). Then,
with ``build.speed_twins`` (default), a twin pass (:func:`_twin_pass`): (7.25) scales exactly
with the travel speed on this rate-independent soil model, so the points that differ only in
speed are one NLP, and each takes the best optimum found at any of its speeds
(:func:`twin_resolve`, verified by its own re-solve). Then a
neighbour pass (:func:`polish_point`, ``build.polish_sweeps`` sweeps) re-solves every solved
point from its neighbours' predicted starts ``x + dx/dp dp`` and keeps a strictly lower
objective: (7.25) has several local optima (a wheel at the motor limit, mirrored steering),
and independent chains can settle on different ones, which interpolation cannot bridge.
Optionally the grid is refined (:mod:`offline.rover.table_refine`). Every finished chain,
retry, pass and refinement solve is checkpointed in ``<out>/.<name>.partial/`` under a key of
the spec and of the library code (:func:`code_hash`), so an interrupted build continues where
it stopped and checkpoints made by other code are discarded. Each point's trust radius comes
from NLP re-solves (:func:`point_trust_radius`).
"""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import functools
import hashlib
import importlib
import json
import math
import multiprocessing
import os
import shutil
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from rtctl.layout import NlpLayout
from rtctl.table import (CONTROLLER_NAMES, POINT_FIELDS, SCHEMA, SCHEMA_VERSION, STATUS_NAMES, TableError,
                         content_hash, field_shapes, table_bytes)

from ..files import check_output_dir, write_bytes, write_text

__all__ = [
    "AXES", "FAMILY_KINDS", "TABLE_SOLVER_BUDGETS", "MAX_RETRY_NEIGHBOURS", "COMPILE_MIN_POINTS", "compile_mode", "structure_key", "RUN_SEED_INDEX", "RUN_RECHECK_INDEX", "sibling_leaders", "seeds_others", "build_tables", "BuildError", "GridSpec", "TableSpec", "BuildOptions", "default_grid", "parse_grid",
    "family_of", "scenario_at", "failure_header", "describe_table", "table_spec", "chains", "solve_chain", "point_data", "build_table", "write_index",
    "encode", "decode", "scenario_from_header", "linearisation_errors", "retry_point", "point_trust_radius",
    "predicted_start", "polish_point", "upgrade_table", "speed_twin", "twin_resolve",
    "CODE_SOURCES", "code_hash", "world_header", "wheel_set_header", "relaxation_of", "relaxation_verdict",
    "point_resolves", "RESOLVE_FIELDS", "search_verdict", "RECHECK_WAVES",
]

AXES: dict[str, tuple[str, str, float]] = {
    "slope": ("rad", "deg", math.pi / 180),
    "cross_slope": ("rad", "deg", math.pi / 180),
    "speed": ("m/s", "cm/s", 0.01),
    "steer_stuck": ("rad", "deg", math.pi / 180),
    "rim_speed_cap_fraction": ("1", "1", 1.0),
    "trench_depth": ("m", "mm", 1e-3),
}
"""Known axes: name -> (SI unit, display unit, display-to-SI factor)."""

FAMILY_KINDS = ("steer_stuck", "rim_speed_cap_fraction", "trench_depth")
"""Failure parameters a table can carry as an axis (one table covers the whole family)."""

_DEFAULT_DISPLAY = {
    "slope": (0.0, 5.0, 10.0, 15.0, 20.0, 25.0),
    "cross_slope": (-10.0, 0.0, 10.0),
    "speed": (2.0, 4.0),
    "steer_stuck": (-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0),
    "rim_speed_cap_fraction": (0.25, 0.5, 0.75, 1.0),
    "trench_depth": (20.0, 25.0, 30.0, 35.0),
}

COMPILE_MIN_POINTS = 64
"""Under ``build.compile = "auto"`` an NLP structure (:func:`structure_key`) with fewer points to
solve than this -- a table's grid, or in :func:`build_tables` the grids of all its tables on that
structure -- is not compiled: a table uses the compiled library if the cache already holds it
(an earlier build of the same parameter set, rover and world terms), else runs the same per-wheel
graph in casadi's virtual machine
(compile mode ``"cached"``, :mod:`offline.rover.compiled_nlp`; the same graph, so the same table
bytes either way). Break-even from measured costs: a compilation takes 92-136 CPU s once per NLP
structure (``SolverOptions.nlp_structure``; the 2026-11-28 01:26 rebuild of every shipped table: 3
compilations, 409 CPU s), and the per-wheel graph in the virtual machine costs about 1.6 CPU s a
grid point more than compiled (README's worked example: 1.32 x 610 CPU s against 391 for 252
points, ``tests/bench/results_nlp_structure.md``), so a compilation pays from about 56-83 points.
The shipped ``rr_trench_clean_mu01`` (3 points, a soil of its own) compiled a library for itself.
Counted per structure over the call, not per table: decided per table, the small tables that share
the nominal structure (rr_unpowered 36 points, the locked ones 6) started in the virtual machine
while the large ones were still compiling it, and paid about 1.2 CPU s a point more for the run
(a cold rebuild of every shipped table: 911 CPU s against 530 warm, of which 181 were the compiler)."""


def compile_mode(spec: "TableSpec", points: int | None = None) -> str:
    """The NLP's compile mode for building ``spec`` (:attr:`~offline.rover.primitives.SolverOptions.compile`):
    ``build.compile``, except ``"auto"`` with fewer than :data:`COMPILE_MIN_POINTS` points to
    solve on this NLP structure, which becomes ``"cached"`` (no compilation; a cached library is
    used). ``points``: those points (:func:`build_tables` sums the grids of the tables that share
    the structure, :func:`structure_key`); default ``spec``'s grid alone."""
    mode = str(spec.build.compile)
    n = spec.grid.size if points is None else points
    return "cached" if mode == "auto" and n < COMPILE_MIN_POINTS else mode


def structure_key(spec: "TableSpec") -> str:
    """What decides the NLP's casadi graph, hence its compiled library (the arguments of
    :func:`~offline.rover.primitives.get_problem` but the solver's data): parameter set, rover,
    exit angle, trench wheel and world terms. The grid's values and the failures are parameters
    and bounds of one NLP."""
    from . import primitives as P

    sc = spec.scenario
    return repr((sc.params, sc.rover, sc.exit_angle, sc.trench.wheel if sc.trench else None,
                 sorted(P.world_of(sc).items())))


MAX_RETRY_NEIGHBOURS = 3
"""An unsolved point is retried from at most this many solved neighbours (in axis order)."""

TABLE_SOLVER_BUDGETS: dict[str, Any] = {"max_attempts": 3, "max_iterations": 300, "confirm_starts": 1, "confirm_rounds": 1}
"""Search budgets of the optimizer inside a table build (iterations and attempts, deterministic).

Smaller than :class:`~offline.rover.primitives.SolverOptions`' defaults: a grid point is
warm-started from a solved neighbour, and one the search cannot solve is retried from every
solved neighbour; the unsolved points dominate a build's time (measured: 1-4 s each against
0.2-0.3 s for a solved one). A point left ``not_found`` can be examined with the full
budgets by ``offnominal primitive``."""


_LIN_PARAMS = ("speed", "slope", "cross_slope", "fy_offset", "mz_offset")


class BuildError(ValueError):
    """A table build that cannot start or continue (bad grid, scenario, output or partial build)."""


# ------------------------------------------------------------------------------ JSON coding
def encode(obj: Any) -> Any:
    """JSON-able form of scenario data: frozen dataclasses tagged with their class (only
    classes of :mod:`offline` are accepted back), tuples tagged, non-finite floats as strings.
    A field marked ``omit_default`` in its metadata is left out at its default (the scenario's
    world terms: files without them stay byte-identical), one marked ``not_data`` always (a
    setting that changes no result, such as ``compile``)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        d = {f.name: encode(getattr(obj, f.name)) for f in dataclasses.fields(obj)
             if f.init and not f.metadata.get("not_data")
             and not (f.metadata.get("omit_default") and getattr(obj, f.name) == f.default)}
        return {"__class__": f"{type(obj).__module__}.{type(obj).__qualname__}", **d}
    if isinstance(obj, (bool, str, type(None))):
        return obj
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else {"__float__": repr(v)}
    if isinstance(obj, tuple):
        return {"__tuple__": [encode(v) for v in obj]}
    if isinstance(obj, list):
        return [encode(v) for v in obj]
    if isinstance(obj, Mapping):
        return {str(k): encode(v) for k, v in sorted(obj.items(), key=lambda kv: str(kv[0]))}
    if isinstance(obj, np.ndarray):
        return [encode(v) for v in obj.tolist()]
    return str(obj)


_MOVED_MODULES = {"offline.physics.hub_drag": "rtctl.physics.hub_drag", "offline.physics.soil_flow": "rtctl.physics.soil_flow"}
"""Modules whose classes moved to the shared physics (headers written before the move name the old path)."""


def decode(obj: Any) -> Any:
    """Inverse of :func:`encode`."""
    if isinstance(obj, list):
        return [decode(v) for v in obj]
    if not isinstance(obj, dict):
        return obj
    if "__float__" in obj:
        return float(obj["__float__"])
    if "__tuple__" in obj:
        return tuple(decode(v) for v in obj["__tuple__"])
    if "__class__" in obj:
        mod, _, name = obj["__class__"].rpartition(".")
        mod = _MOVED_MODULES.get(mod, mod)
        if not mod.startswith(("offline.", "rtctl.physics.")):
            raise BuildError(f"table header names class {obj['__class__']!r}: only offline and rtctl.physics classes "
                             "are rebuilt")
        cls = getattr(importlib.import_module(mod), name)
        names = {f.name for f in dataclasses.fields(cls) if f.init}
        return cls(**{k: decode(v) for k, v in obj.items() if k in names})
    return {k: decode(v) for k, v in obj.items()}


# ------------------------------------------------------------------------------ grid
@dataclass(frozen=True)
class GridSpec:
    """Axes of a table in order; values in SI (:data:`AXES`)."""

    axes: tuple[tuple[str, tuple[float, ...]], ...]

    @property
    def names(self) -> tuple[str, ...]:
        """Axis names in order."""
        return tuple(k for k, _ in self.axes)

    @property
    def shape(self) -> tuple[int, ...]:
        """Grid shape."""
        return tuple(len(v) for _, v in self.axes)

    @property
    def size(self) -> int:
        """Number of grid points."""
        return int(np.prod(self.shape))

    def values(self, name: str) -> tuple[float, ...]:
        """Values of one axis (SI)."""
        return dict(self.axes)[name]

    def point(self, flat: int) -> dict[str, float]:
        """Operating point of a flat grid index."""
        idx = np.unravel_index(flat, self.shape)
        return {k: v[i] for (k, v), i in zip(self.axes, idx)}


def _parse_values(text: str, where: str) -> tuple[float, ...]:
    try:
        if ":" in text:
            a, b, s = (float(t) for t in text.split(":"))
            if s <= 0 or b < a:
                raise ValueError
            n = int(math.floor((b - a) / s + 1e-9)) + 1
            return tuple(round(a + i * s, 12) for i in range(n))
        return tuple(float(t) for t in text.split(",") if t.strip())
    except ValueError:
        raise BuildError(f"--grid {where}: {text!r} is not 'start:stop:step' (step > 0) nor a comma list") from None


def parse_grid(text: str | None, base: GridSpec) -> GridSpec:
    """Override axes of ``base`` from ``"slope=0:25:5;speed=2,3,4"`` (display units of :data:`AXES`:
    deg, cm/s, mm, fraction).

    Raises
    ------
    BuildError
        Unknown axis, an axis the scenario does not have, bad numbers, repeated or unsorted values.
    """
    if not text:
        return base
    axes = dict(base.axes)
    for part in text.replace(" ", "").split(";"):
        if not part:
            continue
        if "=" not in part:
            raise BuildError(f"--grid: {part!r} is not AXIS=VALUES (e.g. slope=0:25:5)")
        name, vals = part.split("=", 1)
        if name not in AXES:
            raise BuildError(f"--grid: unknown axis {name!r}; known: {sorted(AXES)}")
        if name not in axes:
            raise BuildError(f"--grid: this table has no {name!r} axis (its axes: {list(axes)}); "
                             "a family axis comes from the scenario's failure (see 'offnominal tables build -h')")
        v = _parse_values(vals, name)
        if not v or any(np.diff(v) <= 0) or not all(map(math.isfinite, v)):
            raise BuildError(f"--grid {name}: values must be finite and strictly increasing, got {list(v)}")
        axes[name] = tuple(x * AXES[name][2] for x in v)
    return GridSpec(tuple((k, axes[k]) for k, _ in base.axes))


# ------------------------------------------------------------------------------ scenario family
def family_of(sc: Any, choice: str = "auto") -> dict[str, Any] | None:
    """The failure parameter this scenario's table varies, or None.

    ``auto``: a trench goal gives ``trench_depth``; else a stuck steering wheel gives
    ``steer_stuck``; else a rim-speed cap gives ``rim_speed_cap_fraction``; else none.

    Raises
    ------
    BuildError
        When ``choice`` names a family the scenario does not have.
    """
    if choice == "none":
        return None
    found: list[dict[str, Any]] = []
    if getattr(sc, "trench", None) is not None:
        found.append({"axis": "trench_depth", "wheel": sc.trench.wheel, "kind": "trench depth target"})
    wheels = tuple(getattr(sc, "wheels", ("FR", "FL", "RR", "RL")))  # a rover file's wheels, in file order
    for k in wheels:
        f = sc.failure(k)
        if getattr(f, "steer_stuck", None) is not None:
            found.append({"axis": "steer_stuck", "wheel": k, "kind": "stuck steering angle"})
    for k in wheels:
        f = sc.failure(k)
        if math.isfinite(getattr(f, "rim_speed_max", math.inf)) and not getattr(f, "locked", False):
            found.append({"axis": "rim_speed_cap_fraction", "wheel": k, "kind": "rim-speed cap / travel speed"})
    if choice == "auto":
        return found[0] if found else None
    for f in found:
        if f["axis"] == choice:
            return f
    raise BuildError(f"scenario {sc.name!r} has no {choice!r} failure to vary; it has {[f['axis'] for f in found] or 'none'}")


def scenario_at(sc: Any, family: Mapping[str, Any] | None, point: Mapping[str, float]) -> Any:
    """The scenario at one operating point (slope, cross-slope, speed, family value); the
    rim-speed cap of a fraction family follows the speed (cap = fraction x speed)."""
    kw: dict[str, Any] = {}
    for k in ("slope", "cross_slope", "speed"):
        if k in point:
            kw[k] = float(point[k])
    out = replace(sc, **kw)
    if family is None:
        return out
    v = float(point[family["axis"]])
    w = family["wheel"]
    if family["axis"] == "steer_stuck":
        return replace(out, failures={**out.failures, w: replace(out.failure(w), steer_stuck=v)})
    if family["axis"] == "rim_speed_cap_fraction":
        return replace(out, failures={**out.failures, w: replace(out.failure(w), rim_speed_max=v * out.speed)})
    if family["axis"] == "trench_depth":
        return replace(out, trench=replace(out.trench, target_depth=v, min_depth=0.0))
    raise BuildError(f"unknown family axis {family['axis']!r}")


def default_grid(sc: Any, family: Mapping[str, Any] | None) -> GridSpec:
    """Default axes: slope 0-25 deg by 5, cross-slope -10/0/10 deg, speed 2/4 cm/s and the
    family axis (stuck angle -90..90 by 30 deg, cap fraction 0.25..1, trench depth 20..35 mm)."""
    names = ["slope", "cross_slope", "speed"] + ([family["axis"]] if family else [])
    return GridSpec(tuple((n, tuple(v * AXES[n][2] for v in _DEFAULT_DISPLAY[n])) for n in names))


@dataclass(frozen=True)
class BuildOptions:
    """Settings of a build that are not scenario data.

    Attributes
    ----------
    mz_offset, fy_offset : float
        Offsets (N m, N) of the section 7.2.4 controller re-solves (7.26)-(7.27).
    trust_tolerance : float
        Largest error of the first-order prediction, as a fraction of each variable's scale
        (layout), inside the trust radius.
    trust_search : tuple
        Steps of the per-point trust-radius search, in parameter scales, ascending (a
        geometric ladder): its middle step is the probe of the quadratic law, its largest the
        largest radius, and the fall-back bisects on it, both signs (:func:`point_trust_radius`).
    trust_max_iter : int
        IPOPT iterations of each of the (at most two) verification runs of one trust-radius
        step, both started at the first-order prediction (:func:`point_trust_radius`).
    trust_steps : tuple
        Steps of ``offnominal tables verify``'s linearisation check, in parameter scales.
    active_tol : float
        Multiplier magnitude (scaled problem) above which a bound or inequality is active.
    polish_sweeps : int
        Sweeps of the neighbour pass (:func:`polish_point`): a solved point takes a neighbour's
        lower-objective optimum, so adjacent points lie on the same branch (0: off).
    polish_warm : bool
        Start each neighbour-pass run from the neighbour's primal-dual point (its primitive
        moved by its sensitivity, with its multipliers; IPOPT's warm start) instead of the
        primal point alone with IPOPT's own dual initialisation (issue 22: the cold runs took
        46 IPOPT iterations each on README's worked example and were the largest phase of its
        build, ``tests/bench/results_worked_example_i22.md``).
    polish_max_iter : int
        IPOPT iterations of one warm neighbour-pass run (``polish_warm``); a run that does not
        converge within them offers nothing. Cold runs keep the solver's ``max_iter``.
    speed_twins : bool
        Twin pass (:func:`_twin_pass`): points that differ only in speed (one NLP up to the exact
        speed scaling of (7.25)) take the best optimum found at any of their speeds.
    relaxation_evidence : bool
        Relaxation pass (:func:`_relaxation_pass`): a point still ``not_found`` becomes
        ``infeasible`` when the same operating point without the failures (a relaxation,
        :func:`relaxation_of`) is confirmed infeasible by the optimizer with its default budgets
        (one solve per slope and cross slope, shared by every speed and family value). With the
        continuation schedule the relaxation is decided *first* where no seed table has a
        primitive, and decides those points without a search.
    schedule : str
        ``"continuation"`` (default): :mod:`offline.rover.table_continuation` -- easiest points
        first from a seed table's primitive, along the failure's axis, the other speeds by the
        exact speed scaling, the full search only for what is left. ``"chains"``: the former
        schedule (chains along the slope axis, every speed searched, :func:`chains`).
    seed_index : str
        Where the continuation schedule looks for seed tables (tables without failures built
        for the same NLP, :func:`~offline.rover.table_continuation.seed_tables`): ``"shipped"``
        (the shipped ``tables/index.json``), ``"none"``, ``"run"`` (the tables built earlier in
        the same :func:`build_tables` call: it builds the failure-free tables first and seeds the
        others from them, so a rebuild of a folder from scratch still starts every failure from
        a nominal primitive without reading the files it replaces), or an ``index.json`` path.
    compile : str
        ``"off"`` (default: casadi's virtual machine), ``"auto"`` (IPOPT evaluates the NLP's
        functions as C compiled once per NLP structure and cached on disk when a C compiler is
        found, else the virtual machine with one line saying so; a table of fewer than
        :data:`COMPILE_MIN_POINTS` grid points compiles nothing and uses the library only if it
        is cached) or ``"on"`` (compiled or an error), :mod:`offline.rover.compiled_nlp`. Off by default in the library (the inlined
        graph in the virtual machine, the path the tests pin); ``offnominal tables build``
        defaults to ``auto``: compiled, the NLP is built per wheel
        (:attr:`~offline.rover.primitives.SolverOptions.nlp_structure` ``"auto"``), which
        compiles in about 90 CPU s once per machine and NLP structure (cached on disk) and builds
        README's worked example in about 0.6 of the virtual machine's CPU
        (``tests/bench/results_new_failure.md``). The environment variable
        ``OFFNOMINAL_COMPILE`` sets the default (the test suite sets ``off``). Not data, neither
        written to the file nor hashed: the virtual machine and the compiled C of one graph give
        the same table; the two graphs give primitives equal to rounding (the per-wheel graph is
        chosen only when compiled).
    defer_resolves : bool
        Compute a point's re-solve fields (:data:`RESOLVE_FIELDS`: the section 7.2.4 controllers
        and the trust radius, about 30 short IPOPT runs per point) once, for the primitive the
        table finally holds (:func:`_resolve_pass`), instead of for every primitive a pass finds
        and a later pass replaces (a speed twin's, the neighbour pass's, a retry's). The same
        numbers either way (they depend only on the final primal-dual point), so not data.
    """

    mz_offset: float = 0.2
    fy_offset: float = 1.0
    trust_tolerance: float = 0.02
    trust_search: tuple[float, ...] = (0.0625, 0.125, 0.25, 0.5, 1.0, 2.0)
    trust_max_iter: int = 30
    trust_steps: tuple[float, ...] = (0.0625, 0.125, 0.25, 0.5, 1.0, 2.0)
    active_tol: float = 1e-7
    polish_sweeps: int = 2
    polish_warm: bool = True
    polish_max_iter: int = 60
    speed_twins: bool = True
    relaxation_evidence: bool = True
    schedule: str = "continuation"
    seed_index: str = "shipped"
    compile: str = field(default_factory=lambda: os.environ.get("OFFNOMINAL_COMPILE") or "off",
                         metadata={"not_data": True})
    defer_resolves: bool = field(default=True, metadata={"not_data": True})

    def __post_init__(self) -> None:
        if self.schedule not in ("continuation", "chains"):
            raise BuildError(f"BuildOptions.schedule = {self.schedule!r}: expected 'continuation' or 'chains'")
        if self.compile not in ("auto", "on", "off"):
            raise BuildError(f"BuildOptions.compile = {self.compile!r}: expected 'auto', 'on' or 'off' "
                             "(from --compile or the environment variable OFFNOMINAL_COMPILE)")


@dataclass(frozen=True)
class TableSpec:
    """Everything that determines a table file (its hash covers all of it); ``refine``: a
    :class:`~offline.rover.table_refine.RefineOptions` or None (no grid refinement)."""

    name: str
    scenario: Any
    grid: GridSpec
    family: dict[str, Any] | None
    description: str
    sources: dict[str, Any]
    build: BuildOptions = field(default_factory=BuildOptions)
    solver: Any = None
    refine: Any = None

    def key(self) -> str:
        """sha256 of the spec (names the checkpoint folder's content)."""
        d = {"name": self.name, "scenario": self.scenario, "grid": self.grid.axes, "family": self.family,
             "build": self.build, "solver": self.solver, "sources": self.sources}
        if self.refine is not None:
            d["refine"] = self.refine
        blob = json.dumps(encode(d), sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()


def _file_record(path: Path) -> dict[str, str]:
    return {"name": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}


def table_spec(path: str | Path, grid: str | None = None, family: str = "auto", build: BuildOptions | None = None,
               solver: Any = None, refine: Any = None, world: Any = None) -> TableSpec:
    """Read a scenario file and make the spec of its table (default grid, overridden by ``grid``).

    ``world``: an :class:`offline.sim.truth.Truth` (``--world accepted_truth.toml``) whose terms
    the scenario takes (:func:`offline.rover.scenario.scenario_with_world`); its file's name and
    sha256 go to the header's ``sources["world_file"]``.

    Raises
    ------
    BuildError
        Unreadable scenario (the loader's message), or a bad grid.
    """
    from .scenario import ScenarioError, load_scenario, param_preset_file

    p = Path(path)
    try:
        sc = load_scenario(p)
    except ScenarioError as exc:
        raise BuildError(str(exc)) from None
    fam = family_of(sc, family)
    g = parse_grid(grid, default_grid(sc, fam))
    sources: dict[str, Any] = {"scenario_file": _file_record(p), "scenario_text": p.read_text()}
    try:
        ref = tomllib.loads(p.read_text()).get("scenario", {}).get("params")
    except tomllib.TOMLDecodeError:
        ref = None
    preset_file = param_preset_file(ref) if isinstance(ref, str) else None
    if preset_file is not None:  # a shipped parameter file by name: its name and hash, and the name
        sources["params_file"] = _file_record(preset_file)
        sources["params_preset"] = ref
    elif isinstance(ref, str) and (p.parent / ref).is_file():
        sources["params_file"] = _file_record(p.parent / ref)
    elif isinstance(ref, str):
        sources["params_preset"] = ref
    if world is not None:
        from .scenario import scenario_with_world

        try:
            sc = scenario_with_world(sc, world)
        except ScenarioError as exc:
            raise BuildError(str(exc)) from None
        wp = Path(world.source) if getattr(world, "source", "") else None
        sources["world_file"] = _file_record(wp) if wp is not None and wp.is_file() else {"name": "(in memory)"}
    sc = replace(sc, source=p.name)
    if getattr(sc, "rover_file", None) is not None:
        sc = _rover_file_sources(sc, sources)
    if solver is None:
        from .primitives import SolverOptions

        solver = SolverOptions(**TABLE_SOLVER_BUDGETS)
    return TableSpec(sc.name, sc, g, fam, sc.description, sources, build or BuildOptions(), solver, refine)


def _rover_file_sources(sc: Any, sources: dict[str, Any]) -> Any:
    """Record a rover-file scenario's rover file (and its wheels' parameter file) by name and
    sha256 in ``sources``, and return the scenario with the file's machine path replaced by its
    name (in the rover spec and the rover's ``source`` text): a table header names files, never
    where they were on the machine that built it."""
    rf = sc.rover_file
    where = Path(rf.path) if rf.path else None
    if where is not None and where.is_file():
        sources["rover_file"] = _file_record(where)
    else:  # a rover given as a mapping: its canonical JSON stands for the file
        blob = json.dumps(encode(replace(rf, path="")), sort_keys=True).encode()
        sources["rover_file"] = {"name": f"{rf.name} (no file)", "sha256": hashlib.sha256(blob).hexdigest()}
    refs = {rf.wheel_params(w) for w in rf.wheel_names}
    if "params_file" not in sources and "params_preset" not in sources and len(refs) == 1:
        ref = next(iter(refs))
        if ref.endswith(".toml") and Path(ref).is_file():
            sources["params_file"] = _file_record(Path(ref))
        elif not ref.endswith(".toml"):
            sources["params_preset"] = ref
    if where is None:
        return sc
    rover = sc.rover
    if isinstance(getattr(rover, "source", None), str) and rf.path in rover.source:
        rover = replace(rover, source=rover.source.replace(rf.path, where.name))
    return replace(sc, rover=rover, rover_file=replace(rf, path=where.name))


def wheel_set_header(sc: Any, sources: Mapping[str, Any]) -> dict[str, Any]:
    """The header's ``wheel_set``: the wheels a table is for, so the rover reads their names and
    count from the table (:mod:`rtctl.wheel_set`).

    ``wheels`` (names in layout order), ``count``, ``steerable`` and ``driven`` (per wheel),
    ``steer_range_rad`` (per wheel ``[min, max]``; None without a rover file), ``suspension``
    (``rocker`` for the mini rover of Table 7.2, else the rover file's kind), ``drive_direction``,
    ``rover`` (name) and ``rover_file`` (``{"name", "sha256"}`` of the rover file, None for a
    scenario without one: the four-wheel rocker of its ``[rover]`` section)."""
    rf = getattr(sc, "rover_file", None)
    if rf is None:
        wheels = tuple(sc.wheels)
        return {"wheels": list(wheels), "count": len(wheels), "steerable": [True] * len(wheels),
                "driven": [True] * len(wheels), "steer_range_rad": None, "suspension": "rocker",
                "drive_direction": "forward", "rover": sc.rover.name, "rover_file": None}
    backward = rf.name.endswith(" (backward)")
    return {"wheels": list(rf.wheel_names), "count": len(rf.wheels),
            "steerable": [bool(w.steerable) for w in rf.wheels], "driven": [bool(w.driven) for w in rf.wheels],
            "steer_range_rad": [[float(w.steer_min), float(w.steer_max)] for w in rf.wheels],
            "suspension": rf.suspension, "drive_direction": "backward" if backward else "forward",
            "rover": rf.name[: -len(" (backward)")] if backward else rf.name,
            "rover_file": dict(sources["rover_file"]) if "rover_file" in sources else None}


def chains(grid: GridSpec) -> list[list[int]]:
    """Flat grid indices cut into chains along the slope axis (ascending), other axes fixed;
    chains are listed in flat-index order of their first point."""
    shape = grid.shape
    idx = np.arange(grid.size).reshape(shape)
    if "slope" not in grid.names:
        return [[int(i)] for i in idx.ravel()]
    a = grid.names.index("slope")
    moved = np.moveaxis(idx, a, -1).reshape(-1, shape[a])
    return sorted(([int(i) for i in row] for row in moved), key=lambda c: c[0])


# ------------------------------------------------------------------------------ per point
class _Derivatives:
    """casadi functions of one NLP for the table data (built once per problem and process)."""

    def __init__(self, pb: Any) -> None:
        import casadi as ca

        s = pb.symbols
        x, p, f, g = s["x"], s["p"], s["f"], s["g"]
        lam = type(x).sym("lam_g", g.shape[0])  # SX, or MX for the per-wheel NLP structure
        lag = f + ca.dot(lam, g)
        gl = ca.gradient(lag, x)
        self.fun = ca.Function("table_data", [x, p, lam],
                               [g, f, ca.jacobian(g, x), ca.jacobian(g, p), ca.gradient(f, x),
                                ca.jacobian(gl, x), ca.jacobian(gl, p)])
        self.gfun = ca.Function("table_g", [x, p], [g])

    def __call__(self, x: NDArray[np.float64], p: NDArray[np.float64], lam_g: NDArray[np.float64]) -> list[NDArray[np.float64]]:
        return [np.asarray(v, dtype=float) for v in self.fun(x, p, lam_g)]


_DERIV: dict[int, _Derivatives] = {}


def _derivatives(pb: Any) -> _Derivatives:
    d = _DERIV.get(id(pb))
    if d is None:
        d = _DERIV[id(pb)] = _Derivatives(pb)
    return d


def _problem(sc: Any, solver: Any) -> Any:
    from . import primitives as P

    return P.get_problem(sc.params, sc.rover, sc.exit_angle, sc.trench.wheel if sc.trench else None,
                         solver if solver is not None else P.SolverOptions(), **P.world_of(sc))


def _active_codes(v: NDArray[np.float64], lo: NDArray[np.float64], hi: NDArray[np.float64], lam: NDArray[np.float64],
                  tol: float) -> NDArray[np.int8]:
    """-1 lower active, +1 upper active, 2 fixed (lo == hi), 0 inactive (casadi's sign: lam > 0 upper)."""
    out = np.zeros(v.shape, dtype=np.int8)
    out[(lam < -tol) & np.isfinite(lo)] = -1
    out[(lam > tol) & np.isfinite(hi)] = 1
    out[np.isfinite(lo) & (lo == hi)] = 2
    return out


def point_data(spec: TableSpec, sc: Any, x_s: NDArray[np.float64], lam_x_s: NDArray[np.float64],
               lam_g_s: NDArray[np.float64]) -> dict[str, Any]:
    """Everything the table stores for one solved grid point, in physical units (module doc).

    ``x_s``, ``lam_x_s``, ``lam_g_s``: IPOPT's scaled primal and dual solution.
    """
    from ..physics.backend import NUMPY

    pb = _problem(sc, spec.solver)
    lay: NlpLayout = pb.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    b = pb.bounds(sc)
    p = np.asarray(b["p"], dtype=float)
    g_s, f, jgx_s, jgp_s, gf_s, h_s, hxp_s = _derivatives(pb)(x_s, p, lam_g_s)
    g_s = g_s.ravel()
    nx, np_, ng = lay.nx, lay.np_, lay.ng
    tol = spec.build.active_tol
    act_x = _active_codes(x_s, b["lbx"], b["ubx"], lam_x_s, tol)
    act_g = _active_codes(g_s, b["lbg"], b["ubg"], lam_g_s, tol)
    # d(bounds)/dp: only the speed moves bounds (motor limit, rim-speed cap = fraction x speed,
    # raised wheel); bounds are linear in it, so a central difference is exact
    dlbx = np.zeros((nx, np_))
    dubx = np.zeros((nx, np_))
    dlbg = np.zeros((ng, np_))
    dubg = np.zeros((ng, np_))
    i_speed = lay.index("speed")
    ds = 1e-4 * sc.speed
    bp = pb.bounds(replace(sc, speed=sc.speed + ds, **_fam_follow(spec, sc, sc.speed + ds)))
    bm = pb.bounds(replace(sc, speed=sc.speed - ds, **_fam_follow(spec, sc, sc.speed - ds)))
    for dst, key in ((dlbx, "lbx"), (dubx, "ubx"), (dlbg, "lbg"), (dubg, "ubg")):
        with np.errstate(invalid="ignore"):
            d = (np.asarray(bp[key]) - np.asarray(bm[key])) / (2 * ds)
        dst[:, i_speed] = np.where(np.isfinite(d), d, 0.0)
    # KKT sensitivity system on the active set (scaled variables, physical parameters)
    rows, rhs = [], []
    for i in np.flatnonzero(act_g):
        rows.append(jgx_s[i])
        rhs.append(jgp_s[i] - (dubg[i] if act_g[i] == 1 else dlbg[i]))
    for i in np.flatnonzero(act_x):
        e = np.zeros(nx)
        e[i] = 1.0
        rows.append(e)
        rhs.append(-(dlbx[i] if act_x[i] == -1 else dubx[i]))
    A = np.array(rows).reshape(-1, nx)
    Ap = np.array(rhs).reshape(-1, np_)
    m = A.shape[0]
    K = np.block([[h_s, A.T], [A, np.zeros((m, m))]])
    R = -np.vstack([hxp_s, Ap])
    cond = float(np.linalg.cond(K))
    if np.isfinite(cond) and cond < 1e12:
        sol = np.linalg.solve(K, R)
    else:
        sol = np.linalg.lstsq(K, R, rcond=None)[0]
    dx_dp_s = sol[:nx]
    # physical units
    x = x_s * xsc
    out: dict[str, Any] = {
        "x": x, "p": p, "g": g_s * csc,
        "lbx": np.asarray(b["lbx"]) * xsc, "ubx": np.asarray(b["ubx"]) * xsc,
        "lbg": np.asarray(b["lbg"]) * csc, "ubg": np.asarray(b["ubg"]) * csc,
        "lam_x": lam_x_s / xsc, "lam_g": lam_g_s / csc,
        "jac_g_x": csc[:, None] * jgx_s / xsc[None, :], "jac_g_p": csc[:, None] * jgp_s,
        "grad_f": gf_s.ravel() / xsc, "hess_lag": h_s / np.outer(xsc, xsc), "hess_lag_xp": hxp_s / xsc[:, None],
        "dx_dp": xsc[:, None] * dx_dp_s,
        "objective": np.float64(f.item()),
    }
    # per wheel: wrench and its exact Jacobian (AD graph), slip, slip angle, torque, power
    nw = len(lay.wheels)
    wr, wj = np.zeros((nw, 6)), np.zeros((nw, 6, 5))
    slip, sang, torque, power = (np.zeros(nw) for _ in range(4))
    for k, wname in enumerate(lay.wheels):
        om, beta, _, h, h0 = (x[lay.var(v, wname)] for v in ("omega", "beta", "W", "h", "h0"))
        contact = p[lay.index(f"contact {wname}")]
        if contact == 0.0:
            sang[k] = beta
            continue
        vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, beta)
        w6, J = pb.wheel_function(wname)(np.array([vx, vy, om, h, h0], dtype=float))  # hub drag included
        wr[k], wj[k] = np.asarray(w6).ravel(), np.asarray(J)
        d = pb.model_of[wname].wrench(vx, vy, om, h, h0)
        slip[k], sang[k] = float(d.slip), float(d.beta)
        torque[k] = -wr[k, 4]
        power[k] = torque[k] * om
    out.update(wrench=wr, wrench_jac=wj, slip=slip, slip_angle=sang, torque=torque, power=power)
    out["active_x"], out["active_g"] = act_x, act_g
    out["kkt_cond"] = np.float64(cond)
    if not spec.build.defer_resolves:
        out.update(point_resolves(spec, sc, x_s, lam_x_s, lam_g_s, out))
    return out


RESOLVE_FIELDS = ("controllers", "controller_source", "trust_radius", "trust_unverified")
"""The fields of a point's data that come from NLP re-solves around its primitive
(:func:`point_resolves`); with ``build.defer_resolves`` they are computed once, for the final
primitive, by :func:`_resolve_pass`."""


def point_resolves(spec: TableSpec, sc: Any, x_s: NDArray[np.float64], lam_x_s: NDArray[np.float64],
                   lam_g_s: NDArray[np.float64], data: Mapping[str, Any]) -> dict[str, Any]:
    """The table fields of one solved point that come from NLP re-solves around it
    (:data:`RESOLVE_FIELDS`): the steering controllers of section 7.2.4 (eqs. (7.26)-(7.27)) and
    the per-parameter trust radius (:func:`point_trust_radius`).

    ``data``: the point's other data (:func:`point_data`: ``x``, ``p``, ``dx_dp`` in physical
    units). Deterministic in ``(x_s, lam_x_s, lam_g_s)``: computed when the point is solved or
    later for the same primal-dual point, the numbers are the same.
    """
    pb = _problem(sc, spec.solver)
    lay: NlpLayout = pb.layout
    xsc = lay.variable_scale
    b = pb.bounds(sc)
    p = np.asarray(data["p"], dtype=float)
    nw = len(lay.wheels)
    out: dict[str, Any] = {}
    # steering controllers of section 7.2.4: +-offset re-solves minus the primitive, per unit offset
    ctl = np.zeros((len(CONTROLLER_NAMES), nw, 2))
    src = np.zeros(len(CONTROLLER_NAMES), dtype=np.int8)
    for c, name in enumerate(CONTROLLER_NAMES):
        par = "mz_offset" if name.startswith("Mz") else "fy_offset"
        mag = spec.build.mz_offset if par == "mz_offset" else spec.build.fy_offset
        sgn = 1.0 if name.endswith("+") else -1.0
        b2 = dict(b)
        b2["p"] = p.copy()
        b2["p"][lay.index(par)] += sgn * mag
        r = pb.solve(b2, x_s, lam_x_s, lam_g_s)
        if r["success"]:
            dx = (np.asarray(r["x"]) - x_s) * xsc / (sgn * mag)
        else:
            dx = np.asarray(data["dx_dp"])[:, lay.index(par)]
            src[c] = 1
        for k, wname in enumerate(lay.wheels):
            ctl[c, k] = (dx[lay.var("omega", wname)] * pb.rs_of[wname], dx[lay.var("beta", wname)])
    out["controllers"] = ctl
    out["controller_source"] = src
    out["trust_radius"], out["trust_unverified"] = point_trust_radius(spec, pb, sc, x_s, lam_x_s, lam_g_s,
                                                                      np.asarray(data["x"]), np.asarray(data["dx_dp"]))
    return out


def point_trust_radius(spec: TableSpec, pb: Any, sc: Any, x_s: NDArray[np.float64], lam_x: NDArray[np.float64],
                       lam_g: NDArray[np.float64], x: NDArray[np.float64],
                       dx_dp: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per parameter, the step over which the first-order prediction ``x + dx/dp dp`` stays within
    ``trust_tolerance`` (of the variable scales) of the NLP's solution at ``p + dp``.

    A step ``d`` is *verified* when a re-solve of the NLP at ``p + d`` started at the prediction
    ``x + dx/dp d`` converges and lands within the tolerance of it (:func:`_prediction_error`:
    one IPOPT run warm-started there with the primitive's multipliers and, if that does not
    converge, one from the same point with IPOPT's own dual initialisation, each with
    ``build.trust_max_iter`` iterations; no further search: a step whose re-solve from the
    prediction does not converge is not verified). Every radius returned for a sign is a
    verified step of that sign, and the radius is the smaller of the two signs.

    Search (issue 22, second cut): one probe and one verification per sign instead of a
    bisection on a ladder. Where the active set does not change, the prediction's error is the
    second-order term ``x_pp d^2 / 2``: quadratic in the step and the same for both signs. So the
    error ``e0`` at the probe ``+d0`` (``d0``: the middle of the ladder ``build.trust_search``,
    1/4 of the parameter scale by default) predicts the radius
    ``d0 sqrt(TRUST_MARGIN tol / e0)`` (at most the ladder's largest step), and one re-solve at
    that step verifies it (the minus sign: with the plus sign's ``e0``, no probe of its own). A
    verification that fails (a kink: the active set changes inside the step) shrinks the step by
    the same law from its own error (at most 4 times; by half when it did not converge); the
    probe ``d0`` itself, when it passed, is the plus sign's fall-back. A sign whose probe or
    shrinking finds no verified step falls back to the former search (:func:`_ladder_radius`:
    bisection on the ladder, the linear law from the smallest step, the optimizer's per-run
    budget at the smallest step). A speed step that would leave less than a quarter of the
    travel speed is not verified.

    Measured (``tests/bench/results_new_failure.md``, 2026-11-27 section): about 3 re-solves
    per parameter instead of 6, most of them converging (the ladder's failing upper probes cost
    ``build.trust_max_iter`` iterations twice).

    Returns ``(radius, unverified)``: ``unverified`` is 1 where no re-solve of that parameter
    succeeded at any step (both signs); its radius is then the documented fallback, the
    smallest ladder step ``d_min`` (1/16 of the parameter scale by default), neither 0 nor NaN.
    Parameters that are not continuous (contact, pivot lock) get radius 0 (the QP must not
    move them) and are not flagged.
    """
    lay = pb.layout
    xsc = lay.variable_scale
    tol = spec.build.trust_tolerance
    ladder = tuple(sorted(spec.build.trust_search))
    radius, unverified = np.zeros(lay.np_), np.zeros(lay.np_)
    for name in _LIN_PARAMS:
        j = lay.index(name)
        scale = lay.parameters[j].scale
        cap, d0 = ladder[-1] * scale, ladder[(len(ladder) - 1) // 2] * scale

        def err(d: float, its: int | None = None) -> float:
            return _prediction_error(spec, pb, sc, name, d, lam_x, lam_g, x, dx_dp[:, j], xsc, its)

        best, solved_any = math.inf, False
        e0 = math.inf  # error at the probe +d0 (the quadratic law's anchor)
        for sgn in (1.0, -1.0):
            r, fallback = math.nan, math.nan  # this sign's verified radius; a verified smaller step
            if sgn > 0:
                e0 = err(d0)
                solved_any = solved_any or math.isfinite(e0)
                if e0 <= tol:
                    fallback = d0
            law = e0 if math.isfinite(e0) else math.nan
            if law == law:
                step = cap if law <= 0.0 else min(cap, d0 * math.sqrt(TRUST_MARGIN * tol / law))
                if e0 <= tol:  # the probe passed: its step on both sides (the law is even in d)
                    step = max(step, d0)
                for _ in range(5):
                    if sgn > 0 and step == d0:
                        e = e0
                    else:
                        e = err(sgn * step)
                        solved_any = solved_any or math.isfinite(e)
                    if e <= tol:
                        r = step
                        break
                    # a smaller step from the growth law through (d0, e0) and this step (the
                    # exponent fitted between 1, linear past a kink, and 4; 2 without a fit)
                    k = 2.0
                    if math.isfinite(e) and step > d0 and 0.0 < law < e:
                        k = min(4.0, max(1.0, math.log(e / law) / math.log(step / d0)))
                    nxt = step * (min(0.9, max(0.25, (TRUST_MARGIN * tol / e) ** (1.0 / k)))
                                  if math.isfinite(e) else 0.5)
                    if fallback == fallback and nxt <= fallback:
                        r = fallback  # the probe passed: a verified step, no more re-solves
                        break
                    step = nxt
            if r != r:  # nothing verified by the law: the former ladder search for this sign
                known = {(len(ladder) - 1) // 2: e0} if sgn > 0 else {}  # the probe is a ladder step: not re-solved
                r, solved = _ladder_radius(spec, pb, sc, name, sgn, ladder, scale, lam_x, lam_g, x, dx_dp[:, j], xsc,
                                           known)
                solved_any = solved_any or solved
            best = min(best, r)
        if not solved_any or not math.isfinite(best):
            radius[j], unverified[j] = ladder[0] * scale, 1.0
        else:
            radius[j] = best
    return radius, unverified


TRUST_MARGIN = 0.5
"""Fraction of the tolerance the quadratic law aims at when it predicts a trust radius
(:func:`point_trust_radius`): the step ``d0 sqrt(TRUST_MARGIN tol / e0)``, about 0.7 of the
law's radius, so that a verification rarely fails on a law that holds only approximately."""


def _ladder_radius(spec: TableSpec, pb: Any, sc: Any, name: str, sgn: float, ladder: tuple[float, ...], scale: float,
                   lam_x: NDArray[np.float64], lam_g: NDArray[np.float64], x: NDArray[np.float64],
                   col: NDArray[np.float64], xsc: NDArray[np.float64],
                   known: Mapping[int, float] | None = None) -> tuple[float, bool]:
    """The former trust-radius search of one parameter and sign (the fall-back of
    :func:`point_trust_radius`): bisection on the ladder for the largest verified step (the
    error taken as growing with the step); when no step passes, ``d tol / e`` from the smallest
    step ``d`` that was re-solved (error ``e``, the linear growth law), re-solved there and
    shrunk (by 0.9 tol / e, at most to half) while its error exceeds the tolerance, at most 3
    times; if no re-solve converged, the smallest step is re-solved once more from the
    prediction with the optimizer's per-run budget ``solver.max_iter`` (measured at 3
    rim-speed-cap points: such re-solves converge in 52-116 iterations to a point 1-20 variable
    scales from the prediction, so the radius is tiny, not the fallback). ``known``: errors of
    ladder steps (index -> error) already re-solved with ``build.trust_max_iter`` (IPOPT is
    deterministic: the same run is not made twice; measured on README's worked example, the
    probe's re-solve that did not converge was otherwise repeated at every point whose slope or
    cross-slope radius ends below the ladder). Returns the radius (inf: nothing converged) and
    whether any re-solve converged."""
    tol = spec.build.trust_tolerance
    cache: dict[int, float] = dict(known or {})  # ladder index -> error (inf: no re-solve)

    def err(k: int, its: int | None = None) -> float:
        if k not in cache:
            cache[k] = _prediction_error(spec, pb, sc, name, sgn * ladder[k] * scale, lam_x, lam_g, x, col, xsc, its)
        return cache[k]

    lo, hi = -1, len(ladder)  # invariant: lo passes (or -1), hi fails (or len)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if err(mid) <= tol:
            lo = mid
        else:
            hi = mid
    if lo >= 0:
        return ladder[lo] * scale, True
    err(0)
    if not any(math.isfinite(e) for e in cache.values()):
        # nothing converged within build.trust_max_iter: the smallest step once more
        # with the optimizer's per-run budget (its error sizes the radius)
        del cache[0]
        err(0, spec.solver.max_iter if spec.solver is not None else None)
    done = sorted(k for k, e in cache.items() if math.isfinite(e))
    r = ladder[done[0]] * scale * tol / cache[done[0]] if done else math.inf
    # the linear law is an estimate: re-solve at r and shrink while it fails (at most 3
    # re-solves; measured on a nominal point: 0.021 > 0.02 at the law's cross-slope
    # radius, which `tables verify` rejected)
    for _ in range(3 if math.isfinite(r) else 0):
        e_r = _prediction_error(spec, pb, sc, name, sgn * r, lam_x, lam_g, x, col, xsc)
        if e_r <= tol:
            break
        r *= min(0.5, 0.9 * tol / e_r) if math.isfinite(e_r) else 0.5
    return r, bool(done)


def _prediction_error(spec: TableSpec, pb: Any, sc: Any, name: str, d: float, lam_x: NDArray[np.float64],
                      lam_g: NDArray[np.float64], x: NDArray[np.float64], col: NDArray[np.float64],
                      xsc: NDArray[np.float64], max_iter: int | None = None) -> float:
    """Largest ``|x + col d - x*(p + d)| / scale``, ``x*`` re-solved from the prediction
    ``x + col d`` with ``max_iter`` (default ``build.trust_max_iter``) iterations per run
    (:func:`point_trust_radius`); inf when the re-solve does not converge."""
    kw: dict[str, Any] = {name: getattr(sc, name) + d}
    if name == "speed":
        if sc.speed + d < 0.25 * sc.speed:
            return math.inf
        kw.update(_fam_follow(spec, sc, sc.speed + d))
    b2 = pb.bounds(replace(sc, **kw))
    pred = x + col * d
    its = spec.build.trust_max_iter if max_iter is None else max_iter
    r = pb.solve(b2, pred / xsc, lam_x, lam_g, max_iter=its)  # warm: the primitive's multipliers
    if not r["success"]:
        r = pb.solve(b2, pred / xsc, max_iter=its)  # IPOPT's own dual initialisation
    if not r["success"]:
        return math.inf
    return float(np.max(np.abs(pred - np.asarray(r["x"], dtype=float) * xsc) / xsc))


def _fam_follow(spec: TableSpec, sc: Any, speed: float) -> dict[str, Any]:
    """Scenario fields that follow the speed in a family (a cap given as a fraction of it)."""
    fam = spec.family
    if fam is None or fam["axis"] != "rim_speed_cap_fraction":
        return {}
    w = fam["wheel"]
    frac = sc.failure(w).rim_speed_max / sc.speed
    return {"failures": {**sc.failures, w: replace(sc.failure(w), rim_speed_max=frac * speed)}}


def _solve_point(spec: TableSpec, flat: int, x0: NDArray[np.float64] | None,
                 op: Mapping[str, float] | None = None, data: bool = True, solver: Any = None) -> dict[str, Any]:
    """Solve one point (grid index ``flat`` or operating point ``op``) from ``x0`` (with the
    spec's solver options, or ``solver``); with ``data`` the table's per-point data too
    (:func:`point_data`)."""
    from . import primitives as P

    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat) if op is None else op)
    r = P.solve_primitive(sc, spec.solver if solver is None else solver, x0=x0)
    rec: dict[str, Any] = {"flat": flat, "status": r.status, "iterations": int(r.stats.get("iterations", 0)),
                           "evidence": encode(r.evidence) if r.status != "optimal" else None}
    if r.status == "optimal":
        lam_x = np.asarray(r.stats["lam_x"], dtype=float).ravel()
        lam_g = np.asarray(r.stats["lam_g"], dtype=float).ravel()
        rec["x_scaled"] = np.asarray(r.x, dtype=float)
        rec["lam_x"], rec["lam_g"] = lam_x, lam_g
        rec["data"] = point_data(spec, sc, rec["x_scaled"], lam_x, lam_g) if data else {}
    return rec


def solve_chain(spec: TableSpec, chain: Sequence[int]) -> list[dict[str, Any]]:
    """Solve the grid points of one chain in order, each warm-started from the last solved one."""
    out, x0 = [], None
    for flat in chain:
        rec = _solve_point(spec, flat, x0)
        if rec["status"] == "optimal":
            x0 = rec["x_scaled"]
        out.append(rec)
    return out


def speed_twin(grid: GridSpec, flat: int) -> int | None:
    """The grid point that differs from ``flat`` only in speed and is at the grid's first speed
    (None when ``flat`` is at the first speed or the grid has fewer than two speeds)."""
    if "speed" not in grid.names or len(grid.values("speed")) < 2:
        return None
    idx = [int(i) for i in np.unravel_index(flat, grid.shape)]
    a = grid.names.index("speed")
    if idx[a] == 0:
        return None
    idx[a] = 0
    return int(np.ravel_multi_index(idx, grid.shape))


def twin_resolve(spec: TableSpec, flat: int, twin: Mapping[str, Any]) -> dict[str, Any] | None:
    """The primitive at ``flat`` from the solved point ``twin`` that differs from it only in
    speed, or None if it does not verify.

    (7.25) scales exactly with the travel speed on this rate-independent soil model: every
    wheel's omega and every bound on it (motor limit (7.2), a rim-speed cap given as a fraction
    of the speed) scale with it, all other variables, constraint rows and the objective are
    unchanged (measured on the shipped rim-speed-cap table: the scaled optimum violates the
    other speed's constraints by 2e-9 scaled, its objective differs by < 1e-8). The twin's
    optimum moved by its sensitivity (exact in speed, :func:`predicted_start`) and its
    multipliers (those of the omega bounds divided by the speed ratio) start one warm IPOPT run
    of ``build.trust_max_iter`` iterations; the point is accepted only if that run converges
    and passes the optimizer's independent numeric check."""
    from . import primitives as P

    op, op_t = spec.grid.point(flat), spec.grid.point(int(twin["flat"]))
    sc = scenario_at(spec.scenario, spec.family, op)
    pb = _problem(sc, spec.solver)
    lay = pb.layout
    x0 = predicted_start(spec, twin, op_t, op)
    lam_x = np.asarray(twin["lam_x"], dtype=float).copy()
    om = [lay.var("omega", w) for w in lay.wheels]
    lam_x[om] /= op["speed"] / op_t["speed"]
    r = pb.solve(pb.bounds(sc), x0, lam_x, twin["lam_g"], max_iter=spec.build.trust_max_iter)
    if not r["success"] or not P.check_solution(pb, sc, r["x"])[1]:
        return None
    x, lx, lg = (np.asarray(r[k], dtype=float) for k in ("x", "lam_x", "lam_g"))
    return {"flat": flat, "status": "optimal", "iterations": int(r["iterations"]), "evidence": None,
            "speed_twin_of": int(twin["flat"]), "x_scaled": x, "lam_x": lx, "lam_g": lg,
            "data": point_data(spec, sc, x, lx, lg)}


def predicted_start(spec: TableSpec, rec: Mapping[str, Any], op_from: Mapping[str, float],
                    op_to: Mapping[str, float]) -> NDArray[np.float64]:
    """Warm start (scaled) for ``op_to`` from the solved point ``rec`` at ``op_from``: its primitive
    moved by its sensitivity, ``x + dx/dp (p_to - p_from)`` over the NLP parameters among the axes
    (slope, cross-slope, speed; exact in speed on this rate-independent model), so the new point
    continues the same branch of (7.25); a family axis (not an NLP parameter) adds nothing."""
    d = rec["data"]
    lay = _problem(spec.scenario, spec.solver).layout
    dp = np.zeros(lay.np_)
    for k in ("slope", "cross_slope", "speed"):
        if k in op_to and k in op_from:
            dp[lay.index(k)] = float(op_to[k]) - float(op_from[k])
    return (np.asarray(d["x"]) + np.asarray(d["dx_dp"]) @ dp) / lay.variable_scale


def polish_point(spec: TableSpec, flat: int, f_now: float, starts: Sequence[tuple[Any, ...]],
                 x_now: NDArray[np.float64] | None = None) -> dict[str, Any] | None:
    """Re-solve a solved grid point from each neighbour's predicted start (``(flat, x0)``, fixed
    order; :func:`predicted_start`) and return the record of the best optimum found if it beats
    the current one (``f_now``, scaled ``x_now``), else None.

    A start ``(flat, x0, lam_x, lam_g)`` also carries the neighbour's (scaled) multipliers: that
    run is IPOPT's warm start from the primal-dual point with ``build.polish_max_iter``
    iterations (``build.polish_warm``); a 2-tuple start is a cold run with the solver's budget.

    Better = lower objective by more than 1e-6 relative; at an equal objective (within that),
    a different point whose steering angles (scaled, in layout order FR, FL, RR, RL) are
    lexicographically lower (the first one differing by more than 1e-3 is lower): mirrored
    optima have equal objectives (measured: beta FR, FL = -0.494, +0.494 rad and +0.494, -0.494
    rad at 20 deg slope, 0 cross-slope), and this fixed preference puts every grid point on the
    same one. Candidates must
    pass the optimizer's independent check. The NLP (7.25) has several local optima (a wheel at
    the motor limit, mirrored steering), and chains solved independently can settle on
    different ones; taking the neighbours' better optimum makes adjacent grid points lie on the
    same branch, which is what interpolation between them needs. The order is strict, so sweeps
    cannot cycle."""
    from . import primitives as P

    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    pb = _problem(sc, spec.solver)
    lay = pb.layout
    ib = [lay.var("beta", w) for w in lay.wheels]
    b = pb.bounds(sc)
    tol_f = 1e-6 * max(abs(f_now), 1e-3)

    def better(f: float, x: NDArray[np.float64], f0: float, x0: NDArray[np.float64] | None) -> bool:
        if f < f0 - tol_f:
            return True
        if x0 is None or f > f0 + tol_f:
            return False
        return steering_lower(x, x0, ib)

    best, its = None, 0
    for start in starts:
        nb, x0 = start[0], start[1]
        if len(start) == 4:  # warm: the neighbour's multipliers, a smaller budget
            r = pb.solve(b, x0, start[2], start[3], max_iter=spec.build.polish_max_iter)
        else:
            r = pb.solve(b, x0)
        its += int(r["iterations"])
        if not r["success"] or not better(r["f"], r["x"], f_now, x_now):
            continue
        if (best is None or better(r["f"], r["x"], best[1]["f"], best[1]["x"])) and P.check_solution(pb, sc, r["x"])[1]:
            best = (nb, r)
    if best is None:
        return None
    nb, r = best
    x, lx, lg = (np.asarray(r[k], dtype=float) for k in ("x", "lam_x", "lam_g"))
    return {"flat": flat, "status": "optimal", "iterations": its, "evidence": None, "polished_from": nb,
            "x_scaled": x, "lam_x": lx, "lam_g": lg, "data": point_data(spec, sc, x, lx, lg)}


def steering_lower(x: NDArray[np.float64], x0: NDArray[np.float64], ib: Sequence[int]) -> bool:
    """The neighbour pass's tie-break between two optima of equal objective (:func:`polish_point`):
    whether ``x``'s steering angles (scaled, entries ``ib`` in layout order) are lexicographically
    lower than ``x0``'s, the first one differing by more than 1e-3 deciding. Steering angles do
    not scale with the speed, so the rule compares speed twins as they are."""
    d = np.asarray(x)[list(ib)] - np.asarray(x0)[list(ib)]
    k = np.flatnonzero(np.abs(d) > 1e-3)
    return bool(k.size) and bool(d[k[0]] < 0)


def tie_tolerance(f0: float) -> float:
    """Objectives within this of ``f0`` tie (1e-6 relative, 1e-9 absolute at least): the rule of the
    neighbour pass (:func:`polish_point`) and of the twin pass (:func:`_twin_pass`)."""
    return 1e-6 * max(abs(f0), 1e-3)


TWIN_AGREE = 1e-6
"""Speed twins whose primitives, one scaled exactly to the other's speed (:func:`scaled_to_speed`),
differ by at most this many variable scales hold the same optimum (rounding level: the shipped
tables' twins agree within 1e-6 scales); beyond it :func:`_twin_pass` carries the group's chosen
optimum to a tied member."""


def scaled_to_speed(spec: TableSpec, x_scaled: NDArray[np.float64], v_from: float, v_to: float) -> NDArray[np.float64]:
    """A primitive (scaled variables) at travel speed ``v_from`` scaled exactly to ``v_to``: every
    wheel's omega times the speed ratio, everything else unchanged (the speed twins' rule,
    :func:`twin_resolve`)."""
    lay = _problem(spec.scenario, spec.solver).layout
    x = np.array(x_scaled, dtype=float)
    x[[lay.var("omega", w) for w in lay.wheels]] *= v_to / v_from
    return x


def _neighbours(shape: tuple[int, ...], flat: int) -> list[int]:
    idx = np.unravel_index(flat, shape)
    out = []
    for a in range(len(shape)):
        for d in (-1, 1):
            j = list(idx)
            j[a] += d
            if 0 <= j[a] < shape[a]:
                out.append(int(np.ravel_multi_index(j, shape)))
    return out


def retry_point(spec: TableSpec, flat: int, starts: Sequence[tuple[int, NDArray[np.float64], NDArray[np.float64],
                                                                 NDArray[np.float64]]]) -> dict[str, Any]:
    """Retry an unsolved point from each solved neighbour in turn (``(flat, x, lam_x, lam_g)``,
    fixed order): one warm-started IPOPT run each, accepted only if it converges and passes the
    optimizer's independent numeric check; ``not_found`` if none does."""
    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    r, nb, tried, its = first_checked_start(spec, flat, [(f"neighbour {nb}", nb, x0, lx, lg) for nb, x0, lx, lg in starts])
    if r is not None:
        x = np.asarray(r["x"], dtype=float)
        return {"flat": flat, "status": "optimal", "iterations": its, "evidence": None, "retried_from": nb,
                "x_scaled": x, "lam_x": np.asarray(r["lam_x"], dtype=float), "lam_g": np.asarray(r["lam_g"], dtype=float),
                "data": point_data(spec, sc, x, np.asarray(r["lam_x"], dtype=float), np.asarray(r["lam_g"], dtype=float))}
    return {"flat": flat, "status": "not_found", "iterations": its,
            "evidence": {"retries": tried or ["no solved neighbour to start from"]}}


def first_checked_start(spec: TableSpec, flat: int, starts: Sequence[tuple[str, Any, Any, Any, Any]]
                        ) -> tuple[dict[str, Any] | None, Any, list[str], int]:
    """One IPOPT run (the solver's ``max_iter``) from each start ``(label, tag, x0, lam_x, lam_g)``
    in turn at grid point ``flat``; the first that converges and passes the optimizer's independent
    numeric check wins. Returns ``(solver result or None, its tag, what each start gave, IPOPT
    iterations)``."""
    from . import primitives as P

    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    pb = _problem(sc, spec.solver)
    b = pb.bounds(sc)
    tried: list[str] = []
    its = 0
    for label, tag, x0, lx, lg in starts:
        r = pb.solve(b, x0, lx, lg)
        its += int(r["iterations"])
        ok = bool(r["success"]) and P.check_solution(pb, sc, r["x"])[1]
        tried.append(f"from {label}: {r['status']}{'' if ok or not r['success'] else ' (failed the independent check)'}")
        if ok:
            return r, tag, tried, its
    return None, None, tried, its


# ------------------------------------------------------------------------------ linearisation check
def linearisation_errors(spec: TableSpec, flat: int, data: Mapping[str, Any], x_s: NDArray[np.float64],
                         params: Sequence[str] = ("speed", "slope", "cross_slope", "fy_offset", "mz_offset"),
                         steps: Sequence[float] | None = None,
                         stop_above: float | None = None) -> dict[str, list[tuple[float, float]]]:
    """First-order prediction ``x + dx/dp dp`` against a re-solve of the NLP at ``p + dp``.

    Steps ascend; a parameter's sequence stops at the first failed re-solve or, with
    ``stop_above``, at the first error above it.

    Returns, per parameter, ``[(dp, error), ...]`` with the error the largest
    ``|x_pred - x_solved| / scale`` over the variables (NaN when the re-solve fails).
    """
    from . import primitives as P

    pb = _problem(spec.scenario, spec.solver)
    lay = pb.layout
    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    xsc = lay.variable_scale
    out: dict[str, list[tuple[float, float]]] = {}
    for name in params:
        j = lay.index(name)
        res = []
        for m in (steps or spec.build.trust_steps):
            dp = m * lay.parameters[j].scale
            kw: dict[str, Any] = {name: getattr(sc, name) + dp}
            if name == "speed":
                kw.update(_fam_follow(spec, sc, sc.speed + dp))
            r = P.solve_primitive(replace(sc, **kw), spec.solver, x0=x_s)
            if r.status != "optimal":
                res.append((dp, math.nan))
                break
            pred = data["x"] + data["dx_dp"][:, j] * dp
            res.append((dp, float(np.max(np.abs(pred - np.asarray(r.x) * xsc) / xsc))))
            if stop_above is not None and res[-1][1] > stop_above:
                break
        out[name] = res
    return out


def _trust_radius(errs: Mapping[str, list[tuple[float, float]]], tol: float) -> dict[str, float]:
    out = {}
    for name, res in errs.items():
        r = 0.0
        for dp, e in res:  # ascending steps: the radius ends at the first failure
            if not (e <= tol):
                break
            r = dp
        out[name] = r
    return out


# ------------------------------------------------------------------------------ orchestration
CODE_SOURCES = ("offline/physics", "offline/rover", "rtctl/layout.py", "rtctl/table.py")
"""Library sources (relative to the repository root) whose code determines a table's numbers;
their hash, with the library version, keys a build's checkpoints (:func:`code_hash`)."""


@functools.lru_cache(maxsize=1)
def code_hash() -> str:
    """sha256 of the library version and of every ``*.py`` file under :data:`CODE_SOURCES`
    (relative path and bytes, sorted), so checkpoints made by other code are not reused."""
    root = Path(__file__).resolve().parents[2]
    h = hashlib.sha256(f"offnominal-rover {_library_version()}\n".encode())
    files: list[Path] = []
    for rel in CODE_SOURCES:
        p = root / rel
        files.extend(sorted(p.rglob("*.py")) if p.is_dir() else [p])
    for f in sorted(files):
        h.update(f"\n{f.relative_to(root).as_posix()}\n".encode())
        h.update(f.read_bytes())
    return h.hexdigest()


class _Checkpoint:
    """Finished chains and retries of one build, one file each (atomic), keyed by the spec and
    by the library code (:func:`code_hash`).

    A folder of another spec is refused (the user changed the grid, scenario or options: keep
    it or delete it); a folder of the same spec written by other library code (or by a builder
    that did not record its code) is discarded with a message and the build starts afresh.
    """

    def __init__(self, folder: Path, key: str) -> None:
        self.folder, self.key = folder, key
        code = code_hash()
        if folder.exists():
            kf, cf_ = folder / "spec.sha256", folder / "code.sha256"
            if not kf.is_file() or kf.read_text().strip() != key:
                raise BuildError(f"{folder}: a partial build of a different spec (grid, scenario or options changed); "
                                 "delete this folder to start afresh, or rerun with the original options")
            old = cf_.read_text().strip() if cf_.is_file() else "none recorded"
            if old != code:
                old = old[:12] if cf_.is_file() else old
                print(f"note: {folder.name}: discarded the checkpoints of a partial build made by other library code "
                      f"(code hash {old}, now {code[:12]}); starting this table afresh")
                shutil.rmtree(folder)
        if not folder.exists():
            folder.mkdir(parents=True)
            write_text(folder / "spec.sha256", key)
            write_text(folder / "code.sha256", code)

    def _path(self, kind: str, i: int | str) -> Path:
        return self.folder / (f"{kind}_{i:06d}.npz" if isinstance(i, int) else f"{kind}_{i}.npz")

    def load(self, kind: str, i: int | str) -> list[dict[str, Any]] | None:
        p = self._path(kind, i)
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            head = json.loads(arrays.pop("header").tobytes().decode())
            if head.get("content_hash") != content_hash(head, arrays):
                raise ValueError("hash mismatch")
        except (OSError, ValueError, KeyError) as exc:
            p.unlink()  # a damaged checkpoint is recomputed, not trusted
            print(f"note: discarded damaged checkpoint {p.name} ({exc})")
            return None
        recs = head["records"]
        for r in recs:
            if r["status"] == "optimal":
                n = r["flat"]
                for k in ("x_scaled", "lam_x", "lam_g"):  # IPOPT's scaled solution
                    r[k] = arrays.pop(f"{n}#{k}")
                r["data"] = {k.split("/", 1)[1]: arrays[k] for k in arrays if k.startswith(f"{n}/")}
        return recs

    def save(self, kind: str, i: int | str, recs: list[dict[str, Any]]) -> None:
        arrays, meta = {}, []
        for r in recs:
            m = {k: v for k, v in r.items() if k not in ("x_scaled", "lam_x", "lam_g", "data")}
            meta.append(m)
            if r["status"] == "optimal":
                for k in ("x_scaled", "lam_x", "lam_g"):
                    arrays[f"{r['flat']}#{k}"] = r[k]
                for k, v in r["data"].items():
                    arrays[f"{r['flat']}/{k}"] = np.asarray(v)
        head = {"schema": SCHEMA + " checkpoint", "records": meta}
        write_bytes(self._path(kind, i), table_bytes(head, arrays))


def _executor(jobs: int, scheduler: str | None) -> tuple[cf.Executor | None, Any]:
    if scheduler:
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - dependency of the package
            raise BuildError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
        try:
            client = Client(scheduler, timeout="10s")
        except OSError as exc:
            raise BuildError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc}); check the address") from None
        return client.get_executor(pure=False), client
    if jobs <= 1:
        return None, None
    return cf.ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")), None


def _run(tasks: list[tuple[Callable[..., Any], tuple[Any, ...], int]], ex: cf.Executor | None,
         done: Callable[[int, Any], None]) -> None:
    """Run ``fn(*args)`` for every task; ``done(task_id, result)`` in the main process as each finishes."""
    if ex is None:
        for fn, args, tid in tasks:
            done(tid, fn(*args))
        return
    futs = {ex.submit(fn, *args): tid for fn, args, tid in tasks}
    for fut in cf.as_completed(futs):
        done(futs[fut], fut.result())


RUN_SEED_INDEX = ".seed-index-run.json"
"""The index of a :func:`build_tables` call's failure-free tables (``build.seed_index = "run"``),
written beside them in the output folder while the others are built, removed at the end."""


RUN_RECHECK_INDEX = ".recheck-index-{}.json"
"""The index (``.format(follower name)``) of the leader a :func:`build_tables` call built for a
*follower* (:func:`sibling_leaders`), whose primitives re-check the follower's search verdicts;
written in the output folder while the follower is built, removed at the end."""


def sibling_leaders(specs: Sequence[TableSpec]) -> dict[str, str]:
    """Follower name -> leader name among ``specs``: tables built with the continuation schedule
    that pose the same failures (:func:`~offline.rover.table_continuation.failure_tables`' rule:
    failure kinds and values, trench goal, rover and family; parameters and world may differ) are
    siblings, and every sibling but the one with the most grid points (ties: the first name) is
    a follower of it. E.g. ``rr_trench_clean_mu01`` (3 points on a soil of its own) follows
    ``rr_trench_clean`` (108 points): built after it, its search verdicts are re-checked from the
    leader's primitives at the same point, as they would be from a shipped sibling in a seed
    index, so a from-scratch folder build (``--seed-index none``) no longer loses the one optimum
    (15 mm) that only a sibling's start reaches."""
    from . import table_continuation as TC

    groups: dict[str, list[TableSpec]] = {}
    for s in specs:
        if s.build.schedule == "continuation":
            groups.setdefault(TC._failure_key(s.scenario, s.family), []).append(s)
    out: dict[str, str] = {}
    for g in groups.values():
        if len(g) > 1:
            lead = min(g, key=lambda s: (-s.grid.size, s.name))
            out.update({s.name: lead.name for s in g if s is not lead})
    return out


def seeds_others(spec: TableSpec) -> bool:
    """Whether ``spec``'s table can seed other tables' continuation (no failure, no trench goal,
    no family axis: :func:`~offline.rover.table_continuation.seed_tables`)."""
    sc = spec.scenario
    return spec.family is None and not sc.failures and sc.trench is None


def build_tables(specs: Sequence[TableSpec], out_dir: str | Path, jobs: int = 1, scheduler: str | None = None,
                 progress: bool = True, keep_partial: bool = False, inputs: Sequence[str | Path] = (),
                 on_done: Callable[[Path, dict[str, Any]], None] | None = None,
                 tables_at_once: int | None = None) -> list[tuple[Path, dict[str, Any]]]:
    """Build several tables with one pool of workers (each worker builds an NLP once and keeps it
    for every table that shares it); see :func:`build_table`.

    With a pool (``jobs > 1``) or a Dask cluster (``scheduler``) up to ``tables_at_once`` tables
    (default: all of them) are built at the same time, each from its own driver thread submitting
    to the shared workers: one table's schedule is a chain of dependent waves (its critical path
    bounds what any number of workers can do for it), so a sweep of many tables keeps a large
    cluster busy only when their waves interleave. Each table's file is the same, byte for byte,
    as when it is built alone (its tasks and their inputs do not depend on the others);
    ``on_done`` is called in the order of ``specs``. Without workers the tables are built one
    after another.

    Specs with ``build.seed_index = "run"`` are built in two stages: first those that can seed
    others (:func:`seeds_others`, built without seeds), then the rest, seeded from the first
    stage's files through a temporary index (:data:`RUN_SEED_INDEX`). Whatever the seed index, a
    sibling's follower (:func:`sibling_leaders`; siblings are always in the same stage) builds
    beside the others and, at its re-check of search verdicts, waits for its leader's file and
    re-checks also from it (a temporary index, :data:`RUN_RECHECK_INDEX`; its header's
    ``continuation.recheck_tables`` names it). ``on_done`` follows the stages (within each, the
    order of ``specs``, followers after the others). A file is then the same as when built alone
    after its seed tables (and, for a follower, its leader).
    """
    for spec in specs:  # every output and partial build checked before any work
        out = check_output_dir(out_dir, inputs=list(inputs), names=[f"{spec.name}.npz"])
        kf = out / f".{spec.name}.partial" / "spec.sha256"
        if kf.is_file() and kf.read_text().strip() != spec.key():
            raise BuildError(f"{kf.parent}: a partial build of a different spec (grid, scenario or options changed); "
                             "delete this folder to start afresh, or rerun with the original options")
    if tables_at_once is not None and tables_at_once < 1:
        raise BuildError(f"tables_at_once = {tables_at_once}: must be >= 1")
    run = [s.build.seed_index == "run" for s in specs]
    first = [s for s, r in zip(specs, run) if not r or seeds_others(s)]
    second = [s for s, r in zip(specs, run) if r and not seeds_others(s)]
    if not any(run) or not second:
        first, second = list(specs), []
    points: dict[str, int] = {}  # per NLP structure, the points of every table on it (compile_mode)
    for s in specs:
        points[structure_key(s)] = points.get(structure_key(s), 0) + s.grid.size
    shared = {s.name: points[structure_key(s)] for s in specs}
    ex, client = _executor(jobs, scheduler)
    built: list[tuple[Path, dict[str, Any]]] = []
    seed_ix = Path(out_dir) / RUN_SEED_INDEX
    try:
        built += _build_stage(first, out_dir, ex, client, progress, keep_partial, inputs, on_done, tables_at_once, None,
                              shared)
        if second:
            run_first = {s.name for s in first if s.build.seed_index == "run"}
            seeds = [pth for pth, _ in built if Path(pth).stem in run_first]
            ix = write_index(out_dir, seeds, index_name=RUN_SEED_INDEX) if seeds else None
            built += _build_stage(second, out_dir, ex, client, progress, keep_partial, inputs, on_done,
                                  tables_at_once, ix, shared)
    finally:
        seed_ix.unlink(missing_ok=True)
        if client is not None:
            client.close()
        elif ex is not None:
            ex.shutdown()
    return built


def _identity(p: Path) -> Path:
    return p


def _result_path(fut: cf.Future[tuple[Path, dict[str, Any]]]) -> Path:
    """The file of a table build's future (waits for it)."""
    return fut.result()[0]


def _build_stage(specs: Sequence[TableSpec], out_dir: str | Path, ex: cf.Executor | None, client: Any, progress: bool,
                 keep_partial: bool, inputs: Sequence[str | Path], on_done: Callable[[Path, dict[str, Any]], None] | None,
                 tables_at_once: int | None, run_index: Path | None,
                 shared: Mapping[str, int]) -> list[tuple[Path, dict[str, Any]]]:
    """The tables ``specs`` on the shared workers ``ex`` (:func:`build_tables`): leaders first; a
    follower (:func:`sibling_leaders`) builds beside the others and waits for its leader's file
    only at its re-check of search verdicts."""
    follows = sibling_leaders(specs)
    specs = [s for s in specs if s.name not in follows] + [s for s in specs if s.name in follows]
    at_once = 1 if ex is None else min(len(specs), tables_at_once or len(specs))
    built: list[tuple[Path, dict[str, Any]]] = []
    done: dict[str, Callable[[], Path]] = {}

    def one(spec: TableSpec) -> tuple[Path, dict[str, Any]]:
        rix = Path(out_dir) / RUN_RECHECK_INDEX.format(spec.name)

        def leader_index() -> Path:  # called by the follower's build at its re-check phase
            return write_index(out_dir, [done[follows[spec.name]]()], index_name=rix.name)

        try:
            return build_table(spec, out_dir, progress=progress, keep_partial=keep_partial, inputs=inputs, executor=ex,
                               run_index=run_index, structure_points=shared[spec.name],
                               recheck_index=leader_index if spec.name in follows else None)
        finally:
            rix.unlink(missing_ok=True)

    if at_once <= 1:
        for spec in specs:
            res = one(spec)
            done[spec.name] = functools.partial(_identity, res[0])
            built.append(res)
            if on_done is not None:
                on_done(*res)
        return built
    tp = cf.ThreadPoolExecutor(max_workers=at_once, thread_name_prefix="table")
    futs: list[cf.Future[tuple[Path, dict[str, Any]]]] = []
    try:
        for spec in specs:  # a follower is queued after its leader, so it never waits on a table not yet started
            fut = tp.submit(one, spec)
            done[spec.name] = functools.partial(_result_path, fut)
            futs.append(fut)
        for fut in futs:
            res = fut.result()
            built.append(res)
            if on_done is not None:
                on_done(*res)
    except BaseException:
        for fut in futs:
            fut.cancel()
        if client is None and ex is not None:  # the running tables' tasks end with the pool
            ex.shutdown(wait=False, cancel_futures=True)
        raise
    finally:
        tp.shutdown(wait=True)
    return built


def build_table(spec: TableSpec, out_dir: str | Path, jobs: int = 1, scheduler: str | None = None,
                progress: bool = True, keep_partial: bool = False,
                inputs: Sequence[str | Path] = (), executor: cf.Executor | None = None,
                run_index: Path | None = None, structure_points: int | None = None,
                recheck_index: Path | Callable[[], Path] | None = None) -> tuple[Path, dict[str, Any]]:
    """Build (or resume) one table and write ``<out_dir>/<name>.npz`` atomically.

    Runs on ``executor`` if given, else on ``jobs`` local processes or the Dask scheduler at
    ``scheduler``. Returns the path and a summary (grid points, statuses, feasible fraction,
    file size, retries, trust radius). Finished chains are checkpointed; a rerun resumes.
    ``run_index``: the seed index of ``build.seed_index = "run"`` (:func:`build_tables`);
    ``structure_points``: the points of every table of the call on ``spec``'s NLP structure
    (:func:`compile_mode`); ``recheck_index``: an index of tables built in the same call whose
    primitives also re-check this table's search verdicts (:func:`sibling_leaders`; only tables
    with the same failures are used), or a function returning it, called (and waited for) when
    the build reaches that re-check, so the rest of the build runs beside the leader's.
    """
    from tqdm import tqdm

    solver: Any = spec.solver
    if dataclasses.is_dataclass(solver) and not isinstance(solver, type) and hasattr(solver, "compile"):
        spec = replace(spec, solver=replace(solver, compile=compile_mode(spec, structure_points)))  # build.compile -> the NLP (not data)
    out = check_output_dir(out_dir, inputs=list(inputs), names=[f"{spec.name}.npz"])
    ck = _Checkpoint(out / f".{spec.name}.partial", spec.key())
    twin_of = {f: speed_twin(spec.grid, f) for f in range(spec.grid.size)} if spec.build.speed_twins else {}
    recs: dict[int, dict[str, Any]] = {}
    todo: list[tuple[Callable[..., Any], tuple[Any, ...], int]] = []
    continuation = spec.build.schedule == "continuation"
    seeds: tuple[str, ...] = ()
    same_failures: tuple[str, ...] = ()
    former: str | None = None
    if continuation:
        from . import table_continuation as TC

        index = _seed_index(spec.build.seed_index, run_index)
        seeds = TC.seed_tables(spec, index)
        fam_seeds = TC.family_seed_tables(spec, index)
        same_failures = TC.failure_tables(spec, index)
        if isinstance(recheck_index, Path):
            same_failures += tuple(p for p in TC.failure_tables(spec, recheck_index) if p not in same_failures)
        former = TC.former_table(spec, index)
        kind = "group"
        for i, g in enumerate(TC.group_points(spec.grid)):
            got = ck.load(kind, i)
            if got is not None:
                recs.update({r["flat"]: r for r in got})
                continue
            first = min(g, key=lambda f: (TC._speed_index(spec.grid, f), f))
            seed = TC.seed_start(spec, seeds, spec.grid.point(first))
            pseeds = {f: s for f in g if TC._speed_index(spec.grid, f) == 0
                      and (s := TC.point_seed(spec, fam_seeds, spec.grid.point(f))) is not None}
            todo.append((TC.continuation_group,
                         (spec, g, seed, seed is None and spec.build.relaxation_evidence, pseeds), i))
        seeds = seeds + tuple(f"{p} (mirrored)" if m else p for p, m in fam_seeds)
        # the groups that decide a relaxation first (one solve with the optimizer's default budgets,
        # about 13 CPU s each on README's worked example, where the others take a few) are submitted
        # first, so that no worker is left alone with one at the end of the phase; results are kept
        # by group, so the order changes no number
        todo.sort(key=lambda task: not task[1][3])
    else:
        kind = "chain"
        for i, c in enumerate(chains(spec.grid)):
            got = ck.load(kind, i)
            if got is not None:
                recs.update({r["flat"]: r for r in got})
            else:
                todo.append((solve_chain, (spec, c), i))
    bar = tqdm(total=spec.grid.size, initial=len(recs), desc=f"{spec.name}", unit="pt", disable=not progress,
               leave=True, dynamic_ncols=True)
    ex, client = (executor, None) if executor is not None else _executor(jobs, scheduler)
    try:
        def chain_done(i: int, res: list[dict[str, Any]]) -> None:
            ck.save(kind, i, res)
            recs.update({r["flat"]: r for r in res})
            bar.update(len(res))

        _run(todo, ex, chain_done)
        pending = {f for f in recs if recs[f].get("pending")}
        relax_known = {tuple(spec.grid.point(f).values()): recs[f]["relaxation_status"] for f in recs
                       if recs[f].get("relaxation_status")}  # by operating point: refinement re-indexes
        # retry unsolved points from solved neighbours (phase-1 results only: deterministic)
        unsolved = [f for f in sorted(recs) if recs[f]["status"] in ("not_found", "solver_failure")]
        if continuation:  # one member of a speed-twin group is retried; the search carries its result
            unsolved = [f for f in unsolved if not (f in pending and speed_twin(spec.grid, f) in pending)]
        retry_tasks, retried = [], {}
        # (point, neighbour) pairs whose run from the neighbour's primal-dual point is done: IPOPT is
        # deterministic, so the same run again gives the same failure (not repeated)
        tried_pairs = {(f, nb) for f in recs for nb in recs[f].get("tried_neighbours", ())}
        for f in unsolved:
            starts = [(nb, recs[nb]["x_scaled"], recs[nb]["lam_x"], recs[nb]["lam_g"])
                      for nb in _neighbours(spec.grid.shape, f) if recs[nb]["status"] == "optimal"][:MAX_RETRY_NEIGHBOURS]
            new = [s for s in starts if (f, s[0]) not in tried_pairs]
            tried_pairs.update((f, s[0]) for s in new)
            if starts and not new:  # every start already run: the record's evidence says so
                continue
            starts = new
            got = ck.load("retry", f)
            if got is not None:
                retried[f] = got[0]
                continue
            retry_tasks.append((retry_point, (spec, f, starts), f))
        if retry_tasks:
            bar.set_description(f"{spec.name} (retrying {len(retry_tasks)})")

        def retry_done(f: int, rec: dict[str, Any]) -> None:
            ck.save("retry", f, [rec])
            retried[f] = rec

        _run(retry_tasks, ex, retry_done)
        for f, rec in retried.items():
            rec = dict(rec)
            rec["evidence"] = {"first attempt": recs[f]["evidence"], **(rec.get("evidence") or {})} \
                if rec["status"] != "optimal" else None
            recs[f] = rec
        searched = 0
        if continuation:
            searched = _search_pass(spec, recs, pending, ck, ex, bar)
        if twin_of:
            bar.set_description(f"{spec.name} (speed twins)")
            _twin_pass(spec, recs, twin_of, ck, ex, "twin")
        if continuation and callable(recheck_index):
            bar.set_description(f"{spec.name} (waiting for its sibling's table)")
            same_failures += tuple(p for p in TC.failure_tables(spec, recheck_index()) if p not in same_failures)
        bar.set_description(f"{spec.name} (re-checking infeasible verdicts)")
        rechecked = _recheck_infeasible(spec, recs, ck, ex, tried_pairs, twin_of if continuation else None,
                                        same_failures)
        polished = _polish(spec, recs, ck, ex, bar, twin_of, former)
        relaxed = 0
        if spec.build.relaxation_evidence:
            bar.set_description(f"{spec.name} (relaxations)")
            relaxed = _relaxation_pass(spec, recs, ck, ex)
        refinement = None
        refined_twins = 0
        if spec.refine is not None:
            from .table_refine import refine_grid

            bar.close()
            spec, recs, refinement = refine_grid(spec, recs, ck, ex, progress)
            if spec.build.speed_twins:
                # refine_grid solves each new point on its own: one primitive per speed-twin group
                # again on the refined grid (issue 22/23: 4 groups of a from-scratch nominal held a
                # worse optimum at one speed on inserted axis values)
                twins = {f: speed_twin(spec.grid, f) for f in range(spec.grid.size)}
                refined_twins = _twin_pass(spec, recs, twins, ck, ex, "twin_refined")
            if spec.build.relaxation_evidence:  # the points refinement added get the same evidence
                relaxed += _relaxation_pass(spec, recs, ck, ex)
        if continuation:
            from .table_continuation import hole_reason

            for f in sorted(recs):
                if recs[f]["status"] == "not_found":
                    ev = dict(recs[f].get("evidence") or {})
                    ev["undecided"] = hole_reason(spec, f, relax_known.get(tuple(spec.grid.point(f).values())))
                    recs[f] = {**recs[f], "evidence": ev}
        if spec.build.defer_resolves:
            bar.set_description(f"{spec.name} (controllers and trust radii)")
            _resolve_pass(spec, recs, ck, ex)
    finally:
        bar.close()
        if executor is None:
            if client is not None:
                client.close()
            elif ex is not None:
                ex.shutdown()
    header, arrays = _assemble(spec, recs, refinement)
    if continuation:
        header["continuation"] = _continuation_header(spec, recs, seeds, searched, same_failures, former)
    path = out / f"{spec.name}.npz"
    blob = table_bytes(header, arrays)
    write_bytes(path, blob)
    if not keep_partial:
        shutil.rmtree(ck.folder, ignore_errors=True)
    st = [recs[f]["status"] for f in range(spec.grid.size)]
    summary = {"name": spec.name, "grid_points": spec.grid.size, "shape": spec.grid.shape,
               "statuses": {s: st.count(s) for s in STATUS_NAMES if st.count(s)},
               "feasible_fraction": st.count("optimal") / spec.grid.size, "bytes": len(blob),
               "retried": len(retried), "rechecked": rechecked, "polished": polished, "relaxed": relaxed, "trust_radius": header["trust_radius"],
               "refinement": header.get("refinement"), "refined_twins": refined_twins, "searched": searched,
               "continuation": header.get("continuation", {}).get("counts")}
    return path, summary


def _seed_index(choice: str, run_index: Path | None = None) -> Path | None:
    """The index whose failure-free tables seed a continuation build (``BuildOptions.seed_index``);
    ``"run"``: ``run_index``, the index of the tables :func:`build_tables` built first (None: no
    seeds, e.g. for those tables themselves)."""
    if choice == "none":
        return None
    if choice == "run":
        return run_index
    if choice == "shipped":
        from offnominal_tables import index_path

        return Path(index_path())
    return Path(choice)


def _search_pass(spec: TableSpec, recs: dict[int, dict[str, Any]], pending: set[int], ck: _Checkpoint,
                 ex: cf.Executor | None, bar: Any) -> int:
    """The full search for the points the continuation left unsolved (and the neighbour retries
    did not solve): one task per operating point of the axes other than speed
    (:func:`~offline.rover.table_continuation.search_group`). Returns the number of points searched."""
    from .table_continuation import search_group

    left = sorted(f for f in pending if recs[f]["status"] in ("not_found", "solver_failure"))
    groups: dict[int, list[int]] = {}
    for f in left:
        t = speed_twin(spec.grid, f)
        groups.setdefault(f if t is None else t, []).append(f)
    members: dict[int, list[int]] = {}
    for f in range(spec.grid.size):
        t = speed_twin(spec.grid, f)
        members.setdefault(f if t is None else t, []).append(f)
    tasks, got = [], {}
    for key in sorted(groups):
        c = ck.load("search", key)
        if c is not None:
            got[key] = c
        else:
            solved = [m for m in members[key] if recs[m]["status"] == "optimal"]
            tasks.append((search_group, (spec, groups[key], recs[solved[0]] if solved else None), key))
    if tasks:
        bar.set_description(f"{spec.name} (search: {len(left)} points)")

    def done(key: int, res: list[dict[str, Any]]) -> None:
        ck.save("search", key, res)
        got[key] = res

    _run(tasks, ex, done)
    for key in sorted(got):
        for rec in got[key]:
            f = rec["flat"]
            rec = dict(rec)
            if rec["status"] != "optimal":
                rec["evidence"] = {"continuation": recs[f].get("evidence"), **(rec.get("evidence") or {})}
            recs[f] = rec
    return len(left)


def _resolve_task(spec: TableSpec, flat: int, x_s: NDArray[np.float64], lam_x: NDArray[np.float64],
                  lam_g: NDArray[np.float64], data: Mapping[str, Any]) -> dict[str, Any]:
    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    return point_resolves(spec, sc, x_s, lam_x, lam_g, data)


def _resolve_pass(spec: TableSpec, recs: dict[int, dict[str, Any]], ck: _Checkpoint | None,
                  ex: cf.Executor | None) -> int:
    """The re-solve fields (:data:`RESOLVE_FIELDS`, :func:`point_resolves`) of every optimal
    point that lacks them (``build.defer_resolves``), one task per point, for the primitive the
    table holds now. Checkpointed with the primitive they belong to (a checkpoint of another
    primitive is recomputed). Returns the number of points computed."""
    tasks: list[tuple[Callable[..., Any], tuple[Any, ...], int]] = []
    for f in sorted(recs):
        r = recs[f]
        if r["status"] != "optimal" or all(k in r["data"] for k in RESOLVE_FIELDS):
            continue
        c = ck.load("resolves", f) if ck is not None else None
        if c is not None and np.array_equal(c[0]["x_scaled"], r["x_scaled"]) \
                and np.array_equal(c[0]["lam_x"], r["lam_x"]) and np.array_equal(c[0]["lam_g"], r["lam_g"]):
            r["data"] = {**r["data"], **{k: c[0]["data"][k] for k in RESOLVE_FIELDS}}
            continue
        small = {k: r["data"][k] for k in ("x", "p", "dx_dp")}
        tasks.append((_resolve_task, (spec, f, r["x_scaled"], r["lam_x"], r["lam_g"], small), f))

    def done(f: int, extra: dict[str, Any]) -> None:
        r = recs[f]
        if ck is not None:
            ck.save("resolves", f, [{"flat": f, "status": "optimal", "x_scaled": r["x_scaled"], "lam_x": r["lam_x"],
                                     "lam_g": r["lam_g"], "data": extra}])
        recs[f] = {**r, "data": {**r["data"], **extra}}

    _run(tasks, ex, done)
    return len(tasks)


FORMER = -2
"""The neighbour pass's tag of a start from the former table (:func:`_polish`; a grid point's is its
flat index, -1 means none)."""

RECHECK_WAVES = 4
"""Waves of :func:`_recheck_infeasible`: a point re-solved in one wave offers its primitive to its
still-infeasible neighbours in the next (each (point, neighbour) pair is tried once)."""


def search_verdict(rec: Mapping[str, Any]) -> bool:
    """Whether an ``infeasible`` record rests on a search (the optimizer's automatic start, its
    confirmation search, or a speed twin's such verdict) rather than on a relaxation's confirmed
    verdict (evidence key ``"relaxation"``: the failures only add constraints, a proof given the
    relaxation's verdict)."""
    return rec["status"] == "infeasible" and "relaxation" not in (rec.get("evidence") or {})


def table_retry(spec: TableSpec, flat: int, starts: Sequence[tuple[str, NDArray[np.float64], NDArray[np.float64],
                                                                 NDArray[np.float64]]]) -> dict[str, Any]:
    """Re-check a search's verdict at grid point ``flat`` from other tables' primal-dual points at
    the very point (``(source, x, lam_x, lam_g)``, scaled, fixed order;
    :func:`~offline.rover.table_continuation.table_start`): one IPOPT run (the solver's ``max_iter``)
    each, the first that converges and passes the optimizer's independent check is the point's
    primitive (``continued_from`` names the table); else status ``"none"`` with what each start
    gave (evidence ``"table re-solves"``)."""
    sc = scenario_at(spec.scenario, spec.family, spec.grid.point(flat))
    r, src, tried, its = first_checked_start(spec, flat, [(f"table {s}", s, x0, lx, lg) for s, x0, lx, lg in starts])
    if r is None:
        return {"flat": flat, "status": "none", "iterations": its, "evidence": {"table re-solves": tried}}
    x, lx, lg = (np.asarray(r[k], dtype=float) for k in ("x", "lam_x", "lam_g"))
    return {"flat": flat, "status": "optimal", "iterations": its, "evidence": None,
            "continued_from": f"table {src} at the same point (re-check of a search's verdict)",
            "x_scaled": x, "lam_x": lx, "lam_g": lg, "data": point_data(spec, sc, x, lx, lg)}


def _recheck_from_tables(spec: TableSpec, recs: dict[int, dict[str, Any]], ck: _Checkpoint | None,
                         ex: cf.Executor | None, tables: Sequence[str]) -> int:
    """Re-check every search verdict (``infeasible`` resting on a search, :func:`search_verdict`;
    ``not_found``; ``solver_failure``) from the primitives that tables with the same failures hold
    at the very point (``tables``: :func:`~offline.rover.table_continuation.failure_tables`, the
    former build of this table first), scaled exactly to the point's speed (:func:`table_retry`).

    Issue 22/23 (``tests/bench/results_tables.md``): the from-scratch rr_steer_stuck called (0 deg,
    +45 deg stuck) infeasible at both speeds, and rr_trench_clean_mu01 lost its single optimum,
    while the shipped tables' primitives there pass today's independent check. The neighbour
    re-check (:func:`_recheck_infeasible`) starts from this table's own neighbours only.

    Records updated in place (a kept verdict's evidence gains ``"table re-solves"``). Returns the
    number of points made optimal."""
    if not tables:
        return 0
    from .table_continuation import table_start

    tasks: list[tuple[Callable[..., Any], tuple[Any, ...], int]] = []
    got: dict[int, dict[str, Any]] = {}
    for f in sorted(recs):
        if not (search_verdict(recs[f]) or recs[f]["status"] in ("not_found", "solver_failure")):
            continue
        op = spec.grid.point(f)
        starts = [s for p in tables if (s := table_start(spec, p, op)) is not None]
        if not starts:
            continue
        c = ck.load("tables", f) if ck is not None else None
        if c is not None:
            got[f] = c[0]
            continue
        tasks.append((table_retry, (spec, f, [(src, x, lx, lg) for x, lx, lg, src in starts]), f))

    def done(f: int, rec: dict[str, Any]) -> None:
        if ck is not None:
            ck.save("tables", f, [rec])
        got[f] = rec

    _run(tasks, ex, done)
    solved = 0
    for f in sorted(got):
        rec = got[f]
        if rec["status"] == "optimal":
            recs[f] = rec
            solved += 1
        else:
            recs[f] = {**recs[f], "evidence": {**(recs[f].get("evidence") or {}), **(rec.get("evidence") or {})}}
    return solved


def _recheck_infeasible(spec: TableSpec, recs: dict[int, dict[str, Any]], ck: _Checkpoint | None,
                        ex: cf.Executor | None, tried_pairs: set[tuple[int, int]] | None = None,
                        twin_of: Mapping[int, int | None] | None = None, tables: Sequence[str] = ()) -> dict[str, int]:
    """Re-solve every ``infeasible`` verdict that rests on a search (:func:`search_verdict`) from
    its solved grid neighbours before accepting it.

    A search's "infeasible" is the optimizer's failure to find a feasible point from its own
    starts within its budgets, not a proof: on README's worked example the per-wheel NLP's
    search declared cross slope 10 deg, stuck -60 deg infeasible after 908 iterations where the
    inlined NLP's (the same functions to rounding) found a checked primitive
    (``tests/bench/results_nlp_structure.md``). A solved neighbour is a start on the branch the
    table already holds: each is tried in turn (its primitive moved by its sensitivity to this
    point, :func:`predicted_start`, with its multipliers; one IPOPT run of the solver's
    ``max_iter`` each, :func:`retry_point`), and the first that converges and passes the
    optimizer's independent numeric check replaces the verdict. In waves
    (:data:`RECHECK_WAVES`): a point re-solved in one wave is a start for its neighbours in the
    next; each wave uses the records as they were at its start (deterministic). A verdict no
    start overturns stays ``infeasible`` with the re-solves added to its evidence
    (``"neighbour re-solves"``). A relaxation's verdict is kept without a solve.

    ``tried_pairs``: ``(point, neighbour)`` pairs already run from the neighbour's primal-dual
    point (the continuation, the retries). A neighbour on the family axis (not an NLP parameter)
    has the predicted start of its own primitive, so that run is not repeated; along slope,
    cross slope and speed the predicted start is another start and is tried.

    ``twin_of`` (speed twins, :func:`speed_twin`): a verdict whose first-speed twin also rests on
    a search is not re-solved at its own speed (its neighbours' starts pose the same NLPs as the
    twin's up to the exact speed scaling; on README's worked example that halves the pass): the
    twin's re-solves are its evidence, and a twin they solve is carried to it by
    :func:`_twin_pass` (verified). Where that carry does not verify, or the twin had no solved
    neighbour to be re-solved from, the point is re-checked from its own neighbours as before.

    ``tables`` (continuation schedule: the seed index's tables with the same failures, the former
    build of this table first, :func:`~offline.rover.table_continuation.failure_tables`): before
    the neighbours, every search verdict (``infeasible``, ``not_found``, ``solver_failure``) is
    re-solved from their primitives at the very point (:func:`_recheck_from_tables`); a point so
    solved is a start for its neighbours in the waves.

    Returns
    -------
    dict
        ``{"re-solved": points made optimal (those from a table included; the header's
        continuation counts name them), "kept": search verdicts re-checked and kept}``.
    """
    from_tables = _recheck_from_tables(spec, recs, ck, ex, tables)
    shape = spec.grid.shape
    tried: dict[int, list[str]] = {}
    done_pairs: set[tuple[int, int]] = set()
    fam_axis = spec.grid.names.index(spec.family["axis"]) if spec.family is not None else None
    for f, nb in tried_pairs or ():
        a = np.flatnonzero(np.subtract(np.unravel_index(f, shape), np.unravel_index(nb, shape)))
        if fam_axis is not None and a.size == 1 and int(a[0]) == fam_axis:
            done_pairs.add((f, nb))
    tw: dict[int, int] = {f: t for f, t in (twin_of or {}).items() if t is not None}
    skip = {f for f, t in tw.items() if f in recs and search_verdict(recs[f]) and search_verdict(recs[t])}
    solved = from_tables + _recheck_waves(spec, recs, ck, ex, done_pairs, tried, skip, "recheck")
    if skip and twin_of is not None:
        keys = {tw[f] for f in skip if recs[tw[f]]["status"] == "optimal"}
        if keys and ck is not None:
            solved += _twin_pass(spec, recs, {f: t for f, t in twin_of.items() if (f if t is None else t) in keys},
                                 ck, ex, "twin_recheck")
        # a twin solved but not carried (its carry did not verify), or a twin with no re-solve (no
        # solved neighbour of its own): this point's own neighbours after all
        own = {f for f in skip if search_verdict(recs[f]) and (recs[tw[f]]["status"] == "optimal" or tw[f] not in tried)}
        solved += _recheck_waves(spec, recs, ck, ex, done_pairs, tried, set(recs) - own, "recheck_own")
        for f in sorted(skip - own):
            if search_verdict(recs[f]):
                tried.setdefault(f, []).append(f"at the speed twin {tw[f]} (the same NLP up to the exact speed "
                                               "scaling): " + "; ".join(str(v) for v in tried[tw[f]]))
    kept = 0
    for f, t in sorted(tried.items()):
        if recs[f]["status"] == "infeasible":
            recs[f] = {**recs[f], "evidence": {**(recs[f].get("evidence") or {}), "neighbour re-solves": t}}
            kept += 1
    return {"re-solved": solved, "kept": kept}


def _recheck_waves(spec: TableSpec, recs: dict[int, dict[str, Any]], ck: _Checkpoint | None, ex: cf.Executor | None,
                   done_pairs: set[tuple[int, int]], tried: dict[int, list[str]], skip: set[int], kind: str) -> int:
    """The waves of :func:`_recheck_infeasible` over the search verdicts not in ``skip`` (records,
    ``done_pairs`` and ``tried`` updated in place). Returns the number of points made optimal."""
    shape = spec.grid.shape
    fresh = {f for f in recs if recs[f]["status"] == "optimal"}  # the starts new in this wave
    solved = 0
    for wave in range(RECHECK_WAVES):
        tasks: list[tuple[Callable[..., Any], tuple[Any, ...], int]] = []
        got: dict[int, dict[str, Any]] = {}
        for f in sorted(recs):
            if f in skip or not search_verdict(recs[f]):
                continue
            nbs = [nb for nb in _neighbours(shape, f)
                   if nb in fresh and recs[nb]["status"] == "optimal" and (f, nb) not in done_pairs]
            if not nbs:
                continue
            done_pairs.update((f, nb) for nb in nbs)
            c = ck.load(f"{kind}{wave}", f) if ck is not None else None
            if c is not None:
                got[f] = c[0]
                continue
            op = spec.grid.point(f)
            starts = [(nb, predicted_start(spec, recs[nb], spec.grid.point(nb), op), recs[nb]["lam_x"], recs[nb]["lam_g"])
                      for nb in nbs]
            tasks.append((retry_point, (spec, f, starts), f))

        def done(f: int, rec: dict[str, Any], wave: int = wave) -> None:
            if ck is not None:
                ck.save(f"{kind}{wave}", f, [rec])
            got[f] = rec

        _run(tasks, ex, done)
        fresh = set()
        for f in sorted(got):
            rec = got[f]
            if rec["status"] == "optimal":
                recs[f] = {**rec, "continued_from": f"re-check from neighbour {rec['retried_from']} (a search had "
                                                    "said infeasible)"}
                fresh.add(f)
                solved += 1
            else:
                tried.setdefault(f, []).extend((rec.get("evidence") or {}).get("retries", []))
        if not fresh:
            break
    return solved


def _continuation_header(spec: TableSpec, recs: Mapping[int, dict[str, Any]], seeds: Sequence[str],
                         searched: int, same_failures: Sequence[str] = (), former: str | None = None) -> dict[str, Any]:
    """The header's ``continuation`` record: the seed tables (name and content hash), the tables
    whose primitives re-checked the searches' verdicts (``recheck_tables``) and the former build
    offered to the neighbour pass (``former_table``), where each optimal point's primitive was
    continued from, and counts."""
    from rtctl.table import load_table

    src = {str(f): str(r.get("continued_from", "")) for f, r in sorted(recs.items())
           if r["status"] == "optimal" and r.get("continued_from")}
    counts: dict[str, int] = {}
    for v in src.values():
        k = v.split(" ")[0] if not v.startswith("seed table") else "seed table"
        k = {"neighbour": "failure-axis neighbour", "speed": "speed twin", "table": "table at the same point",
             "former": "former table (neighbour pass)"}.get(k, k)
        counts[k] = counts.get(k, 0) + 1
    counts["full search"] = searched
    return {"rule": ("continuation schedule (offline/rover/table_continuation.py): per slope and cross slope, the "
                     "failure value whose bounds a seed table's primitive violates least first, then outward along "
                     "the failure's axis, each from its solved neighbour; other speeds by the exact speed scaling; "
                     "the relaxation decided first where no seed has a primitive; the full search only for the rest"),
            "seed_tables": [{"name": load_table(p.removesuffix(" (mirrored)")).name,
                             "content_hash": load_table(p.removesuffix(" (mirrored)")).header["content_hash"],
                             "mirrored": p.endswith(" (mirrored)")} for p in seeds],
            "recheck_tables": [{"name": load_table(p).name, "content_hash": load_table(p).header["content_hash"]}
                               for p in same_failures],
            "former_table": (None if former is None else
                             {"name": load_table(former).name, "content_hash": load_table(former).header["content_hash"]}),
            "started_from": src, "counts": counts}


def relaxation_of(sc: Any) -> Any | None:
    """The scenario whose feasible set contains ``sc``'s: failures and trench goal removed
    (everything else -- parameters, rover, world terms, operating point -- kept), or None when
    that is not a relaxation.

    Every failure kind but one only adds constraints to (7.25) with the same objective (7.25):
    a stuck or narrowed steering angle, a rim-speed cap, a locked, unpowered or torque-limited
    wheel, a trench goal. A raised wheel changes the equations (no ground contact), and a
    failure kind written elsewhere (``WheelFailure.extra``) is not known to be a restriction;
    a stuck angle beyond the optimizer's free steering range (+-89 deg, ``BETA_LIMIT``) lies
    outside the nominal problem's bounds. So if the relaxation has no primitive (a confirmed
    verdict), neither has ``sc``: sound infeasibility evidence for a point the table's own
    search could not decide.
    """
    from .primitives import BETA_LIMIT

    for k in sc.failures:
        f = sc.failure(k)
        if f.raised or f.extra:
            return None
        pf = sc.physical_failure(k)
        if pf.steer_stuck is not None and abs(pf.steer_stuck) > BETA_LIMIT:
            return None
    if not sc.failures and sc.trench is None:
        return None
    return replace(sc, failures={}, trench=None, name=f"{sc.name} (relaxation: no failures)")


def relaxation_verdict(spec: TableSpec, op: Mapping[str, float]) -> dict[str, Any]:
    """The optimizer's verdict (default budgets) on the relaxation of the scenario at ``op``
    (:func:`relaxation_of`): ``{"status", "evidence"}``."""
    from . import primitives as P

    rel = relaxation_of(scenario_at(spec.scenario, spec.family, op))
    if rel is None:
        return {"status": "none", "evidence": None}
    r = P.solve_primitive(rel, replace(spec.solver, **{k: getattr(P.SolverOptions(), k) for k in TABLE_SOLVER_BUDGETS})
                          if spec.solver is not None else P.SolverOptions())
    return {"status": r.status, "evidence": encode(r.evidence) if r.status != "optimal" else None}


def _relaxation_pass(spec: TableSpec, recs: dict[int, dict[str, Any]], ck: _Checkpoint, ex: cf.Executor | None) -> int:
    """Points still ``not_found``: solve the relaxation of each distinct (slope, cross slope) once,
    at the speed of its first such point, with the optimizer's default budgets
    (:func:`relaxation_verdict`; measured: 17.5 CPU s for the nominal rover at 25 deg, confirmed
    infeasible); where it is confirmed ``infeasible``, so is every such point, at every speed
    (exact speed scaling of (7.25)) and every value of the failure's axis (evidence: the
    relaxation's). Returns how many points became ``infeasible``."""
    names = spec.grid.names
    groups: dict[str, list[int]] = {}
    ops: dict[str, dict[str, float]] = {}
    for f in sorted(recs):
        if recs[f]["status"] != "not_found":
            continue
        op = spec.grid.point(f)
        if relaxation_of(scenario_at(spec.scenario, spec.family, op)) is None:
            continue
        # one solve per (slope, cross slope): (7.25) scales exactly with the travel speed (the
        # speed twins' rule), so the relaxation's verdict at one speed holds at every speed
        base = {k: v for k, v in op.items() if k in ("slope", "cross_slope")}
        key = "_".join(f"{k}{base[k]:.9g}" for k in names if k in base) or "all"
        if key not in groups:
            ops[key] = {k: v for k, v in op.items() if k in ("slope", "cross_slope", "speed")}
        groups.setdefault(key, []).append(f)
    verdicts: dict[str, dict[str, Any]] = {}
    keys = sorted(groups)
    tasks: list[tuple[Callable[..., Any], tuple[Any, ...], int]] = []
    for i, key in enumerate(keys):
        got = ck.load("relax", key)
        if got is not None:
            verdicts[key] = {"status": got[0]["verdict"], "evidence": got[0]["evidence"]}
        else:
            tasks.append((relaxation_verdict, (spec, {**spec.grid.point(groups[key][0]), **ops[key]}), i))

    def done(i: int, v: dict[str, Any]) -> None:
        # the verdict under its own key: a checkpoint record with status "optimal" must carry a
        # primitive, and a relaxation that solves has none to store (an "optimal" relaxation
        # crashed the pass with KeyError 'x_scaled' on README's worked example)
        ck.save("relax", keys[i], [{"flat": -1, "status": "none", "verdict": v["status"], "evidence": v["evidence"]}])
        verdicts[keys[i]] = v

    _run(tasks, ex, done)
    n = 0
    for key, flats in groups.items():
        v = verdicts[key]
        if v["status"] != "infeasible":
            continue
        for f in flats:
            recs[f] = {**recs[f], "status": "infeasible",
                       "evidence": {"relaxation": "the same operating point without the failures (a relaxation: "
                                                  "the failures only add constraints) is confirmed infeasible by "
                                                  "the optimizer with its default budgets",
                                    "relaxation evidence": v["evidence"], "table search": recs[f]["evidence"]}}
            n += 1
    return n


def _twin_pass(spec: TableSpec, recs: dict[int, dict[str, Any]], twin_of: Mapping[int, int | None], ck: _Checkpoint,
               ex: cf.Executor | None, kind: str) -> int:
    """Make the speeds of one operating point agree: one primitive per speed-twin group.

    Points that differ only in speed are one NLP up to the exact speed scaling
    (:func:`twin_resolve`), yet each speed was searched on its own and the searches can end
    differently (measured on the shipped tables of main 832105c: ``infeasible`` at one speed and
    ``optimal`` at the other at 6 rim-speed-cap, 3 stuck-steering and 2 trench operating points,
    ``not_found`` and ``optimal`` at 1 trench point).

    The group's chosen optimum is the lowest objective; among members tied with it (within
    :func:`tie_tolerance`) the one with the lexicographically lower steering angles
    (:func:`steering_lower`, the neighbour pass's tie-break), then the lowest speed. It is
    carried to every other member that

    * has no primitive or a higher objective (beyond the tie tolerance): the carried point
      replaces the member if its re-solve verifies (:func:`twin_resolve`: converges and passes
      the optimizer's independent check) and its objective is strictly lower;
    * holds a tied optimum whose primitive, scaled to the chosen member's speed, differs from the
      chosen one by more than :data:`TWIN_AGREE` variable scales (another member of a tie, e.g.
      mirrored steering): replaced if the re-solve verifies with an objective within the tie
      tolerance of the member's. Issue 22/23 (``tests/bench/results_tables.md``): the neighbour
      pass runs at the first speed only and takes a tied optimum there by its tie-break, which
      the former twin pass (tied members skipped) did not carry: a from-scratch nominal held
      (12.5-20 deg, 0 deg) at 4 cm/s on the other member of a tie, 0.18-3.3 scales away.

    Uses the records as they are when called (deterministic). Returns the number of points
    replaced."""
    lay = _problem(spec.scenario, spec.solver).layout
    ib = [lay.var("beta", w) for w in lay.wheels]
    groups: dict[int, list[int]] = {}
    for f in range(spec.grid.size):
        t = twin_of.get(f)
        groups.setdefault(f if t is None else t, []).append(f)
    tasks, got, tied = [], {}, set()
    for members in groups.values():
        solved = [f for f in sorted(members) if recs[f]["status"] == "optimal"]
        if not solved:
            continue
        obj = {f: float(recs[f]["data"]["objective"]) for f in solved}
        fb = min(obj.values())
        ties = [f for f in solved if obj[f] <= fb + tie_tolerance(fb)]
        best = ties[0]
        for f in ties[1:]:
            if steering_lower(recs[f]["x_scaled"], recs[best]["x_scaled"], ib):
                best = f
        v_best = spec.grid.point(best).get("speed", 1.0)
        for f in sorted(members):
            if f == best:
                continue
            if f in obj and obj[f] <= obj[best] + tie_tolerance(obj[best]):
                x_f = scaled_to_speed(spec, recs[f]["x_scaled"], spec.grid.point(f).get("speed", 1.0), v_best)
                if float(np.max(np.abs(x_f - np.asarray(recs[best]["x_scaled"])))) <= TWIN_AGREE:
                    continue  # the same optimum to rounding
                tied.add(f)
            c = ck.load(kind, f) if ck is not None else None
            if c is not None:
                got[f] = c[0] if c[0]["status"] != "none" else None
                continue
            tasks.append((twin_resolve, (spec, f, recs[best]), f))

    def done(f: int, rec: dict[str, Any] | None) -> None:
        if ck is not None:
            ck.save(kind, f, [rec if rec is not None else {"flat": f, "status": "none"}])
        got[f] = rec

    _run(tasks, ex, done)
    changed = []
    for f in sorted(got):
        r = got[f]
        if r is None:
            continue
        if recs[f]["status"] == "optimal":
            f0, f1 = float(recs[f]["data"]["objective"]), float(r["data"]["objective"])
            # a tied member takes the chosen optimum at an objective within the tie tolerance;
            # otherwise only a strictly better optimum replaces one
            if not (f1 <= f0 + tie_tolerance(f0) if f in tied else f1 < f0 - tie_tolerance(f0)):
                continue
        recs[f] = r
        changed.append(f)
    return len(changed)


def _polish(spec: TableSpec, recs: dict[int, dict[str, Any]], ck: _Checkpoint, ex: cf.Executor | None,
            bar: Any, twin_of: Mapping[int, int | None] | None = None, former: str | None = None) -> int:
    """``build.polish_sweeps`` sweeps of :func:`polish_point` over the solved points (each sweep
    uses the previous sweep's results only, so the outcome does not depend on the order in which
    workers finish; a later sweep visits only points next to one that changed). Returns the
    number of points replaced.

    With speed twins (``twin_of``, :func:`speed_twin`; continuation schedule) only the first
    speed of a group whose first-speed member is solved is swept: at another speed the same
    neighbours' starts pose the same NLP up to the exact speed scaling (:func:`twin_resolve`),
    so sweeping it repeats the search (on README's worked example half the pass's IPOPT runs).
    What the sweeps found is then carried to the other speeds by :func:`_twin_pass` (each
    carried optimum verified by its own re-solve and the independent check; a member keeps its
    own optimum where the carry does not verify or is not strictly better).

    ``former`` (:func:`~offline.rover.table_continuation.former_table`: the file this build
    replaces, same NLP): in the first sweep its optimum at each swept point (scaled to the
    point's speed, with its multipliers) is one more start where it differs from the point's
    primitive by more than :data:`TWIN_AGREE` scales; like a neighbour's it is taken only if
    strictly better (or equal and preferred by the tie-break) and verified, so a rebuild holds
    no worse an optimum than the former file at a point both solve (``continued_from`` names
    the table)."""
    from . import table_continuation as TC

    shape = spec.grid.shape
    changed = set(recs)
    polished_ever: set[int] = set()
    total = 0
    by_twin = bool(twin_of) and spec.build.schedule == "continuation"
    for sweep in range(spec.build.polish_sweeps):
        tasks, got = [], {}
        for f in sorted(recs):
            if recs[f]["status"] != "optimal" or not any(nb in changed for nb in _neighbours(shape, f) + [f]):
                continue
            if by_twin and twin_of is not None and (t := twin_of.get(f)) is not None \
                    and recs[t]["status"] == "optimal":
                continue  # swept at the first speed, carried below
            c = ck.load(f"polish{sweep}", f)
            if c is not None:
                got[f] = c[0] if c[0]["status"] != "none" else None
                continue
            op = spec.grid.point(f)
            starts = [(nb, predicted_start(spec, recs[nb], spec.grid.point(nb), op))
                      + ((recs[nb]["lam_x"], recs[nb]["lam_g"]) if spec.build.polish_warm else ())
                      for nb in _neighbours(shape, f)
                      if recs[nb]["status"] == "optimal" and not _polish_redundant(spec, recs, f, nb, polished_ever)]
            if former is not None and sweep == 0 and (fs := TC.table_start(spec, former, op)) is not None \
                    and float(np.max(np.abs(fs[0] - np.asarray(recs[f]["x_scaled"])))) > TWIN_AGREE:
                starts.append((FORMER, fs[0]) + ((fs[1], fs[2]) if spec.build.polish_warm else ()))
            if starts:
                tasks.append((polish_point, (spec, f, float(recs[f]["data"]["objective"]), starts, recs[f]["x_scaled"]), f))
        if tasks:
            bar.set_description(f"{spec.name} (neighbour pass {sweep + 1}: {len(tasks)} points)")

        def done(f: int, rec: dict[str, Any] | None, sweep: int = sweep) -> None:
            ck.save(f"polish{sweep}", f, [rec if rec is not None else {"flat": f, "status": "none"}])
            got[f] = rec

        _run(tasks, ex, done)
        changed = {f for f, r in got.items() if r is not None}
        polished_ever |= changed
        for f in sorted(changed):
            rec = got[f]
            assert rec is not None  # noqa: S101  (changed holds only the points with a result)
            if rec.get("polished_from") == FORMER and former is not None:
                rec = {k: v for k, v in rec.items() if k != "polished_from"}
                t = TC._load(former)
                rec["continued_from"] = (f"former table {t.name}@{t.header['content_hash'][:12]} (neighbour pass: a "
                                         "better optimum at the same point)")
            recs[f] = rec
        total += len(changed)
        if not changed:
            break
    if by_twin and twin_of is not None and polished_ever:
        keys = {f if (t := twin_of.get(f)) is None else t for f in polished_ever}  # the groups a sweep changed
        total += _twin_pass(spec, recs, {f: t for f, t in twin_of.items() if (f if t is None else t) in keys}, ck, ex,
                            "twin_polish")
    return total


def _polish_redundant(spec: TableSpec, recs: Mapping[int, dict[str, Any]], f: int, nb: int, polished: set[int]) -> bool:
    """With the continuation schedule, a neighbour-pass start that cannot change ``f``: the
    neighbour differs only in speed (its predicted start is ``f``'s own twin scaled exactly, and
    the twin pass already gave the group its best optimum), or ``f`` was continued from it and
    neither has changed since (the start is the one ``f`` was solved from). The former schedule
    keeps every start."""
    if spec.build.schedule != "continuation" or f in polished or nb in polished:
        return False
    if spec.build.speed_twins and "speed" in spec.grid.names:
        a = spec.grid.names.index("speed")
        i, j = np.unravel_index(f, spec.grid.shape), np.unravel_index(nb, spec.grid.shape)
        if all(i[k] == j[k] for k in range(len(i)) if k != a):
            return True
    src = str(recs[f].get("continued_from", ""))
    return src == f"neighbour {nb} on the failure axis" and "speed_twin_of" not in recs[f]


def _library_version() -> str:
    try:
        from importlib.metadata import version

        return version("offnominal-rover")
    except Exception:  # noqa: BLE001 - metadata missing in a source checkout
        return "unknown"


def _assemble(spec: TableSpec, recs: Mapping[int, dict[str, Any]],
              refinement: Mapping[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    pb = _problem(spec.scenario, spec.solver)
    lay: NlpLayout = pb.layout
    shapes = field_shapes(lay.nx, lay.np_, lay.ng, len(lay.wheels))
    shapes.update(controller_source=(len(CONTROLLER_NAMES),), kkt_cond=())
    G = spec.grid.shape
    arrays: dict[str, NDArray[Any]] = {k: np.full(G + s, np.nan) for k, s in shapes.items() if k != "controller_source"}
    arrays["controller_source"] = np.full(G + (len(CONTROLLER_NAMES),), -1, dtype=np.int8)
    arrays["active_x"] = np.zeros(G + (lay.nx,), dtype=np.int8)
    arrays["active_g"] = np.zeros(G + (lay.ng,), dtype=np.int8)
    arrays["status"] = np.full(G, STATUS_NAMES.index("not_attempted"), dtype=np.int8)
    arrays["iterations"] = np.zeros(G, dtype=np.int32)
    arrays["retried_from"] = np.full(G, -1, dtype=np.int64)
    arrays["polished_from"] = np.full(G, -1, dtype=np.int64)
    evidence: dict[str, Any] = {}
    for f in range(spec.grid.size):
        r = recs.get(f)
        if r is None:
            continue
        idx = np.unravel_index(f, G)
        status = r["status"] if r["status"] in STATUS_NAMES else "solver_failure"
        arrays["status"][idx] = STATUS_NAMES.index(status)
        arrays["iterations"][idx] = r.get("iterations", 0)
        arrays["retried_from"][idx] = r.get("retried_from", -1)
        arrays["polished_from"][idx] = r.get("polished_from", -1)
        if status == "optimal":
            for k in (*shapes, "active_x", "active_g"):
                arrays[k][idx] = r["data"][k]
        else:
            evidence[str(f)] = r.get("evidence")
    # table-wide summary of the per-point trust radius (the smallest over the feasible points)
    feas = arrays["status"] == 0
    tr: dict[str, float] = {}
    if feas.any():
        for name in _LIN_PARAMS:
            tr[name] = float(np.min(arrays["trust_radius"][feas][:, lay.index(name)]))
    axes = {k: {"values": list(v), "unit": AXES[k][0], "display_unit": AXES[k][1], "display_factor": AXES[k][2]}
            for k, v in spec.grid.axes}
    sc = spec.scenario
    header: dict[str, Any] = {
        "schema": SCHEMA, "schema_version": SCHEMA_VERSION, "name": spec.name, "description": spec.description,
        "library_version": _library_version(),
        "rover": {k: v for k, v in dataclasses.asdict(sc.rover).items()},
        "params": encode(sc.params), "scenario": encode(sc), "sources": spec.sources,
        "family": spec.family, "axis_order": list(spec.grid.names), "axes": axes,
        "layout": json.loads(lay.to_json()), "status_names": list(STATUS_NAMES),
        "controller_names": list(CONTROLLER_NAMES),
        "controller_offsets": {"mz_offset_Nm": spec.build.mz_offset, "fy_offset_N": spec.build.fy_offset},
        "objective": f"f = sum_i M_y,i^2 / (W/{len(lay.wheels)} r_s)^2 (eq. 7.24, dimensionless as the NLP defines it)",
        "units": {"x": "per layout variable unit", "p": "per layout parameter unit", "g": "per layout constraint unit",
                  "wrench": "N, N m (Fx, Fy, Fz, Mx, My, Mz), wheel frame Fig. 5.1",
                  "wrench_jac": "per (m/s, m/s, rad/s, m, m)", "slip": "1", "slip_angle": "rad", "torque": "N m",
                  "power": "W", "controllers": "(m/s, rad) per N m (Mz) or per N (Fy)",
                  "bounds": "inf where unbounded (rtctl uses 1e30 inside the QP)"},
        "solver_options": encode(pb.options),
        "build_options": encode(spec.build),
        "evidence": evidence,
        "speed_twins": {str(f): int(r["speed_twin_of"]) for f, r in sorted(recs.items()) if "speed_twin_of" in r},
        "speed_twins_rule": ("grid point -> the point at another speed whose optimum it took (the twin pass's better "
                             "optimum, or among tied optima the one with the lower steering angles, or the continuation "
                             "schedule's carry of the first speed; exact speed scaling of (7.25); verified by a warm "
                             "re-solve and the independent check)"),
        "trust_radius": {k: (v if math.isfinite(v) else None) for k, v in tr.items()},
        "trust_radius_rule": (f"per point and parameter (field trust_radius): a step, both signs, whose NLP re-solve "
                              f"from the first-order prediction matches it within {spec.build.trust_tolerance} of the "
                              "variable scales; predicted by the quadratic law from the error at the probe "
                              f"{sorted(spec.build.trust_search)[(len(spec.build.trust_search) - 1) // 2]} x the "
                              f"parameter scale (aiming at {TRUST_MARGIN} x the tolerance, at most "
                              f"{max(spec.build.trust_search)} x the scale), verified by one re-solve per sign and "
                              "shrunk while it fails; fall-back: bisection on the ladder "
                              f"{list(spec.build.trust_search)} x the parameter scale (below the ladder: d tol / e "
                              "from the smallest re-solved step); where no re-solve succeeded, the fallback "
                              "'smallest ladder step' with trust_unverified = 1; this entry: the smallest over the "
                              "feasible points"),
        "trust_unverified_points": {n: int(np.sum(arrays["trust_unverified"][feas][:, lay.index(n)] > 0))
                                    for n in _LIN_PARAMS} if feas.any() else {},
        "grid_points": spec.grid.size,
        "feasible_points": int(np.sum(arrays["status"] == 0)),
    }
    header.update(failure_header(sc, spec.family))
    header["wheel_set"] = wheel_set_header(sc, spec.sources)
    if refinement is not None:
        header["refinement"] = refinement
    world = world_header(sc, pb)
    if world:
        header["world"] = world
    return header, arrays


def failure_header(sc: Any, family: Mapping[str, Any] | None) -> dict[str, Any]:
    """The header's failure description for the rover (:mod:`rtctl.failures`), written by the
    failure-kind objects themselves (:meth:`offline.rover.failures.FailureKind.rover_description`):

    * ``failure_kinds``: every kind of :data:`offline.rover.failures.KINDS` and every other kind
      the scenario uses, by its rover name;
    * ``failures``: the scenario's failures (wheel, kind, declared value, text), and ``task``:
      its trench goal's wheel and the task kind as data, written by the goal's own class
      (``{"kind": "trench", "wheel": ..., "description": TrenchGoal.rover_description()}``: the
      value's name, unit and range, and whether the wheel still serves the odometry), i.e. what
      the table serves;
      a constraint on the task's wheel that the rover cannot declare (the trenching wheel's
      one-sided steer range: no single declared value) is marked ``with_task`` (part of the task,
      not of the signature);
    * ``family`` (when the table has a family axis) gains ``declares``: which declared failure
      or task gives the axis its value (``{"kind": k, "per_speed": b}``: the value of k, divided
      by the travel speed when b; ``{"task": "trench"}``).
    """
    from .failures import KINDS, with_task

    classes = list(KINDS)
    records = []
    for w in sorted(sc.failures):
        for k in sc.failure(w).kinds():
            if type(k) not in classes:
                classes.append(type(k))
            if k.ROVER_KIND:
                rec = k.rover_record(w)
                if with_task(k, w, getattr(sc, "trench", None)):
                    rec["with_task"] = True  # e.g. the trenching wheel's one-sided steer range: part of the task
                records.append(rec)
    kinds = {c.ROVER_KIND: c.rover_description() for c in classes if c.ROVER_KIND}
    out: dict[str, Any] = {"failure_kinds": kinds, "failures": records}
    if getattr(sc, "trench", None) is not None:
        out["task"] = {"kind": type(sc.trench).ROVER_KIND, "wheel": sc.trench.wheel,
                       "description": type(sc.trench).rover_description()}
    if family is not None:
        fam = dict(family)
        axis = fam.get("axis")
        if axis == "steer_stuck":
            fam["declares"] = {"kind": "steer_stuck", "per_speed": False}
        elif axis == "rim_speed_cap_fraction":
            fam["declares"] = {"kind": "rim_speed_cap", "per_speed": True}
        elif axis == "trench_depth":
            fam["declares"] = {"task": type(sc.trench).ROVER_KIND}
        out["family"] = fam
    return out


def world_header(sc: Any, pb: Any) -> dict[str, Any]:
    """The table header's ``world`` record of a scenario's world terms (empty without them):
    ``wheel_radius_m`` / ``shearing_radius_m`` per wheel (rtctl converts omega to rim speed
    with the latter), ``steer_offset_rad`` per wheel (true minus encoder angle: rtctl commands
    ``beta - offset``), ``external_force`` (body frame ``fx_N``, ``fy_N``, ``mz_Nm`` about O),
    ``hub_contact`` (``clearance_m``, ``face_width_m``, ``arm_m``: the drag of
    :func:`rtctl.physics.hub_drag.hub_wrench`, included in the stored ``wrench`` and
    ``wrench_jac``)."""
    out: dict[str, Any] = {}
    if getattr(sc, "wheel_radius", None) is not None:
        out["wheel_radius_m"] = [float(pb.radius_of[k]) for k in pb.layout.wheels]
        out["shearing_radius_m"] = [float(pb.rs_of[k]) for k in pb.layout.wheels]
    if getattr(sc, "steer_offset", None) is not None:
        out["steer_offset_rad"] = [float(sc.offset(k)) for k in pb.layout.wheels]
    if getattr(sc, "external", None) is not None:
        out["external_force"] = {"fx_N": sc.external.fx, "fy_N": sc.external.fy, "mz_Nm": sc.external.mz}
    hub = getattr(sc, "hub_contact", None)
    if hub is not None:
        out["hub_contact"] = {"clearance_m": hub.clearance, "face_width_m": hub.face_width, "arm_m": hub.arm}
    if out:
        out["order"] = list(pb.layout.wheels)
    return out


def write_index(out_dir: str | Path, paths: Iterable[Path], base_index: str | Path | None = None,
                index_name: str = "index.json") -> Path:
    """Write ``<out_dir>/index.json``: every table's file, hashes, grid, family and feasible ranges
    (entries of tables already in the index and not rebuilt are kept). ``index_name``: another
    file name in ``out_dir`` (:data:`RUN_SEED_INDEX`); the tables must lie in ``out_dir``.

    ``base_index``: when ``<out_dir>`` has no index yet, start from this one's entries (e.g. the
    shipped ``tables/index.json``), their files re-pointed relative to ``<out_dir>`` (rtctl
    resolves an entry's ``file`` against the index's folder) and their hashes kept, so an index
    in a fresh folder lists the new tables *and* the base ones, each loaded from where it is and
    checked against its hash. A table built here replaces a base entry of the same name.

    Raises
    ------
    BuildError
        ``base_index`` is not a readable table index.
    """
    from rtctl.table import load_table

    out = Path(out_dir)
    ip = out / index_name
    entries: dict[str, Any] = {}
    if ip.is_file():
        try:
            old = json.loads(ip.read_text())
            entries = dict(old.get("tables", {}))
        except json.JSONDecodeError:
            entries = {}
    elif base_index is not None:
        entries = _rebased_entries(Path(base_index), out)
    for p in paths:
        t = load_table(p)
        entries[t.name] = {
            "file": p.name, "sha256": hashlib.sha256(p.read_bytes()).hexdigest(),
            "content_hash": t.header["content_hash"], "description": t.header.get("description", ""),
            "axes": {k: v.tolist() for k, v in t.axes.items()}, "family": t.header.get("family"),
            "grid_points": int(t.feasible.size), "feasible_fraction": t.feasible_fraction,
            "feasible_ranges": {k: (list(v) if v else None) for k, v in t.feasible_ranges().items()},
            "statuses": {s: int(np.sum(t.status == i)) for i, s in enumerate(STATUS_NAMES) if np.any(t.status == i)},
            "rover": t.meta["rover"].get("name"), "sources": {k: v for k, v in t.header["sources"].items() if k != "scenario_text"},
            "trust_radius": t.header.get("trust_radius"), "library_version": t.header.get("library_version"),
        }
    doc = {"schema": SCHEMA + " index", "schema_version": SCHEMA_VERSION, "tables": dict(sorted(entries.items()))}
    write_text(ip, json.dumps(doc, indent=1, sort_keys=True) + "\n")
    return ip


def _rebased_entries(base: Path, out: Path) -> dict[str, Any]:
    """Entries of the index ``base`` with each ``file`` made relative to the folder ``out``."""
    from rtctl.table import TableError, load_index

    try:
        infos = load_index(base)
    except TableError as exc:
        raise BuildError(f"base index: {exc}") from None
    entries = {}
    for name, info in infos.items():
        e = dict(info.entry)
        target = Path(os.path.abspath(info.path))
        try:
            e["file"] = os.path.relpath(target, os.path.abspath(out))
        except ValueError:  # another drive (Windows): an absolute path
            e["file"] = str(target)
        entries[name] = e
    return entries


def upgrade_table(src: str | Path, out_dir: str | Path) -> Path:
    """Upgrade a schema-1 table file to schema 2 without re-solving (``offnominal tables upgrade``).

    ``hess_lag_xp`` is computed exactly at every optimal point from the stored primitive and
    IPOPT's multipliers (the AD graph of the same NLP; no new solve). The trust radius keeps the
    schema-1 rule (one warm re-solve per parameter at half its scale, the growth-law estimate):
    a radius the old build left at 0 (its re-solve failed) becomes the schema-2 fallback, the
    smallest step of the search ladder, with ``trust_unverified = 1``. The header records
    ``upgraded_from_schema = 1`` and the old rule. A fresh build (``offnominal tables build``)
    gives the schema-2 trust radius and neighbour pass; use this where a rebuild is too costly.

    Raises
    ------
    TableError
        ``src`` is not a readable schema-1 table, or its content hash does not match.
    """
    from rtctl import table as T

    p = Path(src)
    header, arrays = T._read(p)
    if header.get("schema") != SCHEMA or header.get("schema_version") != 1:
        raise TableError(f"{p}: not a schema-1 table (schema {header.get('schema_version')!r}); nothing to upgrade")
    if header.get("content_hash") != content_hash(header, arrays):
        raise TableError(f"{p}: content hash mismatch: the file is corrupted; rebuild it")
    out = check_output_dir(out_dir, inputs=[p], names=[p.name])
    sc = scenario_from_header(header)
    solver = decode(header["solver_options"]) if "solver_options" in header else None
    pb = _problem(sc, solver)
    lay: NlpLayout = pb.layout
    xsc, csc = lay.variable_scale, lay.constraint_scale
    d = _derivatives(pb)
    build = decode(header["build_options"]) if "build_options" in header else BuildOptions()
    G = arrays["status"].shape
    hxp = np.full(G + (lay.nx, lay.np_), np.nan)
    unv = np.full(G + (lay.np_,), np.nan)
    tr = np.array(arrays["trust_radius"], dtype=float)
    floor = np.array([min(getattr(build, "trust_search", BuildOptions().trust_search)) * b.scale for b in lay.parameters])
    lin = [lay.index(n) for n in _LIN_PARAMS]
    for idx in np.ndindex(*G):
        if arrays["status"][idx] != 0:
            continue
        x_s = arrays["x"][idx] / xsc
        lam_g_s = arrays["lam_g"][idx] * csc
        hxp[idx] = d(x_s, arrays["p"][idx], lam_g_s)[6] / xsc[:, None]
        unv[idx] = 0.0
        for j in lin:
            if not tr[idx + (j,)] > 0.0:
                tr[idx + (j,)], unv[idx + (j,)] = floor[j], 1.0
    arrays = dict(arrays, hess_lag_xp=hxp, trust_unverified=unv, trust_radius=tr)
    feas = arrays["status"] == 0
    head = {k: v for k, v in header.items() if k != "content_hash"}
    head.update(schema_version=SCHEMA_VERSION, upgraded_from_schema=1,
                trust_radius_rule="schema-1 rule kept by 'offnominal tables upgrade': " + str(header.get("trust_radius_rule", ""))
                + "; a radius of 0 (failed re-solve) replaced by the smallest step of the schema-2 ladder, trust_unverified = 1",
                trust_unverified_points={n: int(np.sum(unv[feas][:, lay.index(n)] > 0)) for n in _LIN_PARAMS} if feas.any() else {})
    if feas.any():
        head["trust_radius"] = {n: float(np.min(tr[feas][:, lay.index(n)])) for n in _LIN_PARAMS}
    path = out / p.name
    write_bytes(path, table_bytes(head, arrays))
    return path


def describe_table(src: str | Path, out_dir: str | Path) -> Path:
    """Add the failure description for the rover (:func:`failure_header`) to a table built
    before it (``offnominal tables describe``), without re-solving: the scenario is decoded from
    the header and its failure-kind objects write the description; every array is unchanged.
    A mirrored table (header ``mirror_of``) gets the mirror of its scenario's failures.

    Raises
    ------
    TableError
        ``src`` is not a readable table, or its content hash does not match.
    """
    from rtctl import table as T

    p = Path(src)
    header, arrays = T._read(p)
    if header.get("content_hash") != content_hash(header, arrays):
        raise TableError(f"{p}: content hash mismatch: the file is corrupted; rebuild it")
    out = check_output_dir(out_dir, inputs=[p], names=[p.name])
    sc = scenario_from_header(header)
    head = {k: v for k, v in header.items() if k != "content_hash"}
    head.update(failure_header(sc, header.get("family")))
    path = out / p.name
    write_bytes(path, table_bytes(head, arrays))
    return path


def scenario_from_header(header: Mapping[str, Any]) -> Any:
    """Rebuild the scenario a table was built from (its header's ``scenario`` entry)."""
    try:
        return decode(header["scenario"])
    except (KeyError, TypeError) as exc:
        raise TableError(f"table header has no usable scenario spec ({exc}); rebuild the table") from None
