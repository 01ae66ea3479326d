"""Steady-state driving primitives: the full nonlinear optimizer of chapter 7, eq. (7.25).

For a rover, a soil and a :class:`~offline.rover.scenario.Scenario`, find the wheel speeds and
steering angles (with each wheel's load and sinkage) that hold the rover in steady straight
driving with the least actuator effort, ``min sum M_y^2`` (7.24), subject to the balance
equations (7.12)-(7.18)/(7.23) (with the slope (7.32)-(7.33) and steering offsets
(7.26)-(7.27)), the per-wheel load constraints (7.19)-(7.22), the failure constraints
(7.30)-(7.31), locked/unpowered/raised/torque-limited wheels, and trenching goals
(7.28)-(7.29).

Design (the dissertation's section 7.2.7 lists what made its solver fragile)
--------------------------------------------------------------------------
* Exact derivatives: the wheel physics is the casadi graph of
  :func:`offline.physics.terramechanics.wrench_core` (Gauss-Legendre quadrature, no finite
  differences), solved by IPOPT with the exact Hessian.
* No inner loops: per wheel the decision variables are ``omega, beta, W, h`` **and** the
  zero-slip sinkage ``h0`` that fixes theta_m0 in skid, with its own load constraint
  ``F_z(v, omega0 = v / r_s, h0, h0) = W``.
* One NLP structure per (parameters, rover, exit angle, trench wheel): a scenario only
  changes variable/constraint bounds and parameters (speed, slope, offsets, wheel contact),
  so the solver is built once and warm-started across scenarios and table grids.
* Scaled variables (typical values ``v / r_s``, 0.3 rad, ``W / 4``, ``r_s / 4``) and
  constraints (forces by the rover weight, moments by weight times rocker length).
* Automatic start: the nominal primitive from a symmetric guess, then the scenario reached
  by continuation of its bounds from the nominal solution (what the dissertation did by
  hand for the speed cap), adaptive step halving, and a few perturbed restarts. No
  per-scenario hand tuning.
* Infeasibility is reported with evidence: the furthest point of the continuation (the
  closest achievable compromise: the lowest reachable speed cap, the steepest slope, ...)
  and the constraint that could not be met.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from ..physics.backend import CASADI, NUMPY
from ..physics.params import ParameterSet, Rover
from .statics import BALANCE_NAMES, WHEELS, FourWheelRocker
from .scenario import Scenario, WheelFailure
from ..physics.terramechanics import ModelOptions, PhysParams, WheelModel, _SoilView, _WheelView, wrench_core

__all__ = [
    "SolverOptions",
    "SteadyStateProblem",
    "WheelSolution",
    "PrimitiveResult",
    "solve_primitive",
    "check_solution",
    "steering_controllers",
    "slope_sweep",
    "envelope",
    "lowest_speed_cap",
    "mirror_scenario",
    "DISSERTATION_CH7",
]

DISSERTATION_CH7 = {
    "nominal": "15 % slip on flat ground; feasible up to 24 deg; slip reaches 50 % at 12.5 deg",
    "rr_speed_cap_half": "69 % average / 76 % maximum slip on flat ground; lowest reachable cap 1.5 cm/s",
    "rr_steer_stuck_50": "40 % average slip on flat ground; slip reaches 50 % at 2.5 deg",
    "rr_trench_clean": "a clean-sided trench 2.6 cm deep predicted (1.5 cm measured) with zeta = 1",
}
"""What the dissertation reports for the chapter-7 scenarios (section 7.3.4, Fig. 7.12)."""

VARS = ("omega", "beta", "W", "h", "h0")
BETA_LIMIT = math.radians(89.0)  # |beta| < 90 deg keeps v_x > 0 (travel direction well defined)


@dataclass(frozen=True)
class SolverOptions:
    """Solver settings (not scenario data).

    Parameters
    ----------
    tol : float
        IPOPT tolerance on the scaled problem.
    max_iter : int
        IPOPT iterations per attempt.
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
        and weight times rocker length (moments).
    time_budget : float
        Seconds after which no further attempt (continuation step, restart) is started; the
        result then reports what was reached.
    """

    tol: float = 1e-9
    max_iter: int = 150
    time_budget: float = 6.5
    max_rim_speed_factor: float = 12.0
    continuation: tuple[int, ...] = (4, 12)
    restarts: int = 3
    pitch_includes_wheel_torque: bool = True
    shear_direction_smoothing: float = 1e-6
    check_rtol: float = 1e-6
    hessian: str = "exact"


@functools.lru_cache(maxsize=16)
def _problem(params: ParameterSet, rover: Rover, exit_angle: str, trench_wheel: str | None,
             options: SolverOptions) -> "SteadyStateProblem":
    return SteadyStateProblem(params, rover, exit_angle, trench_wheel, options)


class SteadyStateProblem:
    """The NLP (7.25) for one rover, parameter set, exit-angle model and trench wheel.

    Built once (graph and IPOPT instance); :meth:`solve` takes a scenario's bounds and
    parameters and a start point. Use :func:`solve_primitive` for the automatic strategy.
    """

    def __init__(self, params: ParameterSet, rover: Rover, exit_angle: str = "soil_flow",
                 trench_wheel: str | None = None, options: SolverOptions | None = None) -> None:
        import casadi as ca

        self.params, self.rover, self.exit_angle, self.trench_wheel = params, rover, exit_angle, trench_wheel
        self.options = options or SolverOptions()
        self.model_options = ModelOptions(exit_angle=exit_angle,  # type: ignore[arg-type]
                                          shear_direction_smoothing=self.options.shear_direction_smoothing)
        self.statics = FourWheelRocker(rover, self.options.pitch_includes_wheel_torque)
        self.model = WheelModel(params.soil, params.wheel, params.tuning, self.model_options)
        wheel = params.wheel
        self.rs = wheel.shearing_radius
        W = rover.weight
        v_typ = rover.travel_speed
        self.xscale = np.tile([v_typ / self.rs, 0.3, W / 4, self.rs / 4, self.rs / 4], len(WHEELS))
        phys = PhysParams.from_sets(params.soil, wheel, params.tuning)
        xs = ca.SX.sym("x", 5 * len(WHEELS))
        p = ca.SX.sym("p", 5 + len(WHEELS))  # speed, slope, fy_offset, mz_offset, contact per wheel, pivot lock
        x = xs * ca.DM(self.xscale)
        speed, slope, fyo, mzo = p[0], p[1], p[2], p[3]
        wr, beta, h, load = {}, {}, {}, {}
        g_load, g_load0, g_torque, my_all = [], [], [], []
        trench_g: list[Any] = []
        for i, k in enumerate(WHEELS):
            om, b, Wi, hi, h0 = (x[5 * i + j] for j in range(5))
            c = p[4 + i]
            vx, vy = self.statics.wheel_velocity(CASADI, speed, b)
            w6, _ = wrench_core(CASADI, vx, vy, om, hi, h0, phys, self.model_options)
            w6 = tuple(c * q for q in w6)
            w0, _ = wrench_core(CASADI, vx, vy, speed / self.rs, h0, h0, phys, self.model_options)
            wr[k], beta[k], h[k], load[k] = w6, b, hi, Wi
            g_load.append((w6[2] - Wi) / (W / 4))
            g_load0.append(c * (w0[2] - Wi) / (W / 4))
            g_torque.append(w6[4])
            my_all.append(w6[4])
            if k == trench_wheel:
                from ..physics.soil_flow import trench_quantities

                tq = trench_quantities(CASADI, hi, b, om, vx, _WheelView(phys), _SoilView(phys))
                trench_g = [tq["A_R2_margin"] * 1e4, tq["d"] * 1e2, tq["p"] * 1e2]
        bal = self.statics.balance(CASADI, wr, beta, h, load, slope, fyo, mzo)
        bal["My_right"], bal["My_left"] = self.statics.pivot_balance(bal, p[4 + len(WHEELS)])
        bal_scaled = [bal[n] / (W if n in ("Fx", "Fy", "Fz") else W * rover.rocker_length) for n in BALANCE_NAMES]
        g = ca.vertcat(*bal_scaled, *g_load, *g_load0, *g_torque, *trench_g)
        f = sum(m * m for m in my_all) / ((W / 4 * self.rs) ** 2)
        self.g_names = ([f"balance {n}" for n in ("Fx", "Fy", "Fz", "Mx", "My (both rockers)", "My (right rocker)", "Mz")] + [f"load {k}" for k in WHEELS]
                        + [f"zero-slip load {k}" for k in WHEELS] + [f"wheel torque {k}" for k in WHEELS]
                        + ([f"trench clean-side pile {trench_wheel}", f"trench depth {trench_wheel}",
                            f"trench flat width {trench_wheel}"] if trench_wheel else []))
        self.ng = int(g.shape[0])
        nlp = {"x": xs, "p": p, "f": f, "g": g}
        io = {"ipopt.print_level": 0, "print_time": 0, "ipopt.sb": "yes", "ipopt.tol": self.options.tol,
              "ipopt.max_iter": self.options.max_iter, "ipopt.mu_strategy": "adaptive",
              "ipopt.hessian_approximation": self.options.hessian, "ipopt.constr_viol_tol": 1e-9}
        t0 = time.perf_counter()
        self.solver = ca.nlpsol("primitive", "ipopt", nlp, io)
        self.eval_g = ca.Function("eval_g", [xs, p], [g, f])
        self.build_seconds = time.perf_counter() - t0

    # ------------------------------------------------------------------ bounds
    def bounds(self, sc: Scenario) -> dict[str, NDArray[np.float64]]:
        """Variable and constraint bounds and parameters of a scenario (scaled variables)."""
        wheel = self.params.wheel
        W = self.rover.weight
        hmin, hmax = wheel.grouser_height, 1.5 * wheel.radius + wheel.grouser_height
        wmax = self.options.max_rim_speed_factor * sc.speed / self.rs
        lbx, ubx = np.zeros(5 * len(WHEELS)), np.zeros(5 * len(WHEELS))
        lbg, ubg = np.zeros(self.ng), np.zeros(self.ng)
        contact = np.ones(len(WHEELS))
        t0 = 7 + 2 * len(WHEELS)
        for i, k in enumerate(WHEELS):
            f = sc.failure(k)
            om_hi = min(wmax, f.rim_speed_max / self.rs) if math.isfinite(f.rim_speed_max) else wmax
            if f.locked:
                om_hi = 0.0
            b_lo, b_hi = max(f.steer_min, -BETA_LIMIT), min(f.steer_max, BETA_LIMIT)
            if f.steer_stuck is not None:
                b_lo = b_hi = max(min(f.steer_stuck, BETA_LIMIT), -BETA_LIMIT)
            lo = [0.0, b_lo, 0.0, hmin, hmin]
            hi = [om_hi, b_hi, W / 2 * 1.0, hmax, hmax]
            if f.raised:
                contact[i] = 0.0
                lo = [sc.speed / self.rs, 0.0, 0.0, 2 * hmin, 2 * hmin]
                hi = list(lo)
            lbx[5 * i:5 * i + 5], ubx[5 * i:5 * i + 5] = lo, hi
            tq = math.inf
            if f.unpowered:
                tq = 0.0
            elif math.isfinite(f.torque_limit):
                tq = f.torque_limit
            lbg[t0 + i], ubg[t0 + i] = -tq, tq
        if self.trench_wheel:
            j = t0 + len(WHEELS)
            tr = sc.trench
            lbg[j:j + 3], ubg[j:j + 3] = -math.inf, math.inf  # no trench goal: quantities are free
            if tr is not None:
                if tr.clean_side:
                    ubg[j] = 0.0
                if tr.target_depth is not None:
                    lbg[j + 1] = ubg[j + 1] = tr.target_depth * 1e2
                elif tr.min_depth > 0:
                    lbg[j + 1] = tr.min_depth * 1e2
                if tr.min_flat_width > 0:
                    lbg[j + 2] = tr.min_flat_width * 1e2
        # a raised wheel means a stuck suspension: the pivot transmits the pitch moment
        p = np.array([sc.speed, sc.slope, sc.fy_offset, sc.mz_offset, *contact, float(np.any(contact == 0))])
        return {"lbx": lbx / self.xscale, "ubx": ubx / self.xscale, "lbg": lbg, "ubg": ubg, "p": p}

    def guess(self, sc: Scenario, omega: Sequence[float], beta: Sequence[float], load: Sequence[float]) -> NDArray[np.float64]:
        """A start point from wheel speeds, angles and loads, with every sinkage (and
        zero-slip sinkage) solved from its load so the load constraints hold at the start."""
        om, b, W = (np.asarray(a, dtype=float) for a in (omega, beta, load))
        vx, vy = self.statics.wheel_velocity(NUMPY, sc.speed, b)
        sol = self.model.sinkage_from_load(np.maximum(W, 1e-3), vx, vy, om)
        h = np.where(sol.converged, sol.h, self.rs / 4)
        h0 = np.where(sol.converged, sol.h_zero_slip, h)
        return np.stack([om, b, W, h, h0], axis=1).ravel() / self.xscale

    def nominal_guess(self, sc: Scenario, slip: float = 0.08) -> NDArray[np.float64]:
        """Symmetric start: straight wheels at a small slip, equal loads, sinkage from load."""
        n = len(WHEELS)
        load = self.rover.weight * math.cos(sc.slope) / n
        om = sc.speed / (self.rs * (1 - slip))
        return self.guess(sc, [om] * n, [0.0] * n, [load] * n)

    # ------------------------------------------------------------------ solve
    def solve(self, b: dict[str, NDArray[np.float64]], x0: NDArray[np.float64]) -> dict[str, Any]:
        """One IPOPT run; returns x (scaled), g, f, status, iterations, seconds, feasible flag."""
        t = time.perf_counter()
        x0 = np.clip(x0, b["lbx"], b["ubx"])
        r = self.solver(x0=x0, p=b["p"], lbx=b["lbx"], ubx=b["ubx"], lbg=b["lbg"], ubg=b["ubg"])
        st = self.solver.stats()
        x = np.asarray(r["x"]).ravel()
        g = np.asarray(r["g"]).ravel()
        viol = np.maximum(b["lbg"] - g, 0) + np.maximum(g - b["ubg"], 0)
        ok = bool(st["success"]) or (st["return_status"] in ("Solved_To_Acceptable_Level",) and viol.max() < 1e-6)
        return {"x": x, "g": g, "f": float(r["f"]), "status": st["return_status"], "iterations": int(st["iter_count"]),
                "seconds": time.perf_counter() - t, "success": ok and np.isfinite(x).all(), "violation": viol}


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
        ``"optimal"``, ``"infeasible"`` (with evidence) or ``"failed"`` (solver trouble).
    wheels : dict
        :class:`WheelSolution` per wheel (the best point found when not optimal).
    power : float
        Mechanical drive power ``sum(T_i omega_i)`` with ``T = -M_y`` the motor torque, W.
    residuals : dict
        Independent numeric check: every balance and wheel constraint evaluated with the
        numpy model (not casadi), in N or N m.
    check_passed : bool
    trench : TrenchProfile or None
    evidence : dict
        For infeasible scenarios: the constraint that could not be met, the continuation
        fraction reached and the closest achievable compromise.
    stats : dict
        Solver statistics: attempts, iterations, seconds, IPOPT status.
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
        return self.status == "optimal"

    def mean_slip(self, exclude_failed: bool = True) -> float:
        """Average slip of the wheels (unaffected ones only by default; Fig. 7.12)."""
        s = [w.slip for w in self.wheels.values() if not (exclude_failed and not w.failure.nominal)]
        return float(np.mean(s)) if s else math.nan

    def max_slip(self) -> float:
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
    xs = x * pb.xscale
    out: dict[str, WheelSolution] = {}
    power = 0.0
    for i, k in enumerate(WHEELS):
        om, b, Wi, hi, h0 = xs[5 * i:5 * i + 5]
        f = sc.failure(k)
        if f.raised:
            zero = (0.0,) * 6
            out[k] = WheelSolution(k, 0.0, 0.0, float(b), 0.0, 0.0, 0.0, 0.0, float(b), 0.0, zero, f)
            continue
        vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, b)
        w = pb.model.wrench(vx, vy, om, hi, h0)
        wrench = tuple(float(q) for q in w.as_array())
        torque = -wrench[4]
        power += torque * om
        out[k] = WheelSolution(k, float(om), float(om * pb.rs), float(b), float(Wi), float(hi), float(h0),
                               float(w.slip), float(w.beta), torque, wrench, f)
    return out, power


def check_solution(pb: SteadyStateProblem, sc: Scenario, x: NDArray[np.float64]) -> tuple[dict[str, float], bool]:
    """Re-evaluate a solution with the numeric (numpy) model and the rover statics.

    Returns every residual in physical units and whether all are within
    ``options.check_rtol`` (relative to the weight, or weight times rocker length).
    """
    xs = x * pb.xscale
    W, lr = pb.rover.weight, pb.rover.rocker_length
    wr, beta, h, load = {}, {}, {}, {}
    res: dict[str, float] = {}
    tol: dict[str, float] = {}
    for i, k in enumerate(WHEELS):
        om, b, Wi, hi, h0 = (float(v) for v in xs[5 * i:5 * i + 5])
        f = sc.failure(k)
        vx, vy = pb.statics.wheel_velocity(NUMPY, sc.speed, b)
        if f.raised:
            wr[k] = (0.0,) * 6
        else:
            w = pb.model.wrench(vx, vy, om, hi, h0)
            wr[k] = tuple(float(q) for q in w.as_array())
            w0 = pb.model.wrench(vx, vy, sc.speed / pb.rs, h0, h0)
            res[f"load {k}"] = wr[k][2] - Wi
            res[f"zero-slip load {k}"] = float(w0.Fz) - Wi
            tol[f"load {k}"] = tol[f"zero-slip load {k}"] = W
            if f.unpowered or math.isfinite(f.torque_limit):
                lim = 0.0 if f.unpowered else f.torque_limit
                res[f"torque {k}"] = max(abs(wr[k][4]) - lim, 0.0)
                tol[f"torque {k}"] = W * lr
            if math.isfinite(f.rim_speed_max) or f.locked:
                cap = 0.0 if f.locked else f.rim_speed_max
                res[f"rim speed {k}"] = max(om * pb.rs - cap, 0.0)
                tol[f"rim speed {k}"] = sc.speed
            if f.steer_stuck is not None:
                res[f"steer {k}"] = b - f.steer_stuck
                tol[f"steer {k}"] = 1.0
        beta[k], h[k], load[k] = b, hi, Wi
    if sc.trench is not None:
        from ..physics.soil_flow import trench_profile

        i = WHEELS.index(sc.trench.wheel)
        om, b, _, hi, _ = (float(v) for v in xs[5 * i:5 * i + 5])
        tp = trench_profile(hi, b, om, sc.speed * math.cos(b), pb.params.wheel, pb.params.soil)
        dim_tol = 5e-4 / pb.options.check_rtol  # trench dimensions to 0.5 mm (section 7.2.7 used 1 mm)
        if sc.trench.clean_side:
            res["trench rim-side pile height"] = tp.h_R2
            tol["trench rim-side pile height"] = dim_tol
        if sc.trench.target_depth is not None:
            res["trench depth"] = tp.d - sc.trench.target_depth
        else:
            res["trench depth"] = max(sc.trench.min_depth - tp.d, 0.0)
        tol["trench depth"] = dim_tol
    bal = pb.statics.balance(NUMPY, wr, beta, h, load, sc.slope, sc.fy_offset, sc.mz_offset)
    locked = float(any(sc.failure(k).raised for k in WHEELS))
    bal["My_right"], bal["My_left"] = pb.statics.pivot_balance(bal, locked)
    for n in BALANCE_NAMES:
        res[f"balance {n}"] = float(bal[n])
        tol[f"balance {n}"] = W if n in ("Fx", "Fy", "Fz") else W * lr
    ok = all(abs(res[k]) <= pb.options.check_rtol * tol[k] for k in res)
    return res, ok


def _interpolate(b0: dict[str, NDArray[np.float64]], b1: dict[str, NDArray[np.float64]], x0: NDArray[np.float64],
                 g0: NDArray[np.float64], t: float) -> dict[str, NDArray[np.float64]]:
    """Bounds a fraction ``t`` of the way from the nominal solution to the target scenario.

    A target bound that the nominal solution already satisfies applies at once; one that it
    violates moves linearly from the nominal value (so the start is always feasible for
    the bounds); parameters (speed, slope, offsets, wheel contact) move linearly.
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


