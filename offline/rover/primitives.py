"""Steady-state driving primitives: the full nonlinear optimizer of chapter 7, eq. (7.25).

For a rover, a soil and a :class:`~offline.rover.scenario.Scenario`, find the wheel speeds and
steering angles (with each wheel's load and sinkage) that hold the rover in steady straight
driving with the least actuator effort, ``min sum M_y^2`` (7.24), subject to the balance
equations (7.12)-(7.18)/(7.23) (derived from the geometry, :mod:`offline.rover.statics`; with
the slope (7.32)-(7.33), a cross slope and the steering offsets (7.26)-(7.27)), the per-wheel
load constraints (7.19)-(7.22), the failure constraints (one object per kind,
:mod:`offline.rover.failures`) and trenching goals (7.28)-(7.29).

Design (the dissertation's section 7.2.7 lists what made its solver fragile)
--------------------------------------------------------------------------
* One named layout (:class:`rtctl.layout.NlpLayout`) of variables, parameters and constraint
  rows with their scales: the NLP builder, the bounds, the independent check and the
  evidence index by name, and the table files carry the same description.
* Exact derivatives: the wheel physics is the casadi graph of
  :func:`offline.physics.terramechanics.wrench_core`, solved by IPOPT with the exact Hessian.
* No inner loops: per wheel the decision variables are ``omega, beta, W, h`` **and** the
  zero-slip sinkage ``h0`` that fixes theta_m0 in skid, with its own load constraint.
* One NLP structure per (parameters, rover, exit angle, trench wheel): a scenario only
  changes bounds and parameters, so the solver is built once (:func:`get_problem`).
* Deterministic budgets: every search is limited by IPOPT iterations per attempt, a number
  of attempts and a total of iterations, never by seconds, so a scenario gets the same
  verdict on an idle and on a loaded machine. An optional wall-clock limit
  (``SolverOptions.time_limit``, off by default) is a reported safety net only.
* Automatic start: the nominal primitive (starts on both sides of zero slip: driving and
  skidding wheels), then the scenario by continuation of its bounds from the nominal
  solution with adaptive step halving, jumps from where a continuation stalls (on both sides
  of zero slip), the failure kinds' own start hints, the mirror-image scenario and seeded
  perturbed restarts. An IPOPT run that stops at its iteration limit on a point that
  satisfies the constraints is continued from there, never thrown away.
* Verdicts with distinct meanings (:class:`PrimitiveResult`): ``optimal`` (IPOPT converged
  and the independent check passed); ``infeasible`` (the search and a second, longer and
  differently started confirmation search failed, and the evidence is consistent: the
  furthest point reached is feasible for its intermediate problem and passes the
  independent check); ``not_found`` (budget spent without a verdict); ``solver_failure``
  (IPOPT converged on a point the independent check rejects, or could not evaluate).

Any rover from a file (issue 23)
--------------------------------
A scenario that names a rover file (:attr:`offline.rover.scenario.Scenario.rover_file`) gets an
NLP with five variables per wheel of the file (file order), the balance rows its suspension
implies (:class:`rtctl.physics.suspension.SuspensionStatics`: rocker, rocker-bogie with
differential, rigid with height compatibility), the file's steering ranges, driven flags and
actuator limits as bounds, every failure kind on any named wheel, and the independent check by
:class:`offline.rover.statics.FreeBodyBalance` (root-found link angles, rotation matrices: not
the NLP's row function). The mirror-image search step uses the mirror map found from the file's
positions (:func:`mirror_wheels`; skipped for an asymmetric rover). Without a rover file the NLP
is the mini rover's, variable for variable as before (``tests/test_any_rover_nlp.py`` re-solves
seven scenarios against a stored reference). Driving backward is a rover turned half round
(:func:`rtctl.physics.rover_file.driving_backward`).
"""

from __future__ import annotations

import functools
import math
import os
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence, cast

import numpy as np
from numpy.typing import NDArray

from rtctl.layout import PARAMETERS, WHEEL_VARIABLES, NlpLayout

from rtctl.physics.hub_drag import HubFace
from rtctl.physics.rover_file import RoverSpec
from rtctl.physics.steady_state import SteadyStateModel, steady_state_rows, with_hub
from rtctl.physics.suspension import SuspensionStatics

from ..physics.backend import CASADI, NUMPY, Backend
from ..physics.params import ParameterSet, Rover
from ..physics.terramechanics import ModelOptions, PhysParams, WheelModel, _SoilView, _WheelView, wrench_core
from .compiled_nlp import compiled_functions, find_compiler
from .failures import SolutionView, WheelBounds
from .scenario import Scenario, WheelFailure
from .statics import WHEELS, FourWheelRocker, FreeBodyBalance, free_body_residuals

__all__ = [
    "SolverOptions",
    "SteadyStateProblem",
    "WheelSolution",
    "PrimitiveResult",
    "STATUSES",
    "NLP_STRUCTURES",
    "per_wheel_graph",
    "get_problem",
    "world_of",
    "solve_primitive",
    "check_solution",
    "steering_controllers",
    "slope_sweep",
    "envelope",
    "lowest_speed_cap",
    "mirror_scenario",
    "mirror_x",
    "mirror_wheels",
]

STATUSES = ("optimal", "infeasible", "not_found", "solver_failure")
NLP_STRUCTURES = ("auto", "inlined", "per_wheel")
"""Values of :attr:`SolverOptions.nlp_structure`."""
"""The four verdicts of :func:`solve_primitive` (module docstring)."""

BETA_LIMIT = math.radians(89.0)  # |beta| < 90 deg keeps v_x > 0 (travel direction well defined)
_IPOPT_OK = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
_IPOPT_ERROR = ("Invalid_Number_Detected", "Error_In_Step_Computation", "Internal_Error", "Insufficient_Memory",
                "NonIpopt_Exception_Thrown", "Unrecoverable_Exception", "Invalid_Problem_Definition", "Invalid_Option")


@dataclass(frozen=True)
class SolverOptions:
    """Solver settings (not scenario data). Every budget counts iterations or attempts.

    Parameters
    ----------
    tol : float
        IPOPT tolerance on the scaled problem.
    max_iter : int
        IPOPT iterations per attempt.
    max_attempts : int
        IPOPT runs of the main search (nominal primitive included).
    max_iterations : int
        IPOPT iterations of the main search, all attempts together.
    continue_rounds : int
        An attempt that stops at ``max_iter`` on a feasible point is continued from that point
        up to this many more times.
    confirm : bool
        Run the confirmation search before declaring a scenario infeasible (otherwise the
        verdict without a solution is ``not_found``).
    confirm_starts, confirm_rounds : int
        Seeded starts of the confirmation search, and IPOPT runs chained per start (each
        continuing from where the last stopped: ``confirm_rounds * max_iter`` iterations).
    seed : int
        Seed of every perturbed start.
    time_limit : float or None
        Wall-clock safety net in seconds (off by default). When it stops a search the result
        says so in ``stats["time_limit_hit"]`` and the status is ``not_found``.
    max_rim_speed_factor : float
        Motor limit: rim speed at most this times the travel speed (bound 7.2).
    continuation : tuple of int
        Step counts tried in turn when the direct solve from the nominal primitive fails.
    restarts : int
        Perturbed restarts after continuation fails.
    pitch_includes_wheel_torque : bool
        See :class:`offline.rover.statics.FourWheelRocker`.
    shear_direction_smoothing : float
        Passed to :class:`~offline.physics.terramechanics.ModelOptions`.
    check_rtol : float
        Tolerance of the independent numeric check, relative to the rover weight (forces)
        and weight times rocker length (moments; a rover file: weight times wheelbase).
    feasibility_tol : float
        Largest scaled constraint violation of a point called feasible.
    hessian : str
        IPOPT ``hessian_approximation`` (``"exact"`` or ``"limited-memory"``).
    compile : str
        How IPOPT evaluates the NLP's functions: ``"off"`` (casadi's virtual machine),
        ``"on"`` or ``"auto"`` (C compiled once per NLP structure and cached on disk,
        :mod:`offline.rover.compiled_nlp`). Not data: it changes no result (the compiled C does
        the virtual machine's operations in the same order), so it is not written to table files
        and not hashed. A table build sets it from ``build.compile``.
    nlp_structure : str
        How the NLP's casadi graph is built (:data:`NLP_STRUCTURES`): ``"auto"`` (the default:
        per wheel when the functions are compiled, ``compile`` not ``"off"`` and a C compiler
        found, else inlined), ``"inlined"`` (one SX graph, every wheel's wrench inlined) or
        ``"per_wheel"`` (an MX graph calling one SX function per wheel model four times,
        :func:`per_wheel_graph`). The same rows and objective from the same source
        (:func:`rtctl.physics.steady_state.steady_state_rows`,
        :func:`rtctl.physics.terramechanics.wrench_core`), IPOPT's functions equal to rounding.
        Measured on README's worked example (``tests/bench/results_nlp_structure.md``): in
        casadi's virtual machine the per-wheel graph is slower (Hessian 3.5 against 2.4 ms per
        call, 1.32x the build's CPU on 42 grid points), so the virtual machine keeps the inlined
        graph; compiled, the per-wheel graph's distinct code is 0.4 of the inlined Hessian's and
        is reused by the four wheels: 92-107 s of compiler CPU instead of 354 s, and 0.64 of the
        inlined virtual machine's CPU for the whole worked example (391 against 610 s). Its
        search's verdicts had differed at 4 of 252 points (the search's path parts at rounding
        level: at stuck -60 deg, cross slope 10 deg the per-wheel search declared infeasible
        what the inlined one solved); since the table builder re-solves every search's
        ``infeasible`` verdict from its solved neighbours before accepting it
        (:func:`offline.rover.table_builder._recheck_infeasible`), both structures give the same
        verdicts there (``tests/bench/results_new_failure.md``), hence ``auto``. Not data. The
        environment variable ``OFFNOMINAL_NLP_STRUCTURE`` sets the default (benchmarks).
    """

    tol: float = 1e-9
    max_iter: int = 150
    max_attempts: int = 100
    max_iterations: int = 4000
    continue_rounds: int = 2
    confirm: bool = True
    confirm_starts: int = 4
    confirm_rounds: int = 3
    seed: int = 0
    time_limit: float | None = None
    max_rim_speed_factor: float = 12.0
    continuation: tuple[int, ...] = (4, 12)
    restarts: int = 3
    pitch_includes_wheel_torque: bool = True
    shear_direction_smoothing: float = 1e-6
    check_rtol: float = 1e-6
    feasibility_tol: float = 1e-7
    hessian: str = "exact"
    compile: str = field(default="off", metadata={"not_data": True})
    nlp_structure: str = field(default_factory=lambda: os.environ.get("OFFNOMINAL_NLP_STRUCTURE") or "auto",
                               metadata={"not_data": True})

    def __post_init__(self) -> None:
        if self.nlp_structure not in NLP_STRUCTURES:
            raise ValueError(f"SolverOptions.nlp_structure = {self.nlp_structure!r}: expected one of {NLP_STRUCTURES} "
                             "(or set the environment variable OFFNOMINAL_NLP_STRUCTURE to one of them)")


