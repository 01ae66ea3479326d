"""Controller configuration: actuator limits, noise levels, gains, QP settings (TOML).

One frozen :class:`ControllerConfig` holds everything :class:`rtctl.controller.Controller`
needs besides its tables; nothing global. The file is TOML with degrees where a human writes
angles (keys ending in ``_deg``), converted to radians once here; every other value is SI.
Unknown sections or keys, wrong types and out-of-range values raise :class:`ConfigError`
naming the file, the section and the key, e.g.::

    controller.toml: [actuators] max_steer_deg = -5.0: must be > 0 (got -5.0)

Every key has a default (:data:`DEFAULT_TOML` shows them all), so an empty file is valid.
A gain left at ``nan`` means "from the table" (the section 7.2.4 steering controllers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from .physics.parameters import read_toml

__all__ = ["ConfigError", "Actuators", "Drive", "Noise", "EstimatorSettings", "OuterLoop", "QpSettings",
           "ControllerConfig", "DEFAULT_TOML"]


class ConfigError(ValueError):
    """A configuration file or value that is malformed; the message names the key and the fix."""


def _deg(x: float) -> float:
    return math.radians(x)


# Each field: (toml key, converter from file units to SI, check, description). The check returns
# an error text or None.
def _pos(v: float) -> str | None:
    return None if (math.isfinite(v) and v > 0) else "must be finite and > 0"


def _nonneg(v: float) -> str | None:
    return None if (math.isfinite(v) and v >= 0) else "must be finite and >= 0"


def _count(v: float) -> str | None:
    return None if (v >= 0 and v == int(v)) else "must be an integer >= 0"


def _any_finite(v: float) -> str | None:
    return None if math.isfinite(v) else "must be finite"


def _gain(v: float) -> str | None:
    return None if (math.isnan(v) or (math.isfinite(v) and v >= 0)) else "must be >= 0, or nan for the table's gain"


def _fraction(v: float) -> str | None:
    return None if (math.isfinite(v) and 0 < v < 1) else "must be in (0, 1)"


def _key(name: str, toml_key: str | None = None, conv: Any = None, check: Any = None) -> dict[str, Any]:
    return {"toml": toml_key or name, "conv": conv, "check": check}


@dataclass(frozen=True)
class Actuators:
    """Actuator limits (SI). TOML section ``[actuators]``.

    Attributes
    ----------
    max_rim_speed : float
        Largest rim speed ``omega * r_s`` a drive motor can command, m/s (``max_rim_speed``).
    min_rim_speed : float
        Smallest rim speed, m/s (0: the drive does not reverse; ``min_rim_speed``).
    max_steer : float
        Largest steering angle magnitude, rad (``max_steer_deg``).
    max_steer_rate : float
        Steering slew rate, rad/s (``max_steer_rate_deg_s``).
    max_rim_accel : float
        Largest change of rim speed per second, m/s^2 (``max_rim_accel``).
    """

    max_rim_speed: float = 0.36
    min_rim_speed: float = 0.0
    max_steer: float = math.radians(90.0)
    max_steer_rate: float = math.radians(20.0)
    max_rim_accel: float = 0.02

    SPEC = {"max_rim_speed": _key("max_rim_speed", check=_pos), "min_rim_speed": _key("min_rim_speed", check=_nonneg),
            "max_steer": _key("max_steer", "max_steer_deg", _deg, _pos),
            "max_steer_rate": _key("max_steer_rate", "max_steer_rate_deg_s", _deg, _pos),
            "max_rim_accel": _key("max_rim_accel", check=_pos)}


@dataclass(frozen=True)
class Drive:
    """What to drive (``[drive]``): target travel speed and the straight reference line.

    Attributes
    ----------
    speed : float
        Target travel speed, m/s (``speed``).
    path_heading : float
        Heading of the reference line in the world frame, rad (``path_heading_deg``).
    path_x, path_y : float
        A point of the reference line, m (``path_x``, ``path_y``).
    wheel_radius : float
        Shearing radius r_s used to turn omega into rim speed, m (``wheel_radius``); nan: from the
        table's metadata.
    """

    speed: float = 0.03
    path_heading: float = 0.0
    path_x: float = 0.0
    path_y: float = 0.0
    wheel_radius: float = math.nan

    SPEC = {"speed": _key("speed", check=_pos), "path_heading": _key("path_heading", "path_heading_deg", _deg, _any_finite),
            "path_x": _key("path_x", check=_any_finite), "path_y": _key("path_y", check=_any_finite),
            "wheel_radius": _key("wheel_radius", check=lambda v: None if (math.isnan(v) or (math.isfinite(v) and v > 0))
                                 else "must be > 0, or nan for the table's")}


@dataclass(frozen=True)
class Noise:
    """Sensor and process noise, 1-sigma (``[noise]``).

    The defaults are the simulated mini rover's sensors (``offline.sim.sensors.SensorConfig``:
    encoders 0.005 rad/s and 0.002 rad, gyro 0.001 rad/s white and a bias random walk of
    1.94e-5 rad/s/sqrt(s), the ADIS16448 value; pose fixes 2 mm and 0.002 rad) and the model
    error the EKF sees there, measured as the rate of change of the true rover-level slip and
    disturbance crab in closed-loop drives (rtctl on the shipped tables, RR steering stuck):
    ``sqrt(E[(q(t + tau) - q(t))^2] / tau)`` over tau = 0.2-10 s is 0.003-0.0065 /sqrt(s) for
    the slip (the largest with pose fixes every 10 s, when the outer loop moves in steps) and
    0.0047-0.0053 rad/sqrt(s) for the crab once the commanded crab is an input of the motion
    model (:mod:`rtctl.estimator`). ``position_walk`` (unmodelled position motion) is not
    measured: a small floor. With these, the time-averaged NEES of the EKF in the simulator is
    inside its chi-square band (``tests/test_rtctl_ekf_sim.py``); with the defaults of issue 12
    (4-8x the sensor noise) it was 0.2 for the pose (3 expected).

    Attributes
    ----------
    wheel_speed : float
        Encoder wheel-speed noise, rad/s.
    steer : float
        Encoder steering-angle noise, rad (``steer_deg``).
    gyro : float
        Gyro yaw-rate noise, rad/s.
    gyro_bias_walk : float
        Gyro bias random walk, rad/s per sqrt(s).
    slip_walk : float
        Random walk of the longitudinal slip, 1/sqrt(s).
    crab_walk : float
        Random walk of the crab angle, rad/sqrt(s) (``crab_walk_deg``).
    position_walk : float
        Unmodelled position motion, m/sqrt(s).
    pose_xy : float
        Pose-fix position noise, m.
    pose_heading : float
        Pose-fix heading noise, rad (``pose_heading_deg``).
    crab_cmd_rel : float
        Relative 1-sigma error of the crab the commands ask for (the lateral resistance of the
        model around the primitive; :mod:`rtctl.estimator`), 1.
    """

    wheel_speed: float = 0.005
    steer: float = math.radians(0.115)
    gyro: float = 0.001
    gyro_bias_walk: float = 1.94e-5
    slip_walk: float = 0.006
    crab_walk: float = math.radians(0.2865)
    position_walk: float = 2e-4
    pose_xy: float = 0.002
    pose_heading: float = math.radians(0.115)
    crab_cmd_rel: float = 0.3

    SPEC = {"wheel_speed": _key("wheel_speed", check=_pos), "steer": _key("steer", "steer_deg", _deg, _pos),
            "gyro": _key("gyro", check=_pos), "gyro_bias_walk": _key("gyro_bias_walk", check=_pos),
            "slip_walk": _key("slip_walk", check=_pos), "crab_walk": _key("crab_walk", "crab_walk_deg", _deg, _pos),
            "position_walk": _key("position_walk", check=_pos),
            "pose_xy": _key("pose_xy", check=_pos), "pose_heading": _key("pose_heading", "pose_heading_deg", _deg, _pos),
            "crab_cmd_rel": _key("crab_cmd_rel", check=_nonneg)}


@dataclass(frozen=True)
class EstimatorSettings:
    """EKF settings (``[estimator]``).

    Attributes
    ----------
    gate_chi2 : float
        Mahalanobis gate on the squared normalised innovation of a 3-dof pose fix (default: the
        99.9 % point of chi-square(3), 16.27).
    max_pose_delay : float
        Oldest pose fix (taken this long before the tick) still used at the time it was taken, s.
    reset_after_rejections : int
        After this many consecutive gated-out pose fixes that agree with each other, the filter
        re-initialises its pose on them (a pose jump of the tracker, not an outlier).
    initial_sigma_xy, initial_sigma_heading, initial_sigma_slip, initial_sigma_crab, initial_sigma_bias
        Initial 1-sigma uncertainties (m, rad ``_deg``, 1, rad ``_deg``, rad/s).
    initial_slip : float
        Initial longitudinal slip estimate.
    """

    gate_chi2: float = 16.27
    max_pose_delay: float = 2.0
    reset_after_rejections: int = 5
    initial_sigma_xy: float = 0.02
    initial_sigma_heading: float = math.radians(2.0)
    initial_sigma_slip: float = 0.2
    initial_sigma_crab: float = math.radians(5.0)
    initial_sigma_bias: float = 0.005
    initial_slip: float = 0.1

    SPEC = {"gate_chi2": _key("gate_chi2", check=_pos), "max_pose_delay": _key("max_pose_delay", check=_nonneg),
            "reset_after_rejections": _key("reset_after_rejections", check=lambda v: None if (v >= 1 and v == int(v)) else "must be an integer >= 1"),
            "initial_sigma_xy": _key("initial_sigma_xy", check=_pos),
            "initial_sigma_heading": _key("initial_sigma_heading", "initial_sigma_heading_deg", _deg, _pos),
            "initial_sigma_slip": _key("initial_sigma_slip", check=_pos),
            "initial_sigma_crab": _key("initial_sigma_crab", "initial_sigma_crab_deg", _deg, _pos),
            "initial_sigma_bias": _key("initial_sigma_bias", check=_pos),
            "initial_slip": _key("initial_slip", check=lambda v: None if (math.isfinite(v) and -1 < v < 1) else "must be in (-1, 1)")}


@dataclass(frozen=True)
class OuterLoop:
    """Heading / cross-track loop producing the offsets of eqs. (7.26)-(7.27) (``[outer_loop]``).

    Attributes
    ----------
    heading_gain : float
        M_z offset per rad of heading error, N m/rad; nan: from the table's steering controller.
    crosstrack_gain : float
        F_y offset per m of cross-track error, N/m; nan: from the table.
    heading_integral : float, crosstrack_integral : float
        Integral gains, N m/(rad s) and N/(m s): an integral time of 10 s on the table-derived
        proportional gains of Table 7.2's offsets (0.2 N m at 5 deg, 1 N at 5 cm). The EKF's crab
        estimate removes a lateral drift, but a yaw-moment mismatch between the tables and the
        ground (measured: RR steering stuck on the shipped tables in the chapter-7 world, a steady
        -1.9 deg with the proportional loop alone, +0.2 deg with the integral) needs the integral.
    max_mz_offset : float
        Clamp of the yaw-moment offset, N m.
    max_fy_offset : float
        Clamp of the lateral-force offset, N.
    """

    heading_gain: float = math.nan
    crosstrack_gain: float = math.nan
    heading_integral: float = 0.23
    crosstrack_integral: float = 2.0
    max_mz_offset: float = 0.4
    max_fy_offset: float = 2.0

    SPEC = {"heading_gain": _key("heading_gain", check=_gain), "crosstrack_gain": _key("crosstrack_gain", check=_gain),
            "heading_integral": _key("heading_integral", check=_nonneg),
            "crosstrack_integral": _key("crosstrack_integral", check=_nonneg),
            "max_mz_offset": _key("max_mz_offset", check=_pos), "max_fy_offset": _key("max_fy_offset", check=_pos)}


@dataclass(frozen=True)
class QpSettings:
    """Allocator QP settings (``[qp]``).

    Attributes
    ----------
    slack_l1 : float
        Exact (L1) penalty on the slack of every linearised model row, in units of the
        normalised objective: where it exceeds the row's multiplier a feasible QP has zero slack.
    slack_l2 : float
        Quadratic penalty on the same slacks. Measured on the synthetic table: (l1, l2) = (10, 100)
        converges in ~50 warm ADMM iterations where (100, 10) needs ~1000.
    regularization : float
        Proximal weight on the scaled step (Levenberg-Marquardt style), and the floor of the
        Hessian's eigenvalues after convexification. 1e-5: the exact active-set solve needs no
        conditioning from it; at 1e-3 (the value while OSQP solved every tick) it dominated the
        curvature in the objective's flat directions, and the iterate crept a few % a tick toward
        the optimum (measured: tick-5 agreement with the NLP 14/76 points at 1e-3, 36/76 at 1e-5,
        same at 1e-6; ``tests/bench/bench_online_step.py accuracy``). 1e-8 since the structured
        Hessian (``gauss_newton``): the exact reduced curvature of the off-grid rim-speed-cap and
        unpowered points is 1e-7-1e-6 of the normalisation, so a floor of 1e-5 was a proximal term
        that limited each tick's step in the flat directions to a constant (measured on an
        unpowered point: speeds 21 % -> 6 % off the optimum in five ticks at 1e-5, 0.1 % at 1e-8 or
        1e-9; all tables, tick-5 agreement 60/73 at 1e-5 against 64/73 at 1e-8, same run).
    command_weight : float
        Weight on the change of the commanded variables from the previous command (smoothness).
        At steady state the previous command is the iterate's, so it acts as a proximal term as
        well and slows convergence in flat directions (tick-5 agreement 66/76 at 1e-5 against
        46/76 at 1e-3, with the other defaults); the actuators' rate limits bound the changes.
        1e-8 (with ``regularization``, same measurement): 2e-5 on the diagonal of P dominated
        the exact reduced curvature (1e-7-1e-6) in the flat directions.
    max_iter : int
        OSQP iteration budget per solve. 4000: the warm-started ADMM needs more than 1000 on the
        strongly slipping primitives of the rim-speed cap tables (measured: 196 of 253 ticks fell
        back at 1000 on the test tables' rr_speed_cap_half, 1 at 4000); a budget in iterations.
    eps : float
        OSQP absolute and relative tolerance.
    balance_tolerance : float
        Largest accepted slack of a model row (scaled units: 0.5 = half the rover's weight in a
        force row) before the step is refused and the fallback used; smaller slacks (a rate limit
        that keeps the balance out of reach for a tick) are commanded and reported.
    step_limit : float
        Trust region of one tick: the largest change of each variable from the tick's starting
        iterate, in variable scales (the step in x is limited; the measured parameters never are).
        1.0: a point beyond a table's axes (a 6-8 deg cross slope on a table built at 0) lies
        0.5-1 scales from the table's primitive, and 0.5 left its first tick unbalanced. 2.0 since
        the structured Hessian: with the curvature no longer overestimated, the remaining slow
        points took a step at the box every tick (an off-grid rim-speed-cap point whose optimum
        lies 3.7 scales from the interpolated primitive), and the 6 deg cross-slope point of
        rr_steer_stuck was unbalanced after its first tick (1.1 N); measured
        (``bench_online_step.py accuracy``, 73 points, same day): tick-1 66/73 and tick-5 64/73 at
        1.0, 69/73 and 66/73 at 2.0. The actuators' rate limits still bound each command's change.
    exact_jacobian : bool
        Linearise the rows with their exact Jacobian at the iterate (structured forward
        differences of the shared physics, :class:`rtctl.physics.steady_state.SteadyStateResidual`):
        the iteration's fixed point is then the NLP's KKT point anywhere. False: the table's
        interpolated Jacobian (exact residual and gradient still; the fixed point is then off by
        the Jacobian's interpolation error times the multipliers).
    iterations_per_tick : int
        Most SQP iterations (linearisation + QP) in one tick (:meth:`rtctl.rti.RealTimeIteration.step`):
        after the first, another while the last step was longer than ``extra_iteration_step``.
        Measured (``bench_online_step.py accuracy``, 76 off-grid points, residual after one tick
        within 0.1 N / 0.01 N m / 0.2 N): 1 iteration 31/76, 2: 61/76, 3: 72/76, 5: 73/76. Each
        iteration costs one exact linearisation (the step's largest part), so 3, and only on a
        tick that starts the iterate or follows a jump of speed, slope or cross slope
        (:meth:`rtctl.rti.RealTimeIteration.step`): allowed on every tick, the noise of a closed
        loop made 18 % of ticks iterate again and the step's p99 thread CPU 4.0 times 40a08e8's;
        on jumps only, 2.1 times (``bench_online_step.py timing``, same run), at the price of
        tick-5 agreement 56/76 instead of 65/76.
    extra_iteration_step : float
        Step length (largest change of a variable, in variable scales) above which the tick
        iterates again: a step of ``dz`` leaves a second-order residual of about ``c dz^2``
        (measured on the shipped tables: ~0.1 N after a step of 0.09 scales). 0.05 gives the same
        agreement as 0.02 (73/76 and 66/76 at five iterations) with fewer iterations in closed
        loop (ticks with more than one: 29 % at 0.02, 18 % at 0.05, kinematic rover of
        ``bench_online_step.py timing``).
    restart_iterations : int
        Most SQP iterations on the first tick after the iterate restarts (:meth:`rtctl.rti.RealTimeIteration.start`:
        a new table, or a QP that failed), while the last step was longer than
        ``restart_iteration_step``; at least ``iterations_per_tick``. A restart starts from the
        table's interpolated primitive, which between grid points and across a kink of the
        wheel model lies far from the optimum in the objective's flat directions, and the
        steady ticks that follow take one iteration each (more on every tick cost 4.0 times
        40a08e8's p99, see ``iterations_per_tick``); a restart happens once per table switch, so
        its tick may take more. Measured (``bench_online_step.py accuracy``, 73 points, same
        day, with the branch-consistent start): tick-1 / tick-5 within targets 69/66 at 3
        iterations and 0.05 scales (the jump tick's), 73/68 at 8 and 0.05, 73/69 at 8 and 0.025,
        73/72 at 8 and 0.01, 71/71 at 6 and 0.01, 73/73 at 10 and 0.01 (and at 12). A budget in
        iterations: each costs one exact linearisation and one QP solve.
    restart_iteration_step : float
        Step length (largest change of a variable, in variable scales) above which the first
        tick after a restart iterates again (``restart_iterations``).
    restart_continuation_stages : int
        Stages of the parameter continuation a restart runs from each corner of the table's cell
        (:meth:`rtctl.rti.RealTimeIteration._continued_start`): the corner's parameters and bounds
        move to the point's in this many equal stages; 0: no continuation (the interpolated or
        branch start, as before issue 22's online gate). Measured at every cell centre of the
        shipped rr_rim_speed_cap, rr_unpowered and rr_steer_stuck tables (36, check 4 of
        ``tables verify``; ``tests/bench/results_tables_online_i22.md``): 2 stages of 2
        iterations and 3 at the point pass 35, against 31 without the continuation; 2 + 2 + 2
        also 35 but it failed the worked example's (2.5, -5, -75 deg) centre of
        fl_steer_stuck, which 2 + 2 + 3 passes; 2 + 2 + 5 and 3 + 2 + 2 34. A restart's first
        tick then costs a median 52 ms of thread CPU over the 36 centres (at most 109; 9 and 16
        without), once per table switch or refused QP.
    restart_continuation_iterations : int
        SQP iterations per continuation stage.
    restart_continuation_polish : int
        SQP iterations at the point itself after the last stage, before the ends are compared.
    restart_work_per_tick : int
        Most units of a restart's work (an SQP iteration of the continuation, or a branch
        candidate's QP) the controller's preparation runs in one tick
        (:meth:`rtctl.rti.RealTimeIteration.prepare` with a budget); the rest in the next ticks,
        while the controller commands its fallback (the table's interpolated primitive with the
        declared failures, clipped to the actuator limits and rate-limited, flagged
        ``restart in progress``). 0: the whole restart in one preparation. The controller's
        start-up preparation (before any tick) is never spread. With the default, a tick's SQP
        iterations are bounded by this plus ``restart_iterations`` (the first tick after a
        restart) plus ``iterations_per_tick`` (a QP refused in the same tick).
    active_set_iterations : int
        Budget of KKT systems of the exact active-set solve (:mod:`rtctl.active_set`) tried before
        OSQP: from the last tick's active set the QP is usually one dense linear system, solved to
        rounding (OSQP's ADMM stops at ``eps``) and without OSQP's refactorisation; when the set
        does not settle within the budget (and the restart below neither), or the balance needs
        slack, OSQP solves the tick. 0: OSQP alone (the C flight path of :mod:`rtctl.codegen` is
        OSQP's).
    active_set_restart_iterations : int
        Budget of a second active-set solve, started from the equality rows and the fixed
        variables alone, when the one from the last tick's set did not settle (0: none, OSQP
        next). The last tick's set is the right start where a bound holds tick after tick (a
        capped wheel at its cap: from the equality rows alone no solve of the section 7.3
        recordings settled within 8 KKT systems, from the last set every one in 1); of its
        variable bounds only those that did not move since the last tick are guessed active
        again (:meth:`rtctl.allocator.QpAllocator.solve_at`): the rate limits around the last
        command and the step limit around the iterate move every tick, and re-adding them all
        at once over-determined the KKT system (multipliers of 1e9) so that the set cycled.
        Measured on the closed loop of ``bench_online_step.py timing`` (one run, 551 QPs): with
        the whole last set and a budget of 5, 20 QPs went to OSQP (about 0.7 ms each, which set
        the step's p99); with the moved bounds dropped every QP settled from the last set
        within 6 KKT systems (650 QPs of another run: 520 in 1, 78 in 2, at most 6). The
        restart is the safety net for a set that still cycles.
    gauss_newton : bool
        Structured Hessian (:meth:`rtctl.rti.RealTimeIteration._structured_hessian`): the exact
        Gauss-Newton part of the objective (7.24) from the wheel-torque rows of each iteration's
        exact Jacobian, plus the constraints' curvature from the table (each cell corner's own,
        a corner on the wheel model's zero-slip kink left out), corrected by BFGS when
        ``quasi_newton``; the objective's normalisation from that matrix. Needs
        ``exact_jacobian`` and a table with physics. Measured (``bench_online_step.py accuracy``,
        73 off-grid points, same run): tick-5 agreement 64/73 against 53/73 with the table's
        interpolated Hessian (rr_rim_speed_cap 9/13 against 3/13, rr_unpowered 15/16 against 11/16).
    quasi_newton : bool
        Improve the table's Lagrangian Hessian from iteration to iteration by damped BFGS updates
        with the exact Lagrangian gradients (:meth:`rtctl.rti.RealTimeIteration.step`); needs
        ``exact_jacobian``. Between grid points and beyond the axes the table's Hessian is
        another point's, and it is wrong where it matters most: in the directions the objective
        hardly curves (measured at an off-grid rim-speed-cap point: table reduced-Hessian
        eigenvalues 0.04 and 0.33 where the exact ones are 1e-6 and 1.3e-5). On (tick-5 agreement
        with the NLP 66/76 against 36/76 off). It was off while OSQP solved every tick: the
        updated Hessians raised OSQP's iterations from 225 to 2600 at p99; the exact active-set
        solve does not care about conditioning.
    """

    slack_l1: float = 10.0
    slack_l2: float = 100.0
    regularization: float = 1e-8
    command_weight: float = 1e-8
    max_iter: int = 4000
    eps: float = 1e-6
    balance_tolerance: float = 0.5
    step_limit: float = 2.0
    exact_jacobian: bool = True
    quasi_newton: bool = True
    active_set_iterations: int = 5
    active_set_restart_iterations: int = 6
    gauss_newton: bool = True
    iterations_per_tick: int = 3
    extra_iteration_step: float = 0.05
    restart_iterations: int = 10
    restart_iteration_step: float = 0.01
    restart_continuation_stages: int = 2
    restart_continuation_iterations: int = 2
    restart_continuation_polish: int = 3
    restart_work_per_tick: int = 12

    SPEC = {"slack_l1": _key("slack_l1", check=_pos), "slack_l2": _key("slack_l2", check=_pos),
            "regularization": _key("regularization", check=_pos), "command_weight": _key("command_weight", check=_nonneg),
            "max_iter": _key("max_iter", check=lambda v: None if (v >= 10 and v == int(v)) else "must be an integer >= 10"),
            "eps": _key("eps", check=_pos), "balance_tolerance": _key("balance_tolerance", check=_pos),
            "step_limit": _key("step_limit", check=_pos), "exact_jacobian": _key("exact_jacobian"),
            "quasi_newton": _key("quasi_newton"), "gauss_newton": _key("gauss_newton"),
            "iterations_per_tick": _key("iterations_per_tick",
                                        check=lambda v: None if (v >= 1 and v == int(v)) else "must be an integer >= 1"),
            "extra_iteration_step": _key("extra_iteration_step", check=_pos),
            "restart_iterations": _key("restart_iterations",
                                       check=lambda v: None if (v >= 1 and v == int(v)) else "must be an integer >= 1"),
            "restart_iteration_step": _key("restart_iteration_step", check=_pos),
            "restart_continuation_stages": _key("restart_continuation_stages", check=_count),
            "restart_continuation_iterations": _key("restart_continuation_iterations", check=_count),
            "restart_continuation_polish": _key("restart_continuation_polish", check=_count),
            "restart_work_per_tick": _key("restart_work_per_tick", check=_count),
            "active_set_iterations": _key("active_set_iterations",
                                          check=lambda v: None if (v >= 0 and v == int(v)) else "must be an integer >= 0"),
            "active_set_restart_iterations": _key("active_set_restart_iterations",
                                                  check=lambda v: None if (v >= 0 and v == int(v)) else "must be an integer >= 0")}


_SECTIONS: dict[str, type] = {"actuators": Actuators, "drive": Drive, "noise": Noise, "estimator": EstimatorSettings,
                              "outer_loop": OuterLoop, "qp": QpSettings}


@dataclass(frozen=True)
class ControllerConfig:
    """Everything the controller is tuned with; frozen, logged with the controller state.

    Attributes
    ----------
    actuators, drive, noise, estimator, outer_loop, qp
        One frozen dataclass per TOML section (see each class).
    period : float
        Control period, s (``[timing] period``; 0.2 s for 5 Hz).
    max_gap : float
        A gap between ticks longer than this is a dropout: the EKF predicts over at most this
        long and counts it (``[timing] max_gap``).
    tables_index : str
        Path of the table index (``[tables] index``), relative to the config file; '' if none.
    default_table : str
        Table used when no table matches the declared failures (``[tables] default``, e.g. a
        trench table, whose goal is not a failure); '': the table built without failures.
    """

    actuators: Actuators = field(default_factory=Actuators)
    drive: Drive = field(default_factory=Drive)
    noise: Noise = field(default_factory=Noise)
    estimator: EstimatorSettings = field(default_factory=EstimatorSettings)
    outer_loop: OuterLoop = field(default_factory=OuterLoop)
    qp: QpSettings = field(default_factory=QpSettings)
    period: float = 0.2
    max_gap: float = 1.0
    tables_index: str = ""
    default_table: str = ""

    @classmethod
    def from_toml(cls, path: str | Path) -> "ControllerConfig":
        """Read a TOML file; raises :class:`ConfigError` naming the file and key on any problem."""
        path = Path(path)
        data = read_toml(path, ConfigError, "config file", "; pass the path of a controller TOML file")
        cfg = cls.from_dict(data, source=path.name)
        if cfg.tables_index:
            cfg = replace(cfg, tables_index=str((path.parent / cfg.tables_index)))
        return cfg

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "<config>") -> "ControllerConfig":
        """Build from a parsed TOML mapping (file units); errors name ``source``, section and key."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table of sections, got {type(data).__name__}")
        known = set(_SECTIONS) | {"timing", "tables"}
        for sec in data:
            if sec not in known:
                raise ConfigError(f"{source}: unknown section [{sec}]; known sections: {sorted(known)}")
        kw: dict[str, Any] = {}
        for sec, klass in _SECTIONS.items():
            kw[sec] = _section(klass, data.get(sec, {}), sec, source)
        timing = data.get("timing", {})
        _only(timing, {"period", "max_gap"}, "timing", source)
        for k, default in (("period", 0.2), ("max_gap", 1.0)):
            v = _number(timing.get(k, default), "timing", k, source)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{source}: [timing] {k} = {v}: must be finite and > 0")
            kw[k] = v
        if kw["max_gap"] < kw["period"]:
            raise ConfigError(f"{source}: [timing] max_gap = {kw['max_gap']} is shorter than period = {kw['period']}")
        tables = data.get("tables", {})
        _only(tables, {"index", "default"}, "tables", source)
        idx = tables.get("index", "")
        if not isinstance(idx, str):
            raise ConfigError(f"{source}: [tables] index must be a path string, got {idx!r}")
        kw["tables_index"] = idx
        default = tables.get("default", "")
        if not isinstance(default, str):
            raise ConfigError(f"{source}: [tables] default must be a table name (string), got {default!r}")
        kw["default_table"] = default
        act = kw["actuators"]
        if act.min_rim_speed >= act.max_rim_speed:
            raise ConfigError(f"{source}: [actuators] min_rim_speed = {act.min_rim_speed} must be < max_rim_speed = {act.max_rim_speed}")
        if kw["drive"].speed > act.max_rim_speed:
            raise ConfigError(f"{source}: [drive] speed = {kw['drive'].speed} m/s exceeds [actuators] max_rim_speed = {act.max_rim_speed}")
        return cls(**kw)


def _only(table: Any, allowed: set[str], sec: str, source: str) -> None:
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{sec}] must be a table of keys, got {table!r}")
    for k in table:
        if k not in allowed:
            raise ConfigError(f"{source}: [{sec}] unknown key {k!r}; known keys: {sorted(allowed)}")


def _number(v: Any, sec: str, key: str, source: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(f"{source}: [{sec}] {key} = {v!r}: expected a number")
    return float(v)


def _section(klass: type, table: Any, sec: str, source: str) -> Any:
    spec: dict[str, dict[str, Any]] = klass.SPEC  # type: ignore[attr-defined]
    by_toml = {s["toml"]: (attr, s) for attr, s in spec.items()}
    _only(table, set(by_toml), sec, source)
    kw: dict[str, Any] = {}
    names = {f.name for f in fields(klass)}
    for tkey, value in table.items():
        attr, s = by_toml[tkey]
        if attr in names and isinstance(getattr(klass(), attr), bool):  # a switch: true or false only
            if not isinstance(value, bool):
                raise ConfigError(f"{source}: [{sec}] {tkey} = {value!r}: expected true or false")
            kw[attr] = value
            continue
        raw = _number(value, sec, tkey, source)
        v = s["conv"](raw) if s["conv"] else raw
        err = s["check"](v) if s["check"] else None
        if err:
            raise ConfigError(f"{source}: [{sec}] {tkey} = {value!r}: {err}")
        if attr in names and isinstance(getattr(klass(), attr), int) and not isinstance(getattr(klass(), attr), bool):
            v = int(v)
        kw[attr] = v
    return klass(**kw)


DEFAULT_TOML = """\
# rtctl controller configuration (SI; angles in degrees where the key ends in _deg)
[actuators]
max_rim_speed = 0.36        # m/s (the optimizer's rim-speed bound: 12x 3 cm/s)
min_rim_speed = 0.0         # m/s
max_steer_deg = 90.0
max_steer_rate_deg_s = 20.0
max_rim_accel = 0.02        # m/s^2

[drive]
speed = 0.03                # m/s
path_heading_deg = 0.0
path_x = 0.0
path_y = 0.0
wheel_radius = nan          # m; nan: from the table

[noise]                     # the simulated mini rover's sensors (see rtctl.config.Noise)
wheel_speed = 0.005         # rad/s
steer_deg = 0.115           # 0.002 rad
gyro = 0.001                # rad/s
gyro_bias_walk = 1.94e-5    # rad/s/sqrt(s)
slip_walk = 0.006           # 1/sqrt(s)
crab_walk_deg = 0.2865      # deg/sqrt(s) (0.005 rad)
position_walk = 2e-4        # m/sqrt(s)
pose_xy = 0.002             # m
pose_heading_deg = 0.115    # 0.002 rad
crab_cmd_rel = 0.3          # relative error of the crab the commands ask for

[estimator]
gate_chi2 = 16.27
max_pose_delay = 2.0        # s
reset_after_rejections = 5
initial_sigma_xy = 0.02
initial_sigma_heading_deg = 2.0
initial_sigma_slip = 0.2
initial_sigma_crab_deg = 5.0
initial_sigma_bias = 0.005
initial_slip = 0.1

[outer_loop]
heading_gain = nan          # N m/rad; nan: the table's steering controller
crosstrack_gain = nan       # N/m
heading_integral = 0.23     # N m/(rad s): integral time 10 s on the table's gain
crosstrack_integral = 2.0   # N/(m s)
max_mz_offset = 0.4         # N m
max_fy_offset = 2.0         # N

[qp]
slack_l1 = 10.0
slack_l2 = 100.0
regularization = 1e-8
command_weight = 1e-8
max_iter = 4000
eps = 1e-6
balance_tolerance = 0.5
step_limit = 2.0            # variable scales: the tick's step in x (never the parameters)
exact_jacobian = true       # linearise at the iterate with the exact Jacobian (false: the table's)
quasi_newton = true         # damped BFGS updates of the table's Hessian from iteration to iteration
gauss_newton = true         # structured Hessian: exact Gauss-Newton part of (7.24) + the table corners' curvature
active_set_iterations = 5   # exact active-set solve first (0: OSQP alone, as the C flight path)
active_set_restart_iterations = 6   # then once more from the equality rows alone (0: none)
iterations_per_tick = 3     # SQP iterations in one tick, while a step is longer than:
extra_iteration_step = 0.05 # variable scales
restart_iterations = 10     # the first tick after a restart (new table, refused QP): SQP iterations while a step is longer than:
restart_iteration_step = 0.01   # variable scales
restart_work_per_tick = 12  # a restart's SQP iterations per tick; the rest in the next ticks, on the fallback (0: all at once)

[timing]
period = 0.2
max_gap = 1.0

[tables]
index = ""                  # path of tables/index.json, relative to this file
default = ""                # table when no declared failure matches ('' = the one without failures)
"""
"""Every key with its default value (a valid config file)."""