@functools.lru_cache(maxsize=64)
def _nominal_solution(pb: SteadyStateProblem, speed: float, slope: float, fyo: float, mzo: float) -> tuple[Any, ...]:
    sc = Scenario("nominal", pb.params, pb.rover, pb.exit_angle, speed, 0.0, 0.0, 0.0)
    b = pb.bounds(sc)
    best = None
    for slip in (0.08, 0.2, 0.02):
        r = pb.solve(b, pb.nominal_guess(sc, slip))
        if r["success"]:
            best = r
            break
    if best is None:
        return (None, None, 0)
    x, g, attempts = best["x"], best["g"], 1
    target = Scenario("nominal", pb.params, pb.rover, pb.exit_angle, speed, slope, fyo, mzo)
    if slope or fyo or mzo:  # continuation in slope and offsets from flat ground
        b1 = pb.bounds(target)
        for n in (1, 4, 10):
            xs, gs, ok = x, g, True
            for i in range(1, n + 1):
                r = pb.solve(_interpolate(b, b1, xs, gs, i / n), xs)
                attempts += 1
                if not r["success"]:
                    ok = False
                    break
                xs, gs = r["x"], r["g"]
            if ok:
                return (xs, gs, attempts)
        return (None, None, attempts)
    return (x, g, attempts)