@functools.lru_cache(maxsize=16)
def get_problem(params: ParameterSet, rover: Rover, exit_angle: str = "classic", trench_wheel: str | None = None,
                options: SolverOptions | None = None, external: tuple[float, float, float] | None = None,
                wheel_radius: tuple[float, ...] | None = None, hub: HubFace | None = None,
                rover_file: RoverSpec | None = None) -> "SteadyStateProblem":
    """The (cached) NLP of one parameter set, rover, exit-angle model and trench wheel, with an
    optional constant external pull, per-wheel rim radii, hub contact and rover file
    (:class:`SteadyStateProblem`)."""
    return SteadyStateProblem(params, rover, exit_angle, trench_wheel, options or SolverOptions(), external, wheel_radius,
                              hub, rover_file)


def world_of(sc: Scenario) -> dict[str, Any]:
    """The NLP-structure arguments of a scenario's world terms (:func:`get_problem`): ``external``
    (body-frame ``(F_x, F_y, M_z)``), ``wheel_radius``, ``hub`` (the hub contact) and
    ``rover_file``, each only when set, so a scenario without them keys (and builds) exactly
    the NLP it always did."""
    out: dict[str, Any] = {}
    if sc.external is not None and not sc.external.zero:
        out["external"] = (float(sc.external.fx), float(sc.external.fy), float(sc.external.mz))
    if sc.wheel_radius is not None:
        out["wheel_radius"] = tuple(float(r) for r in sc.wheel_radius)
    if sc.hub_contact is not None:
        out["hub"] = sc.hub_contact
    if sc.rover_file is not None:
        out["rover_file"] = sc.rover_file
    return out


_problem = get_problem  # former private name


_WHEEL_STATE = ("beta", "omega", "h", "h0")
"""A wheel's variables its wrench depends on (its load ``W`` enters the rows only), in the order
of the per-wheel function's input (:func:`per_wheel_graph`)."""


def per_wheel_graph(model: SteadyStateModel, L: NlpLayout) -> tuple[Any, Any, Any, Any]:
    """The NLP (7.25) as a casadi MX graph that calls one SX function per wheel model.

    ``wheel(q, speed) -> (F_x, F_y, F_z, M_x, M_y, M_z, F_z0)``, ``q = (beta, omega, h, h0)``: the
    wheel's soil wrench (:func:`rtctl.physics.terramechanics.wrench_core` at the wheel velocity
    of ``model.statics``) and the load ``F_z0`` of its zero-slip state (``omega = speed / r_s``,
    sinkage ``h0``), built once per distinct wheel (one for equal wheels) and called once per
    wheel; the rows and objective are one SX function of ``(x, p, wrenches)``, built by
    :func:`rtctl.physics.steady_state.steady_state_rows` from those wrenches (its ``wrenches``
    argument: hub drag, contact, trench rows and balance as in the inlined graph). IPOPT's
    derivative functions are then built from one wheel's derivatives (called four times) instead
    of four inlined copies: the code is about a quarter, the operations are not fewer.

    The wheel functions use ``jac_penalty = 0.5`` (also on their derivatives): casadi then takes
    their (4-column) Jacobian instead of pushing the Hessian's 7 colour directions through each
    call, the cheaper of the two here (``tests/bench/results_nlp_structure.md``).

    Returns
    -------
    x, p, f, g : casadi.MX
        Scaled variables (``x_phys = x * layout.variable_scale``), physical parameters,
        objective and scaled rows, as :attr:`SteadyStateProblem.symbols`.
    """
    import casadi as ca

    jopt: dict[str, Any] = {"jac_penalty": 0.5, "der_options": {"jac_penalty": 0.5}}
    funs: list[tuple[PhysParams, float, Any]] = []

    def wheel_function(ph: PhysParams, rs: float) -> Any:
        for ph_, rs_, fun in funs:
            if (ph_ is ph or ph_ == ph) and rs_ == rs:
                return fun
        q, s = ca.SX.sym("q", len(_WHEEL_STATE)), ca.SX.sym("speed")
        vx, vy = model.statics.wheel_velocity(CASADI, s, q[0])
        w, _ = wrench_core(CASADI, vx, vy, q[1], q[2], q[3], ph, model.options)
        w0, _ = wrench_core(CASADI, vx, vy, s / rs, q[3], q[3], ph, model.options)
        fun = ca.Function(f"wheel_{len(funs)}", [q, s], [ca.vertcat(*w, w0[2])], ["q", "speed"], ["w"], jopt)
        funs.append((ph, rs, fun))
        return fun

    nw = len(model.wheels)
    xs, p = ca.SX.sym("x", L.nx), ca.SX.sym("p", L.np_)
    x = xs * ca.DM(L.variable_scale)
    P = {n: p[L.index(n)] for n in L.parameter_names}
    xw = {k: tuple(x[L.var(v, k)] for v in WHEEL_VARIABLES) for k in model.wheels}
    ws = ca.SX.sym("w", 7, nw)
    blocks: list[tuple[Any, ...]] = []
    for i in range(nw):  # [wheel 0, its zero-slip state, ...]: only F_z of the zero-slip state enters the rows
        blocks += [tuple(ws[j, i] for j in range(6)), (0.0, 0.0, ws[6, i], 0.0, 0.0, 0.0)]
    rows, f, _ = steady_state_rows(CASADI, model, xw, P, wrenches=blocks)
    g = ca.vertcat(*(rows[b.name] / b.scale for b in L.constraints))
    outer = ca.Function("steady_state_rows", [xs, p, ws], [g, f], ["x", "p", "w"], ["g", "f"])
    xm, pm = ca.MX.sym("x", L.nx), ca.MX.sym("p", L.np_)
    xph = xm * ca.DM(L.variable_scale)
    speed = pm[L.index("speed")]
    cols = [wheel_function(model.phys[i], model.shearing_radius[i])(
        ca.vertcat(*(xph[L.var(v, k)] for v in _WHEEL_STATE)), speed) for i, k in enumerate(model.wheels)]
    gm, fm = outer(xm, pm, ca.horzcat(*cols))
    return xm, pm, fm, gm


