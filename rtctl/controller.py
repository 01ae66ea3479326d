"""The 5 Hz controller: measurements -> EKF -> outer loop -> QP around the tabulated primitive -> commands.

``Controller(tables, config).step(m) -> (Commands, Diagnostics)`` is pure and deterministic:
the same sequence of measurements gives the same commands bit for bit; there is no clock, no
randomness and no global state (the 5 Hz clock and the deadline are :mod:`rtctl.runner`'s).

Wheel set: the controller takes it from its tables (:mod:`rtctl.wheel_set`: the mini rover's
FR, FL, RR, RL, or a rover file's wheels, e.g. the MER-class RF, LF, RM, LM, RR, LR); every
loaded table must be for the same wheels, steerable and driven flags and drive direction (else a
start-up :class:`ControllerError` naming the tables), and every per-wheel vector of the
measurements and commands has one entry per wheel in that order (:attr:`Controller.wheels`). A
table this rtctl does not drive (:func:`rtctl.wheel_set.unsupported_reason`) is refused at
start-up with its reason.
Tables of a rover driving backward are in the travel frame; :meth:`Controller.feedback` turns the
body-frame measurements and commands at the boundary.

Each tick is one real-time iteration of the steady-state problem (7.25) (acados' SQP-RTI), split
as there:

* **feedback** (:meth:`Controller.feedback`, on the new measurement): input checks, EKF predict
  and update, outer loop, then the QP linearised at the current iterate ``x_k`` and the
  *measured* parameters ``p`` (speed, slope, cross slope, the offsets of (7.26)-(7.27)): the
  residual of every row, the objective gradient and the rows' Jacobian are evaluated exactly
  there with the shared numpy physics (:class:`rtctl.physics.steady_state.SteadyStateResidual`,
  the same rows the NLP is built from), one warm-started OSQP solve gives ``x_{k+1}``, which
  is commanded and carried to the next tick;
* **preparation** (:meth:`Controller.prepare`, after the commands are out, for the next tick):
  table choice from the declared failures and the operator's task (``Measurements.task``, e.g.
  ``Task("trench", "RR", 0.02)``: the trench table of that wheel, read at that depth), table
  interpolation at the operating point (measured slope and cross slope clamped into the table's
  axes, the travel speed shifted by the EKF's slip, the failure's or task's own parameter): the
  table supplies the Lagrangian Hessian, bounds and active-set hints, and the starting iterate
  when a table is (re)entered.

:meth:`Controller.step` is feedback then preparation. At a constant operating point the
iterates converge to the NLP's optimum at that point, between grid points and beyond a table's
axes alike (a parameter outside the axes is never clipped: it enters through the exact
residual; only the step in ``x`` is limited, by ``[qp] step_limit`` variable scales). A table
whose header does not define the model (no ``params`` / ``rover`` records: a hand-made table)
is driven on its own first-order model at the iterate, flagged on every tick.

Outer loop (section 7.2.4): the heading error and the cross-track error to a straight reference
line become the yaw-moment and lateral-force offsets of eqs. (7.26)-(7.27), which enter the
balance rows exactly; by default the gains reach the offsets at which the table's steering
controllers were computed (the table's ``controller_offsets``; Table 7.2's +/-0.2 N m and
+/-1 N if it does not say) at 5 deg of heading error and 5 cm of cross-track error. The offsets
are clamped to the configured maxima. A table whose free variables cannot move the F_y balance
row (:func:`lateral_authority`: no steerable wheel, the rigid skid-steer) gets no F_y offset and
no crab bias; its cross-track error becomes a heading demand ``atan(e_y / (v 50 s))`` added to
the heading error (1.9 deg at 5 cm and 3 cm/s), flagged on every tick.

Slip correction: where the EKF's slip departs from the model's, the model is corrected rather
than ignored. (a) Operating-point shift: the speed parameter is ``v (1 - s_k) / (1 - s_hat)``,
with ``s_k`` the rover-level slip of the *iterate* (the model at the measured slope and cross
slope), so that the real rover, slipping at ``s_hat``, travels at ``v``. On a table without
lateral authority the shift is 1 while ``s_hat`` is within ``_SLIP_DEAD_BAND`` standard deviations
of ``s_k``. (Before the real-time
iteration this used the slip of the table's grid primitive at cross slope 0: on a 6 deg cross
slope the real rover slips more than that primitive, and the shift sped the rover up by 16-33 %.)
(b) Force bias: a steady crab ``alpha_hat`` means the real rover balances with a lateral speed
``v tan(alpha_hat)`` the model does not have; the model's lateral force and yaw moment at that
speed (from the wheels' wrench Jacobians, eqs. (7.6)-(7.7) and (7.13), (7.18)) are added to the
offsets, so the QP cancels the disturbance that causes the crab. The lateral speed the outer
loop's own F_y offset asks for (offset / lateral resistance) is subtracted first: that part of
the crab is wanted.

Bad input never raises and never reaches the commands: every field is converted once at the
boundary (:mod:`rtctl.inputs`: anything not a finite real number of the right type is rejected,
a string is never parsed, an int beyond the float range is not an error); a measurement without
a valid time, a duplicate, one out of order or one whose time stamp and sequence number jumped
implausibly from the last accepted measurement is rejected (the previous commands are held; the
rule, and how a restart is taken up after :data:`rtctl.inputs.REBASE_AFTER` consistent
measurements, is in :mod:`rtctl.inputs`); a NaN, infinite or
out-of-range wheel reading takes that wheel out of the odometry; a bad gyro or tilt reading is
replaced by the last good one with inflated uncertainty; a bad, late, future or inconsistent
pose is rejected or gated by the EKF; every case is counted in the diagnostics. A QP that fails,
is infeasible in its model rows beyond the tolerance, or returns non-finite values gives the
flagged fallback: the interpolated primitive (with the declared failures), rate-limited. So do the
ticks of a restart of the iterate (a new table, a refused QP) spread over ticks
(``QpSettings.restart_work_per_tick``), until its start is ready: the fallback is in the actuator
limits and the declared failures' bounds, and it is the table's own primitive at the operating
point (what the controller commanded at every tick before the real-time iteration).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from .allocator import AllocatorError, QpAllocator, merge_bounds
from .config import ControllerConfig
from .estimator import Odometry, SlipHeadingEKF, wheel_odometry, wrap_angle
from .failures import FailureDescriptionError, KindSpec, apply_rules, read_kinds, read_table_failures, read_task_kinds, rule_text
from .inputs import Inputs, TickClock, read_measurements, wheel_vector_problem
from .layout import WHEELS
from .wheel_set import WheelSet, unsupported_reason, wheel_set_of
from .messages import Commands, Diagnostics, Measurements, Pose, Task
from .mirror import MirrorError, mirror_table, mirror_wheel_map
from .rti import RealTimeIteration
from .physics.rover_file import RoverFileError, rover_spec_from_record

_Quad = tuple[float, ...]  # one value per wheel, in the wheel set's order (Controller.wheels)

__all__ = ["ControllerError", "Controller", "table_signature", "wheel_radius_of", "wheel_radii_of", "steer_offsets_of",
           "load_tables"]

_MAX_YAW_RATE = 2.0  # rad/s: a gyro reading beyond this is not a rover on soft soil
_MAX_TILT = math.radians(45.0)
_TILT_TAU = 1.0  # s: low-pass time constant of the slope / cross-slope measurement
_SPEED_SHIFT = (0.7, 1.5)  # bounds of the slip operating-point shift factor
_SLIP_DEAD_BAND = 2.0  # sigmas: on a table without lateral authority, no speed shift while the slip estimate is within
# this many of its standard deviations of the model's (Controller.prepare)
_SLIP_SIGMA_USE = 0.02  # use the slip / crab correction only when the EKF is this sure (0.05 acted on the
# start-up transient of the trench drive, when the slip is still 2 sigma off)
_CRAB_SIGMA_USE = math.radians(3.0)
_UNREACHABLE_SLACK = 0.05  # scaled model-row slack: 5 % of the weight in a force row
_UNREACHABLE_SMALL_SLACK = 2e-3  # a violation the exact iteration never leaves at a reachable steady state
_UNREACHABLE_SMALL_TICKS = 50  # 10 s of it: RR locked on the chapter-7 soil settles at 0.007 (0.24 N)
_UNREACHABLE_STEADY_TICKS = 3  # 0.6 s: a balance out of reach with no transient bound holding the QP
_UNREACHABLE_TICKS = 15  # 3 s at 5 Hz: longer than the rate-limited transient to a primitive (10 ticks flagged one tick of a
# reachable front-right cap imposed on the nominal table)
_REF_HEADING_ERROR = math.radians(5.0)
_REF_CROSSTRACK_ERROR = 0.05
_SIDE = np.array([-1.0, 1.0, -1.0, 1.0])  # y sign of FR, FL, RR, RL (right is negative; Fig. 7.2)
_FRONT = np.array([1.0, 1.0, -1.0, -1.0])
_CROSSTRACK_TIME = 50.0
"""s: without lateral authority (:func:`lateral_authority`) a cross-track error ``e_y`` asks for
the heading change ``atan(e_y / (v T))`` with ``T`` this time: the cross-track error then decays
with time constant ``T``, five times the heading loop's integral time (10 s,
:class:`rtctl.config.OuterLoop`), so the heading loop follows (measured on the skid-steer, 5 m,
seeds 1 and 2: max heading 0.44 / 0.35 deg with 50 s; 1.74 / 0.52 deg with 19 s, where the
cascade oscillated; 0.57 / 0.46 deg and 1.1 / 1.0 cm without the term)."""
_AUTHORITY_RTOL = 1e-6


class ControllerError(ValueError):
    """Tables or configuration the controller cannot run with (raised at construction only)."""


UNDESCRIBED = ("*", "undescribed failures")
"""Signature entry of a failure table whose header has no failure description (it matches no
declaration and is never taken for the nominal table)."""


def _held_by_transient(x: Any, box: tuple[NDArray[np.float64], NDArray[np.float64]],
                       steady: tuple[NDArray[np.float64], NDArray[np.float64]] | None) -> bool:
    """Whether the QP's answer ``x`` lies on a bound of the tick's ``box`` that is tighter than
    the ``steady`` box (a rate limit or the step limit around the iterate: a transient bound the
    next ticks move). Unknown (no answer or no steady box): True, the cautious answer."""
    if x is None or steady is None:
        return True
    x = np.asarray(x, dtype=float)
    lo, hi = box
    slo, shi = steady
    if x.shape != lo.shape or lo.shape != slo.shape:
        return True
    width = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    tol = 1e-3 * np.maximum(width, 1e-12)
    at_lo = (x <= lo + tol) & (lo > slo + 1e-9 * (1.0 + np.abs(lo)))
    at_hi = (x >= hi - tol) & (hi < shi - 1e-9 * (1.0 + np.abs(hi)))
    return bool(np.any(at_lo | at_hi))


def table_signature(table: Any) -> frozenset[tuple[str, str]]:
    """The declared failures and task a table was built for: ``{(wheel, kind), ...}`` from its
    header's ``failures`` and ``task`` (:func:`rtctl.failures.read_table_failures`; a trench goal
    gives ``(wheel, "trench")``, the kind of :class:`rtctl.messages.Task`). A failure table
    without the description gives ``{UNDESCRIBED}``: never matched, never nominal.

    Raises
    ------
    rtctl.failures.FailureDescriptionError
        A malformed description.
    """
    tf = read_table_failures(table.header, tuple(table.layout.wheels), str(getattr(table, "name", "table")))
    return frozenset({UNDESCRIBED}) if tf is None else tf.signature()


def _find_key(obj: Any, key: str) -> Any:
    if isinstance(obj, dict):
        if key in obj:
            return obj[key]
        for v in obj.values():
            r = _find_key(v, key)
            if r is not None:
                return r
    return None


def wheel_radius_of(table: Any) -> float:
    """Shearing radius r_s = r + h_g (eq. (5.2)) from a table's parameter record (nan if absent)."""
    wheel = _find_key(table.meta.get("params", {}), "wheel")
    if isinstance(wheel, dict):
        r, hg = wheel.get("radius"), wheel.get("grouser_height", 0.0)
        if isinstance(r, (int, float)) and isinstance(hg, (int, float)):
            return float(r) + float(hg)
    return math.nan