def solve_primitive(sc: Scenario, options: SolverOptions | None = None,
                    x0: NDArray[np.float64] | None = None) -> PrimitiveResult:
    """Solve a scenario from the automatic start (module docstring); never raises on an
    infeasible scenario: the result says ``"infeasible"`` and carries the evidence."""
    options = options or SolverOptions()
    t_start = time.perf_counter()
    pb = _problem(sc.params, sc.rover, sc.exit_angle, sc.trench.wheel if sc.trench else None, options)
    b1 = pb.bounds(sc)
    attempts: list[str] = []
    iterations = 0
    best: dict[str, Any] | None = None
    t_reached = 0.0
    last_fail: dict[str, Any] | None = None

    def try_starts(starts: Sequence[tuple[str, NDArray[np.float64]]], suffix: str = "") -> dict[str, Any] | None:
        """Direct solves of the target from each start in turn, within the time budget."""
        nonlocal iterations, last_fail
        for label, start in starts:
            if time.perf_counter() - t_start > options.time_budget:
                attempts.append("time budget spent")
                return None
            r = pb.solve(b1, start)
            iterations += r["iterations"]
            attempts.append(f"{label}{suffix}: {r['status']}")
            if r["success"]:
                return r
            last_fail = r
        return None

    if x0 is not None:
        r = pb.solve(b1, x0)
        attempts.append(f"given start: {r['status']}")
        iterations += r["iterations"]
        if r["success"]:
            best = r
    xn, gn, n_att = _nominal_solution(pb, sc.speed, sc.slope, sc.fy_offset, sc.mz_offset)
    attempts.append(f"nominal primitive ({n_att} solves): {'ok' if xn is not None else 'failed'}")
    if best is None and xn is not None:
        b0 = pb.bounds(replace(_nominal_of(sc)))
        r = pb.solve(b1, xn)
        iterations += r["iterations"]
        attempts.append(f"direct from nominal: {r['status']}")
        if r["success"]:
            best, t_reached = r, 1.0
        else:
            last_fail = r
            best = try_starts(_symmetric_guesses(pb, sc, b1))  # cheap single solves first
            t_reached = 1.0 if best is not None else 0.0
        if best is None:
            for n in options.continuation:
                if time.perf_counter() - t_start > options.time_budget:
                    attempts.append("time budget spent")
                    break
                xs, gs, t_ok = xn, gn, 0.0
                step = 1.0 / n
                t = 0.0
                while (t < 1.0 - 1e-12 and step >= 1.0 / (8 * n)
                       and time.perf_counter() - t_start < options.time_budget):
                    t_try = min(1.0, t + step)
                    r = pb.solve(_interpolate(b0, b1, xs, gs, t_try), xs)
                    iterations += r["iterations"]
                    if r["success"]:
                        xs, gs, t = r["x"], r["g"], t_try
                        t_ok = t
                    else:
                        last_fail = r
                        step /= 2  # adaptive: halve the continuation step
                attempts.append(f"continuation in {n} steps: reached t = {t_ok:.3f}")
                if t_ok > t_reached:
                    t_reached = t_ok
                    best_partial = (xs, gs)
                if t >= 1.0 - 1e-12:
                    best = {"x": xs, "g": gs, "status": "Solve_Succeeded (continuation)", "success": True}
                    break
                # the continuation path may hit a fold or a model kink (a wheel crossing from slip
                # to skid): jump to the target from where it stopped, and from perturbed points
                best = try_starts(_jumps(pb, sc, xs, seed=n), f" (after {n}-step continuation)")
                if best is not None:
                    t_reached = 1.0
                    break
    if best is None and x0 is None and _mirror_depth(sc) == 0 and time.perf_counter() - t_start < options.time_budget:
        # the rover is left-right symmetric: the mirror-image scenario takes another numerical
        # path; if it solves, its mirrored solution is a start for this one
        left = options.time_budget - (time.perf_counter() - t_start)
        mr = solve_primitive(mirror_scenario(sc), replace(options, time_budget=0.5 * left))
        attempts.append(f"mirror-image scenario: {mr.status}")
        if mr.ok:
            r = pb.solve(b1, mirror_x(mr.x))
            iterations += r["iterations"]
            attempts.append(f"from the mirrored solution: {r['status']}")
            if r["success"]:
                best, t_reached = r, 1.0
    if best is None:
        starts = [] if xn is not None else _symmetric_guesses(pb, sc, b1)
        rng = np.random.default_rng(0)
        guess = pb.nominal_guess(sc)
        for k in range(options.restarts):
            pert = guess * (1 + 0.3 * rng.standard_normal(guess.size) * np.tile([1, 0, 0.2, 0.2, 0.2], len(WHEELS)))
            pert += np.tile([0, 1, 0, 0, 0], len(WHEELS)) * rng.uniform(-0.5, 0.5, guess.size)
            starts.append((f"restart {k + 1}", pert))
        best = try_starts(starts)
        if best is not None:
            t_reached = 1.0
    evidence: dict[str, Any] = {}
    if best is not None:
        x = best["x"]
        status = "optimal"
    else:
        partial = locals().get("best_partial")
        x = partial[0] if partial is not None else (xn if xn is not None else pb.nominal_guess(sc))
        status = "infeasible" if xn is not None else "failed"
        evidence = _evidence(pb, sc, b1, xn, gn, t_reached, last_fail)
    wheels, power = _wheel_solutions(pb, sc, x)
    residuals, passed = check_solution(pb, sc, x)
    if status == "optimal" and not passed:
        status = "failed"
        evidence["check"] = "IPOPT converged but the independent numeric check failed"
    trench = None
    if sc.trench is not None:
        from ..physics.soil_flow import trench_profile

        w = wheels[sc.trench.wheel]
        vx = sc.speed * math.cos(w.steer)
        trench = trench_profile(w.sinkage, w.steer, w.omega, vx, sc.params.wheel, sc.params.soil)
    g, f = pb.eval_g(x, b1["p"])
    stats = {"attempts": attempts, "iterations": iterations, "seconds": time.perf_counter() - t_start,
             "continuation_reached": t_reached, "build_seconds": pb.build_seconds}
    return PrimitiveResult(sc, status, wheels, power, float(f), residuals, passed, trench, evidence, stats, x)


