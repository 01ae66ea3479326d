"""Lookup tables of driving primitives: file format, loader, checks and interpolation (numpy only).

A table is one rover + parameter file + scenario family tabulated over a grid of operating
conditions (slope, cross-slope, speed and, for a family, the failure's own parameter such as a
stuck steering angle). Per grid point it holds what the on-rover QP needs to be one exact SQP
step of the steady-state problem (7.25) around the tabulated primitive (ARCHITECTURE.md, point
3): the primitive ``x``, the constraint values ``g`` and Jacobians in the decision variables and
in the parameters, the objective gradient, the Hessian of the Lagrangian with IPOPT's
multipliers, the bounds and active sets, the parametric sensitivity ``dx*/dp`` from the KKT
system, each wheel's six-component wrench and its exact Jacobian in ``(v_x, v_y, omega, h, h0)``,
and the steering controllers of section 7.2.4 (eqs. (7.26)-(7.27)).

File format (schema version :data:`SCHEMA_VERSION`)
----------------------------------------------------
A ``.npz`` archive (zip, stored, fixed time stamps, members in sorted order, so the same
content gives the same bytes) loadable with ``numpy.load(path, allow_pickle=False)``:

* ``header.npy``: UTF-8 JSON (uint8 array): ``schema``, ``schema_version``, ``name``, the
  rover/soil/wheel/tuning parameters, the scenario spec and the scenario file's name and
  sha256, the library version, ``axis_order`` and ``axes`` (values in SI, units), the NLP
  layout (:class:`rtctl.layout.NlpLayout` JSON), units of every field, status names, the
  optimizer's evidence for points without a primitive, trust radii and the
  ``content_hash``;
* one array per field, shaped ``grid_shape + field_shape`` (:data:`POINT_FIELDS`).
  Infeasible and not-found points hold NaN (never made-up values) and are marked by
  ``status``.

``content_hash`` is the sha256 of the canonical header (without the hash) and of every
array's name, dtype, shape and bytes (:func:`content_hash`). :func:`load_table` recomputes it
and refuses a corrupted file, a file of another schema, or (when asked) a table built for
another rover, with a :class:`TableError` saying which and what to do.

Interpolation
-------------
:meth:`Table.at` is multilinear in the grid axes over the corners of the cell that holds the
operating point. Points outside the axes are clamped to them; corners without a primitive get
zero weight and the rest are renormalised (``extrapolated``); a cell with no feasible corner
falls back to the nearest feasible grid point (``clamped``, ``feasible = False``). The result
is never NaN. All per-point fields are precomputed into one row matrix, so a call is a few
numpy operations on at most ``2**d`` rows, gathered into a buffer the table keeps (so a
call allocates little more than the interpolated row it returns; one :class:`Table` must not be
interpolated from two threads at once).
"""

from __future__ import annotations

import bisect
import hashlib
import io
import json
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from .layout import WHEELS, LayoutError, NlpLayout

__all__ = [
    "SCHEMA", "SCHEMA_VERSION", "BIG", "STATUS_NAMES", "CONTROLLER_NAMES", "POINT_FIELDS", "TableError", "TablePoint",
    "Table", "TableInfo", "load_table", "load_index", "content_hash", "table_bytes", "field_shapes", "rebuild_command",
]

SCHEMA = "offnominal-rover lookup table"
"""Value of the header's ``schema`` entry."""
SCHEMA_VERSION = 2
"""Version of the file layout this module reads and writes (2: ``hess_lag_xp`` and
``trust_unverified`` added; a version-1 file is refused with the command that rebuilds it)."""
STATUS_NAMES: tuple[str, ...] = ("optimal", "infeasible", "not_found", "solver_failure", "not_attempted")
"""Per-point ``status`` codes (index = code). Only ``optimal`` points carry a primitive."""
CONTROLLER_NAMES: tuple[str, ...] = ("Mz+", "Mz-", "Fy+", "Fy-")
"""Steering controllers of section 7.2.4, in the order of the ``controllers`` array: re-solves
with a positive/negative yaw-moment offset (7.26) and lateral-force offset (7.27), minus the
primitive, per unit offset."""