def wheel_radii_of(table: Any) -> tuple[float, ...]:
    """Shearing radius per wheel (layout order) from the header's ``world`` record (a table built
    with per-wheel radii), else :func:`wheel_radius_of` on every wheel."""
    world = table.header.get("world") or {}
    rs = world.get("shearing_radius_m")
    n = len(table.layout.wheels)
    if isinstance(rs, list) and len(rs) == n and all(isinstance(v, (int, float)) for v in rs):
        return tuple(float(v) for v in rs)
    return (wheel_radius_of(table),) * n


def steer_offsets_of(table: Any) -> tuple[float, ...]:
    """Steering offset per wheel (true minus encoder angle, rad, layout order) from the header's
    ``world`` record; zeros when the table has none."""
    world = table.header.get("world") or {}
    d = world.get("steer_offset_rad")
    n = len(table.layout.wheels)
    if isinstance(d, list) and len(d) == n and all(isinstance(v, (int, float)) for v in d):
        return tuple(float(v) for v in d)
    return (0.0,) * n


def _wheel_xy(table: Any) -> NDArray[np.float64] | None:
    """Wheel centres ``(2, N)`` (x forward, y left, body frame about O, m) of a table built from a
    rover file (the header's ``scenario.rover_file`` record, as the builder used it); None for the
    mini rover's tables (their geometry is the Table 7.2 rocker's track and length)."""
    sc = table.header.get("scenario")
    rec = sc.get("rover_file") if isinstance(sc, Mapping) else None
    xy: NDArray[np.float64] | None = None
    if isinstance(rec, Mapping):
        try:
            spec = rover_spec_from_record(rec, f"table {getattr(table, 'name', '?')}")
            xy = np.array([[w.position[0] for w in spec.wheels], [w.position[1] for w in spec.wheels]])
        except RoverFileError:
            xy = None
    return xy


def lateral_authority(tp: Any, layout: Any) -> bool:
    """Whether the QP can move the lateral-force balance row (``balance Fy``, eq. (7.13) with the
    offset of (7.27)) while it keeps every other equality row, the yaw-moment balance
    included: the row's Jacobian in the variables the table point leaves free (``lbx < ubx``),
    scaled as the QP scales it, has a part outside the span of the other equality rows' larger
    than ``_AUTHORITY_RTOL`` of the row's own largest entry.

    Why: the outer loop's F_y offset and the crab bias (module docstring, slip correction (b))
    are balanced by steering. A rover with no steerable wheel (the rigid skid-steer of issue 23)
    has none: at zero wheel slip angle no wheel speed, load or sinkage changes a wheel's lateral
    force, so that row's Jacobian in its free variables is exactly zero (in every steered test
    table the part is 0.05-0.18 in the QP's scaled units, the row's largest entry 0.07-0.29). An F_y offset there only fills the row's slack, and
    the crab bias's M_z part (the crab's yaw moment, 2.4 times the table's controller offset at a
    0.75 deg crab estimate within one sigma of zero) was balanced alone by the wheel speeds and
    drove the iterate off the primitive (measured: the skid-steer turned to 180 deg). A layout
    without these rows, or a Jacobian that is not finite, is taken to have authority (the
    behaviour before)."""
    names = list(layout.constraint_names)
    if "balance Fy" not in names or "balance Mz" not in names:
        return True
    iy = names.index("balance Fy")
    sx, sg = np.asarray(layout.variable_scale, dtype=float), np.asarray(layout.constraint_scale, dtype=float)
    J = np.asarray(tp.jac_g_x, dtype=float) * sx[None, :] / sg[:, None]
    free = np.asarray(tp.ubx, dtype=float) - np.asarray(tp.lbx, dtype=float) > 0.0
    row = J[iy]
    scale = float(np.abs(row).max(initial=0.0))
    if not math.isfinite(scale) or not math.isfinite(float(J[:, free].sum())):
        return True  # not judged: the behaviour before
    if scale == 0.0 or not free.any():
        return False
    lbg, ubg = np.asarray(tp.lbg, dtype=float), np.asarray(tp.ubg, dtype=float)
    others = [i for i in range(len(names)) if i != iy and lbg[i] == ubg[i] and bool(np.any(J[i] != 0.0))]
    a = row[free]
    if others:
        B = J[np.ix_(np.array(others, dtype=np.intp), np.flatnonzero(free))]
        c, *_ = np.linalg.lstsq(B.T, a, rcond=None)
        a = a - B.T @ c
    return bool(np.abs(a).max(initial=0.0) > _AUTHORITY_RTOL * scale)


def _turned_half_round(inp: Inputs) -> Inputs:
    """A body-frame measurement in the frame of a rover driving backward (the body turned by pi
    about z, :meth:`Controller.feedback`)."""
    def neg(v: tuple[float, ...] | None) -> tuple[float, ...] | None:
        return None if v is None else tuple(-q for q in v)

    pose = inp.pose
    if pose is not None:
        pose = Pose(pose.t, pose.x, pose.y, float(wrap_angle(pose.heading + math.pi)))
    return dataclasses.replace(inp, wheel_speed=neg(inp.wheel_speed), motor_torque=neg(inp.motor_torque),
                               roll=-inp.roll, pitch=-inp.pitch, pose=pose)


def _common_wheel_set(tables: Mapping[str, Any]) -> WheelSet:
    """The one wheel set of every table (:func:`rtctl.wheel_set.wheel_set_of`): the same wheel
    names in the same order, and the same steerable and driven flags where both tables record
    them, and one drive direction; else :class:`ControllerError` naming the tables of each."""
    sets = {name: wheel_set_of(t.header, t.layout) for name, t in sorted(tables.items())}
    groups: dict[tuple[tuple[str, ...], str], list[str]] = {}
    for name, ws in sets.items():
        groups.setdefault((ws.wheels, ws.drive_direction), []).append(name)
    if len(groups) > 1:
        raise ControllerError("the tables are for different wheel sets: " + "; ".join(
            f"{', '.join(names)}: {sets[names[0]].text()}" for names in groups.values())
            + "; give the controller the tables of one rover (one index per rover)")
    first = next(iter(sets.values()))
    for attr in ("steerable", "driven"):
        known = {name: getattr(ws, attr) for name, ws in sets.items() if getattr(ws, attr) is not None}
        if len(set(known.values())) > 1:
            raise ControllerError(f"the tables disagree on which wheels are {attr}: " + "; ".join(
                f"{name}: {[w for w, f in zip(first.wheels, v) if f]}" for name, v in known.items())
                + "; rebuild them from one rover file")
    ref = next((ws for ws in sets.values() if ws.steerable is not None), first)
    return ref


class _Index:
    """Positions in a table layout, looked up once (the 5 Hz path does no name lookups)."""

    def __init__(self, lay: Any) -> None:
        self.om = np.array([lay.var("omega", w) for w in lay.wheels])
        self.be = np.array([lay.var("beta", w) for w in lay.wheels])
        self.speed, self.slope, self.cross = lay.index("speed"), lay.index("slope"), lay.index("cross_slope")
        self.fy, self.mz = lay.index("fy_offset"), lay.index("mz_offset")
        self.varying = [self.speed, self.slope, self.cross, self.fy, self.mz]
        rows = {b.name: b.start for b in lay.constraints}
        self.torque = [rows.get(f"wheel torque {w}", -1) for w in lay.wheels]
        self.var = {}  # wheel variable -> its position per wheel (the targets of the failure rules)
        for v in ("omega", "beta", "W", "h", "h0"):
            try:
                self.var[v] = [int(lay.var(v, w)) for w in lay.wheels]
            except (KeyError, ValueError, IndexError):
                continue
        names = list(lay.parameter_names)
        self.contact = [names.index(f"contact {w}") if f"contact {w}" in names else -1 for w in lay.wheels]
        self.pivot = names.index("pivot_locked") if "pivot_locked" in names else -1