def _jumps(pb: SteadyStateProblem, sc: Scenario, x_partial: NDArray[np.float64], seed: int) -> list[tuple[str, NDArray[np.float64]]]:
    """Starts for a direct solve of the target: the furthest continuation point, and two
    perturbations of it (speeds and loads +-30 %, steering +-0.3 rad on unconstrained wheels)."""
    rng = np.random.default_rng(seed)
    out = [("jump from the continuation end", x_partial)]
    for k in range(2):
        pert = x_partial * (1 + 0.3 * rng.standard_normal(x_partial.size) * np.tile([1, 0, 0.5, 0.3, 0.3], len(WHEELS)))
        pert = pert + np.tile([0, 1, 0, 0, 0], len(WHEELS)) * rng.uniform(-1.0, 1.0, x_partial.size)
        out.append((f"perturbed jump {k + 1}", pert))
    return out


_MIRROR = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}


def _mirror_depth(sc: Scenario) -> int:
    return 1 if sc.name.endswith(" (mirror)") else 0


def mirror_scenario(sc: Scenario) -> Scenario:
    """The left-right mirror image: wheels swapped, steer angles, lateral force and yaw
    moment offsets negated (a trench wheel moves to the other side)."""
    fails = {}
    for k, f in sc.failures.items():
        fails[_MIRROR[k]] = replace(
            f, steer_stuck=None if f.steer_stuck is None else -f.steer_stuck, steer_min=-f.steer_max, steer_max=-f.steer_min)
    trench = replace(sc.trench, wheel=_MIRROR[sc.trench.wheel]) if sc.trench else None
    return replace(sc, failures=fails, trench=trench, fy_offset=-sc.fy_offset, mz_offset=-sc.mz_offset,
                   name=f"{sc.name} (mirror)")