class SteadyStateProblem:
    """The NLP (7.25) for one rover, parameter set, exit-angle model and trench wheel.

    Built once (graph and IPOPT instance); :meth:`solve` takes a scenario's bounds and
    parameters and a start point. Use :func:`solve_primitive` for the automatic strategy.

    Attributes
    ----------
    layout : rtctl.layout.NlpLayout
        Names, slices and scales of variables, parameters (in :data:`rtctl.layout.PARAMETERS`
        order) and constraint rows.
    symbols : dict
        casadi SX ``"x"`` (scaled variables, ``x_phys = x * layout.variable_scale``), ``"p"``
        (physical parameters), ``"f"`` (objective), ``"g"`` (rows = physical residual /
        ``layout.constraint_scale``).
    rs_of, model_of : dict
        Per wheel: shearing radius r_s = r + h_g (eq. (5.2)) and wheel model (the parameter
        set's wheel, or its rim radius replaced by ``wheel_radius``).

    Parameters
    ----------
    params, rover, exit_angle, trench_wheel, options
        As :func:`get_problem`.
    external : tuple of 3 float, optional
        Constant body-frame pull ``(F_x, F_y, M_z about O)`` (N, N, N m), added to the balance
        (:meth:`offline.rover.statics.FourWheelRocker.balance`); None: no term in the graph.
    wheel_radius : tuple of 4 float, optional
        Rim radius per wheel (FR, FL, RR, RL), m; None: the parameter set's on every wheel.
        The variable scales stay those of the parameter set's wheel (within a few per cent).
    hub : HubFace, optional
        Hub contact on every wheel: the drag of :func:`rtctl.physics.hub_drag.hub_wrench`
        (the parameter set's soil) added to each wheel's wrench (:meth:`with_hub`) in the graph,
        the independent check and the tables' stored wrenches; None: no term in the graph.
    rover_file : RoverSpec, optional
        A rover described by a file (:mod:`rtctl.physics.rover_file`): the wheels are its wheels
        in file order, the balance rows those its suspension implies
        (:class:`rtctl.physics.suspension.SuspensionStatics`: the generalisation of
        (7.12)-(7.18), (7.23), (7.32)-(7.33)), the independent check its free bodies
        (:class:`offline.rover.statics.FreeBodyBalance`); its steering ranges, driven flags and
        actuator limits bound each wheel (:meth:`wheel_bounds`). ``rover`` then only carries
        the weight, speed and the length of the moment scale (the wheelbase,
        :func:`offline.rover.scenario.rover_scale_record`). None: the mini rover of Table 7.2
        (:class:`~offline.rover.statics.FourWheelRocker`), exactly as before.

    Notes
    -----
    Scales: loads and torques by ``W / N`` (``N`` wheels; for the mini rover ``W / 4`` as
    before), moment rows by ``W`` times the rocker length (mini rover) or wheelbase (rover
    file), the height-compatibility rows of a rigid frame by ``r_s / 4``.
    """

    def __init__(self, params: ParameterSet, rover: Rover, exit_angle: str = "classic",
                 trench_wheel: str | None = None, options: SolverOptions | None = None,
                 external: tuple[float, float, float] | None = None,
                 wheel_radius: tuple[float, ...] | None = None, hub: HubFace | None = None,
                 rover_file: RoverSpec | None = None) -> None:
        import casadi as ca

        t0 = time.perf_counter()
        self.params, self.rover, self.exit_angle, self.trench_wheel = params, rover, exit_angle, trench_wheel
        self.options = options or SolverOptions()
        self.model_options = ModelOptions(exit_angle=exit_angle,  # type: ignore[arg-type]
                                          shear_direction_smoothing=self.options.shear_direction_smoothing)
        self.rover_file = rover_file
        self.wheels: tuple[str, ...] = WHEELS if rover_file is None else rover_file.wheel_names
        """Wheel names in layout order."""
        WH = self.wheels
        self.statics: FourWheelRocker | SuspensionStatics
        if rover_file is None:
            self.statics = FourWheelRocker(rover, self.options.pitch_includes_wheel_torque)
            self.free_body: FreeBodyBalance | None = None
        else:
            self.statics = SuspensionStatics(rover_file, None, self.options.pitch_includes_wheel_torque)
            self.free_body = FreeBodyBalance(rover_file, self.options.pitch_includes_wheel_torque)
        self.mirror = mirror_wheels(rover_file)
        """Left-right mirror-image wheel of each wheel (None: the rover is not symmetric)."""
        self.weight = float(rover.weight if rover_file is None else rover_file.weight)
        self.length = float(rover.rocker_length)
        """Length of the moment scale, m: rocker length (mini rover) or wheelbase (rover file)."""
        self.model = WheelModel(params.soil, params.wheel, params.tuning, self.model_options)
        wheel = params.wheel
        self.rs = wheel.shearing_radius
        self.external, self.wheel_radius, self.hub = external, wheel_radius, hub
        self._wheel_functions: dict[str, Any] = {}
        wheel_of = {k: wheel if wheel_radius is None or wheel_radius[i] == wheel.radius
                    else replace(wheel, radius=float(wheel_radius[i])) for i, k in enumerate(WH)}
        self.rs_of = {k: w.shearing_radius for k, w in wheel_of.items()}
        self.radius_of = {k: w.radius for k, w in wheel_of.items()}
        self.model_of = {k: self.model if w is wheel else WheelModel(params.soil, w, params.tuning, self.model_options)
                         for k, w in wheel_of.items()}
        W = self.weight
        n = len(WH)
        self.torque_scale = W / n * self.rs
        self.layout = NlpLayout.build(
            {"omega": rover.travel_speed / self.rs, "beta": 0.3, "W": W / n, "h": self.rs / 4, "h0": self.rs / 4},
            {"force": W, "moment": W * self.length, "load": W / n, "torque": self.torque_scale,
             "trench_area": 1e-4, "trench_length": 1e-2, "height": self.rs / 4},
            trench_wheel=trench_wheel, wheels=WH, balance_rows=self.statics.balance_names)
        L = self.layout
        if rover_file is None and tuple(L.parameter_names) != PARAMETERS:
            raise RuntimeError(f"internal: the mini rover's layout parameters {L.parameter_names} are not {PARAMETERS}")
        self.xscale = L.variable_scale
        self.gscale = L.constraint_scale
        self.ng = L.ng
        phys = PhysParams.from_sets(params.soil, wheel, params.tuning)
        phys_of = {k: phys if w is wheel else PhysParams.from_sets(params.soil, w, params.tuning)
                   for k, w in wheel_of.items()}
        self.steady_state = SteadyStateModel(
            tuple(WH), tuple(phys_of[k] for k in WH), tuple(self.rs_of[k] for k in WH), self.model_options,
            self.statics, params.soil, hub, external, trench_wheel, self.torque_scale)
        """The rows' definition shared with the rover's exact residual (:mod:`rtctl.physics.steady_state`)."""
        xs: Any
        p: Any
        self.nlp_structure = self.options.nlp_structure
        """The graph built: ``"inlined"`` or ``"per_wheel"`` (``"auto"`` resolved, :class:`SolverOptions`)."""
        if self.nlp_structure == "auto":
            compiled = self.options.compile != "off" and find_compiler() is not None
            self.nlp_structure = "per_wheel" if compiled else "inlined"
        if self.nlp_structure == "per_wheel":
            xs, p, f, g = per_wheel_graph(self.steady_state, L)
        else:
            xs = ca.SX.sym("x", L.nx)
            p = ca.SX.sym("p", L.np_)
            x = xs * ca.DM(self.xscale)
            P = {n: p[L.index(n)] for n in L.parameter_names}
            xw = {k: tuple(x[L.var(v, k)] for v in WHEEL_VARIABLES) for k in WH}
            rows, f, _ = steady_state_rows(CASADI, self.steady_state, xw, P)
            g = ca.vertcat(*(rows[b.name] / b.scale for b in L.constraints))
        self.symbols = {"x": xs, "p": p, "f": f, "g": g}
        self.g_names = L.constraint_names
        self._nlp = {"x": xs, "p": p, "f": f, "g": g}
        self._compiled: dict[str, Any] | None = None
        self.solver = ca.nlpsol("primitive", "ipopt", self._nlp, self._ipopt_options(warm=False))
        self._compiled = compiled_functions(self.solver, self.options.compile, "steady-state NLP")
        """IPOPT's functions as compiled C (None: casadi's virtual machine), :mod:`.compiled_nlp`."""
        if self._compiled is not None:
            self.solver = ca.nlpsol("primitive", "ipopt", self._nlp, self._ipopt_options(warm=False))
        self._solvers: dict[tuple[bool, int | None], Any] = {}  # (warm start, max_iter) -> IPOPT instance
        self.eval_g = ca.Function("eval_g", [xs, p], [g, f])
        self.build_seconds = time.perf_counter() - t0

    def with_hub(self, ops: Backend, w: Sequence[Any], vx: Any, vy: Any, omega: Any, h: Any) -> tuple[Any, ...]:
        """A wheel's soil wrench (wheel frame, about its centre) plus the hub drag
        (:func:`rtctl.physics.hub_drag.hub_wrench`: ``F_x``, ``F_y`` against the travel and
        ``M_y`` against the spin); the wrench itself, unchanged, without hub contact. The one
        place every path (NLP graph, independent check, tables) adds the term."""
        return with_hub(ops, self.steady_state, w, vx, vy, omega, h)

    def wheel_wrench(self, wheel: str, vx: float, vy: float, omega: float, h: float,
                     h0: float) -> tuple[tuple[float, ...], Any]:
        """Numeric wrench of one wheel (numpy model of its own radius, hub drag included) and the
        model's :class:`~offline.physics.terramechanics.Wrench` (slip, slip angle)."""
        w = self.model_of[wheel].wrench(vx, vy, omega, h, h0)
        soil = tuple(float(np.asarray(q).ravel()[0]) for q in w.as_array())
        return tuple(float(np.asarray(q).ravel()[0]) for q in self.with_hub(NUMPY, soil, vx, vy, omega, h)), w

    def wheel_function(self, wheel: str) -> Any:
        """``casadi.Function`` ``(v_x, v_y, omega, h, h0) -> (w[6], J[6x5])`` of one wheel's wrench
        with the hub drag (exact Jacobian); the wheel model's own function without hub contact."""
        model = self.model_of[wheel]
        if self.hub is None:
            return model.casadi_function(jacobian=True)
        if wheel not in self._wheel_functions:
            import casadi as ca

            z = ca.SX.sym("x", 5)
            wr, _ = model.expressions(z[0], z[1], z[2], z[3], z[4])
            w = ca.vertcat(*self.with_hub(CASADI, wr, z[0], z[1], z[2], z[3]))
            self._wheel_functions[wheel] = ca.Function("wheel_wrench_hub_jac", [z], [w, ca.jacobian(w, z)], ["x"], ["w", "J"])
        return self._wheel_functions[wheel]

    def _ipopt_options(self, warm: bool, max_iter: int | None = None) -> dict[str, Any]:
        o = self.options
        io = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": o.tol, "calc_lam_p": False,
              "ipopt.max_iter": o.max_iter if max_iter is None else int(max_iter),
              "ipopt.mu_strategy": "adaptive", "ipopt.hessian_approximation": o.hessian, "ipopt.constr_viol_tol": 1e-9}
        if self._compiled is not None:
            io["cache"] = self._compiled
        if warm:
            io.update({"ipopt.warm_start_init_point": "yes", "ipopt.warm_start_bound_push": 1e-9,
                       "ipopt.warm_start_mult_bound_push": 1e-9, "ipopt.mu_init": 1e-6})
        return io

    # ------------------------------------------------------------------ bounds
    def wheel_bounds(self, sc: Scenario, wheel: str) -> WheelBounds:
        """Physical bounds of one wheel: the general bounds (7.2)-(7.5), with a rover file its
        wheel's steering range (a wheel that does not steer: ``beta = 0``), drive (an undriven
        wheel: torque row 0) and actuator limits (wheel speed, torque), then every failure kind
        (steering angles in physical terms: :meth:`~offline.rover.scenario.Scenario.physical_failure`)."""
        w = self.params.wheel
        rs = self.rs_of[wheel]
        hmin, hmax = w.grouser_height, 1.5 * self.radius_of[wheel] + w.grouser_height
        wb = WheelBounds(lo={"omega": 0.0, "beta": -BETA_LIMIT, "W": 0.0, "h": hmin, "h0": hmin},
                         hi={"omega": self.options.max_rim_speed_factor * sc.speed / rs, "beta": BETA_LIMIT,
                             "W": self.weight / 2, "h": hmax, "h0": hmax},
                         rim_radius=self.rs, speed=sc.speed)  # command radius: caps are on rim-speed commands
        if self.rover_file is not None:
            spec, act = self.rover_file.wheel(wheel), self.rover_file.actuators
            if spec.steerable:
                wb.lo["beta"], wb.hi["beta"] = max(wb.lo["beta"], spec.steer_min), min(wb.hi["beta"], spec.steer_max)
            else:
                wb.lo["beta"] = wb.hi["beta"] = 0.0
            wb.hi["omega"] = min(wb.hi["omega"], act.drive_speed_max)
            wb.torque = (0.0, 0.0) if not spec.driven else (-act.drive_torque_max, act.drive_torque_max)
        for kind in sc.physical_failure(wheel).kinds():
            kind.apply(wb)
        return wb

    def bounds(self, sc: Scenario) -> dict[str, NDArray[np.float64]]:
        """Variable (scaled) and constraint (scaled) bounds and parameters (physical) of a scenario."""
        L = self.layout
        lbx, ubx = np.zeros(L.nx), np.zeros(L.nx)
        lbg, ubg = np.zeros(L.ng), np.zeros(L.ng)
        par = {"speed": sc.speed, "slope": sc.slope, "cross_slope": sc.cross_slope, "fy_offset": sc.fy_offset,
               "mz_offset": sc.mz_offset}
        for k in self.wheels:
            wb = self.wheel_bounds(sc, k)
            for v in WHEEL_VARIABLES:
                lbx[L.var(v, k)], ubx[L.var(v, k)] = wb.lo[v], wb.hi[v]
            j = L.index(f"wheel torque {k}")
            lbg[j], ubg[j] = wb.torque
            par[f"contact {k}"] = wb.contact
        # a raised wheel means a stuck suspension: the pivot transmits the pitch moment
        par["pivot_locked"] = float(any(par[f"contact {k}"] == 0.0 for k in self.wheels))
        if self.trench_wheel:
            for row, (lo, hi) in (sc.trench.row_bounds() if sc.trench is not None else {
                    "clean-side pile": (-math.inf, math.inf), "depth": (-math.inf, math.inf),
                    "flat width": (-math.inf, math.inf)}).items():
                j = L.index(f"trench {row} {self.trench_wheel}")
                lbg[j], ubg[j] = lo, hi
        p = np.array([par[n] for n in L.parameter_names])
        return {"lbx": lbx / self.xscale, "ubx": ubx / self.xscale, "lbg": lbg / self.gscale, "ubg": ubg / self.gscale,
                "p": p}

    def guess(self, sc: Scenario, omega: Sequence[float], beta: Sequence[float], load: Sequence[float]) -> NDArray[np.float64]:
        """A start point from wheel speeds, angles and loads, with every sinkage (and
        zero-slip sinkage) solved from its load so the load constraints hold at the start."""
        om, b, W = (np.asarray(a, dtype=float) for a in (omega, beta, load))
        vx, vy = self.statics.wheel_velocity(NUMPY, sc.speed, b)
        if self.wheel_radius is None:
            sol = self.model.sinkage_from_load(np.maximum(W, 1e-3), vx, vy, om)
            h = np.where(sol.converged, sol.h, self.rs / 4)
            h0 = np.where(sol.converged, sol.h_zero_slip, h)
        else:  # one wheel model per radius
            h, h0 = np.zeros(len(self.wheels)), np.zeros(len(self.wheels))
            for i, k in enumerate(self.wheels):
                si = self.model_of[k].sinkage_from_load(np.maximum(W[i:i + 1], 1e-3), vx[i:i + 1], vy[i:i + 1], om[i:i + 1])
                h[i] = float(np.where(si.converged, si.h, self.rs / 4)[0])
                h0[i] = float(np.where(si.converged, si.h_zero_slip, h[i])[0])
        x = np.zeros(self.layout.nx)
        for i, k in enumerate(self.wheels):
            for v, val in zip(WHEEL_VARIABLES, (om[i], b[i], W[i], h[i], h0[i])):
                x[self.layout.var(v, k)] = val
        return x / self.xscale

    def nominal_guess(self, sc: Scenario, slip: float = 0.08) -> NDArray[np.float64]:
        """Symmetric start: straight wheels at a slip (negative: skid), equal loads, sinkage from load."""
        n = len(self.wheels)
        load = self.weight * math.cos(sc.slope) * math.cos(sc.cross_slope) / n
        om = [sc.speed / (self.rs_of[k] * (1 - slip)) if slip >= 0 else sc.speed * (1 + slip) / self.rs_of[k]
              for k in self.wheels]
        return self.guess(sc, om, [0.0] * n, [load] * n)

    def physical(self, x: NDArray[np.float64]) -> dict[str, dict[str, float]]:
        """Physical variables by wheel: ``{wheel: {omega, beta, W, h, h0}}``."""
        xp = np.asarray(x, dtype=float) * self.xscale
        return {k: {v: float(xp[self.layout.var(v, k)]) for v in WHEEL_VARIABLES} for k in self.wheels}

    def violation(self, b: dict[str, NDArray[np.float64]], x: NDArray[np.float64], g: NDArray[np.float64]) -> float:
        """Largest scaled violation of the bounds ``b`` by the point ``x`` with rows ``g``."""
        v = np.concatenate([np.maximum(b["lbg"] - g, 0), np.maximum(g - b["ubg"], 0),
                            np.maximum(b["lbx"] - x, 0), np.maximum(x - b["ubx"], 0)])
        return float(np.max(v)) if v.size and np.isfinite(v).all() else math.inf

    # ------------------------------------------------------------------ solve
    def solve(self, b: dict[str, NDArray[np.float64]], x0: NDArray[np.float64], lam_x0: NDArray[np.float64] | None = None,
              lam_g0: NDArray[np.float64] | None = None, max_iter: int | None = None) -> dict[str, Any]:
        """One IPOPT run from ``x0`` (scaled; clipped into the bounds).

        With multipliers ``lam_x0``, ``lam_g0`` (from a previous result) IPOPT is warm-started
        (``warm_start_init_point``). ``max_iter``: this run's iteration budget (default the
        options' ``max_iter``; an IPOPT instance per budget is built once and kept). Returns ``x`` (scaled), ``g`` (scaled rows), ``f``,
        ``lam_x``, ``lam_g`` (IPOPT multipliers), ``status`` (IPOPT return status),
        ``iterations``, ``success`` (converged and within ``feasibility_tol``), ``feasible``
        (the end point satisfies the constraints) and ``violation``.
        """
        import casadi as ca

        x0 = np.clip(np.asarray(x0, dtype=float), b["lbx"], b["ubx"])
        args = {"x0": x0, "p": b["p"], "lbx": b["lbx"], "ubx": b["ubx"], "lbg": b["lbg"], "ubg": b["ubg"]}
        warm = lam_x0 is not None or lam_g0 is not None
        mi = None if max_iter is None or int(max_iter) == self.options.max_iter else int(max_iter)
        solver: Any
        if not warm and mi is None:
            solver = self.solver
        else:
            solver = self._solvers.get((warm, mi))
            if solver is None:
                name = "primitive" + ("_warm" if warm else "") + (f"_{mi}" if mi is not None else "")
                solver = self._solvers[(warm, mi)] = ca.nlpsol(name, "ipopt", self._nlp, self._ipopt_options(warm, mi))
        if warm:
            args["lam_x0"] = np.zeros(self.layout.nx) if lam_x0 is None else lam_x0
            args["lam_g0"] = np.zeros(self.layout.ng) if lam_g0 is None else lam_g0
        try:
            r = solver(**args)
            st = solver.stats()
            status, iters = str(st["return_status"]), int(st["iter_count"])
            x, g = np.asarray(r["x"]).ravel(), np.asarray(r["g"]).ravel()
            lam_x, lam_g, fv = np.asarray(r["lam_x"]).ravel(), np.asarray(r["lam_g"]).ravel(), float(r["f"])
        except RuntimeError as exc:  # casadi raises when IPOPT cannot even start (e.g. NaN at x0)
            status, iters = f"exception: {exc}".splitlines()[0][:120], 0
            x, g = x0.copy(), np.full(self.layout.ng, np.nan)
            lam_x, lam_g, fv = np.zeros(self.layout.nx), np.zeros(self.layout.ng), math.nan
        finite = bool(np.isfinite(x).all() and np.isfinite(g).all())
        viol = self.violation(b, x, g) if finite else math.inf
        feasible = finite and viol <= self.options.feasibility_tol
        return {"x": x, "g": g, "f": fv, "lam_x": lam_x, "lam_g": lam_g, "status": status, "iterations": iters,
                "success": status in _IPOPT_OK and feasible, "feasible": feasible, "violation": viol}