def load_tables(index_path: str | Path) -> dict[str, Any]:
    """Every table of a table index (``tables/index.json``), each checked against the hash the
    index lists (:func:`rtctl.table.load_index`); raises :class:`rtctl.table.TableError`."""
    from .table import load_index

    return {name: info.load() for name, info in load_index(index_path).items()}


def load_tables_tolerant(index_path: str | Path, names: Any = None) -> tuple[dict[str, Any], dict[str, str]]:
    """The tables of an index that load, and why each other one did not (a missing or corrupt
    file, a hash that differs from the index): ``(tables, {name: reason})``. The index itself
    must be readable (:class:`rtctl.table.TableError` otherwise)."""
    from .table import TableError, load_index

    tables: dict[str, Any] = {}
    gaps: dict[str, str] = {}
    for name, info in load_index(index_path).items():
        if names is not None and name not in names:
            continue
        try:
            tables[name] = info.load()
        except (TableError, OSError, ValueError, KeyError) as exc:
            gaps[name] = str(exc).splitlines()[0][:300]
    return tables, gaps


@dataclass
class _Prepared:
    """Everything the preparation phase leaves for the next feedback phase."""

    table: str
    point: Any
    allocator: QpAllocator
    idx: _Index
    rti: RealTimeIteration
    step_box: NDArray[np.float64]
    gains: tuple[float, float]
    crab_sensitivity: tuple[float, float]
    primitive_slip: float
    speed_factor: float
    operating_point: tuple[tuple[str, float], ...]
    signature: frozenset[tuple[str, str]]
    flags: tuple[str, ...] = ()
    lateral: bool = True
    """The QP can move the F_y balance row (:func:`lateral_authority`); else the cross-track
    error is corrected through the heading and no F_y offset or crab bias is asked for."""