def mirror_x(x: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mirror a solution vector: swap left and right wheels, negate steer angles."""
    xs = x.reshape(len(WHEELS), 5).copy()
    out = np.empty_like(xs)
    for i, k in enumerate(WHEELS):
        j = WHEELS.index(_MIRROR[k])
        out[j] = xs[i]
        out[j, 1] = -xs[i, 1]
    return out.ravel()


def _symmetric_guesses(pb: SteadyStateProblem, sc: Scenario, b: dict[str, Any]) -> list[tuple[str, NDArray[np.float64]]]:
    """Hand-style starts the dissertation used (section 7.2.7), generated from the scenario:
    the axle partner of a steered failed wheel mirrors it (balanced lateral forces and yaw),
    and a trenching wheel starts turned 60 deg toward its allowed side, partner mirrored, both
    rear wheels at 4x the travel speed and a sinkage near the required depth."""
    out = []
    partner = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}
    n = len(WHEELS)
    load = pb.rover.weight * math.cos(sc.slope) / n
    lo, hi = b["lbx"] * pb.xscale, b["ubx"] * pb.xscale
    om0 = sc.speed / (pb.rs * 0.85)
    for k, f in sc.failures.items():
        if f.steer_stuck is not None:
            betas = [0.0] * n
            betas[WHEELS.index(k)], betas[WHEELS.index(partner[k])] = f.steer_stuck, -f.steer_stuck
            out.append((f"mirrored partner of {k}", [om0] * n, betas))
    if sc.trench is not None:
        k = sc.trench.wheel
        i, j = WHEELS.index(k), WHEELS.index(partner[k])
        sign = -1.0 if hi[5 * i + 1] <= 0 else 1.0
        for ang, fast in ((75.0, 8.0), (60.0, 4.0), (85.0, 8.0)):
            betas, oms = [0.0] * n, [om0] * n
            betas[i], betas[j] = sign * math.radians(ang), -sign * math.radians(ang)
            oms[i] = oms[j] = fast * sc.speed / pb.rs
            out.append((f"trench start: {k} at {sign * ang:.0f} deg, partner mirrored, rim speed x{fast:.0f}", oms, betas))
    res = []
    for name, oms, betas in out:
        oms = np.clip(oms, lo[0::5], hi[0::5])
        betas = np.clip(betas, lo[1::5], hi[1::5])
        g = pb.guess(sc, oms, betas, np.clip([load] * n, lo[2::5], hi[2::5]))
        res.append((name, g))
    return res


def _evidence(pb: SteadyStateProblem, sc: Scenario, b1: dict[str, Any], xn: Any, gn: Any, t: float,
              fail: dict[str, Any] | None) -> dict[str, Any]:
    """What could not be met, and the closest achievable compromise (continuation end)."""
    ev: dict[str, Any] = {"continuation_reached": t}
    if fail is not None:
        v = fail["violation"]
        i = int(np.argmax(v))
        ev["most_violated_constraint"] = pb.g_names[i]
        ev["violation"] = float(v[i])
    if xn is None:
        ev["closest"] = "no nominal primitive: the rover cannot drive at this speed and slope even without failures"
        return ev
    b0 = pb.bounds(_nominal_of(sc))
    bt = _interpolate(b0, b1, xn, gn, t)
    parts = []
    for i, k in enumerate(WHEELS):
        f = sc.failure(k)
        if math.isfinite(f.rim_speed_max) or f.locked:
            parts.append(f"{k}: lowest reachable rim speed cap {bt['ubx'][5 * i] * pb.xscale[5 * i] * pb.rs * 100:.2f} cm/s")
        if f.steer_stuck is not None:
            lo, hi = bt["lbx"][5 * i + 1] * pb.xscale[1], bt["ubx"][5 * i + 1] * pb.xscale[1]
            parts.append(f"{k}: steer reachable within [{math.degrees(lo):.1f}, {math.degrees(hi):.1f}] deg")
        if f.unpowered or math.isfinite(f.torque_limit):
            j = 7 + 2 * len(WHEELS) + i
            parts.append(f"{k}: smallest reachable |torque| limit {bt['ubg'][j]:.4f} N m")
    if sc.slope:
        parts.append(f"steepest slope on the path {math.degrees(bt['p'][1]):.2f} deg")
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
    out = {}
    for name, kw, mag in (("Mz+", {"mz_offset": sc.mz_offset + mz_offset}, mz_offset),
                          ("Mz-", {"mz_offset": sc.mz_offset - mz_offset}, mz_offset),
                          ("Fy+", {"fy_offset": sc.fy_offset + fy_offset}, fy_offset),
                          ("Fy-", {"fy_offset": sc.fy_offset - fy_offset}, fy_offset)):
        r = solve_primitive(replace(sc, **kw), options, x0=primitive.x)
        if not r.ok:
            out[name] = {}
            continue
        out[name] = {k: ((r.wheels[k].rim_speed - primitive.wheels[k].rim_speed) / mag,
                         (r.wheels[k].steer - primitive.wheels[k].steer) / mag) for k in WHEELS}
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
