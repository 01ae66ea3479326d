"""The rows and objective of the steady-state problem (7.25), written once for both sides.

:func:`steady_state_rows` builds every constraint row of the NLP (per wheel: load (5.34) /
(7.23), zero-slip load, wheel torque, the trench rows (7.28)-(7.29); the balance
(7.12)-(7.18), (7.26)-(7.27), (7.32)-(7.33) with the pivot rows) and the objective (7.24)
against :class:`rtctl.physics.backend.Backend`:

* the ground side calls it with casadi's backend to build the NLP graph that IPOPT solves and
  the table builder differentiates (``offline.rover.primitives.SteadyStateProblem``);
* the rover calls it with :data:`~rtctl.physics.backend.NUMPY` for each tick's exact residual
  and objective gradient at the current iterate and the measured parameters
  (:class:`SteadyStateResidual`), so a point between grid values, or beyond a table's axes, is
  judged by the physics itself, not by interpolated table values.

With numpy the wheels are evaluated in one batched call of
:func:`~rtctl.physics.terramechanics.wrench_core` (every wheel's wrench and zero-slip wrench,
and with :meth:`SteadyStateResidual.evaluate` ``gradient=True`` the forward-difference
perturbations of each wheel's own variables too). Its cost is mostly the number of array
operations (measured on the shared 2-core machine: about 150 us for one wheel state), and at
the tick's 32 states about as much again in the element-wise work, most of it the sines and
cosines over the 48 nodes of every state (numpy's float64 sin/cos are not vectorised there,
about 20 ns an element, against about 3 ns for exp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from .backend import NUMPY, Backend
from .hub_drag import HubFace, hub_wrench
from .parameters import ParameterError, Record, SoilLike, record
from .statics import FourWheelRocker
from .rover_file import rover_spec_from_record
from .suspension import SuspensionStatics
from .terramechanics import ModelOptions, PhysParams, _SoilView, _WheelView, wrench_core

__all__ = ["SteadyStateModel", "steady_state_rows", "with_hub", "SteadyStateResidual", "WHEEL_VARIABLES"]

WHEEL_VARIABLES: tuple[str, ...] = ("omega", "beta", "W", "h", "h0")
"""Per-wheel decision variables, as :data:`rtctl.layout.WHEEL_VARIABLES`."""

_SOIL_KEYS = ("k", "n0", "n1", "n2", "friction_angle", "unit_weight", "cohesion", "shear_modulus", "repose_angle")
_WHEEL_KEYS = ("radius", "width", "grouser_height", "grouser_area_ratio", "grouser_volume_fraction")
_TUNING_KEYS = ("a0", "a1", "b0", "b1", "a0_per_rad", "a1_per_rad", "b0_per_rad", "b1_per_rad")
_ROVER_KEYS = ("rocker_length", "pivot_height", "track_width", "weight")


@dataclass(frozen=True)
class SteadyStateModel:
    """Everything besides ``x`` and ``p`` that defines the rows of (7.25).

    Attributes
    ----------
    wheels : tuple of str
        Wheel names in layout order.
    phys : tuple of PhysParams
        Per wheel: the physics parameters (its own rim radius where the wheels differ).
    shearing_radius : tuple of float
        Per wheel r_s = r + h_g, m (the zero-slip wheel speed is ``speed / r_s``).
    options : ModelOptions
        Exit-angle model and smoothings of the wheel model.
    statics : FourWheelRocker or SuspensionStatics
        Balance (7.12)-(7.18): the mini rover's :class:`~rtctl.physics.statics.FourWheelRocker`,
        or the balance a rover file's suspension implies
        (:class:`~rtctl.physics.suspension.SuspensionStatics`); its ``balance_names`` are the
        layout's balance rows.
    soil : SoilLike
        The soil (for the hub drag).
    hub : HubFace or None
        Hub contact on every wheel (:func:`rtctl.physics.hub_drag.hub_wrench`); None: no term.
    external : (F_x, F_y, M_z) or None
        Constant body-frame pull, N, N, N m; None: no term.
    trench_wheel : str or None
        The wheel whose trench rows (7.28)-(7.29) the layout holds.
    torque_scale : float
        ``W / N r_s`` (``N`` wheels: ``W / 4 r_s`` for the mini rover), N m: the objective is ``sum M_y^2 / torque_scale^2`` (7.24).
    """

    wheels: tuple[str, ...]
    phys: tuple[PhysParams, ...]
    shearing_radius: tuple[float, ...]
    options: ModelOptions
    statics: FourWheelRocker | SuspensionStatics
    soil: SoilLike
    hub: HubFace | None = None
    external: tuple[float, float, float] | None = None
    trench_wheel: str | None = None
    torque_scale: float = 1.0

    @classmethod
    def from_table_header(cls, header: Mapping[str, Any], wheels: Sequence[str]) -> "SteadyStateModel":
        """The model a table was built with, from its header (``params``, ``rover``,
        ``scenario``, ``solver_options``, ``world``): the rover's exact residual uses it.

        A table built from a rover file (its ``scenario.rover_file`` record, the spec as the
        builder used it, turned round for a backward drive) gets that suspension's balance,
        :class:`~rtctl.physics.suspension.SuspensionStatics` (the source the NLP's rows come
        from, ``offline.rover.primitives.SteadyStateProblem``), and the torque scale
        ``W / N r_s`` of its ``N`` wheels; any other the mini rover's
        :class:`~rtctl.physics.statics.FourWheelRocker` and ``W / 4 r_s``, as before.

        Raises
        ------
        ParameterError
            A record or key the model needs is missing or not a finite number (naming it).
        """
        params = header.get("params")
        if not isinstance(params, Mapping):
            raise ParameterError("table header: no 'params' record (soil, wheel, tuning): rebuild the table")
        soil = record(params.get("soil") or {}, _SOIL_KEYS, "params.soil")
        wheel = record(params.get("wheel") or {}, _WHEEL_KEYS, "params.wheel")
        tuning = record(params.get("tuning") or {}, _TUNING_KEYS, "params.tuning")
        rover = record(header.get("rover") or {}, _ROVER_KEYS, "rover")
        sc = header.get("scenario") or {}
        so = header.get("solver_options") or {}
        world = header.get("world") or {}
        exit_angle = str(sc.get("exit_angle", "classic"))
        smooth = so.get("shear_direction_smoothing")
        mo = ModelOptions(exit_angle=exit_angle)  # type: ignore[arg-type]
        if isinstance(smooth, (int, float)):
            mo = replace(mo, shear_direction_smoothing=float(smooth))
        radii = world.get("wheel_radius_m")
        wheels = tuple(wheels)
        base = PhysParams.from_sets(soil, wheel, tuning)
        if isinstance(radii, list) and len(radii) == len(wheels):
            wheel_of = [wheel if float(r) == float(wheel.radius) else Record({**wheel.values, "radius": float(r)})
                        for r in radii]
        else:
            wheel_of = [wheel] * len(wheels)
        phys = tuple(base if w is wheel else PhysParams.from_sets(soil, w, tuning) for w in wheel_of)
        rs = tuple(float(w.shearing_radius) for w in wheel_of)
        ext = world.get("external_force")
        external = None
        if isinstance(ext, Mapping):
            external = (float(ext.get("fx_N", 0.0)), float(ext.get("fy_N", 0.0)), float(ext.get("mz_Nm", 0.0)))
        hubd = world.get("hub_contact")
        hub = None
        if isinstance(hubd, Mapping):
            hub = HubFace(clearance=float(hubd["clearance_m"]), face_width=float(hubd["face_width_m"]),
                          arm=float(hubd["arm_m"]))
        trench = sc.get("trench")
        tw = trench.get("wheel") if isinstance(trench, Mapping) else None
        pitch = bool(so.get("pitch_includes_wheel_torque", True))
        spec_rec = sc.get("rover_file") if isinstance(sc, Mapping) else None
        if isinstance(spec_rec, Mapping):  # a rover file's table: the statics its suspension implies
            spec = rover_spec_from_record(spec_rec, "table header scenario.rover_file")
            if spec.wheel_names != wheels:
                raise ParameterError(f"table header: the rover file's wheels {list(spec.wheel_names)} are not the "
                                     f"layout's {list(wheels)}: rebuild the table")
            statics: FourWheelRocker | SuspensionStatics = SuspensionStatics(spec, None, pitch)
            ts = float(spec.weight) / len(wheels) * float(wheel.shearing_radius)
        else:
            statics = FourWheelRocker(rover, pitch, wheels)
            ts = float(rover.weight) / 4 * float(wheel.shearing_radius)
        return cls(wheels, phys, rs, mo, statics, soil, hub, external, tw if tw in wheels else None, ts)


def with_hub(ops: Backend, model: SteadyStateModel, w: Sequence[Any], vx: Any, vy: Any, omega: Any,
              h: Any) -> tuple[Any, ...]:
    """A wheel's soil wrench (wheel frame, about its centre) plus the hub drag
    (:func:`rtctl.physics.hub_drag.hub_wrench`: F_x, F_y against the travel, M_y against the
    spin); the wrench itself, unchanged, without hub contact. The one place every path (NLP
    graph, independent check, tables, the rover's residual) adds the term."""
    if model.hub is None:
        return tuple(w)
    fx, fy, my = hub_wrench(ops, model.hub, model.soil, vx, vy, omega, h)
    return (w[0] + fx, w[1] + fy, w[2], w[3], w[4] + my, w[5])


def _stack_params(phys: Sequence[PhysParams], counts: Sequence[int]) -> PhysParams:
    """One PhysParams for a batch of wheel blocks (equal wheels: the shared one)."""
    if all(p is phys[0] or p == phys[0] for p in phys):
        return phys[0]
    cols = []
    for i, _ in enumerate(PhysParams._fields):
        cols.append(np.concatenate([np.full((n, 1), float(p[i])) for p, n in zip(phys, counts)]))
    return PhysParams(*cols)


def _wrenches(ops: Backend, model: SteadyStateModel, blocks: Sequence[tuple[int, Any, Any, Any, Any, Any]]
              ) -> list[tuple[Any, ...]]:
    """Soil wrenches of several wheel-state blocks ``(wheel index, vx, vy, omega, h, h0)``:
    one batched :func:`wrench_core` call with numpy, one graph each with casadi."""
    if ops is not NUMPY:
        return [wrench_core(ops, vx, vy, om, h, h0, model.phys[i], model.options)[0] for i, vx, vy, om, h, h0 in blocks]
    cols = []
    for blk in blocks:
        arrs = [np.asarray(v, dtype=float) for v in blk[1:]]
        shape = np.broadcast_shapes(*(a.shape for a in arrs))
        cols.append([np.broadcast_to(a, shape).reshape(-1, 1) for a in arrs])
    counts = [c[0].shape[0] for c in cols]
    cat = [np.concatenate([c[j] for c in cols]) for j in range(5)]
    w, _ = wrench_core(ops, cat[0], cat[1], cat[2], cat[3], cat[4], _stack_params([model.phys[b[0]] for b in blocks], counts),
                       model.options)
    out, a = [], 0
    for n in counts:
        out.append(tuple(q[a:a + n] for q in w))
        a += n
    return out


def steady_state_rows(ops: Backend, model: SteadyStateModel, x: Mapping[str, Sequence[Any]],
                      P: Mapping[str, Any], wrenches: Sequence[tuple[Any, ...]] | None = None
                      ) -> tuple[dict[str, Any], Any, dict[str, tuple[Any, ...]]]:
    """Constraint rows (physical residuals, by layout row name) and objective of (7.25).

    Parameters
    ----------
    ops : Backend
        NUMPY (every value an array of shape ``(B, 1)`` or a float) or casadi's.
    model : SteadyStateModel
    x : mapping wheel -> (omega, beta, W, h, h0)
        Physical decision variables.
    P : mapping parameter name -> value
        ``speed``, ``slope``, ``cross_slope``, ``fy_offset``, ``mz_offset``, ``contact <wheel>``,
        ``pivot_locked`` (:data:`rtctl.layout.PARAMETERS`). With a statics whose
        ``contact_rows`` is False (a rover file's ``rocker_bogie`` or ``rigid`` suspension)
        ``contact`` multiplies each wheel's wrench but does not enter the balance geometry,
        and ``pivot_locked`` is not used.
    wrenches : sequence, optional
        The soil wrenches (hub drag not included) of the blocks ``[wheel 0, its zero-slip
        state, wheel 1, ...]`` if already evaluated (the structured differences of
        :meth:`SteadyStateResidual.evaluate`); None evaluates them here.

    Returns
    -------
    rows : dict
        Row name (:class:`rtctl.layout.NlpLayout` constraint names) -> physical residual.
    f : value
        Objective (7.24), ``sum_i M_y,i^2 / torque_scale^2`` (with each wheel's contact factor).
    wrench : dict
        Per wheel, the six-component wrench (contact factor and hub drag included).
    """
    speed = P["speed"]
    rows: dict[str, Any] = {}
    wr, beta, h, load, contact = {}, {}, {}, {}, {}
    st = model.statics
    vel = {k: st.wheel_velocity(ops, speed, x[k][1]) for k in model.wheels}
    blocks = []
    for i, k in enumerate(model.wheels):
        om, b, Wi, hi, h0 = x[k]
        vx, vy = vel[k]
        blocks.append((i, vx, vy, om, hi, h0))
        blocks.append((i, vx, vy, speed / model.shearing_radius[i], h0, h0))
    ws = _wrenches(ops, model, blocks) if wrenches is None else list(wrenches)
    f: Any = 0
    for i, k in enumerate(model.wheels):
        om, b, Wi, hi, h0 = x[k]
        vx, vy = vel[k]
        c = P[f"contact {k}"]
        # a wheel on the ground (c the number 1.0, not a symbol): x * 1.0 is x, bit for bit, so the
        # rover's numpy residual skips those multiplications (the cost there is the operation count)
        one = isinstance(c, float) and c == 1.0
        w6 = tuple(with_hub(ops, model, ws[2 * i], vx, vy, om, hi))
        if not one:
            w6 = tuple(c * q for q in w6)
        w0 = ws[2 * i + 1]
        wr[k], beta[k], h[k], load[k], contact[k] = w6, b, hi, Wi, c
        rows[f"load {k}"] = w6[2] - Wi
        rows[f"zero-slip load {k}"] = (w0[2] - Wi) if one else c * (w0[2] - Wi)
        rows[f"wheel torque {k}"] = w6[4]
        f = f + w6[4] * w6[4]
        if k == model.trench_wheel:
            from .soil_flow import trench_quantities

            ph = model.phys[i]
            tq = trench_quantities(ops, hi, b, om, vx, _WheelView(ph), _SoilView(ph))  # type: ignore[arg-type]
            rows[f"trench clean-side pile {k}"] = tq["A_R2_margin"]
            rows[f"trench depth {k}"] = tq["d"]
            rows[f"trench flat width {k}"] = tq["p"]
    bal = st.balance(ops, wr, beta, h, load, P["slope"], P["fy_offset"], P["mz_offset"], P["cross_slope"],
                     contact if st.contact_rows else None, model.external)
    if st.contact_rows:
        bal["My_right"], bal["My_left"] = st.pivot_rows(bal, P["pivot_locked"])
    for n in st.balance_names:
        rows[f"balance {n}"] = bal[n]
    return rows, f / model.torque_scale ** 2, wr


class SteadyStateResidual:
    """Exact residual and objective gradient of (7.25) on the rover, in a table's layout (numpy).

    Parameters
    ----------
    model : SteadyStateModel
    layout : rtctl.layout.NlpLayout
        The table's layout: variable and row order, scales (``g`` is returned physical, i.e.
        ``row value``, not divided by the row scale, as the table's ``g``).
    fd_step : float
        Forward-difference step of the objective gradient, relative to each variable's scale
        (``1e-7``: truncation ~1e-7 and rounding ~1e-9 of the gradient's scale; the objective is
        smooth in every wheel's variables where the wheel model is, section 5 of the module
        notes of :mod:`rtctl.physics.terramechanics`).
    """

    def __init__(self, model: SteadyStateModel, layout: Any, fd_step: float = 1e-7) -> None:
        self.model, self.layout = model, layout
        self.nx, self.ng = int(layout.nx), int(layout.ng)
        self._names = list(layout.constraint_names)
        self._var = {(v, w): int(layout.var(v, w)) for w in layout.wheels for v in WHEEL_VARIABLES}
        self._pnames = list(layout.parameter_names)
        self._sx = np.asarray(layout.variable_scale, dtype=float)
        self._fd = float(fd_step)
        # gradient perturbations: the objective depends on omega, beta, h, h0 of each wheel (not W)
        self._grad_vars = ("omega", "beta", "h", "h0")
        wheels, kinds = model.wheels, self._grad_vars
        self._wheel_cols = {w: tuple(self._var[(v, w)] for v in WHEEL_VARIABLES) for w in wheels}
        kr, kc = [], []
        for j, v in enumerate(kinds):
            for w in wheels:
                kr.append(1 + j)
                kc.append(self._var[(v, w)])
        self._kind_rows, self._kind_cols = np.array(kr), np.array(kc)
        self._kind_steps = self._fd * self._sx[self._kind_cols]
        kind_of = {self._var[(v, w)]: (kw, 1 + j) for kw, w in enumerate(wheels) for j, v in enumerate(kinds)}

        def columns(cols: list[int]) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.float64]]:
            sel = np.zeros((len(wheels), 1 + len(cols)), dtype=np.intp)  # per wheel: its wrench column of each column
            for c, i in enumerate(cols, start=1):
                if i in kind_of:
                    kw, j = kind_of[i]
                    sel[kw, c] = j
            return np.array(cols, dtype=np.intp), sel, self._fd * self._sx[cols]

        self._jac_cols, self._jac_sel, self._jac_steps = columns(list(range(self.nx)))
        self._grad_cols, self._grad_sel, self._grad_steps = columns([self._var[(v, w)] for w in wheels for v in kinds])
        self._iv = {v: np.array([self._var[(v, w)] for w in wheels]) for v in WHEEL_VARIABLES}
        self._iv4 = np.stack([self._iv[v] for v in ("omega", "beta", "h", "h0")])  # (4, nw)
        self._inv_rs = 1.0 / np.asarray(model.shearing_radius, dtype=float)
        nk = 1 + len(kinds)
        # a wheel's zero-slip state (speed / r_s, h0, h0) depends on its beta and h0 only: of the
        # nk columns, the omega and h ones repeat the base, so they are not evaluated again
        self._zero_cols = np.array([0] + [1 + j for j, v in enumerate(kinds) if v in ("beta", "h0")], dtype=np.intp)
        zero_of = np.zeros(nk, dtype=np.intp)
        for i, c in enumerate(self._zero_cols):
            zero_of[c] = i
        nz = len(self._zero_cols)
        self._params = _stack_params(model.phys + model.phys, [nk] * len(wheels) + [nz] * len(wheels))
        # flat positions in the batch (mains wheel-major, then zero-slip states wheel-major) of each
        # wheel's main and zero-slip state of every column (see evaluate)
        nw = len(wheels)

        def batch_index(sel: NDArray[np.intp]) -> NDArray[np.intp]:
            main = np.arange(nw)[:, None] * nk + sel
            zero = nw * nk + np.arange(nw)[:, None] * nz + zero_of[sel]
            return np.stack([main, zero], axis=1)  # (nw, 2, columns)

        self._jac_batch = batch_index(self._jac_sel)
        self._grad_batch = batch_index(self._grad_sel)

    def _batched_wrenches(self, Xk: NDArray[np.float64], speed: float) -> NDArray[np.float64]:
        """Soil wrenches of every wheel at the ``nk`` rows of ``Xk`` and of its zero-slip state at
        the rows ``_zero_cols`` (the others repeat the base), in one :func:`wrench_core` call:
        an array ``(6, nw * (nk + nz))``, the main states wheel-major, then the zero-slip ones."""
        OM, B, H, H0 = Xk[:, self._iv4].transpose(1, 2, 0)  # one gather: each (nw, nk)
        VX, VY = self.model.statics.wheel_velocity(NUMPY, speed, B)
        main = np.stack([VX, VY, OM, H, H0])  # (5, nw, nk): the states' vx, vy, omega, h, h0
        zero = main[:, :, self._zero_cols]  # the zero-slip states: (vx, vy) of the column,
        zero[2] = (speed * self._inv_rs)[:, None]  # omega = speed / r_s,
        zero[3] = zero[4]  # h = h0
        cat = np.concatenate([main.reshape(5, -1), zero.reshape(5, -1)], axis=1)  # (5, states), wheel-major
        vx, vy, om, h, h0 = (c.reshape(-1, 1) for c in cat)
        w, _ = wrench_core(NUMPY, vx, vy, om, h, h0, self._params, self.model.options)
        return np.hstack(w).T

    def residual(self, x: NDArray[np.float64], p: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """``(g, f)`` at physical ``x`` (nx,) and parameters ``p`` (np,): every row's physical
        residual in layout order (as the table's ``g``) and the objective (7.24)."""
        P = {n: float(p[i]) for i, n in enumerate(self._pnames)}
        x = np.asarray(x, dtype=float)
        xs = {w: tuple(np.array([[x[self._var[(v, w)]]]]) for v in WHEEL_VARIABLES) for w in self.model.wheels}
        rows, f, _ = steady_state_rows(NUMPY, self.model, xs, P)
        g = np.array([float(np.asarray(rows[n]).ravel()[0]) for n in self._names])
        return g, float(np.asarray(f, dtype=float).ravel()[0])

    def evaluate(self, x: NDArray[np.float64], p: NDArray[np.float64], jacobian: bool = False
                 ) -> tuple[NDArray[np.float64], float, NDArray[np.float64], NDArray[np.float64] | None]:
        """``(g, f, grad_f, jac_g_x)`` at physical ``x`` (nx,) and parameters ``p`` (np,).

        ``g`` is every row's physical residual in layout order (as the table's ``g``), ``f`` the
        objective (7.24), ``grad_f`` its gradient and ``jac_g_x`` the rows' Jacobian in the
        physical variables (forward differences, step ``fd_step`` variable scales; None unless
        ``jacobian``).

        Structured differences: a wheel's wrench depends on its own ``omega, beta, h, h0`` only
        (not on its load ``W`` nor on other wheels), so the wrenches are evaluated for the base
        point and four columns that move one variable kind on every wheel at once (one batched
        call: per wheel its state at the 5 columns and its zero-slip state, which depends on
        ``beta`` and ``h0`` only, at 3 of them); the rows are then assembled for the base and
        every single-variable column from those wrenches, so each column is an exact
        one-variable difference of the full rows and objective.
        """
        model = self.model
        P = {n: float(p[i]) for i, n in enumerate(self._pnames)}
        x = np.asarray(x, dtype=float)
        wheels = model.wheels
        kinds = self._grad_vars
        nk = 1 + len(kinds)
        # wrenches: base + one column per variable kind moved on every wheel
        Xk = np.repeat(x[None, :], nk, axis=0)
        Xk[self._kind_rows, self._kind_cols] += self._kind_steps
        ws = self._batched_wrenches(Xk, P["speed"])
        # columns: base, then every variable alone (the gradient needs only the wrench kinds)
        cols, bidx, steps = (self._jac_cols, self._jac_batch, self._jac_steps) if jacobian else \
            (self._grad_cols, self._grad_batch, self._grad_steps)
        nc = 1 + len(cols)
        X = np.repeat(x[:, None], nc, axis=1)  # (nx, nc): each variable's columns contiguous
        X[cols, np.arange(1, nc)] += steps
        X3 = X[:, :, None]
        # per wheel and state (main, zero-slip), the six components at every column: one gather
        Wsel = ws[:, bidx].reshape(6, -1, nc, 1)  # (6, nw * 2, nc, 1)
        wsel = list(zip(*Wsel))  # per block, its six (nc, 1) views
        xs = {w: tuple(X3[i] for i in self._wheel_cols[w]) for w in wheels}
        rows, f, _ = steady_state_rows(NUMPY, model, xs, P, wrenches=wsel)
        vals = [rows[n] for n in self._names]
        if all(isinstance(v, np.ndarray) and v.shape == (nc, 1) for v in vals):  # every row depends on the columns
            G = np.concatenate(vals, axis=1).T
        else:
            G = np.empty((len(self._names), nc))
            for r, v in enumerate(vals):
                G[r] = np.asarray(v, dtype=float).reshape(-1)
        fv = np.asarray(f, dtype=float).reshape(-1)
        if fv.size != nc:
            fv = np.broadcast_to(fv, (nc,))
        g = G[:, 0].copy()
        grad = np.zeros(self.nx)
        grad[cols] = (fv[1:] - fv[0]) / steps
        jac = None
        if jacobian:
            jac = (G[:, 1:] - G[:, :1]) / steps[None, :]
        return g, float(fv[0]), grad, jac