POINT_FIELDS: tuple[str, ...] = (
    "x", "p", "g", "lbx", "ubx", "lbg", "ubg", "lam_x", "lam_g", "jac_g_x", "jac_g_p", "grad_f", "hess_lag",
    "hess_lag_xp", "dx_dp", "wrench", "wrench_jac", "slip", "slip_angle", "torque", "power", "controllers", "objective",
    "trust_radius", "trust_unverified",
)
"""Float fields stored per grid point (interpolated by :meth:`Table.at`)."""

_STATUS_OPTIMAL = 0
BIG = 1e30
"""A missing bound (inf in the file) reads as +-BIG in :class:`TablePoint` (OSQP's ``OSQP_INFTY``)."""


class TableError(ValueError):
    """A table file or index that is missing, corrupted, of another schema or for another rover,
    or an operating point the table cannot answer; the message says which and what to do."""


def field_shapes(nx: int, np_: int, ng: int, n_wheels: int = len(WHEELS)) -> dict[str, tuple[int, ...]]:
    """Per-point shape of every field of :data:`POINT_FIELDS` for a layout of the given sizes.

    ``controllers`` is ``(len(CONTROLLER_NAMES), n_wheels, 2)``: per controller and wheel,
    (d rim speed [m/s], d steer [rad]) per unit offset (N m for Mz, N for Fy).
    """
    nw = n_wheels
    return {
        "x": (nx,), "p": (np_,), "g": (ng,), "lbx": (nx,), "ubx": (nx,), "lbg": (ng,), "ubg": (ng,),
        "lam_x": (nx,), "lam_g": (ng,), "jac_g_x": (ng, nx), "jac_g_p": (ng, np_), "grad_f": (nx,),
        "hess_lag": (nx, nx), "hess_lag_xp": (nx, np_), "dx_dp": (nx, np_), "wrench": (nw, 6), "wrench_jac": (nw, 6, 5), "slip": (nw,),
        "slip_angle": (nw,), "torque": (nw,), "power": (nw,), "controllers": (len(CONTROLLER_NAMES), nw, 2),
        "objective": (), "trust_radius": (np_,), "trust_unverified": (np_,),
    }