# ---------------------------------------------------------------------- results
@dataclass(frozen=True)
class WheelSolution:
    """One wheel of a driving primitive (SI; angles in rad)."""

    name: str
    omega: float
    rim_speed: float
    steer: float
    load: float
    sinkage: float
    sinkage_zero_slip: float
    slip: float
    slip_angle: float
    torque: float
    wrench: tuple[float, ...]
    failure: WheelFailure


@dataclass(frozen=True)
class PrimitiveResult:
    """A steady-state driving primitive, or the evidence that none exists.

    Attributes
    ----------
    status : str
        One of :data:`STATUSES`: ``"optimal"``, ``"infeasible"`` (evidence consistent and
        checked, confirmed by a second search), ``"not_found"`` (budget spent without a
        verdict) or ``"solver_failure"``.
    wheels : dict
        :class:`WheelSolution` per wheel (the furthest point reached when not optimal).
    power : float
        Mechanical drive power ``sum(T_i omega_i)`` with ``T = -M_y`` the motor torque, W.
    residuals : dict
        Independent numeric check: every balance and wheel constraint evaluated with the
        numpy model and the free-body balance (not casadi), in N, N m, m/s or m.
    check_passed : bool
    trench : TrenchProfile or None
    evidence : dict
        When not optimal: the constraint that could not be met, the continuation fraction
        reached, the furthest feasible point (and whether it passed the check) and what it
        shows per failure kind.
    stats : dict
        ``attempts`` (list of text), ``iterations``, ``n_attempts``, ``seconds``,
        ``build_seconds``, ``time_limit_hit``; ``lam_x``, ``lam_g`` (IPOPT multipliers, scaled
        problem) when optimal.
    x : ndarray
        Scaled decision variables (``x * layout.variable_scale`` is physical).
    """

    scenario: Scenario
    status: str
    wheels: dict[str, WheelSolution]
    power: float
    objective: float
    residuals: dict[str, float]
    check_passed: bool
    trench: Any
    evidence: dict[str, Any]
    stats: dict[str, Any]
    x: NDArray[np.float64] = field(repr=False, default_factory=lambda: np.zeros(0))

    @property
    def ok(self) -> bool:
        """True for an optimal, checked primitive."""
        return self.status == "optimal"

    def mean_slip(self, exclude_failed: bool = True) -> float:
        """Average slip of the wheels (unaffected ones only by default; Fig. 7.12)."""
        s = [w.slip for w in self.wheels.values() if not (exclude_failed and not w.failure.nominal)]
        return float(np.mean(s)) if s else math.nan

    def max_slip(self) -> float:
        """Largest slip of the wheels on the ground."""
        return float(max(w.slip for w in self.wheels.values() if not w.failure.raised))

    def table(self) -> str:
        """Per-wheel table as text."""
        lines = [f"{'wheel':<5} {'rim speed':>10} {'steer':>8} {'load':>7} {'sinkage':>8} {'slip':>7} {'torque':>8}",
                 f"{'':<5} {'[cm/s]':>10} {'[deg]':>8} {'[N]':>7} {'[mm]':>8} {'[-]':>7} {'[N m]':>8}"]
        for k, w in self.wheels.items():
            tag = "" if w.failure.nominal else "  *"
            lines.append(f"{k:<5} {100 * w.rim_speed:>10.3f} {math.degrees(w.steer):>8.2f} {w.load:>7.2f} "
                         f"{1e3 * w.sinkage:>8.2f} {w.slip:>7.3f} {w.torque:>8.4f}{tag}")
        lines.append(f"power {self.power * 1e3:.2f} mW; mean slip (unaffected wheels) {self.mean_slip():.3f}; "
                     f"max slip {self.max_slip():.3f}")
        return "\n".join(lines)


def _wheel_solutions(pb: SteadyStateProblem, sc: Scenario, x: NDArray[np.float64]) -> tuple[dict[str, WheelSolution], float]:
    xs = pb.physical(x)
    out: dict[str, WheelSolution] = {}
    power = 0.0
    for k in pb.wheels:
        om, b, Wi, hi, h0 = (xs[k][v] for v in WHEEL_VARIABLES)
        f = sc.failure(k)
        if f.raised:
            zero = (0.0,) * 6
            out[k] = WheelSolution(k, 0.0, 0.0, float(b), 0.0, 0.0, 0.0, 0.0, float(b), 0.0, zero, f)
            continue
        vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, b)
        wrench, w = pb.wheel_wrench(k, vx, vy, om, hi, h0)
        torque = -wrench[4]
        power += torque * om
        out[k] = WheelSolution(k, float(om), float(om * pb.rs_of[k]), float(b), float(Wi), float(hi), float(h0),
                               float(np.asarray(w.slip).ravel()[0]), float(np.asarray(w.beta).ravel()[0]), torque, wrench, f)
    return out, power