class Controller:
    """The on-rover controller (module docstring).

    Parameters
    ----------
    tables : Table or mapping name -> Table
        Loaded tables (:func:`rtctl.table.load_table`), all for the same rover. The table whose
        scenario's failures and task equal the declared failures and the measurement's
        :class:`rtctl.messages.Task` (a trench goal) is used (several: ``config.default_table`` if
        it is one of them, else the first by name); otherwise ``config.default_table`` or the one
        built without failures (``nominal`` first), with the declared failures imposed as QP
        constraints (a declared task without a table is flagged in the diagnostics). A table's
        family axis is read at the declared value (stuck angle, rim-speed cap / speed, trench
        depth), clamped into the axis and flagged when outside. A table with no feasible point
        cannot be interpolated: the last good preparation is kept and ``table_errors`` counts it.
    config : ControllerConfig
    unavailable : mapping name -> str, optional
        Tables of the index that did not load at start-up and why
        (:func:`load_tables_tolerant`): flagged on every tick; a failure they served is imposed
        on another table, and said.
    mirror : bool
        Add the left-right mirror of every failure table whose mirrored failures no loaded table
        serves (a rear-right table serves rear-left; :mod:`rtctl.mirror`); a drive on one is
        flagged with the table it mirrors.
    """

    def __init__(self, tables: Any, config: ControllerConfig, unavailable: Mapping[str, str] | None = None,
                 mirror: bool = True) -> None:
        if hasattr(tables, "at"):
            tables = {str(getattr(tables, "name", "table")): tables}
        if not isinstance(tables, Mapping) or not tables:
            raise ControllerError("tables: expected a Table or a non-empty mapping name -> Table")
        tables = dict(tables)
        unavailable = dict(unavailable or {})
        self.kinds: dict[str, KindSpec] = {}
        """Every failure kind the loaded tables describe (:mod:`rtctl.failures`), by its declared name."""
        self.task_kinds: dict[str, KindSpec] = {}
        """Every task kind the loaded task tables describe (:func:`rtctl.failures.read_task_kinds`)."""
        kind_from: dict[str, str] = {}
        for name in sorted(tables):
            t = tables[name]
            why = unsupported_reason(t.header, t.layout)
            if why is not None:  # another rover's wheel set (:mod:`rtctl.wheel_set`): refused, never driven
                unavailable[name] = why
                del tables[name]
                continue
            try:
                kinds = read_kinds(t.header, name)
                task_kinds = read_task_kinds(t.header, name)
                sig = table_signature(t)
            except FailureDescriptionError as exc:
                unavailable[name] = f"its failure description is malformed ({exc})"
                del tables[name]
                continue
            if UNDESCRIBED in sig:
                unavailable[name] = ("a failure table without the failure description rtctl reads (built before it): "
                                     "run 'offnominal tables describe'")
                del tables[name]
                continue
            clash = sorted(k for k, spec in kinds.items() if k in self.kinds and not self.kinds[k].same_physics(spec))
            if clash:
                unavailable[name] = (f"it describes failure kind(s) {clash} differently from table "
                                     f"{kind_from[clash[0]]} (rebuild or describe both with one library version)")
                del tables[name]
                continue
            tclash = sorted(k for k, spec in task_kinds.items()
                            if k in self.task_kinds and not self.task_kinds[k].same_physics(spec))
            if tclash:
                unavailable[name] = (f"it describes task kind(s) {tclash} differently from table "
                                     f"{kind_from['task:' + tclash[0]]} (rebuild or describe both with one library version)")
                del tables[name]
                continue
            for k, spec in kinds.items():
                self.kinds.setdefault(k, spec)
                kind_from.setdefault(k, name)
            for k, spec in task_kinds.items():
                self.task_kinds.setdefault(k, spec)
                kind_from.setdefault("task:" + k, name)
        if not tables:
            raise ControllerError("no usable table: " + "; ".join(f"{k}: {v}" for k, v in sorted(unavailable.items())))
        self.wheel_set: WheelSet = _common_wheel_set(tables)
        """The wheel set every loaded table is for (:mod:`rtctl.wheel_set`): names, count, steerable,
        driven; every per-wheel vector of the measurements and commands follows it."""
        self.wheels: tuple[str, ...] = self.wheel_set.wheels
        self._backward = self.wheel_set.drive_direction == "backward"
        """Wheel names in the order of every per-wheel vector (the mini rover's FR, FL, RR, RL)."""
        self.mirrored: dict[str, str] = {}
        """Tables added as the left-right mirror of a loaded one (mirror name -> original), where no
        loaded table serves the mirrored failures (:func:`rtctl.mirror.mirror_table`)."""
        if mirror:
            sigs = {table_signature(t) for t in tables.values()}
            for name, t in sorted(tables.items()):
                sig = table_signature(t)
                try:  # the mirror map from the wheel positions (the mini rover's FR-FL, RR-RL)
                    wmap = mirror_wheel_map(t)
                except MirrorError:  # not left-right symmetric, or a rigid frame: its mirror must be built
                    continue
                msig = frozenset((wmap.get(w, w), k) for w, k in sig)
                if not sig or msig in sigs:
                    continue
                try:
                    m = mirror_table(t)
                except MirrorError:  # a trench table: its mirror must be built
                    continue
                if m.name not in tables:
                    tables[m.name] = m
                    sigs.add(msig)
                    self.mirrored[m.name] = name
        for name, t in tables.items():  # mirrors handed in already built (a controller rebuilt from another's tables)
            of = (t.header.get("mirror_of") or {}).get("name") if isinstance(t.header.get("mirror_of"), dict) else None
            if of and name not in self.mirrored:
                self.mirrored[name] = str(of)
        self.tables = dict(sorted(tables.items()))
        self.config = config
        self.unavailable = dict(sorted(unavailable.items()))
        """Tables that did not load at start-up or that the controller cannot use (name -> why): flagged
        on every tick."""
        self._gap_flags = tuple(f"table {k} unavailable since start-up: {v}; failures it served are imposed on "
                                "another table" for k, v in self.unavailable.items())
        self.signatures = {k: table_signature(t) for k, t in self.tables.items()}
        self._choice_cache: dict[Any, tuple[str, tuple[str, ...], tuple[tuple[str, int], ...]]] = {}
        self._xy = {k: _wheel_xy(t) for k, t in self.tables.items()}  # rover-file wheel centres (None: mini rover)
        self._index = {k: _Index(t.layout) for k, t in self.tables.items()}
        self._no_primitive = frozenset(k for k, t in self.tables.items()
                                       if getattr(t, "feasible", None) is not None and not np.any(t.feasible))
        """Tables with no primitive at any grid point (:meth:`_choose_table`)."""

        nominal = [k for k, s in self.signatures.items() if not s]
        self.default_table = "nominal" if "nominal" in nominal else (nominal[0] if nominal else next(iter(self.tables)))
        if config.default_table:
            if config.default_table not in self.tables:
                raise ControllerError(f"[tables] default = {config.default_table!r} is not one of the tables "
                                      f"{sorted(self.tables)}")
            self.default_table = config.default_table
        rs = config.drive.wheel_radius
        if not math.isfinite(rs):
            sets = {wheel_radii_of(t) for t in self.tables.values()}
            sets = {r for r in sets if all(math.isfinite(v) for v in r)}
            if len(sets) != 1:
                raise ControllerError(f"wheel radius: tables give {sorted(sets) or 'none'}; set [drive] wheel_radius in the "
                                      "config (or build every table with the same per-wheel radii)")
            radii = sets.pop()
        else:
            radii = (float(rs),) * len(self.wheels)
        offsets = {steer_offsets_of(t) for t in self.tables.values()}
        if len(offsets) != 1:
            raise ControllerError(f"steering offsets: tables give {sorted(offsets)}; build every table with the same "
                                  "[wheels.*] steer_offset_deg (or --world file)")
        self.wheel_radii = np.array(radii, dtype=float)
        """Shearing radius per wheel, m: the wheels' own radii, for odometry (ground speed = omega x radius, eq. (5.2))."""
        self.steer_offset = np.array(offsets.pop(), dtype=float)
        """True minus encoder steering angle per wheel, rad: command = beta - offset, beta = reading + offset."""
        self._per_wheel = len(set(radii)) > 1
        self._offset_on = bool(np.any(self.steer_offset != 0.0))
        if math.isfinite(rs):
            self.wheel_radius = float(rs)
        else:
            cmd = {wheel_radius_of(t) for t in self.tables.values()}
            cmd = {r for r in cmd if math.isfinite(r)}
            if len(cmd) != 1:
                raise ControllerError(f"command radius: tables give {sorted(cmd) or 'none'}; set [drive] wheel_radius in "
                                      "the config")
            self.wheel_radius = cmd.pop()
        """Command radius, m: the parameter set's shearing radius, with which the rover's software turns a
        rim-speed command into a wheel speed (rim-speed command = omega x this); a worn wheel's own radius
        (:attr:`wheel_radii`) enters the odometry only."""
        self.reset()

    def _radii(self) -> float | NDArray[np.float64]:
        """The radii of the odometry: the one radius, or per wheel (a table built with them)."""
        return self.wheel_radii if self._per_wheel else self.wheel_radius

    @classmethod
    def from_config(cls, config: ControllerConfig) -> "Controller":
        """A controller on the tables of ``config.tables_index`` (``[tables] index`` in the TOML)."""
        if not config.tables_index:
            raise ControllerError("[tables] index is empty: give the path of the table index (tables/index.json)")
        tables, gaps = load_tables_tolerant(config.tables_index)
        if not tables:
            raise ControllerError(f"no table of {config.tables_index} loads: " + "; ".join(f"{k}: {v}" for k, v in gaps.items()))
        return cls(tables, config, gaps)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Back to the state right after construction (same outputs for the same inputs)."""
        cfg = self.config
        self.ekf = SlipHeadingEKF(cfg, self.wheel_radius)
        self.ekf.reset(0.0, cfg.drive.path_x, cfg.drive.path_y, cfg.drive.path_heading)
        self._rtis: dict[str, RealTimeIteration] = {}
        self._lateral: dict[tuple[str, bytes], bool] = {}
        self._last_t: float | None = None
        self._last_seq: int | None = None
        self._clock = TickClock(cfg.period)
        self._pose_seen = False
        self._slope = 0.0
        self._cross = 0.0
        self._int_psi = 0.0
        self._int_y = 0.0
        self._failures: dict[tuple[str, str], float] = {}
        self._task: Task | None = None
        self._tick_flags: list[str] = []
        self._crab_cmd = self._crab_used = 0.0
        self._steer_meas = [math.nan] * len(self.wheels)
        self._counters: dict[str, int] = {}
        self._prep: _Prepared | None = None
        self._table_error = ""
        self._last_qp: tuple[QpAllocator, tuple[Any, ...]] | None = None
        self._last_p: NDArray[np.float64] | None = None
        self._short_ticks = 0  # consecutive ticks whose linearised balance stayed out of reach
        self._steady_short = 0  # ... of them with the QP's answer held by no transient bound
        self._small_short = 0  # consecutive ticks with any slack above the small tolerance
        self._steady_box: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._cmd_rules: list[tuple[float, float, bool, bool]] = [(-math.inf, math.inf, False, False)] * len(self.wheels)
        self._param_fix: list[tuple[int, float]] = []
        self._prev_cmd: tuple[_Quad, _Quad] = ((0.0,) * len(self.wheels), (0.0,) * len(self.wheels))
        self.prepare()
        if self._prep is None:
            raise ControllerError(f"no table could be prepared at the start ({self._table_error}); check the tables")
        self._prev_cmd = self._primitive_commands(self._prep.allocator.x0)

    def _count(self, name: str, n: int = 1) -> None:
        self._counters[name] = self._counters.get(name, 0) + n

    # ------------------------------------------------------------------ preparation phase
    def _declared(self) -> frozenset[tuple[str, str]]:
        """Declared failures and task as a table signature."""
        task = {(self._task.wheel, self._task.kind)} if self._task is not None else set()
        return frozenset(self._failures) | frozenset(task)

    def _choose_table(self) -> tuple[str, list[str]]:
        """The table to drive for the declared failures and task, and the preparation's flags
        (:meth:`_choose_table_for`): memoised per declaration (the tables, their signatures and
        the failure descriptions are fixed at construction), the counters it bumps replayed."""
        task = self._task
        key = (tuple(sorted(self._failures.items())), None if task is None else (task.kind, task.wheel, task.value))
        hit = self._choice_cache.get(key)
        if hit is None:
            before = dict(self._counters)
            name, flags = self._choose_table_for()
            bumped = tuple((k, v - before.get(k, 0)) for k, v in self._counters.items() if v != before.get(k, 0))
            if len(self._choice_cache) >= 64:  # a bounded memory: declarations change rarely
                self._choice_cache.clear()
            self._choice_cache[key] = (name, tuple(flags), bumped)
            return name, flags
        name, fl, bumped = hit
        for k, n in bumped:
            self._count(k, n)
        return name, list(fl)

    def _choose_table_for(self) -> tuple[str, list[str]]:
        declared = self._declared()
        flags: list[str] = []
        # a table without a single primitive (the optimizer's verdict at every grid point: e.g. a
        # locked wheel on this soil) is the offline evidence that the declared case is unreachable:
        # said, and the best reachable point is driven on another table with the failures imposed
        empty = sorted(name for name, sig in self.signatures.items()
                       if sig and sig <= declared and name in self._no_primitive)
        if empty:
            self._count("unreachable_preparations")
            t = self.tables[empty[0]]
            n = int(np.size(getattr(t, "feasible", ())))
            served = {wk: v for wk, v in self._failures.items() if wk in self.signatures[empty[0]]}
            part = "" if self.signatures[empty[0]] == declared else f" (of the declared {_describe_failures(self._failures)})"
            flags.append(f"unreachable: table {empty[0]}, built for {_describe_failures(served)}{part}, has no primitive "
                         f"at any of its {n} grid points (the optimizer found none); driving the best reachable point")
        usable = {name: sig for name, sig in self.signatures.items() if name not in self._no_primitive}
        matches = [name for name, sig in usable.items() if sig and sig == declared]
        if matches:
            return (self.config.default_table if self.config.default_table in matches else matches[0]), flags
        # No exact match: the table built for the most of the declared failures (and the task, if
        # its table is among them), the rest imposed on it from their descriptions; none: the
        # default table with every failure imposed.
        subsets = sorted((-len(sig), name) for name, sig in usable.items() if sig and sig < declared)
        name = subsets[0][1] if subsets else self.default_table
        if self._task is not None and (self._task.wheel, self._task.kind) not in self.signatures[name]:
            flags.append(f"no table for the declared task {self._task.kind} {self._task.wheel} with failures "
                         f"{sorted(self._failures) or 'none'}: driving on table {name}")
        if self._failures:
            self._count("unmatched_failure_preparations")
            unknown = sorted({k for _, k in self._failures if k not in self.kinds})
            if unknown:
                self._count("unknown_failure_kind_preparations")
            own = self.signatures[name]
            rest = {wk: v for wk, v in self._failures.items() if wk not in own}
            built = f" (built for {_describe_failures({wk: v for wk, v in self._failures.items() if wk in own})})" if own else ""
            flags.append(f"no table for the declared failures {_describe_failures(self._failures)}: driving on table "
                         f"{name}{built} with {_imposed(rest, self.kinds) if rest else 'nothing more imposed'}")
        return name, flags

    def prepare(self) -> None:
        """Preparation phase: choose and interpolate the table, load the QP's matrices."""
        cfg = self.config
        name, flags = self._choose_table()
        table = self.tables[name]
        lay = table.layout
        speed = cfg.drive.speed
        factor = 1.0
        x = self.ekf.x
        P = self.ekf.P
        prev = self._prep
        # the slip correction shifts the table speed; on a table of a rim-speed cap that would also
        # move the cap fraction (cap / speed) to another primitive (measured: a shift to 0.7 on the
        # shipped tables in the chapter-7 world took the fraction from 0.5 to 0.71 and the rover
        # turned 24 deg off its line); there the speed is left to the cap
        if prev is not None and prev.table == name and math.sqrt(P[3, 3]) < _SLIP_SIGMA_USE \
                and _per_speed_axis(table) is None:
            s_hat = min(max(float(x[3]), -0.5), 0.9)
            factor = min(max((1.0 - prev.primitive_slip) / (1.0 - s_hat), _SPEED_SHIFT[0]), _SPEED_SHIFT[1])
            if not prev.lateral and abs(s_hat - prev.primitive_slip) < _SLIP_DEAD_BAND * math.sqrt(P[3, 3]):
                # a slip estimate within its noise of the model's shifts nothing. Shifted each tick, the
                # skid-steer's command chattered at the rim-rate limit (results_any_rover_drives.md,
                # i23-skid). Only on tables without lateral authority (only the skid-steer's), so the
                # other rovers' drives are unchanged; they were not measured with the band.
                factor = 1.0
        try:
            tp, factor = self._reachable(table, speed, factor, flags)
        except (ValueError, KeyError) as exc:  # the table reader's TableError: keep the last good preparation
            self._count("table_errors")
            self._table_error = str(exc)
            return
        rti = self._rtis.get(name)
        if rti is None:
            rti = self._rtis[name] = RealTimeIteration(table, cfg.qp, self._index[name].torque)
        if prev is None or prev.table != name:  # a new table: the iterate starts at its primitive
            rti.reset()
        alloc = rti.allocator
        # a restart in a tick is spread over ticks (QpSettings.restart_work_per_tick); the
        # start-up preparation, before any tick, is not
        budget = cfg.qp.restart_work_per_tick if (self._last_t is not None and cfg.qp.restart_work_per_tick > 0) else None
        try:
            rti.prepare(tp, budget)
        except AllocatorError as exc:
            self._count("table_point_refused")
            self._table_error = str(exc)
            return
        ix = self._index[name]
        gains = self._gains(table)
        if rti.no_model:
            flags.append(rti.no_model)
        if name in self.mirrored:
            flags.append(f"table {name} is the left-right mirror of table {self.mirrored[name]}")
        xk = rti.iterate if rti.iterate is not None else alloc.x0
        # structural (which variables the point leaves free), so judged once per table and free set
        key = (name, (np.asarray(tp.ubx, dtype=float) > np.asarray(tp.lbx, dtype=float)).tobytes())
        lateral = self._lateral.get(key)
        if lateral is None:
            lateral = self._lateral[key] = lateral_authority(tp, lay)
        if not lateral:
            flags.append(f"table {name}: no free variable moves the F_y balance row (no steering): the cross-track "
                         "error is corrected through the heading, no F_y offset or crab bias")
        self._prep = _Prepared(name, tp, alloc, ix, rti, cfg.qp.step_limit * alloc.sx, gains,
                               self._crab_sensitivity(table, tp, ix), self._primitive_slip(xk, tp, ix, prev is not None),
                               factor, tuple(sorted(tp.operating_point.items())), self.signatures[name], tuple(flags),
                               lateral)

    def _operating_point(self, table: Any, v: float, flags: list[str]) -> dict[str, float]:
        """The table's axes at table speed ``v``: filtered IMU slope and cross slope, the declared
        family value."""
        op: dict[str, float] = {}
        for axis, values in table.axes.items():
            if axis == "slope":
                op[axis] = self._slope
            elif axis == "cross_slope":
                op[axis] = self._cross
            elif axis == "speed":
                op[axis] = v
            else:
                op[axis] = self._family_value(table, axis, v, values, flags)
        return op

    def _reachable(self, table: Any, speed: float, factor: float, flags: list[str]) -> tuple[Any, float]:
        """The table point to drive and its speed factor (table speed / target speed).

        The point at the target speed (times the slip correction) unless the grid point nearest
        to it has no primitive (the target is then taken as unreachable: the interpolation would
        lean on the other corners, e.g. flat-ground primitives on a 5 deg slope). Then, without the
        slip correction, and with a rim-speed cap (whose fraction cap / speed is what decides
        feasibility on this rate-independent soil) at lower travel speeds down to the table's
        lowest, the fastest point interpolated between primitives is driven instead, and a flag
        says so (``target unreachable: ...``); found nothing: flagged, the table's nearest driven."""
        fl: list[str] = []
        op = self._operating_point(table, speed * factor, fl)
        tp = table.at(**op)
        if _nearest_grid_feasible(table, op):
            flags.extend(fl)
            return tp, factor
        cands = [speed] if factor != 1.0 else []
        sp = table.axes.get("speed")
        capped = _per_speed_axis(table) is not None
        if capped and sp is not None and len(sp) > 1:
            top, lo = min(speed, speed * factor), float(sp[0])
            cands += [top - (top - lo) * k / 10 for k in range(1, 11) if top > lo]
        for v in cands:
            fl2: list[str] = []
            tp2 = table.at(**self._operating_point(table, v, fl2))
            if tp2.status == "interpolated":
                if v < speed * (1 - 1e-9):
                    flags.append(f"target unreachable: table {getattr(table, 'name', '?')} has no primitive at "
                                 f"{_describe(op)} ({tp.status}); driving at the reachable "
                                 f"{100 * v:.2f} cm/s ({100 * (v / speed - 1):+.0f} % of the target)")
                flags.extend(fl2)
                return tp2, v / speed
        if capped or tp.status == "nearest feasible grid point":
            flags.append(f"target unreachable: table {getattr(table, 'name', '?')} has no primitive at "
                         f"{_describe(op)} ({tp.status})"
                         + (" nor at lower speeds" if capped else "") + "; driving the table's nearest")
        flags.extend(fl)
        return tp, factor

    def _family_value(self, table: Any, axis: str, speed: float, values: NDArray[np.float64], flags: list[str]) -> float:
        """The table's family axis at the declared value (clamped into the axis; flagged when
        outside or when nothing declares it: read at the axis middle)."""
        fam = table.meta.get("family") or {}
        w = fam.get("wheel")
        dec_any = fam.get("declares")
        dec: Mapping[str, Any] = dec_any if isinstance(dec_any, Mapping) else {}
        tname = getattr(table, "name", "?")
        mid = float(values[len(values) // 2])
        v = math.nan
        if w in self.wheels and fam.get("axis") == axis:
            i = self.wheels.index(w)
            kind = dec.get("kind")
            if isinstance(kind, str):
                spec = self.kinds.get(kind)
                v = self._failures.get((w, kind), math.nan)
                if spec is not None and any(r.prefer_measured for r in spec.rules) and math.isfinite(self._steer_meas[i]):
                    # a measured steering angle, in encoder terms like the declared value and the axis
                    v = self._steer_meas[i] - (float(self.steer_offset[i]) if self._offset_on else 0.0)
                if dec.get("per_speed") is True:
                    v = v / speed if speed > 0 else math.nan
            elif dec.get("task") is not None and self._task is not None and self._task.kind == dec.get("task") \
                    and self._task.wheel == w:
                v = self._task.value
        if not math.isfinite(v):
            flags.append(f"table {tname}: nothing declares its {axis} axis; read at its middle {mid:.4g}")
            return mid
        lo, hi = float(values[0]), float(values[-1])
        if not lo - 1e-12 <= v <= hi + 1e-12:
            c = min(max(v, lo), hi)
            flags.append(f"table {tname}: declared {axis} {v:.4g} outside the table's [{lo:.4g}, {hi:.4g}] "
                         f"(SI): read at {c:.4g}")
            return c
        return float(v)

    def _odometry_wheels(self) -> list[bool]:
        """Wheels whose speed tells the travel speed: not one whose declared failure's description says
        it does not (locked, unpowered, raised), nor one with a failure kind no table describes, nor the
        wheel of a task whose description says so (a trench's digging wheel spins at several times
        the travel speed on purpose: in the trench primitive of section 7.3.1 it would make the
        rover-level slip ~0.6, dominated by that wheel, and the slip correction would chase it)."""
        out = [True] * len(self.wheels)
        if self._task is not None and self._task.wheel in self.wheels:  # the task's description says
            spec = self.task_kinds.get(self._task.kind)
            if spec is None or not spec.odometry:
                out[self.wheels.index(self._task.wheel)] = False
        for (w, k) in self._failures:  # the kind's description says; an unknown kind: left out to be safe
            spec = self.kinds.get(k)
            if w in self.wheels and (spec is None or not spec.odometry):
                out[self.wheels.index(w)] = False
        return out

    def _primitive_slip(self, x: NDArray[np.float64], tp: Any, ix: _Index, carried: bool = False) -> float:
        """Rover-level slip of the model's solution ``x`` (the real-time iteration's iterate: the
        model at the measured slope and cross slope, not the table's grid primitive), by the
        EKF's own odometry definition, at the travel speed of the table point."""
        om, be = x[ix.om].tolist(), x[ix.be].tolist()
        v_odo, _ = wheel_odometry(om, be, self._odometry_wheels(), self._radii(), 1.0)
        # the iterate solves the model at the speed parameter of the last feedback
        v = float(self._last_p[ix.speed]) if carried and self._last_p is not None else float(tp.p[ix.speed])
        return 1.0 - v / v_odo if (math.isfinite(v_odo) and v_odo > 1e-9) else 0.0

    def _crab_sensitivity(self, table: Any, tp: Any, ix: _Index) -> tuple[float, float]:
        """d(sum F_y)/d v_y and d(M_z balance)/d v_y of the rover (eqs. (7.6)-(7.7), (7.13), (7.18))."""
        rover = table.meta.get("rover") or {}
        wr, lr = rover.get("track_width"), rover.get("rocker_length")
        J = np.asarray(tp.wrench_jac, dtype=float)
        b = tp.x[ix.be]
        c, s = np.cos(b), np.sin(b)
        d = J[:, :, 0] * s[:, None] + J[:, :, 1] * c[:, None]  # d wrench / d v_y,rover (wheel frame), per wheel
        fx, fy, mz = c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 5]
        dfy = float(fy.sum())
        dmz = 0.0
        xy = self._xy.get(str(getattr(table, "name", "")))
        if xy is not None and len(b) == xy.shape[1]:  # a rover file's wheel centres (body frame, about O)
            dmz = float(np.sum(mz - xy[1] * fx + xy[0] * fy))
        elif isinstance(wr, (int, float)) and isinstance(lr, (int, float)) and len(b) == len(WHEELS):
            dmz = float(np.sum(mz - _SIDE * fx * wr / 2 + _FRONT * fy * lr / 2))
        return dfy, dmz

    # ------------------------------------------------------------------ feedback phase
    def step(self, m: Measurements) -> tuple[Commands, Diagnostics]:
        """Feedback on ``m``, then preparation for the next tick."""
        out = self.feedback(m)
        self.prepare()
        return out

    def feedback(self, m: Measurements) -> tuple[Commands, Diagnostics]:
        """Feedback phase: from the measurement to the commands (module docstring). Every field
        is converted once by :func:`rtctl.inputs.read_measurements`, and the time stamp and
        sequence number judged by :class:`rtctl.inputs.TickClock` (its docstring states the rule
        and its constants); nothing raises.

        Tables of a rover driving backward (``wheel_set.drive_direction``, the rover turned half
        round, :func:`rtctl.physics.rover_file.driving_backward`) are in the frame of the travel
        direction; measurements and commands stay in the rover's body frame. The controller
        turns them at this boundary: wheel speeds, motor torques and rim-speed commands change
        sign, pitch and roll change sign, a pose's heading gains pi; steering angles (rotations
        about z), the yaw rate and the position of O are the same in both frames. Diagnostics
        are in the travel frame."""
        cmd, diag = self._feedback(m)
        if self._backward:
            cmd = Commands(cmd.t, cmd.seq, tuple(-v for v in cmd.rim_speed), cmd.steer_angle)
        return cmd, diag

    def _feedback(self, m: Measurements) -> tuple[Commands, Diagnostics]:
        cfg = self.config
        self._tick_flags = []
        inp = read_measurements(m, self.wheels)
        if self._backward:
            inp = _turned_half_round(inp)
        t, seq = inp.t, inp.seq
        if t is None or seq is None:
            self._count("rejected_bad_time_or_seq")
            return self._hold(t, seq, "measurement without a finite time stamp (|t| <= 1e9 s) or an integer "
                                      "sequence number")
        ref_t = self._clock.t
        verdict_t = self._clock.judge(t, seq)
        if verdict_t == "duplicate":
            self._count("rejected_duplicate")
            return self._hold(t, seq, "duplicate measurement")
        if verdict_t == "out_of_order":
            self._count("rejected_out_of_order")
            return self._hold(t, seq, "out-of-order measurement")
        if verdict_t == "jump":
            self._count("rejected_time_jump")
            return self._hold(t, seq, "time stamp and sequence number disagree with the last accepted measurement "
                                      "(an implausible jump; rtctl.inputs)")
        if verdict_t == "gap":
            self._count("sequence_gaps")
        first = ref_t is None
        rebase = verdict_t == "rebase"
        if rebase:  # a restart or a stepped clock (rtctl.inputs): go on as after a stale gap
            self._count("clock_rebases")
            self.ekf.rebase_time(t - cfg.max_gap)
        dt = cfg.period if first else (cfg.max_gap if rebase else t - ref_t)  # type: ignore[operator]
        stale = dt > cfg.max_gap or rebase
        if stale:
            self._count("stale_gaps")
            self._int_psi = self._int_y = 0.0
        if first:
            self.ekf.reset(t - cfg.period, cfg.drive.path_x, cfg.drive.path_y, cfg.drive.path_heading)
        self._last_t, self._last_seq = t, seq
        # ---- declared failures and task
        self._read_failures(inp)
        self._read_task(inp)
        # ---- wheels
        om, st, valid = self._read_wheels(inp)
        if inp.wheel_speed is None or inp.steer_angle is None:
            for fname in ("wheel_speed", "steer_angle"):
                why_w = wheel_vector_problem(getattr(m, fname, None), self.wheels)
                if why_w:
                    self._tick_flags.append(f"measurement {fname} rejected: {why_w}; every wheel taken out of the odometry")
        if first and (self._prep is None or self._prep.signature != self._declared()):
            # the first tick declares failures or a task the start-up preparation did not know:
            # prepare on the right table now and take its primitive as the previous command (the
            # rate limits start from it, not from the nominal primitive)
            self.prepare()
            if self._prep is not None:
                self._prev_cmd = self._primitive_commands(self._prep.allocator.x0)
        rs = self._radii()
        odo_ok = [v and ok for v, ok in zip(valid, self._odometry_wheels())]
        v_odo, var = wheel_odometry(om, st, odo_ok, rs, cfg.noise.wheel_speed)
        if stale:
            v_odo, var = math.nan, math.inf
        r = inp.yaw_rate
        if not abs(r) <= _MAX_YAW_RATE:  # NaN (rejected at the boundary) fails too
            self._count("rejected_yaw_rate")
            r = math.nan
        self._read_tilt(inp, dt)
        # ---- EKF
        self._crab_used = self._crab_cmd
        self.ekf.predict(t, Odometry(v_odo, var, r, self._crab_cmd))
        verdict = ""
        pose = inp.pose
        if inp.pose_invalid:
            verdict = "invalid"
            self._count("rejected_pose_invalid")
        elif pose is not None:
            if not self._pose_seen and all(abs(v) < 1e6 for v in (pose.x, pose.y, pose.heading)) \
                    and t - cfg.period <= pose.t <= t:
                self.ekf.initialise_pose(pose)
                verdict = "initial"
                self._pose_seen = True
            else:
                verdict = self.ekf.update_pose(pose)
                if verdict == "invalid":
                    self._count("rejected_pose_invalid")
                elif verdict in ("accepted", "late", "reset"):
                    self._pose_seen = True
        # ---- outer loop
        x = self.ekf.x
        h = cfg.drive.path_heading
        e_psi = float(wrap_angle(h - x[2]))
        lateral = -math.sin(h) * (x[0] - cfg.drive.path_x) + math.cos(h) * (x[1] - cfg.drive.path_y)
        e_y = -lateral
        prep = self._prep
        if prep is None:
            return self._fallback(t, seq, "no table point prepared", e_psi, e_y, 0.0, 0.0, verdict, None)
        if prep.lateral:
            mz, fy = self._offsets(prep, e_psi, e_y, dt)
        else:  # no F_y (lateral_authority): the cross-track error becomes a heading demand
            self._int_y = 0.0
            look = max(abs(cfg.drive.speed), 1e-3) * _CROSSTRACK_TIME
            mz, fy = self._offsets(prep, e_psi + math.atan(e_y / look), 0.0, dt)
        # ---- slip correction (b): crab bias into the offsets
        P = self.ekf.P
        mz_bias = fy_bias = 0.0
        dfy, dmz = prep.crab_sensitivity if prep.lateral else (0.0, 0.0)
        # the lateral speed the outer loop's own offset asks for is not a disturbance: a real
        # rover balances an F_y offset by crabbing until the lateral resistance matches it. The
        # EKF is told this crab (for the next step) and its crab state is the rest.
        vy_wanted = -fy / dfy if dfy < -1e-9 else 0.0
        crab_cmd = math.atan2(vy_wanted, cfg.drive.speed)
        if math.sqrt(P[4, 4]) < _CRAB_SIGMA_USE and math.sqrt(P[3, 3]) < _SLIP_SIGMA_USE:
            v_hat = (1.0 - min(max(float(x[3]), -0.5), 0.9)) * (v_odo if math.isfinite(v_odo) else cfg.drive.speed)
            vy = v_hat * math.tan(min(max(float(x[4]), -0.5), 0.5))
            fy_bias, mz_bias = dfy * vy, dmz * vy
        # ---- QP
        ix = prep.idx
        p = np.array(prep.point.p, dtype=float)
        p[ix.speed] = cfg.drive.speed * prep.speed_factor
        p[ix.slope] = self._slope
        p[ix.cross] = self._cross
        p[ix.fy] = fy + fy_bias
        p[ix.mz] = mz + mz_bias
        # one real-time iteration of (7.25) at the measured parameters (never clipped to the
        # table: a parameter beyond the axes enters through the exact residual)
        rti = prep.rti
        xk = rti.iterate if rti.iterate is not None else prep.allocator.x0
        box, lbg, ubg = self._bounds(prep, dt, xk)
        for j, v in self._param_fix:  # contact and pivot lock of a declared failure (rtctl.failures)
            p[j] = v
        if rti.no_model:
            self._count("first_order_model_ticks")
        if rti.restarting:  # spread over ticks (QpSettings.restart_work_per_tick): the fallback meanwhile
            self._count("restart_ticks")
            return self._fallback(t, seq, f"restart in progress ({rti.restart_work_total} units of work done, "
                                  f"{cfg.qp.restart_work_per_tick} a tick)", e_psi, e_y, float(p[ix.mz]), float(p[ix.fy]),
                                  verdict, None)
        res = rti.step(p, box, lbg, ubg, x_ref=self._x_of_commands(prep, xk))
        self._last_qp = (prep.allocator, prep.allocator.snapshot())
        self._last_p = p
        self._unreachable(res, box)
        if not res.ok:  # the iterate restarts from the table's primitive at the next preparation
            self._count("qp_fallbacks")
            return self._fallback(t, seq, f"QP refused: {res.status}", e_psi, e_y, float(p[ix.mz]),
                                  float(p[ix.fy]), verdict, res)
        rim, steer = self._commands_from_x(prep, res.x)
        rim, steer = self._limit(rim, steer, dt)
        cmd = Commands(t, seq, rim, steer)
        if not self._valid(cmd):  # cannot happen after _limit; kept as the last guard
            self._count("invalid_commands_caught")
            return self._hold(t, seq, "command failed the final check")
        self._prev_cmd = (rim, steer)
        self._crab_cmd = crab_cmd
        return cmd, self._diag(t, seq, "qp", "", res, e_psi, e_y, float(p[ix.mz]),
                               float(p[ix.fy]), verdict)

    def last_qp(self) -> tuple[Any, NDArray[np.float64]] | None:
        """The QP of the last feedback phase that reached the solver and OSQP's answer in the
        QP's own variables (scaled step, slacks): ``(QpProblem, z)``; None before any."""
        if self._last_qp is None:
            return None
        alloc, snap = self._last_qp
        return alloc.problem(snap), snap[-1]

    # ------------------------------------------------------------------ pieces
    def _read_failures(self, inp: Inputs) -> None:
        """The declared failures of this tick (well-formed ones, :mod:`rtctl.inputs`). A value outside
        its kind's described range, or missing where the kind needs one, drops the declaration,
        counted and flagged; a kind no table describes is kept (flagged at the preparation: nothing
        can be imposed for it, and its wheel leaves the odometry)."""
        if inp.rejected_failures:
            self._count("rejected_failure_declaration", inp.rejected_failures)
        out: dict[tuple[str, str], float] = {}
        for f in inp.failures:
            spec = self.kinds.get(f.kind)
            why = spec.check_value(f.value) if spec is not None else ""
            if why:
                self._count("rejected_failure_declaration")
                self._tick_flags.append(f"failure declaration {f.wheel} {f.kind} rejected: {why}")
                continue
            out[(f.wheel, f.kind)] = f.value
        self._failures = out

    def _read_task(self, inp: Inputs) -> None:
        """Accept a well-formed :class:`Task` (:mod:`rtctl.inputs`) of a kind a loaded table
        describes, with its value in the described range; anything else is counted, flagged and
        ignored (no task)."""
        task = inp.task
        why = ""
        if inp.rejected_task:
            why = f"task {inp.rejected_task} rejected: expected Task(kind, wheel, finite value)"
        elif task is not None:
            spec = self.task_kinds.get(task.kind)
            if spec is None:
                known = ", ".join(sorted(self.task_kinds)) or "none"
                why = f"task {task.kind} {task.wheel} rejected: no loaded table describes task kind {task.kind!r} (described: {known})"
            else:
                bad = spec.check_value(task.value)
                why = f"task {task.kind} {task.wheel} rejected: {bad}" if bad else ""
            if why:
                task = None
        if why:
            self._count("rejected_task")
            self._tick_flags.append(why)
        self._task = task

    def _read_wheels(self, inp: Inputs) -> tuple[list[float], list[float], list[bool]]:
        """Wheel speeds and steering angles (physical angles: the encoder plus its offset); a
        non-finite or out-of-range entry takes that wheel out, a missing vector all four."""
        cfg = self.config
        om_max = 2.0 * cfg.actuators.max_rim_speed / float(np.min(self.wheel_radii))
        n = len(self.wheels)
        if inp.wheel_speed is None or inp.steer_angle is None:
            self._count("rejected_wheel_vectors")
            return [0.0] * n, [0.0] * n, [False] * n
        om, st = list(inp.wheel_speed), list(inp.steer_angle)
        valid = []
        for i, w in enumerate(self.wheels):
            ok = abs(om[i]) <= om_max and abs(st[i]) <= math.pi  # NaN (rejected at the boundary) fails
            if not ok:
                self._count(f"rejected_wheel_{w}")
                om[i], st[i] = 0.0, 0.0
            else:
                if self._offset_on:  # the encoder reads the true angle minus the offset
                    st[i] = st[i] + float(self.steer_offset[i])
                self._steer_meas[i] = st[i]
            valid.append(ok)
        return om, st, valid

    def _read_tilt(self, inp: Inputs, dt: float) -> None:
        a = min(max(dt, 0.0) / _TILT_TAU, 1.0)
        for v, attr, name in ((inp.pitch, "pitch", "_slope"), (inp.roll, "roll", "_cross")):
            if abs(v) <= _MAX_TILT:  # NaN (rejected at the boundary) fails
                setattr(self, name, (1 - a) * getattr(self, name) + a * v)
            else:
                self._count(f"rejected_{attr}")

    def _gains(self, table: Any) -> tuple[float, float]:
        """Heading and cross-track gains: configured, or the table's steering-controller offsets
        reached at 5 deg / 5 cm (module docstring)."""
        ol = self.config.outer_loop
        k_psi, k_y = ol.heading_gain, ol.crosstrack_gain
        offs = table.meta.get("controller_offsets") or {}
        mz, fy = offs.get("mz_offset_Nm"), offs.get("fy_offset_N")
        mz = float(mz) if isinstance(mz, (int, float)) and math.isfinite(mz) and mz > 0 else 0.2
        fy = float(fy) if isinstance(fy, (int, float)) and math.isfinite(fy) and fy > 0 else 1.0
        if math.isnan(k_psi):
            k_psi = mz / _REF_HEADING_ERROR
        if math.isnan(k_y):
            k_y = fy / _REF_CROSSTRACK_ERROR
        return k_psi, k_y

    def _offsets(self, prep: _Prepared, e_psi: float, e_y: float, dt: float) -> tuple[float, float]:
        ol = self.config.outer_loop
        k_psi, k_y = prep.gains
        mz_max, fy_max = ol.max_mz_offset, ol.max_fy_offset
        if ol.heading_integral > 0:
            self._int_psi = min(max(self._int_psi + dt * e_psi, -mz_max / ol.heading_integral), mz_max / ol.heading_integral)
        if ol.crosstrack_integral > 0:
            self._int_y = min(max(self._int_y + dt * e_y, -fy_max / ol.crosstrack_integral), fy_max / ol.crosstrack_integral)
        mz = k_psi * e_psi + ol.heading_integral * self._int_psi
        fy = k_y * e_y + ol.crosstrack_integral * self._int_y
        return min(max(mz, -mz_max), mz_max), min(max(fy, -fy_max), fy_max)

    def _bounds(self, prep: _Prepared, dt: float, xk: NDArray[np.float64] | None = None
                ) -> tuple[tuple[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64], NDArray[np.float64]]:
        """Physical box on x (failures > actuators > table > rate limits > step limit around the
        iterate ``xk``, default the table's primitive) and the constraint bounds with the
        declared torque failures."""
        act = self.config.actuators
        alloc = prep.allocator
        lay = alloc.layout
        rs = self.wheel_radius  # actuator limits and rates are on rim-speed commands
        off = self.steer_offset if self._offset_on else 0.0
        tlo, thi = alloc.table_bounds
        x0 = alloc.x0 if xk is None else xk
        nx = lay.nx
        alo, ahi = np.full(nx, -np.inf), np.full(nx, np.inf)
        rlo, rhi = np.full(nx, -np.inf), np.full(nx, np.inf)
        prev_rim, prev_steer = self._prev_cmd
        ix = prep.idx
        pr, ps = np.array(prev_rim), np.array(prev_steer)
        alo[ix.om], ahi[ix.om] = act.min_rim_speed / rs, act.max_rim_speed / rs
        alo[ix.be], ahi[ix.be] = -act.max_steer + off, act.max_steer + off  # encoder limits, physical angles
        rlo[ix.om], rhi[ix.om] = (pr - act.max_rim_accel * dt) / rs, (pr + act.max_rim_accel * dt) / rs
        rlo[ix.be], rhi[ix.be] = ps + off - act.max_steer_rate * dt, ps + off + act.max_steer_rate * dt
        lo, hi = merge_bounds(alo, ahi, (tlo, thi))
        lbg, ubg = prep.point.lbg, prep.point.ubg
        fixed = np.zeros(nx, dtype=bool)
        cmd_rules = [(-math.inf, math.inf, False, False)] * len(lay.wheels)
        self._param_fix = []
        if self._failures:
            lbg, ubg = np.array(lbg, dtype=float), np.array(ubg, dtype=float)
            speed = self.config.drive.speed * prep.speed_factor
            for i, w in enumerate(lay.wheels):
                mine = [(k, v) for (ww, k), v in sorted(self._failures.items()) if ww == w and k in self.kinds]
                if not mine:
                    continue
                j = ix.torque[i]
                cur_lo = {v: float(lo[pos[i]]) for v, pos in ix.var.items()}
                cur_hi = {v: float(hi[pos[i]]) for v, pos in ix.var.items()}
                if j >= 0:
                    cur_lo["torque"], cur_hi["torque"] = float(lbg[j]), float(ubg[j])
                own_lo: dict[str, float] = {}  # the failures' bounds alone: they hold in the commands at once
                own_hi: dict[str, float] = {}
                meas = self._steer_meas[i]
                done: set[str] = set()
                for k, v in mine:
                    mb = meas if math.isfinite(meas) else (float(x0[ix.be[i]]) if math.isnan(v) else math.nan)
                    off = float(self.steer_offset[i]) if self._offset_on else 0.0
                    done |= apply_rules(self.kinds[k], v, speed, rs, cur_lo, cur_hi, off, mb)
                    apply_rules(self.kinds[k], v, speed, rs, own_lo, own_hi, off, mb)
                for var, pos in ix.var.items():
                    a, b = cur_lo[var], cur_hi[var]
                    lo[pos[i]], hi[pos[i]] = min(a, b), b  # a cap below a lower bound: the cap wins
                    if var in done:
                        fixed[pos[i]] = True
                if j >= 0:
                    lbg[j], ubg[j] = min(cur_lo["torque"], cur_hi["torque"]), cur_hi["torque"]
                for par, pos_p in (("contact", ix.contact[i]), ("pivot_locked", ix.pivot)):
                    if par in own_lo and pos_p >= 0 and own_lo[par] == own_hi.get(par):
                        self._param_fix.append((pos_p, own_lo[par]))
                cmd_rules[i] = (own_lo.get("omega", -math.inf) * rs, own_hi.get("omega", math.inf) * rs,
                                "beta" in done, "omega" in done)
        self._cmd_rules = cmd_rules
        rlo[fixed], rhi[fixed] = -np.inf, np.inf
        tb = prep.step_box
        zlo, zhi = np.where(fixed, -np.inf, x0 - tb), np.where(fixed, np.inf, x0 + tb)
        steady = (lo, hi)  # the box of the steady state: what no number of ticks can widen
        lo, hi = merge_bounds(lo, hi, (rlo, rhi), (zlo, zhi))
        self._steady_box = steady
        return (lo, hi), lbg, ubg

    def _x_of_commands(self, prep: _Prepared, base: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        x = prep.allocator.x0 if base is None else np.array(base, dtype=float)
        rim, steer = self._prev_cmd
        x[prep.idx.om] = np.array(rim) / self.wheel_radius
        x[prep.idx.be] = np.array(steer) + self.steer_offset if self._offset_on else steer
        return x

    def _commands_from_x(self, prep: _Prepared, x: NDArray[np.float64]) -> tuple[tuple[float, ...], tuple[float, ...]]:
        rim = tuple((x[prep.idx.om] * self.wheel_radius).tolist())
        steer = tuple((x[prep.idx.be] - self.steer_offset if self._offset_on else x[prep.idx.be]).tolist())
        return rim, steer

    def _primitive_commands(self, x0: NDArray[np.float64]) -> tuple[_Quad, _Quad]:
        rim, steer = self._commands_from_x(self._prep, x0)  # type: ignore[arg-type]
        act = self.config.actuators
        r = [min(max(v, act.min_rim_speed), act.max_rim_speed) for v in rim]
        b = [min(max(v, -act.max_steer), act.max_steer) for v in steer]
        return tuple(r), tuple(b)

    def _limit(self, rim: tuple[float, ...], steer: tuple[float, ...], dt: float) -> tuple[_Quad, _Quad]:
        """Rate-limit from the previous command and clip into the actuator range; the result
        is always finite (a non-finite target holds the previous command). The bounds the declared
        failures' rules put on a wheel's speed hold at once (a lock, a cap), and a steering they fix
        is not rate-limited (:meth:`_bounds` leaves them in ``_cmd_rules``)."""
        act = self.config.actuators
        prev_rim, prev_steer = self._prev_cmd
        out_r, out_s = [], []
        for i in range(len(self.wheels)):
            a = rim[i] if math.isfinite(rim[i]) else prev_rim[i]
            b = steer[i] if math.isfinite(steer[i]) else prev_steer[i]
            da, db = act.max_rim_accel * dt * (1 + 1e-9), act.max_steer_rate * dt * (1 + 1e-9)
            r_lo, r_hi, steer_fixed, rim_fixed = self._cmd_rules[i] if self._failures else (-math.inf, math.inf, False, False)
            if not steer_fixed:  # a steering fixed by a declared failure (stuck) is commanded where it is
                b = min(max(b, prev_steer[i] - db), prev_steer[i] + db)
            if rim_fixed:  # a wheel speed fixed by a declared failure (locked: 0) is commanded at once
                a = r_lo
            else:
                a = min(max(a, prev_rim[i] - da), prev_rim[i] + da)
                a = min(max(a, r_lo), r_hi)  # a declared cap holds at once, like a lock
            out_r.append(min(max(a, act.min_rim_speed), act.max_rim_speed))
            out_s.append(min(max(b, -act.max_steer), act.max_steer))
        return tuple(out_r), tuple(out_s)

    def _valid(self, c: Commands) -> bool:
        act = self.config.actuators
        return c.is_valid(act.max_rim_speed, act.max_steer, len(self.wheels)) and all(v >= act.min_rim_speed for v in c.rim_speed)

    def _unreachable(self, res: Any, box: tuple[NDArray[np.float64], NDArray[np.float64]]) -> None:
        """Say when the steady state is out of reach: the exact residual's linearised balance has
        not been met (model-row slack above ``_UNREACHABLE_SLACK``) for ``_UNREACHABLE_TICKS``
        consecutive ticks, or above ``_UNREACHABLE_SMALL_SLACK`` for ``_UNREACHABLE_SMALL_TICKS``
        (the exact iteration meets a reachable balance exactly once it has converged, so a small
        violation that never goes away is the optimizer's small infeasibility), or for
        ``_UNREACHABLE_STEADY_TICKS`` consecutive ticks on which the QP's
        answer is held by none of the tick's transient bounds (rate limits, the step limit around the
        iterate), only by the steady box (actuator range, table bounds, the declared failures'
        rules), which later ticks cannot widen. Either way no primitive of the failed rover is being
        approached; the QP's answer (the smallest weighted violation within the limits) is the best
        reachable point driven."""
        slack = float(getattr(res, "slack", math.inf))
        short = not slack <= _UNREACHABLE_SLACK
        self._short_ticks = self._short_ticks + 1 if short else 0
        self._small_short = self._small_short + 1 if not slack <= _UNREACHABLE_SMALL_SLACK else 0
        held = _held_by_transient(getattr(res, "x", None), box, self._steady_box)
        self._steady_short = self._steady_short + 1 if short and not held else 0
        if self._short_ticks >= _UNREACHABLE_TICKS:
            how = f"for {self._short_ticks} ticks"
        elif self._steady_short >= _UNREACHABLE_STEADY_TICKS:
            how = (f"for {self._steady_short} ticks with no rate limit or step limit holding the step, only the "
                   "actuator range and the failures")
        elif self._small_short >= _UNREACHABLE_SMALL_TICKS:
            how = f"by a small margin that has not gone for {self._small_short} ticks"
        else:
            return
        self._count("unreachable_ticks")
        self._tick_flags.append(f"unreachable: the steady-state balance of the declared failures has been out of "
                                f"reach {how} (model-row slack {slack:.3g} scaled); driving the best reachable point")

    def _fallback(self, t: float, seq: int, why: str, e_psi: float, e_y: float, mz: float, fy: float, verdict: str,
                  res: Any) -> tuple[Commands, Diagnostics]:
        prep = self._prep
        dt = self.config.period
        self._crab_cmd = 0.0  # the fallback drives the primitive, without offsets
        if prep is not None:
            lo_hi, _, _ = self._bounds(prep, dt)
            x = np.clip(prep.allocator.x0, lo_hi[0], lo_hi[1])  # primitive with the failures applied
            rim, steer = self._commands_from_x(prep, x)
        else:
            rim, steer = self._prev_cmd
        rim, steer = self._limit(rim, steer, dt)
        cmd = Commands(t, seq, rim, steer)
        if not self._valid(cmd):
            self._count("invalid_commands_caught")
            return self._hold(t, seq, why + "; fallback failed the final check")
        self._prev_cmd = (rim, steer)
        self._count("fallbacks")
        return cmd, self._diag(t, seq, "fallback", why, res, e_psi, e_y, mz, fy, verdict)

    def _hold(self, t: float | None, seq: int | None, why: str) -> tuple[Commands, Diagnostics]:
        rim, steer = self._prev_cmd
        tt = t if t is not None else (self._last_t if self._last_t is not None else 0.0)
        ss = seq if seq is not None else -1
        self._count("holds")
        return Commands(tt, ss, rim, steer), self._diag(tt, ss, "hold", why, None, math.nan, math.nan, 0.0, 0.0, "")

    def _diag(self, t: float, seq: int, mode: str, why: str, res: Any, e_psi: float, e_y: float, mz: float, fy: float,
              verdict: str) -> Diagnostics:
        prep = self._prep
        ec = self.ekf.counters
        counters = dict(self._counters)
        for k, v in vars(ec).items():
            counters[f"ekf_{k}"] = v
        x, P = self.ekf.x, self.ekf.P
        return Diagnostics(
            t=t, seq=seq, mode=mode, reason=why, table=prep.table if prep else "", table_status=str(getattr(prep.point, "status", "")) if prep else "",
            operating_point=prep.operating_point if prep else (), qp_status=res.status if res is not None else "",
            qp_iterations=res.iterations if res is not None else 0, qp_slack=res.slack if res is not None else math.nan,
            heading_error=e_psi, crosstrack_error=e_y, mz_offset=mz, fy_offset=fy,
            speed_factor=prep.speed_factor if prep else 1.0, state=tuple(float(v) for v in x),
            state_sigma=tuple(float(v) for v in np.sqrt(np.diag(P))), pose_verdict=verdict,
            counters=tuple(sorted(counters.items())), crab_commanded=self._crab_used,
            flags=self._gap_flags + (prep.flags if prep else ()) + tuple(self._tick_flags))


def _describe_failures(failures: Mapping[tuple[str, str], float]) -> str:
    return ", ".join(f"{w} {k}" + (f" {v:.4g}" if math.isfinite(v) else "") for (w, k), v in sorted(failures.items()))


def _imposed(failures: Mapping[tuple[str, str], float], kinds: Mapping[str, KindSpec]) -> str:
    """What :meth:`Controller._bounds` imposes for each declared failure, from its kind's rules
    (said in the flag); a kind no table describes: nothing."""
    return "; ".join(f"{w} {k}: " + (rule_text(kinds[k]) if k in kinds else
                                     "NOTHING imposed (no loaded table describes this failure kind)")
                     for (w, k) in sorted(failures))


def _per_speed_axis(table: Any) -> str | None:
    """The family axis of a table that follows a declared value divided by the travel speed (a
    rim-speed cap as a fraction of the speed), or None."""
    fam = table.meta.get("family") or {}
    dec = fam.get("declares") if isinstance(fam, Mapping) else None
    if isinstance(dec, Mapping) and dec.get("per_speed") is True and fam.get("axis") in table.axes:
        return str(fam["axis"])
    return None


def _nearest_grid_feasible(table: Any, op: Mapping[str, float]) -> bool:
    """Whether the table's grid point nearest to ``op`` (each axis clamped into its range) has a
    primitive."""
    idx = []
    lists = getattr(table, "_ax", None)  # rtctl.table.Table: each axis as a list of floats
    for i, axis in enumerate(table.axis_order):
        if lists is not None:  # plain floats: the same differences and the first of equal ones, as np.argmin
            ax = lists[i]
            v = float(op.get(axis, ax[0]))
            idx.append(min(range(len(ax)), key=lambda j: abs(ax[j] - v)))
        else:
            vals = np.asarray(table.axes[axis], dtype=float)
            idx.append(int(np.argmin(np.abs(vals - op.get(axis, float(vals[0]))))))
    return bool(np.asarray(table.feasible)[tuple(idx)])


def _describe(op: Mapping[str, float]) -> str:
    """An operating point in display units (deg, cm/s)."""
    out = []
    for k, v in sorted(op.items()):
        if k in ("slope", "cross_slope", "steer_stuck"):
            out.append(f"{k} {math.degrees(v):.1f} deg")
        elif k == "speed":
            out.append(f"speed {100 * v:.2f} cm/s")
        elif k == "trench_depth":
            out.append(f"trench depth {1e3 * v:.1f} mm")
        else:
            out.append(f"{k} {v:.3g}")
    return ", ".join(out)