# ---------------------------------------------------------------------------------- format
def _canonical(header: Mapping[str, Any]) -> bytes:
    try:
        return json.dumps(header, sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")
    except ValueError as exc:
        raise TableError(f"table header holds a non-finite number ({exc}); write NaN as null") from None


def content_hash(header: Mapping[str, Any], arrays: Mapping[str, NDArray[Any]]) -> str:
    """sha256 (hex) of the header without its ``content_hash`` and of every array (name,
    dtype, shape and bytes, names in sorted order)."""
    h = hashlib.sha256()
    h.update(_canonical({k: v for k, v in header.items() if k != "content_hash"}))
    for name in sorted(arrays):
        a = np.asarray(arrays[name], order="C")
        h.update(f"\n{name}|{a.dtype.str}|{a.shape}\n".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def table_bytes(header: Mapping[str, Any], arrays: Mapping[str, NDArray[Any]]) -> bytes:
    """The file bytes of a table: the header gets its ``content_hash``; the zip is written with
    fixed time stamps, no compression and members in sorted order, so equal content gives
    equal bytes (whatever machine, worker count or finishing order produced it)."""
    if "header" in arrays:
        raise TableError("'header' is reserved for the JSON header; rename that array")
    head = dict(header)
    head["content_hash"] = content_hash(head, arrays)
    members = {"header": np.frombuffer(_canonical(head), dtype=np.uint8)}
    members.update({k: np.asarray(v, order="C") for k, v in arrays.items()})
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_STORED) as zf:
        for name in sorted(members):
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.create_system = 3
            info.external_attr = 0o644 << 16
            b = io.BytesIO()
            np.lib.format.write_array(b, members[name], allow_pickle=False)
            zf.writestr(info, b.getvalue())
    return buf.getvalue()


def _read(path: Path) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    if not path.is_file():
        raise TableError(f"{path}: no such table file (build it with 'offnominal tables build')")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise TableError(f"{path}: not a readable table file ({exc}); it is corrupted or not a table: rebuild it") from None
    if "header" not in arrays:
        raise TableError(f"{path}: no 'header' entry: not an offnominal table file")
    try:
        header = json.loads(arrays.pop("header").tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TableError(f"{path}: the header is not valid JSON ({exc}): the file is corrupted; rebuild it") from None
    if not isinstance(header, dict):
        raise TableError(f"{path}: the header is not a JSON object: the file is corrupted; rebuild it")
    return header, arrays


# ---------------------------------------------------------------------------------- point
class TablePoint:
    """The table interpolated at one operating point; every field in physical (SI) units.

    Attributes (all arrays ordered by :attr:`Table.layout`)
    ----------
    x : (nx,)            primitive: per wheel omega [rad/s], beta [rad], W [N], h [m], h0 [m]
    p : (np,)            NLP parameters (speed, slope, cross_slope, offsets, contacts, pivot lock)
    g : (ng,)            constraint values at the primitive (physical residuals, ~0 on equality rows)
    jac_g_x, jac_g_p     d g / d x (ng, nx) and d g / d p (ng, np)
    grad_f : (nx,)       gradient of the objective (7.24) as the NLP defines it (``meta["objective"]``)
    hess_lag : (nx, nx)  Hessian of the Lagrangian ``f + lam_g' g`` with IPOPT's multipliers
    hess_lag_xp : (nx, np)  its cross derivative d^2 L / dx dp (the QP's linear term moves with
                         ``hess_lag_xp @ dp``, which makes the step exact in the parameters too)
    lam_x, lam_g         IPOPT's multipliers for physical bounds/constraints
    lbx, ubx, lbg, ubg   bounds of the scenario at this point (+-BIG = 1e30 where unbounded)
    active : dict        bool masks ``x_lower``, ``x_upper``, ``g_lower``, ``g_upper`` (nearest corner)
    dx_dp : (nx, np)     parametric sensitivity of the primitive from the KKT system
    wrench : (4, 6)      per wheel (Fx, Fy, Fz, Mx, My, Mz) [N, N m]
    wrench_jac : (4,6,5) d wrench / d (v_x, v_y, omega, h, h0)
    slip, slip_angle, torque, power : (4,)
    controllers : dict   ``{"Mz+": (4, 2), ...}``: per wheel (d rim speed [m/s], d steer [rad]) per N m / N
    trust_radius : (np,) step in each parameter over which the first-order prediction held (interpolated)
    trust_verified : (np,) bool: every contributing corner's radius was measured by NLP re-solves
                         (False: at least one corner holds the documented fallback, see the builder)
    feasible : bool      every corner that contributes is an optimal primitive (no fallback used)
    extrapolated : bool  corners without a primitive were dropped and the weights renormalised
    clamped : bool       the operating point was moved into the axes' range or to the nearest
                         feasible grid point
    status : str         ``"interpolated"``, ``"extrapolated"``, ``"nearest feasible grid point"``
    operating_point : dict  the point actually used (after clamping), SI
    """

    __slots__ = ("_table", "_row", "_corner", "feasible", "extrapolated", "clamped", "status", "operating_point",
                 "cell")

    def __init__(self, table: "Table", row: NDArray[np.float64], corner: int, feasible: bool, extrapolated: bool,
                 clamped: bool, status: str, operating_point: dict[str, float],
                 cell: tuple[NDArray[np.intp], NDArray[np.float64]] | None = None) -> None:
        self._table, self._row, self._corner = table, row, corner
        self.cell = cell
        """``(flat grid indices, weights)`` of the corners the point interpolates (weights summing
        to one, zero on corners without a primitive); None at the nearest feasible grid point.
        See :meth:`Table.point_field`."""
        self.feasible, self.extrapolated, self.clamped = feasible, extrapolated, clamped
        self.status, self.operating_point = status, operating_point

    def _f(self, name: str) -> NDArray[np.float64]:
        a, b, shape = self._table._slices[name]
        return self._row[a:b].reshape(shape)

    x = property(lambda self: self._f("x"), doc="Primitive (nx,), physical units.")
    p = property(lambda self: self._f("p"), doc="Parameters (np,).")
    g = property(lambda self: self._f("g"), doc="Constraint values (ng,), physical.")
    lbx = property(lambda self: self._f("lbx"), doc="Variable lower bounds (nx,).")
    ubx = property(lambda self: self._f("ubx"), doc="Variable upper bounds (nx,).")
    lbg = property(lambda self: self._f("lbg"), doc="Constraint lower bounds (ng,).")
    ubg = property(lambda self: self._f("ubg"), doc="Constraint upper bounds (ng,).")
    lam_x = property(lambda self: self._f("lam_x"), doc="Bound multipliers (nx,).")
    lam_g = property(lambda self: self._f("lam_g"), doc="Constraint multipliers (ng,).")
    jac_g_x = property(lambda self: self._f("jac_g_x"), doc="d g / d x (ng, nx).")
    jac_g_p = property(lambda self: self._f("jac_g_p"), doc="d g / d p (ng, np).")
    grad_f = property(lambda self: self._f("grad_f"), doc="Objective gradient (nx,).")
    hess_lag = property(lambda self: self._f("hess_lag"), doc="Lagrangian Hessian (nx, nx).")
    hess_lag_xp = property(lambda self: self._f("hess_lag_xp"), doc="Cross derivative d^2 L / dx dp (nx, np).")
    dx_dp = property(lambda self: self._f("dx_dp"), doc="Sensitivity d x* / d p (nx, np).")
    wrench = property(lambda self: self._f("wrench"), doc="Per-wheel wrench (4, 6).")
    wrench_jac = property(lambda self: self._f("wrench_jac"), doc="d wrench / d (vx, vy, omega, h, h0) (4, 6, 5).")
    slip = property(lambda self: self._f("slip"), doc="Slip ratio per wheel (4,).")
    slip_angle = property(lambda self: self._f("slip_angle"), doc="Slip angle per wheel (4,), rad.")
    torque = property(lambda self: self._f("torque"), doc="Motor torque per wheel (4,), N m (= -M_y).")
    power = property(lambda self: self._f("power"), doc="Mechanical power per wheel (4,), W.")
    objective = property(lambda self: float(self._f("objective")), doc="Objective value (7.24).")

    @property
    def controllers(self) -> dict[str, NDArray[np.float64]]:
        """Section 7.2.4 steering controllers: name -> (4 wheels, (d rim speed, d steer)) per unit offset."""
        c = self._f("controllers")
        return {n: c[i] for i, n in enumerate(CONTROLLER_NAMES)}

    @property
    def active(self) -> dict[str, NDArray[np.bool_]]:
        """Active-set masks of the nearest contributing corner (booleans do not interpolate)."""
        t = self._table
        return {k: v[self._corner] for k, v in t._active.items()}

    trust_radius = property(lambda self: self._f("trust_radius"),
                            doc="Per-parameter step (SI) over which the first-order prediction x + dx_dp dp was "
                                "verified against NLP re-solves at the corners (0: the QP must not move it; "
                                "where no re-solve succeeded, the builder's fallback, see trust_verified).")

    trust_unverified = property(lambda self: self._f("trust_unverified"),
                                doc="Per parameter, interpolated 0/1 flag: 1 where a corner's radius is the fallback.")

    @property
    def trust_verified(self) -> NDArray[np.bool_]:
        """Per parameter: the radius of every contributing corner was measured by re-solves
        (False where some corner holds the fallback value; ``trust_unverified`` interpolates 0/1)."""
        return self._f("trust_unverified") == 0.0

    def __repr__(self) -> str:
        op = ", ".join(f"{k}={v:.4g}" for k, v in self.operating_point.items())
        return f"TablePoint({self._table.name}: {op}; {self.status}, feasible={self.feasible})"


# ---------------------------------------------------------------------------------- table
class Table:
    """A loaded, checked lookup table (use :func:`load_table`).

    Attributes
    ----------
    name : str
    header : dict        the full JSON header
    meta : dict          rover, params, scenario, library version, units, family, build stats
    axes : dict          axis name -> values (SI), in ``axis_order``
    axis_order : tuple
    layout : NlpLayout
    feasible : ndarray   bool, grid shape: an optimal primitive exists at the point
    status : ndarray     int8 codes into :data:`STATUS_NAMES`
    evidence : dict      flat grid index -> the optimizer's evidence for a point without a primitive
    trust_radius : ndarray (np,)  smallest per-point trust radius over the feasible points (0 where none)
    arrays : dict        raw per-point arrays (grid shape + field shape), NaN where no primitive
    """

    def __init__(self, header: dict[str, Any], arrays: dict[str, NDArray[Any]], source: str = "<memory>") -> None:
        self.header, self.source = header, source
        self.name = str(header.get("name", "?"))
        try:
            self.layout = NlpLayout.from_json(json.dumps(header["layout"]))
            self.axis_order = tuple(header["axis_order"])
            self.axes = {k: np.asarray(header["axes"][k]["values"], dtype=float) for k in self.axis_order}
        except (KeyError, TypeError, LayoutError) as exc:
            raise TableError(f"{source}: header lacks or garbles {exc}: not a schema-{SCHEMA_VERSION} table; rebuild it") from None
        self.meta = {k: v for k, v in header.items() if k not in ("layout", "evidence")}
        self.shape = tuple(len(v) for v in self.axes.values())
        for k, v in self.axes.items():
            if v.size == 0 or not np.all(np.isfinite(v)) or np.any(np.diff(v) <= 0):
                raise TableError(f"{source}: axis {k!r} must be finite and strictly increasing, got {v.tolist()}")
        shapes = field_shapes(self.layout.nx, self.layout.np_, self.layout.ng, len(self.layout.wheels))
        for name in (*POINT_FIELDS, "status", "active_x", "active_g"):
            if name not in arrays:
                raise TableError(f"{source}: array {name!r} missing: not a complete schema-{SCHEMA_VERSION} table; rebuild it")
        for name, shp in shapes.items():
            if arrays[name].shape != self.shape + shp:
                raise TableError(f"{source}: array {name!r} has shape {arrays[name].shape}, expected {self.shape + shp} "
                                 "(grid x field): the file does not match its own header; rebuild it")
        self.arrays = arrays
        self.status = arrays["status"].astype(np.int8)
        self.feasible = self.status == _STATUS_OPTIMAL
        self.evidence = {int(k): v for k, v in header.get("evidence", {}).items()}
        tr = header.get("trust_radius", {})
        self.trust_radius = np.array([tr[n] if tr.get(n) is not None else 0.0 for n in self.layout.parameter_names])
        self._prepare(shapes)

    # -------------------------------------------------------------- precomputation
    def _prepare(self, shapes: dict[str, tuple[int, ...]]) -> None:
        n = int(np.prod(self.shape))
        cols, self._slices, pos = [], {}, 0
        for name in POINT_FIELDS:
            a = self.arrays[name].reshape(n, -1).astype(float)
            if name in ("lbx", "ubx", "lbg", "ubg"):  # no bound: +-inf in the file, +-BIG for the QP
                a[np.isposinf(a)], a[np.isneginf(a)] = BIG, -BIG
            cols.append(a)
            self._slices[name] = (pos, pos + a.shape[1], shapes[name])
            pos += a.shape[1]
        flat = np.concatenate(cols, axis=1)
        feas = self.feasible.reshape(n)
        if np.any(~np.isfinite(flat[feas])):
            bad = int(np.argmax(~np.isfinite(flat).all(axis=1) & feas))
            raise TableError(f"{self.source}: grid point {np.unravel_index(bad, self.shape)} is marked optimal but holds "
                             "non-finite values: the file is inconsistent; rebuild it")
        flat[~feas] = 0.0  # zero weight in at(): never read
        self._flat = flat
        self._feas_flat = feas.astype(float)
        act_x, act_g = self.arrays["active_x"].reshape(n, -1), self.arrays["active_g"].reshape(n, -1)
        self._active = {"x_lower": (act_x == -1) | (act_x == 2), "x_upper": (act_x == 1) | (act_x == 2),
                        "g_lower": (act_g == -1) | (act_g == 2), "g_upper": (act_g == 1) | (act_g == 2)}
        self._ax = [list(map(float, v)) for v in self.axes.values()]
        strides = np.cumprod((1,) + self.shape[::-1])[:-1][::-1]
        self._strides = [int(s) for s in strides]
        self._multi = [i for i, v in enumerate(self._ax) if len(v) > 1]
        offs = [0]
        for i in self._multi:
            offs = [o + b * self._strides[i] for o in offs for b in (0, 1)]
        self._offsets = np.array(offs, dtype=np.intp)
        # at()'s gather of the cell's corner rows goes into these (np.take with out=): before, a
        # fancy index allocated 2**d full rows per call (~125 kB per tick on the shipped tables,
        # issue 25); the interpolated row itself stays a new array (the TablePoint keeps it).
        # mode="clip": with the default mode="raise" numpy gathers into a temporary copy of
        # ``out`` first (numpy.take docs); the indices are in range by construction
        self._idx_buf = np.empty(len(offs), dtype=np.intp)
        self._corner_rows = np.empty((len(offs), flat.shape[1]))
        # the cell (its first corner's flat index) whose rows _corner_rows holds: the controller reads
        # the same cell tick after tick, so the gather is skipped while the cell stays the same
        # (the same rows, so the same interpolated numbers; issue 20: the per-tick gather)
        self._rows_base = -1
        # nearest feasible grid point of every grid point (axis-normalised distance)
        coords = np.stack(np.meshgrid(*[np.linspace(0, 1, len(v)) if len(v) > 1 else np.zeros(1) for v in self._ax],
                                      indexing="ij"), axis=-1).reshape(n, -1)
        fidx = np.flatnonzero(feas)
        if fidx.size:
            d = ((coords[:, None, :] - coords[None, fidx, :]) ** 2).sum(-1)
            self._nearest = fidx[np.argmin(d, axis=1)]
        else:
            self._nearest = None
        self._key_set = set(self.axis_order)

    # -------------------------------------------------------------- queries
    @property
    def feasible_fraction(self) -> float:
        """Share of grid points with an optimal primitive."""
        return float(self.feasible.mean())

    def feasible_ranges(self) -> dict[str, tuple[float, float] | None]:
        """Per axis, the smallest and largest value at which some grid point is feasible (None if none)."""
        out: dict[str, tuple[float, float] | None] = {}
        for i, (k, v) in enumerate(self.axes.items()):
            any_f = self.feasible.any(axis=tuple(j for j in range(len(self.shape)) if j != i))
            out[k] = (float(v[any_f].min()), float(v[any_f].max())) if any_f.any() else None
        return out

    def status_at(self, index: tuple[int, ...]) -> str:
        """Status name of a grid point."""
        return STATUS_NAMES[int(self.status[index])]

    def grid_point(self, index: tuple[int, ...]) -> dict[str, float]:
        """Operating point (axis values) of a grid index."""
        return {k: float(self.axes[k][i]) for k, i in zip(self.axis_order, index)}

    def at(self, **operating_point: float) -> TablePoint:
        """Interpolate every field at an operating point (axis name -> SI value).

        Axes of length one may be omitted. Values outside an axis are clamped to it
        (``clamped``). Corners without a primitive are dropped and the weights of the others
        renormalised (``extrapolated``); if none has one, the nearest feasible grid point is used.

        Raises
        ------
        TableError
            For an unknown or missing axis, a non-finite value, or a table without any
            feasible point.
        """
        if operating_point.keys() != self._key_set:
            extra = set(operating_point) - self._key_set
            if extra:
                raise TableError(f"table {self.name}: unknown axis {sorted(extra)}; its axes are {list(self.axis_order)}")
            for i, k in enumerate(self.axis_order):
                if k not in operating_point:
                    if len(self._ax[i]) > 1:
                        raise TableError(f"table {self.name}: operating point lacks axis {k!r} "
                                         f"(range {self._ax[i][0]:.4g}..{self._ax[i][-1]:.4g} SI)")
                    operating_point[k] = self._ax[i][0]
        base, ts, clamped, used = 0, [], False, {}
        for i, k in enumerate(self.axis_order):
            v = float(operating_point[k])
            ax = self._ax[i]
            if not math.isfinite(v):
                raise TableError(f"table {self.name}: {k} = {v} is not finite")
            if v < ax[0] or v > ax[-1]:
                v = min(max(v, ax[0]), ax[-1])
                clamped = True
            used[k] = v
            if len(ax) == 1:
                continue
            j = min(max(bisect.bisect_right(ax, v) - 1, 0), len(ax) - 2)
            base += j * self._strides[i]
            ts.append((v - ax[j]) / (ax[j + 1] - ax[j]))
        wl = [1.0]
        for t in ts:  # corner weights, in the order of self._offsets
            wl = [x for a in wl for x in (a * (1.0 - t), a * t)]
        w = np.array(wl)
        idx = np.add(self._offsets, base, out=self._idx_buf)
        feas = self._feas_flat[idx]
        cell: tuple[NDArray[np.intp], NDArray[np.float64]] | None
        if feas.all():
            row = w @ self._cell_rows(base, idx)
            corner = int(idx[int(np.argmax(w))])
            feasible, extrapolated, status = True, False, "interpolated"
            cell = (idx.copy(), w)
        elif (s := float((wf := w * feas).sum())) > 1e-12:
            extrapolated = float(w.sum()) - s > 1e-12
            wf = wf / s
            row = wf @ self._cell_rows(base, idx)
            corner = int(idx[int(np.argmax(wf))])
            feasible = not extrapolated
            status = "extrapolated" if extrapolated else "interpolated"
            cell = (idx.copy(), wf)
        else:
            if self._nearest is None:
                raise TableError(f"table {self.name}: no grid point has a primitive (all infeasible or not found); "
                                 "the controller must use its safe fallback")
            corner = int(self._nearest[int(idx[int(np.argmax(w))])])
            row = self._flat[corner].copy()
            used = self.grid_point(tuple(int(i) for i in np.unravel_index(corner, self.shape)))
            feasible, extrapolated, clamped, status = False, True, True, "nearest feasible grid point"
            cell = (np.array([corner], dtype=np.intp), np.ones(1))
        return TablePoint(self, row, corner, feasible, extrapolated, clamped, status, used, cell)

    def _cell_rows(self, base: int, idx: NDArray[np.intp]) -> NDArray[np.float64]:
        """The rows of the cell's corners ``idx`` (first corner ``base``), gathered into the
        preallocated buffer unless it already holds that cell's."""
        if base != self._rows_base:
            np.take(self._flat, idx, axis=0, out=self._corner_rows, mode="clip")
            self._rows_base = base
        return self._corner_rows

    def point_field(self, flat_index: int, name: str) -> NDArray[np.float64]:
        """One field (as :class:`TablePoint`'s attribute of that name) at one grid point, by its
        flat index (``TablePoint.cell``); a view, not to be changed."""
        a, b, shape = self._slices[name]
        return self._flat[int(flat_index), a:b].reshape(shape)

    def __repr__(self) -> str:
        ax = ", ".join(f"{k}[{len(v)}]" for k, v in self.axes.items())
        return f"Table({self.name!r}: {ax}; {self.feasible.sum()}/{self.feasible.size} feasible)"


def _expect_rover(table: Table, expect_rover: Mapping[str, Any] | str | None, path: Path) -> None:
    if expect_rover is None:
        return
    got = table.meta.get("rover", {})
    if isinstance(expect_rover, str):
        if got.get("name") != expect_rover:
            raise TableError(f"{path}: this table was built for rover {got.get('name')!r}, not {expect_rover!r}; "
                             "use the tables of your rover or rebuild them for it")
        return
    diff = sorted(k for k in expect_rover if k in ("name", "rocker_length", "pivot_height", "track_width", "weight")
                  and got.get(k) != expect_rover[k])
    if diff:
        pairs = "; ".join(f"{k}: table {got.get(k)!r}, expected {expect_rover[k]!r}" for k in diff)
        raise TableError(f"{path}: this table was built for another rover ({pairs}); rebuild it for this rover")


def rebuild_command(header: Mapping[str, Any]) -> str:
    """The ``offnominal tables build`` command that rebuilds a table from its header (scenario
    file name and grid in display units; ``SCENARIO.toml`` when the header does not name it)."""
    sources = header.get("sources")
    src: dict[str, Any] = sources if isinstance(sources, dict) else {}
    scen = src.get("scenario_file")
    name = str(scen.get("name", "SCENARIO.toml")) if isinstance(scen, dict) else "SCENARIO.toml"
    parts = []
    axes_raw = header.get("axes")
    axes: dict[str, Any] = axes_raw if isinstance(axes_raw, dict) else {}
    for k in header.get("axis_order", []) if isinstance(header.get("axis_order"), list) else []:
        a = axes.get(k, {}) if isinstance(axes.get(k), dict) else {}
        try:
            f = float(a.get("display_factor", 1.0))
            parts.append(f"{k}=" + ",".join(f"{float(v) / f:.10g}" for v in a["values"]))
        except (KeyError, TypeError, ValueError):
            continue
    grid = f' --grid "{";".join(parts)}"' if parts else ""
    return f"offnominal tables build {name}{grid} --out DIR"


def load_table(path: str | Path, expect_rover: Mapping[str, Any] | str | None = None,
               expect_hash: str | None = None) -> Table:
    """Load a table file, check its schema and content hash, and prepare it for :meth:`Table.at`.

    Parameters
    ----------
    path : str or Path
    expect_rover : str or dict, optional
        Rover name, or a dict of rover parameters (``name``, ``rocker_length``, ``pivot_height``,
        ``track_width``, ``weight``) the table must have been built for.
    expect_hash : str, optional
        Content hash the table must have (e.g. from the index file).

    Raises
    ------
    TableError
        Missing or unreadable file, wrong schema or version (the message gives the rebuild
        command, :func:`rebuild_command`), content hash mismatch (corrupted
        or edited file), inconsistent shapes, or a table for another rover.
    """
    p = Path(path)
    header, arrays = _read(p)
    if header.get("schema") != SCHEMA:
        raise TableError(f"{p}: schema {header.get('schema')!r}, expected {SCHEMA!r}: not an offnominal table")
    if header.get("schema_version") != SCHEMA_VERSION:
        raise TableError(f"{p}: table schema {header.get('schema_version')!r}, expected {SCHEMA_VERSION}: rebuild with "
                         f"`{rebuild_command(header)}`")
    stored = header.get("content_hash")
    actual = content_hash(header, arrays)
    if stored != actual:
        raise TableError(f"{p}: content hash mismatch (stored {str(stored)[:16]}..., computed {actual[:16]}...): "
                         "the file is corrupted or was edited; rebuild it with 'offnominal tables build'")
    if expect_hash is not None and actual != expect_hash:
        raise TableError(f"{p}: content hash {actual[:16]}... differs from the expected {expect_hash[:16]}... "
                         "(the index lists another build of this table); rebuild the index or the table")
    table = Table(header, arrays, str(p.name))
    _expect_rover(table, expect_rover, p)
    return table


@dataclass(frozen=True)
class TableInfo:
    """One entry of a table index (``tables/index.json``).

    Attributes
    ----------
    name : str
    path : Path            the table file (resolved beside the index)
    content_hash : str
    sha256 : str           of the file bytes
    axes : dict            axis -> values (SI)
    family : dict or None  failure-parameter axis (``axis``, ``wheel``, ``kind``)
    feasible_fraction : float
    feasible_ranges : dict axis -> [min, max] where some point is feasible (None: no feasible point)
    description : str
    entry : dict           the full index entry
    """

    name: str
    path: Path
    content_hash: str
    sha256: str
    axes: dict[str, list[float]]
    family: dict[str, Any] | None
    feasible_fraction: float
    feasible_ranges: dict[str, Any]
    description: str
    entry: dict[str, Any]

    def load(self, expect_rover: Mapping[str, Any] | str | None = None) -> Table:
        """Load the table and check its content hash against the index."""
        return load_table(self.path, expect_rover=expect_rover, expect_hash=self.content_hash)


def load_index(path: str | Path) -> dict[str, TableInfo]:
    """Read a table index (JSON written by ``offnominal tables build``).

    Raises
    ------
    TableError
        Missing, malformed or other-schema index.
    """
    p = Path(path)
    try:
        d = json.loads(p.read_text())
    except FileNotFoundError:
        raise TableError(f"{p}: no such index file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise TableError(f"{p}: index is not valid JSON ({exc}); rebuild it with 'offnominal tables build'") from None
    if not isinstance(d, dict) or d.get("schema") != SCHEMA + " index" or d.get("schema_version") != SCHEMA_VERSION:
        raise TableError(f"{p}: not a schema-{SCHEMA_VERSION} table index; rebuild it with 'offnominal tables build'")
    out = {}
    for name, e in sorted(d.get("tables", {}).items()):
        try:
            out[name] = TableInfo(name, p.parent / e["file"], e["content_hash"], e["sha256"], e["axes"], e.get("family"),
                                  float(e["feasible_fraction"]), e["feasible_ranges"], e.get("description", ""), e)
        except (KeyError, TypeError) as exc:
            raise TableError(f"{p}: entry {name!r} lacks {exc}; rebuild the index") from None
    return out