def _numeric_point(pb: SteadyStateProblem, x: NDArray[np.float64], p: NDArray[np.float64]) -> dict[str, Any]:
    """Independent numeric evaluation of a point: wheel wrenches (numpy model), zero-slip
    loads and the free-body balance (:func:`offline.rover.statics.free_body_residuals`; with a
    rover file :class:`offline.rover.statics.FreeBodyBalance`)."""
    L = pb.layout
    P = {n: float(p[L.index(n)]) for n in L.parameter_names}
    xs = pb.physical(x)
    wr: dict[str, tuple[float, ...]] = {}
    beta, h, load, contact, fz0 = {}, {}, {}, {}, {}
    for k in pb.wheels:
        om, b, Wi, hi, h0 = (xs[k][v] for v in WHEEL_VARIABLES)
        contact[k] = P[f"contact {k}"]
        vx, vy = pb.statics.wheel_velocity(NUMPY, P["speed"], b)
        if contact[k] == 0.0:
            wr[k], fz0[k] = (0.0,) * 6, Wi
        else:
            wr[k] = tuple(q * contact[k] for q in pb.wheel_wrench(k, vx, vy, om, hi, h0)[0])
            fz0[k] = float(np.asarray(pb.model_of[k].wrench(vx, vy, P["speed"] / pb.rs_of[k], h0, h0).Fz).ravel()[0])
        beta[k], h[k], load[k] = b, hi, Wi
    if pb.free_body is None:
        bal = free_body_residuals(pb.rover, wr, beta, h, load, P["slope"], P["cross_slope"], P["fy_offset"],
                                  P["mz_offset"], contact, pb.options.pitch_includes_wheel_torque, pb.external)
    else:
        bal = pb.free_body.residuals(wr, beta, h, load, P["slope"], P["cross_slope"], P["fy_offset"], P["mz_offset"],
                                     contact, pb.external)
    if P["pivot_locked"] and "My_right" in bal:
        bal["My_right"], bal["My_left"] = bal["My_right"] + bal["My_left"], 0.0
    return {"wrench": wr, "fz0": fz0, "balance": bal, "phys": xs, "P": P}


def check_solution(pb: SteadyStateProblem, sc: Scenario, x: NDArray[np.float64]) -> tuple[dict[str, float], bool]:
    """Re-evaluate a solution independently: numpy wheel model, free-body balance (3-D
    positions, rotation matrices; :func:`offline.rover.statics.free_body_residuals`) and
    each failure kind's and the trench goal's own check.

    Returns every residual in physical units and whether all are within
    ``options.check_rtol`` (relative to the weight, or weight times rocker length / wheelbase;
    speeds to the travel speed; trench dimensions to 0.5 mm absolute; a rigid frame's wheel
    heights from their plane to ``check_rtol`` times the shearing radius). With a rover file
    also its wheels' own constraints: a wheel that does not steer points straight
    (``steer <wheel>``), an undriven wheel has no torque (``undriven torque <wheel>``).
    """
    W, lr = pb.weight, pb.length
    b = pb.bounds(sc)
    num = _numeric_point(pb, x, b["p"])
    res: dict[str, float] = {}
    tol: dict[str, float] = {}
    rtol = pb.options.check_rtol
    for k in pb.wheels:
        ph = num["phys"][k]
        if pb.rover_file is not None:
            spec = pb.rover_file.wheel(k)
            if not spec.steerable:
                res[f"steer {k}"], tol[f"steer {k}"] = ph["beta"], 1e-9
            if not spec.driven:
                res[f"undriven torque {k}"], tol[f"undriven torque {k}"] = num["wrench"][k][4], rtol * W * lr
        if num["P"][f"contact {k}"] != 0.0:
            res[f"load {k}"] = num["wrench"][k][2] - ph["W"]
            res[f"zero-slip load {k}"] = num["fz0"][k] - ph["W"]
            tol[f"load {k}"] = tol[f"zero-slip load {k}"] = rtol * W
        view = SolutionView(ph["omega"], ph["beta"], ph["W"], ph["h"], num["wrench"][k][4], pb.rs, sc.speed)
        for kind in sc.physical_failure(k).kinds():
            for name, (val, scale) in kind.check(view).items():
                key = f"{name} {k}"
                if not math.isfinite(scale):
                    scale = W * lr if "torque" in name else W
                res[key], tol[key] = float(val), rtol * scale
    if sc.trench is not None:
        from rtctl.physics.soil_flow import trench_profile

        ph = num["phys"][sc.trench.wheel]
        tp = trench_profile(ph["h"], ph["beta"], ph["omega"], sc.speed * math.cos(ph["beta"]), pb.params.wheel, pb.params.soil)
        for name, (val, t) in sc.trench.check(tp).items():
            res[name], tol[name] = float(val), t
    for n, v in num["balance"].items():
        res[f"balance {n}"] = float(v)
        tol[f"balance {n}"] = rtol * (W if n in ("Fx", "Fy", "Fz") else pb.rs if n == "height_plane" else W * lr)
    ok = all(math.isfinite(res[k]) and abs(res[k]) <= tol[k] for k in res)
    return res, ok


def _point_check(pb: SteadyStateProblem, x: NDArray[np.float64], b: dict[str, NDArray[np.float64]]) -> tuple[bool, float]:
    """Is ``x`` feasible for the (intermediate) problem ``b``, by the independent numeric
    evaluation? Balance rows and loads to ``check_rtol``; bounds and the torque and trench
    rows (casadi) to ``feasibility_tol``. Returns (passed, largest relative residual)."""
    W, lr = pb.weight, pb.length
    num = _numeric_point(pb, x, b["p"])
    worst = 0.0
    for n, v in num["balance"].items():
        worst = max(worst, abs(v) / (W if n.startswith("F") else pb.rs if n == "height_plane" else W * lr))
    for k in pb.wheels:
        if num["P"][f"contact {k}"] != 0.0:
            worst = max(worst, abs(num["wrench"][k][2] - num["phys"][k]["W"]) / W,
                        abs(num["fz0"][k] - num["phys"][k]["W"]) / W)
        j = pb.layout.index(f"wheel torque {k}")
        t = num["wrench"][k][4] / pb.gscale[j]
        if not b["lbg"][j] - pb.options.feasibility_tol <= t <= b["ubg"][j] + pb.options.feasibility_tol:
            return False, worst
    g_dm, _ = pb.eval_g(x, b["p"])
    g = np.asarray(g_dm).ravel()
    for j in pb.layout.rows("trench"):
        if not b["lbg"][j] - pb.options.feasibility_tol <= g[j] <= b["ubg"][j] + pb.options.feasibility_tol:
            return False, worst
    tol = pb.options.feasibility_tol * (1 + np.abs(x))  # IPOPT relaxes bounds by ~1e-8 relative
    inside = bool(np.all(x >= b["lbx"] - tol) and np.all(x <= b["ubx"] + tol))
    return inside and worst <= pb.options.check_rtol, worst


def _interpolate(b0: dict[str, NDArray[np.float64]], b1: dict[str, NDArray[np.float64]], x0: NDArray[np.float64],
                 g0: NDArray[np.float64], t: float) -> dict[str, NDArray[np.float64]]:
    """Bounds a fraction ``t`` of the way from the nominal solution to the target scenario.

    A target bound that the nominal solution already satisfies applies at once; one that it
    violates moves linearly from the nominal value (so the start is always feasible for
    the bounds); parameters (speed, slope, cross slope, offsets, wheel contact) move linearly.
    """
    def lo(start_val: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
        fin = np.isfinite(target)
        s = np.where(fin, np.minimum(start_val, np.where(fin, target, 0.0)), 0.0)
        return np.where(fin, s + t * (np.where(fin, target, 0.0) - s), target)

    def hi(start_val: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray[np.float64]:
        fin = np.isfinite(target)
        s = np.where(fin, np.maximum(start_val, np.where(fin, target, 0.0)), 0.0)
        return np.where(fin, s + t * (np.where(fin, target, 0.0) - s), target)

    return {"lbx": lo(x0, b1["lbx"]), "ubx": hi(x0, b1["ubx"]), "lbg": lo(g0, b1["lbg"]), "ubg": hi(g0, b1["ubg"]),
            "p": b0["p"] + t * (b1["p"] - b0["p"])}


def _nominal_of(sc: Scenario) -> Scenario:
    return replace(sc, failures={}, trench=None, name=f"{sc.name} (nominal)")


def _flat_of(sc: Scenario) -> Scenario:
    return replace(sc, failures={}, trench=None, slope=0.0, cross_slope=0.0, fy_offset=0.0, mz_offset=0.0,
                   name=f"{sc.name} (flat nominal)")


class _BudgetSpent(Exception):
    """Raised inside a search when its attempt, iteration or (safety-net) time budget is spent."""


class _Search:
    """Bookkeeping of one deterministic search: attempts, iterations, the log, the best
    feasible target point and the furthest continuation point."""

    def __init__(self, pb: SteadyStateProblem, sc: Scenario, options: SolverOptions, max_attempts: int,
                 max_iterations: int, t_start: float) -> None:
        self.pb, self.sc, self.o = pb, sc, options
        self.max_attempts, self.max_iterations, self.t_start = max_attempts, max_iterations, t_start
        self.attempts = 0
        self.iterations = 0
        self.log: list[str] = []
        self.time_limit_hit = False
        self.errors = 0
        self.last_fail: dict[str, Any] | None = None

    def spent(self) -> bool:
        """Budget spent (attempts, iterations, or the optional wall-clock safety net)."""
        if self.o.time_limit is not None and time.perf_counter() - self.t_start > self.o.time_limit:
            self.time_limit_hit = True
            return True
        return self.attempts >= self.max_attempts or self.iterations >= self.max_iterations

    def charge(self, attempts: int, iterations: int) -> None:
        """Count work done elsewhere (a cached nominal primitive, a mirror-image search)."""
        self.attempts += attempts
        self.iterations += iterations

    def solve(self, b: dict[str, Any], x0: NDArray[np.float64], label: str | None = None,
              rounds: int | None = None, longer: bool = False) -> dict[str, Any]:
        """IPOPT from ``x0``; a run that stops at ``max_iter`` on a feasible point is continued
        from its end point up to ``rounds`` more times (a feasible point is never thrown away);
        with ``longer`` every run that stops at ``max_iter`` is continued."""
        if self.spent():
            raise _BudgetSpent
        rounds = self.o.continue_rounds if rounds is None else rounds
        r = self.pb.solve(b, x0)
        if not r["success"]:
            # a start that already satisfies every constraint is kept, whatever IPOPT does next
            xc = np.clip(np.asarray(x0, dtype=float), b["lbx"], b["ubx"])
            gc = np.asarray(self.pb.eval_g(xc, b["p"])[0]).ravel()
            if np.isfinite(gc).all() and self.pb.violation(b, xc, gc) <= self.o.feasibility_tol:
                r["start_feasible"] = (xc, gc)
        self.attempts += 1
        self.iterations += r["iterations"]
        n = 0
        while (not r["success"] and r["status"] == "Maximum_Iterations_Exceeded" and n < rounds
               and (r["feasible"] or longer) and np.isfinite(r["x"]).all() and not self.spent()):
            r2 = self.pb.solve(b, r["x"])
            self.attempts += 1
            self.iterations += r2["iterations"]
            n += 1
            r = r2
        if r["status"] in _IPOPT_ERROR or r["status"].startswith("exception"):
            self.errors += 1
        if label is not None:
            self.log.append(f"{label}: {r['status']}" + (f" (+{n} continued runs)" if n else ""))
        if not r["success"]:
            self.last_fail = r
        return r


def _nominal_search(pb: SteadyStateProblem, sc: Scenario, srch: _Search) -> tuple[Any, float, Any]:
    """The nominal primitive at the scenario's slope, cross slope and offsets: direct starts
    on both sides of zero slip, else continuation from flat ground with adaptive steps and
    jumps. Returns (IPOPT result or None, fraction of the way from flat reached, furthest
    point as (x, g, bounds there))."""
    nom = _nominal_of(sc)
    b1 = pb.bounds(nom)
    downhill = sc.slope < 0
    slips = (-0.05, 0.08, -0.2, 0.2) if downhill else (0.08, 0.2, -0.05, 0.02)
    for s in slips:
        r = srch.solve(b1, pb.nominal_guess(nom, s), f"nominal from a {'skid' if s < 0 else 'slip'} start ({s:+.2f})")
        if r["success"]:
            return r, 1.0, (r["x"], r["g"], b1)
    flat = _flat_of(sc)
    b0 = pb.bounds(flat)
    x0 = None
    for s in (0.08, 0.2, -0.05):
        r = srch.solve(b0, pb.nominal_guess(flat, s), f"flat-ground nominal ({s:+.2f})")
        if r["success"]:
            x0, g0 = r["x"], r["g"]
            break
    if x0 is None:
        return None, 0.0, None
    xs, gs, t, last = _continue(pb, srch, b0, b1, x0, g0, n=8, label="nominal: slope/offset continuation from flat ground")
    if t >= 1.0:
        return last, 1.0, (xs, gs, b1)
    partial = (xs, gs, _interpolate(b0, b1, x0, g0, t))
    try:
        for name, start in _jumps(pb, nom, xs, seed=srch.o.seed):
            r = srch.solve(b1, start, f"nominal: {name}")
            if r["success"]:
                return r, 1.0, (r["x"], r["g"], b1)
    except _BudgetSpent:
        srch.log.append("nominal: budget spent")
    return None, t, partial


def _continue(pb: SteadyStateProblem, srch: _Search, b0: dict[str, Any], b1: dict[str, Any], x0: NDArray[np.float64],
              g0: NDArray[np.float64], n: int, label: str) -> tuple[NDArray[np.float64], NDArray[np.float64], float, Any]:
    """Continuation from ``b0`` (solved at ``x0``) toward ``b1`` in ``n`` steps, halving a
    step that fails (down to 1/8 of it). Returns the furthest point, its fraction and the
    last successful IPOPT result (``None`` if no step succeeded)."""
    xs, gs, t, step, last = x0, g0, 0.0, 1.0 / n, None
    try:
        while t < 1.0 - 1e-12 and step >= 1.0 / (8 * n):
            t_try = min(1.0, t + step)
            r = srch.solve(_interpolate(b0, b1, x0, g0, t_try), xs)
            if r["success"]:
                xs, gs, t, last = r["x"], r["g"], t_try, r
            else:
                step /= 2
    except _BudgetSpent:
        srch.log.append(f"{label}: budget spent")
    finally:
        srch.log.append(f"{label} in {n} steps: reached t = {t:.3f}")
    return xs, gs, t, last


def _jumps(pb: SteadyStateProblem, sc: Scenario, x_partial: NDArray[np.float64], seed: int) -> list[tuple[str, NDArray[np.float64]]]:
    """Starts for a direct solve of the target from where a continuation stopped: the point
    itself, the same point with every free wheel moved to a small skid and to a small slip
    (a continuation can stall where wheels cross zero slip), and two perturbations."""
    rng = np.random.default_rng(seed)
    L = pb.layout
    out = [("jump from the continuation end", x_partial)]
    for s in (-0.05, 0.1):
        xj = x_partial.copy()
        for k in pb.wheels:
            om = sc.speed / (pb.rs_of[k] * (1 - s)) if s >= 0 else sc.speed * (1 + s) / pb.rs_of[k]
            if sc.failure(k).nominal:
                xj[L.var("omega", k)] = om / pb.xscale[L.var("omega", k)]
        out.append((f"jump with free wheels at {'skid' if s < 0 else 'slip'} {s:+.2f}", xj))
    om_i = [L.var("omega", k) for k in pb.wheels]
    b_i = [L.var("beta", k) for k in pb.wheels]
    for j in range(2):
        pert = x_partial * (1 + 0.3 * rng.standard_normal(x_partial.size) * _pattern(pb, 1.0, 0.0, 0.5, 0.3, 0.3))
        pert[b_i] += rng.uniform(-1.0, 1.0, len(b_i))
        pert[om_i] = np.abs(pert[om_i])
        out.append((f"perturbed jump {j + 1}", pert))
    return out


def _pattern(pb: SteadyStateProblem, *per_var: float) -> NDArray[np.float64]:
    """A vector with one value per wheel variable kind (omega, beta, W, h, h0), in layout order."""
    out = np.zeros(pb.layout.nx)
    for k in pb.wheels:
        for v, val in zip(WHEEL_VARIABLES, per_var):
            out[pb.layout.var(v, k)] = val
    return out


_MIRROR = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}


def mirror_wheels(rover_file: RoverSpec | None) -> dict[str, str] | None:
    """The left-right mirror-image wheel of every wheel: the mini rover's FR-FL, RR-RL without a
    rover file; with one, the wheel at ``(x, -y, z)`` on a link of the same kind, found from the
    file's positions (to 1e-9 m). None when the rover (wheels, links or centre of mass) is not
    left-right symmetric or a steering range does not mirror.

    Parameters
    ----------
    rover_file : RoverSpec or None
        The rover file (None: the mini rover).
    """
    if rover_file is None:
        return dict(_MIRROR)
    tol = 1e-9
    if abs(rover_file.centre_of_mass[1]) > tol:
        return None
    out: dict[str, str] = {}
    for w in rover_file.wheels:
        match = [v for v in rover_file.wheels
                 if all(abs(a - b) <= tol for a, b in zip(v.position, (w.position[0], -w.position[1], w.position[2])))]
        if len(match) != 1:
            return None
        v = match[0]
        if (v.steerable, v.driven) != (w.steerable, w.driven) or abs(v.steer_min + w.steer_max) > tol \
                or abs(v.steer_max + w.steer_min) > tol:
            return None
        out[w.name] = v.name
    for lk in rover_file.links:
        if not any(all(abs(a - b) <= tol for a, b in zip(m.pivot, (lk.pivot[0], -lk.pivot[1], lk.pivot[2])))
                   for m in rover_file.links):
            return None
    return out


def _mirror_depth(sc: Scenario) -> int:
    return 1 if sc.name.endswith(" (mirror)") else 0


def mirror_scenario(sc: Scenario) -> Scenario:
    """The left-right mirror image: wheels swapped with every failure kind mirrored (steer
    angles negated), lateral force and yaw moment offsets and the cross slope negated (a
    trench wheel moves to the other side; a hub contact, the same on every wheel, is kept).

    Raises
    ------
    ValueError
        The scenario's rover file is not left-right symmetric (:func:`mirror_wheels`).
    """
    mirror = mirror_wheels(sc.rover_file)
    if mirror is None:
        raise ValueError(f"scenario {sc.name}: rover {sc.rover.name!r} is not left-right symmetric; no mirror image")
    wh = sc.wheels
    fails = {mirror[k]: f.mirror() for k, f in sc.failures.items()}
    trench = None
    if sc.trench is not None:
        trench = sc.trench.mirror() if sc.rover_file is None else replace(sc.trench, wheel=mirror[sc.trench.wheel])
    world: dict[str, Any] = {}
    if sc.external is not None:
        world["external"] = sc.external.mirror()
    if sc.wheel_radius is not None:
        world["wheel_radius"] = tuple(sc.wheel_radius[wh.index(mirror[k])] for k in wh)
    if sc.steer_offset is not None:
        world["steer_offset"] = tuple(-sc.steer_offset[wh.index(mirror[k])] for k in wh)
    return replace(sc, failures=fails, trench=trench, fy_offset=-sc.fy_offset, mz_offset=-sc.mz_offset,
                   cross_slope=-sc.cross_slope, name=f"{sc.name} (mirror)", **world)


def mirror_x(x: NDArray[np.float64], layout: NlpLayout | None = None,
             mirror: dict[str, str] | None = None) -> NDArray[np.float64]:
    """Mirror a solution vector: swap left and right wheels, negate steer angles.

    Parameters
    ----------
    x : ndarray
        Decision variables in ``layout`` order.
    layout : NlpLayout, optional
        Default: the mini rover's.
    mirror : dict, optional
        Mirror-image wheel of each wheel (:func:`mirror_wheels`; default the mini rover's).
    """
    L = layout or NlpLayout.build({v: 1.0 for v in WHEEL_VARIABLES}, {"force": 1, "moment": 1, "load": 1, "torque": 1})
    mirror = mirror or _MIRROR
    out = np.asarray(x, dtype=float).copy()
    for k in L.wheels:
        for v in WHEEL_VARIABLES:
            val = x[L.var(v, k)]
            out[L.var(v, mirror[k])] = -val if v == "beta" else val
    return out


def _symmetric_guesses(pb: SteadyStateProblem, sc: Scenario, b: dict[str, Any]) -> list[tuple[str, NDArray[np.float64]]]:
    """Hand-style starts the dissertation used (section 7.2.7), generated from the failure
    kinds' start hints: the axle partner of a wheel with a steer hint mirrors it (balanced
    lateral forces and yaw), a wheel with a speed hint (locked) starts there with the other
    wheels slipping more; a trenching wheel starts turned 60-85 deg toward its allowed side,
    partner mirrored, both at 4-8x the travel speed."""
    out = []
    WH = pb.wheels
    n = len(WH)
    L = pb.layout
    mirror = pb.mirror or {}
    load = pb.weight * math.cos(sc.slope) * math.cos(sc.cross_slope) / n
    lo, hi = b["lbx"] * pb.xscale, b["ubx"] * pb.xscale
    om0 = sc.speed / (pb.rs * 0.85)
    for k in sc.failures:
        hints: dict[str, float] = {}
        wb = pb.wheel_bounds(sc, k)
        for kind in sc.physical_failure(k).kinds():
            hints.update(kind.start(wb))
        if "beta" in hints and k in mirror:
            betas = [0.0] * n
            betas[WH.index(k)], betas[WH.index(mirror[k])] = hints["beta"], -hints["beta"]
            out.append((f"mirrored partner of {k}", [om0] * n, betas))
        if "omega" in hints:
            for fast in (0.6, 0.4):
                oms = [sc.speed / (pb.rs * (1 - fast))] * n
                oms[WH.index(k)] = hints["omega"]
                out.append((f"{k} at {hints['omega']:.2f} rad/s, others at slip {fast:.1f}", oms, [0.0] * n))
                if "beta" in hints:
                    out[-1][2][WH.index(k)] = hints["beta"]
    if sc.trench is not None and sc.trench.wheel in mirror:
        k = sc.trench.wheel
        i, j = WH.index(k), WH.index(mirror[k])
        sign = -1.0 if hi[L.var("beta", k)] <= 0 else 1.0
        for ang, fast in ((75.0, 8.0), (60.0, 4.0), (85.0, 8.0)):
            betas, oms = [0.0] * n, [om0] * n
            betas[i], betas[j] = sign * math.radians(ang), -sign * math.radians(ang)
            oms[i] = oms[j] = fast * sc.speed / pb.rs
            out.append((f"trench start: {k} at {sign * ang:.0f} deg, partner mirrored, rim speed x{fast:.0f}", oms, betas))
    res = []
    col = lambda v: [L.var(v, k) for k in WH]  # noqa: E731
    for name, oms, betas in out:
        om_c = np.clip(oms, lo[col("omega")], hi[col("omega")]).tolist()
        be_c = np.clip(betas, lo[col("beta")], hi[col("beta")]).tolist()
        g = pb.guess(sc, om_c, be_c, np.clip([load] * n, lo[col("W")], hi[col("W")]).tolist())
        res.append((name, g))
    return res


def _restarts(pb: SteadyStateProblem, sc: Scenario, count: int, seed: int, spread: float) -> list[tuple[str, NDArray[np.float64]]]:
    """Seeded perturbed starts around the symmetric guess, alternating slip and skid."""
    rng = np.random.default_rng(seed)
    beta_i = [pb.layout.var("beta", k) for k in pb.wheels]
    other = np.ones(pb.layout.nx, dtype=bool)
    other[beta_i] = False
    out = []
    for k in range(count):
        guess = pb.nominal_guess(sc, (0.15, -0.1, 0.4, -0.3)[k % 4])
        pert = guess * (1 + spread * rng.standard_normal(guess.size) * _pattern(pb, 1, 0, 0.2, 0.2, 0.2))
        pert[beta_i] += rng.uniform(-0.5, 0.5, len(beta_i)) * spread / 0.3
        pert[other] = np.abs(pert[other])
        out.append((f"seeded restart {k + 1} (seed {seed})", pert))
    return out


_SEARCH_FIELDS = ("max_attempts", "max_iterations", "continue_rounds", "confirm", "confirm_starts", "confirm_rounds",
                  "seed", "time_limit", "continuation", "restarts")


def _problem_for(sc: Scenario, options: SolverOptions) -> SteadyStateProblem:
    """The cached NLP; search budgets do not change the NLP, so they do not key the cache."""
    canon = replace(options, **{k: getattr(SolverOptions(), k) for k in _SEARCH_FIELDS})
    return get_problem(sc.params, sc.rover, sc.exit_angle, sc.trench.wheel if sc.trench else None, canon, **world_of(sc))


_NOMINAL_CACHE: dict[tuple[Any, ...], tuple[Any, ...]] = {}


def _nominal(pb: SteadyStateProblem, sc: Scenario, options: SolverOptions) -> tuple[Any, float, Any, int, int, list[str]]:
    """Nominal search, cached per problem and operating point together with its cost (the
    attempts and iterations are charged again on a cache hit, so the budget accounting and
    the reported counts do not depend on what was solved before)."""
    # the search budgets are part of the key: a search cut short by a table build's small budgets
    # must not answer a later call with the default budgets (it did: the nominal rover at 25 deg
    # read "budget spent" instead of its confirmed "infeasible" in the same process)
    key = (id(pb), sc.speed, sc.slope, sc.cross_slope, sc.fy_offset, sc.mz_offset, options.seed, options.max_iter,
           options.continue_rounds, options.max_attempts, options.max_iterations) \
        + ((sc.steer_offset,) if sc.steer_offset is not None else ())
    if key not in _NOMINAL_CACHE:
        s = _Search(pb, sc, replace(options, time_limit=None), options.max_attempts, options.max_iterations, time.perf_counter())
        try:
            r, t, partial = _nominal_search(pb, sc, s)
        except _BudgetSpent:
            r, t, partial = None, 0.0, None
            s.log.append("nominal: budget spent")
        if len(_NOMINAL_CACHE) > 256:
            _NOMINAL_CACHE.clear()
        _NOMINAL_CACHE[key] = (r, t, partial, s.attempts, s.iterations, list(s.log))
    return _NOMINAL_CACHE[key]


def solve_primitive(sc: Scenario, options: SolverOptions | None = None,
                    x0: NDArray[np.float64] | None = None) -> PrimitiveResult:
    """Solve a scenario from the automatic start (module docstring); never raises on an
    infeasible scenario: the result's status is one of :data:`STATUSES` with evidence.

    Deterministic: the same scenario, options and ``x0`` give the same status, point and
    iteration count on any machine load (budgets count attempts and iterations).
    """
    options = options or SolverOptions()
    t_start = time.perf_counter()
    pb = _problem_for(sc, options)
    b1 = pb.bounds(sc)
    srch = _Search(pb, sc, options, options.max_attempts, options.max_iterations, t_start)
    best: dict[str, Any] | None = None
    feasible_target: dict[str, Any] | None = None
    furthest: tuple[Any, ...] | None = None  # (x, g, bounds there, fraction t, what was continued)

    def consider(r: dict[str, Any]) -> bool:
        nonlocal best, feasible_target
        if r["success"]:
            best = r
            return True
        if r["feasible"] and feasible_target is None:
            feasible_target = r
        elif "start_feasible" in r and feasible_target is None:
            feasible_target = {"x": r["start_feasible"][0], "g": r["start_feasible"][1]}
        return False

    def run_starts(starts: Sequence[tuple[str, NDArray[np.float64]]], suffix: str = "") -> bool:
        return any(consider(srch.solve(b1, x, f"{name}{suffix}")) for name, x in starts)

    has_failures = bool(sc.trench is not None or any(not f.nominal for f in sc.failures.values()))
    xn = None
    try:
        if x0 is not None:
            consider(srch.solve(b1, x0, "given start"))
        if best is None:
            rn, t_nom, partial, n_att, n_it, nlog = _nominal(pb, sc, options)
            srch.charge(n_att, n_it)
            srch.log.extend(nlog)
            if rn is None:
                if partial is not None:
                    furthest = (*partial, t_nom, "slope/offsets from flat ground")
            elif not has_failures:
                best = rn
            else:
                xn, gn = rn["x"], rn["g"]
                furthest = (xn, gn, pb.bounds(_nominal_of(sc)), 0.0, "failures from the nominal primitive")
                b0 = pb.bounds(_nominal_of(sc))
                if not consider(srch.solve(b1, xn, "direct from the nominal primitive")):
                    run_starts(_symmetric_guesses(pb, sc, b1))
                for n in options.continuation if best is None else ():
                    xs, gs, t, last = _continue(pb, srch, b0, b1, xn, gn, n, "failure continuation")
                    if t > furthest[3]:
                        furthest = (xs, gs, _interpolate(b0, b1, xn, gn, t), t, "failures from the nominal primitive")
                    if t >= 1.0 - 1e-12 and last is not None:
                        consider(last)
                        break
                    if run_starts(_jumps(pb, sc, xs, seed=options.seed + n), f" (after {n}-step continuation)"):
                        break
        if best is None and x0 is None and _mirror_depth(sc) == 0 and has_failures and pb.mirror is not None:
            # the rover is left-right symmetric: the mirror-image scenario takes another numerical
            # path; if it solves, its mirrored solution is a start for this one
            left_a, left_i = options.max_attempts - srch.attempts, options.max_iterations - srch.iterations
            if left_a > 2 and left_i > options.max_iter:
                mr = solve_primitive(mirror_scenario(sc), replace(options, confirm=False, max_attempts=left_a // 2,
                                                                  max_iterations=left_i // 2))
                srch.charge(mr.stats["n_attempts"], mr.stats["iterations"])
                srch.log.append(f"mirror-image scenario: {mr.status}")
                if mr.ok:
                    consider(srch.solve(b1, mirror_x(mr.x, pb.layout, pb.mirror), "from the mirrored solution"))
        if best is None:
            run_starts(_restarts(pb, sc, options.restarts, options.seed, 0.3))
    except _BudgetSpent:
        srch.log.append(f"main search budget spent ({srch.attempts} attempts, {srch.iterations} iterations"
                        + (", wall-clock safety net" if srch.time_limit_hit else "") + ")")
    if (best is None and feasible_target is None and x0 is None and _mirror_depth(sc) == 0
            and not sc.name.endswith(" (tightened)") and not srch.time_limit_hit):
        tight = _tightened(sc)
        if tight is not None:
            # a solution with stricter failures (a lower cap) satisfies this scenario's constraints
            tr = solve_primitive(tight, replace(options, confirm=False))
            srch.charge(tr.stats["n_attempts"], tr.stats["iterations"])
            srch.log.append(f"tightened scenario ({'; '.join(k.describe() for f in tight.failures.values() for k in f.kinds())}):"
                            f" {tr.status}")
            if tr.ok:
                tsr = _Search(pb, sc, options, 1 + options.continue_rounds, (1 + options.continue_rounds) * options.max_iter,
                              t_start)
                consider(tsr.solve(b1, tr.x, "from the tightened scenario's solution"))
                srch.charge(tsr.attempts, tsr.iterations)
                srch.log.extend(tsr.log)
    if best is None and feasible_target is not None and not srch.time_limit_hit:
        # a feasible point of the target is never thrown away: polish it with a fresh budget
        pol = _Search(pb, sc, options, 1 + options.confirm_rounds, options.confirm_rounds * options.max_iter, t_start)
        consider(pol.solve(b1, feasible_target["x"], "polish the feasible point reached", rounds=options.confirm_rounds))
        srch.charge(pol.attempts, pol.iterations)
        srch.log.extend(pol.log)
    confirmed = False
    if best is None and options.confirm and not srch.time_limit_hit:
        conf = _Search(pb, sc, options, options.confirm_starts * (options.confirm_rounds + 1) + 2,
                       (options.confirm_starts + 1) * (options.confirm_rounds + 1) * options.max_iter, t_start)
        starts = [("confirmation: longer run from the furthest point", furthest[0])] if furthest is not None else []
        starts += [(f"confirmation: {n}", x) for n, x in _restarts(pb, sc, options.confirm_starts, options.seed + 7919, 0.6)]
        try:
            for name, x in starts:
                if consider(conf.solve(b1, x, name, rounds=options.confirm_rounds, longer=True)):
                    break
            confirmed = best is None
        except _BudgetSpent:
            conf.log.append("confirmation budget spent")
            confirmed = best is None and not conf.time_limit_hit
        srch.charge(conf.attempts, conf.iterations)
        srch.log.extend(conf.log)
        srch.time_limit_hit = srch.time_limit_hit or conf.time_limit_hit
    evidence: dict[str, Any] = {}
    if best is not None:
        x = best["x"]
        residuals, passed = check_solution(pb, sc, x)
        status = "optimal" if passed else "solver_failure"
        if not passed:
            evidence["check"] = "IPOPT converged but the independent numeric check failed"
    else:
        evidence = _evidence(pb, sc, b1, furthest, srch.last_fail, feasible_target)
        if feasible_target is not None:
            x = feasible_target["x"]
        elif furthest is not None:
            x = furthest[0]
        else:
            x = pb.nominal_guess(sc)
        residuals, passed = check_solution(pb, sc, x)
        if srch.time_limit_hit:
            status = "not_found"
            evidence["verdict"] = "wall-clock safety net reached before a verdict"
        elif feasible_target is not None:
            status = "not_found"
            evidence["verdict"] = "a point satisfying every constraint was reached but IPOPT did not converge from it"
        elif furthest is None and srch.errors == srch.attempts and srch.attempts > 0:
            status = "solver_failure"
            evidence["verdict"] = "every IPOPT run ended in an evaluation or solver error"
        elif confirmed and evidence.get("furthest_point_checked", False):
            status = "infeasible"
            evidence["verdict"] = ("no primitive: the search and a longer, differently started confirmation search "
                                   "failed; the furthest point reached is feasible for its intermediate problem "
                                   "and passes the independent check")
        else:
            status = "not_found"
            evidence["verdict"] = "budget spent without a primitive and without consistent evidence of infeasibility"
    wheels, power = _wheel_solutions(pb, sc, x)
    trench = None
    if sc.trench is not None:
        from rtctl.physics.soil_flow import trench_profile

        w = wheels[sc.trench.wheel]
        vx = sc.speed * math.cos(w.steer)
        trench = trench_profile(w.sinkage, w.steer, w.omega, vx, sc.params.wheel, sc.params.soil)
    g, f = pb.eval_g(x, b1["p"])
    stats: dict[str, Any] = {"attempts": srch.log, "iterations": srch.iterations, "n_attempts": srch.attempts,
                             "seconds": time.perf_counter() - t_start, "build_seconds": pb.build_seconds,
                             "time_limit_hit": srch.time_limit_hit,
                             "continuation_reached": 1.0 if best is not None else (furthest[3] if furthest else 0.0)}
    if best is not None:
        stats.update(lam_x=best["lam_x"], lam_g=best["lam_g"], ipopt_status=best["status"])
    return PrimitiveResult(sc, status, wheels, power, float(f), residuals, passed, trench, evidence, stats, x)


def _tightened(sc: Scenario) -> Scenario | None:
    """The scenario with every failure kind that can be tightened tightened, or ``None``."""
    fails, changed = {}, False
    for k, f in sc.failures.items():
        kinds = []
        for kind in f.kinds():
            t = kind.tightened()
            changed = changed or t is not None
            kinds.append(t if t is not None else kind)
        fails[k] = WheelFailure.from_kinds(kinds)
    return replace(sc, failures=fails, name=f"{sc.name} (tightened)") if changed else None


def _evidence(pb: SteadyStateProblem, sc: Scenario, b1: dict[str, Any], furthest: tuple[Any, ...] | None,
              fail: dict[str, Any] | None, feasible_target: dict[str, Any] | None) -> dict[str, Any]:
    """What could not be met, and what the furthest feasible point reached shows (per failure
    kind, from the point itself: e.g. the lowest rim speed actually reached)."""
    ev: dict[str, Any] = {}
    if fail is not None and np.isfinite(fail["g"]).all():
        g = fail["g"]
        v = np.maximum(b1["lbg"] - g, 0) + np.maximum(g - b1["ubg"], 0)
        i = int(np.argmax(v))
        ev["most_violated_constraint"] = pb.layout.constraint_names[i]
        ev["violation"] = float(v[i] * pb.gscale[i])
        ev["violation_unit"] = pb.layout.constraints[i].unit
    if feasible_target is not None:
        ev["feasible_point_found"] = True
    if furthest is None:
        ev["closest"] = "no feasible point reached: the rover cannot drive here even without failures"
        ev["furthest_point_checked"] = False
        return ev
    x, _, bt, t, what = furthest
    ok, worst = _point_check(pb, x, bt)
    ev.update(continuation_reached=t, continued=what, furthest_point_checked=ok, furthest_point_worst_residual=worst)
    num = _numeric_point(pb, x, bt["p"])
    parts = []
    for k in pb.wheels:
        ph = num["phys"][k]
        view = SolutionView(ph["omega"], ph["beta"], ph["W"], ph["h"], num["wrench"][k][4], pb.rs, sc.speed)
        for kind in sc.physical_failure(k).kinds():
            e = kind.evidence(view)
            if e:
                parts.append(f"{k}: {e}")
    if sc.trench is not None:
        from rtctl.physics.soil_flow import trench_profile

        ph = num["phys"][sc.trench.wheel]
        tp = trench_profile(ph["h"], ph["beta"], ph["omega"], sc.speed * math.cos(ph["beta"]), pb.params.wheel,
                            pb.params.soil)
        parts.append(sc.trench.evidence(tp))
    P = num["P"]
    if sc.slope and abs(P["slope"] - sc.slope) > 1e-12:
        parts.append(f"steepest slope reached {math.degrees(P['slope']):.2f} deg (target {math.degrees(sc.slope):.2f})")
    if sc.cross_slope and abs(P["cross_slope"] - sc.cross_slope) > 1e-12:
        parts.append(f"largest cross slope reached {math.degrees(P['cross_slope']):.2f} deg")
    ev["closest"] = "; ".join(parts) if parts else f"continuation stopped at {t:.2f} of the way"
    return ev
def steering_controllers(sc: Scenario, primitive: PrimitiveResult, mz_offset: float = 0.2, fy_offset: float = 1.0,
                         options: SolverOptions | None = None) -> dict[str, dict[str, tuple[float, float]]]:
    """Steering controllers of section 7.2.4: re-solve with +/- yaw-moment and lateral-force
    offsets (7.26)-(7.27) from the primitive and difference the solutions.

    Returns
    -------
    dict
        ``{"Mz+": {wheel: (d rim speed [m/s], d steer [rad])}, "Mz-": ..., "Fy+": ..., "Fy-": ...}``
        per unit of the applied offset (per N m or per N).
    """
    out: dict[str, Any] = {}
    for name, kw, mag in (("Mz+", {"mz_offset": sc.mz_offset + mz_offset}, mz_offset),
                          ("Mz-", {"mz_offset": sc.mz_offset - mz_offset}, mz_offset),
                          ("Fy+", {"fy_offset": sc.fy_offset + fy_offset}, fy_offset),
                          ("Fy-", {"fy_offset": sc.fy_offset - fy_offset}, fy_offset)):
        r = solve_primitive(replace(sc, **cast(dict[str, Any], kw)), options, x0=primitive.x)
        if not r.ok:
            out[name] = {}
            continue
        out[name] = {k: ((r.wheels[k].rim_speed - primitive.wheels[k].rim_speed) / mag,
                         (r.wheels[k].steer - primitive.wheels[k].steer) / mag) for k in sc.wheels}
    return out


def slope_sweep(sc: Scenario, slopes_deg: Sequence[float], options: SolverOptions | None = None,
                progress: Callable[[float, PrimitiveResult], None] | None = None) -> list[PrimitiveResult]:
    """Solve a scenario over increasing slopes (Fig. 7.12), each warm-started from the last;
    stops after the first infeasible slope."""
    out = []
    x = None
    for a in slopes_deg:
        r = solve_primitive(replace(sc, slope=math.radians(a)), options, x0=x)
        out.append(r)
        if progress:
            progress(a, r)
        if not r.ok:
            break
        x = r.x
    return out


def envelope(sc: Scenario, slip_limit: float = 0.5, options: SolverOptions | None = None,
             step_deg: float = 2.5, max_deg: float = 40.0, refine: int = 5) -> dict[str, Any]:
    """Operational limits: the steepest feasible slope (bracketed by the sweep, then
    bisected) and the slope at which the mean slip of the unaffected wheels crosses
    ``slip_limit`` (linear interpolation between solved slopes)."""
    slopes = list(np.arange(0.0, max_deg + 1e-9, step_deg))
    sweep = slope_sweep(sc, slopes, options)
    feas = [r for r in sweep if r.ok]
    res: dict[str, Any] = {"scenario": sc.name, "sweep": sweep}
    if not feas:
        res.update(steepest_slope_deg=math.nan, slip_limit_slope_deg=math.nan)
        return res
    lo = math.degrees(feas[-1].scenario.slope)
    hi = lo + step_deg if len(feas) < len(sweep) else math.nan
    x = feas[-1].x
    if math.isfinite(hi):
        for _ in range(refine):
            mid = 0.5 * (lo + hi)
            r = solve_primitive(replace(sc, slope=math.radians(mid)), options, x0=x)
            if r.ok:
                lo, x = mid, r.x
            else:
                hi = mid
    res["steepest_slope_deg"] = lo
    res["steepest_slope_bracket_deg"] = (lo, hi)
    sl = [(math.degrees(r.scenario.slope), r.mean_slip()) for r in feas]
    cross = math.nan
    if sl[0][1] >= slip_limit:
        cross = sl[0][0]
    for (a0, s0), (a1, s1) in zip(sl[:-1], sl[1:]):
        if s0 < slip_limit <= s1:
            cross = a0 + (slip_limit - s0) / (s1 - s0) * (a1 - a0)
            break
    res["slip_limit"] = slip_limit
    res["slip_limit_slope_deg"] = cross
    return res


def lowest_speed_cap(sc: Scenario, wheel: str, options: SolverOptions | None = None, iterations: int = 8,
                     floor: float = 0.0) -> tuple[float, PrimitiveResult | None]:
    """Lowest rim-speed cap (m/s) on ``wheel`` for which a primitive exists, by bisection
    between ``floor`` and the nominal rim speed, each solve warm-started from the last
    feasible one (the dissertation's manual continuation of section 7.2.7, automated)."""
    nom = solve_primitive(replace(sc, failures={k: f for k, f in sc.failures.items() if k != wheel}), options)
    if not nom.ok:
        return math.nan, None
    hi, lo = nom.wheels[wheel].rim_speed, floor
    best, x = nom, nom.x
    base = sc.failure(wheel)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        r = solve_primitive(replace(sc, failures={**sc.failures, wheel: replace(base, rim_speed_max=mid)}), options, x0=x)
        if r.ok:
            hi, best, x = mid, r, r.x
        else:
            lo = mid
    return hi, best
