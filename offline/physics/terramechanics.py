"""3D rigid-wheel terramechanics for any slip ratio and slip angle (dissertation ch. 5): the ground side.

The physics itself, :func:`wrench_core` with its parameters and options, lives in
:mod:`rtctl.physics.terramechanics` (re-exported here; its module docstring lists frames, signs
and every departure from the printed text), written once against the array backends: numpy on
both sides, casadi (:data:`offline.physics.backend.CASADI`) here. :class:`WheelModel` wraps
both: validated batched evaluation (:meth:`WheelModel.wrench`), casadi functions with
Jacobians (:meth:`WheelModel.casadi_function`), compiled C functions, and sinkage from load,
eq. (5.34) (:meth:`WheelModel.sinkage_from_load`).
"""

from __future__ import annotations

import functools
import hashlib
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from rtctl.physics.terramechanics import (DIAG_NAMES, OMEGA_FLOOR, SHEAR_VELOCITY_REL_EPS, SPEED_FLOOR, STATE_NAMES,
                                          WRENCH_NAMES, ModelOptions, PhysParams, _SoilView, _WheelView,
                                          bulldozing_resistance, normal_force, shear_kinematics, wrench_core)

from .backend import CASADI, NUMPY, Backend
from .params import ContactTuning, ParameterError, ParameterSet, Soil, TuningTable, Wheel

__all__ = [
    "ModelOptions",
    "PhysParams",
    "Wrench",
    "SinkageResult",
    "WheelModel",
    "wrench_core",
    "state_from_slip",
    "bulldozing_resistance",
    "shear_kinematics",
    "WRENCH_NAMES",
    "STATE_NAMES",
    "COMPILE_FLAGS",
]

COMPILE_FLAGS: tuple[str, ...] = ("-O1",)
"""C compiler flags of the compiled wrench/Jacobian and sinkage functions, chosen by measurement
(gcc, the 1.2 MB generated wrench+Jacobian C, 2-core machine under load, 2026-11-22):
-O0 2.1 s CPU to build, 659 us per call; -O1 6.3 s, 168 us; -O2 12.7 s, 139 us. -O1 halves the
one-off build of -O2 for 20 % slower calls. ``OFFNOMINAL_CFLAGS`` (space separated) overrides
them; the flags are part of the cache key."""


def _compile_flags() -> tuple[str, ...]:
    env = os.environ.get("OFFNOMINAL_CFLAGS")
    return tuple(env.split()) if env else COMPILE_FLAGS

@dataclass(frozen=True)
class Wrench:
    """Soil forces (N) and moments (N m) on the wheel, wheel frame (Fig. 5.1), plus diagnostics."""

    Fx: NDArray[np.float64]
    Fy: NDArray[np.float64]
    Fz: NDArray[np.float64]
    Mx: NDArray[np.float64]
    My: NDArray[np.float64]
    Mz: NDArray[np.float64]
    slip: NDArray[np.float64]
    beta: NDArray[np.float64]
    theta_f: NDArray[np.float64]
    theta_m: NDArray[np.float64]
    theta_r: NDArray[np.float64]
    theta_0: NDArray[np.float64]
    n: NDArray[np.float64]

    def as_array(self) -> NDArray[np.float64]:
        """Stack ``(Fx, Fy, Fz, Mx, My, Mz)`` as shape ``(..., 6)``."""
        return np.stack([self.Fx, self.Fy, self.Fz, self.Mx, self.My, self.Mz], axis=-1)


_STATUS_DTYPE = "<U32"
"""dtype of :attr:`SinkageResult.status`: wide enough for every status string."""


@dataclass(frozen=True)
class SinkageResult:
    """Sinkage that carries a given load, eq. (5.34).

    Attributes
    ----------
    h, h_zero_slip : ndarray
        Sinkage (m) and the zero-slip sinkage under the same load (NaN where failed).
    converged : ndarray of bool
    status : ndarray of str
        ``"ok"`` (load residual within tolerance), ``"load_exceeds_capacity"`` (the wheel
        cannot carry the load within the physical sinkage range), ``"load_below_resolution"``
        (carried at a sinkage below ``h_min``), ``"load_at_discontinuity"`` (``F_z(h)`` jumps
        across the load: no sinkage carries it within tolerance), ``"not_converged"``.
        Fixed-width strings wide enough for every status (never truncated).
    residual : ndarray
        ``F_z(h) - W``, N.
    iterations : int
    """

    h: NDArray[np.float64]
    h_zero_slip: NDArray[np.float64]
    converged: NDArray[np.bool_]
    status: NDArray[np.str_]
    residual: NDArray[np.float64]
    iterations: int
    h_max: float

    @property
    def ok(self) -> bool:
        """True when every state converged."""
        return bool(np.all(self.converged))

    def reasons(self) -> list[str]:
        """Human-readable reasons for every failed state."""
        out = []
        for i in np.flatnonzero(~self.converged):
            if self.status[i] == "load_exceeds_capacity":
                out.append(
                    f"state {i}: load exceeds what the wheel carries up to the maximum sinkage "
                    f"{self.h_max * 1e3:.1f} mm (short by {-self.residual[i]:.3g} N at best)"
                )
            else:
                out.append(f"state {i}: {self.status[i]} (residual {self.residual[i]:.3g} N)")
        return out


def state_from_slip(
    slip: NDArray[np.float64] | float, beta: NDArray[np.float64] | float, speed: NDArray[np.float64] | float, wheel: Wheel
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Wheel velocities (v_x, v_y, omega) from slip ratio, slip angle and travel speed.

    Inverts eqs. (5.1)-(5.2): ``v_x = v cos(beta)``, ``v_y = -v sin(beta)``,
    ``omega = v / (r_s (1 - s))`` in slip and ``v (1 + s) / r_s`` in skid.

    Raises
    ------
    ValueError
        Slip outside [-1, 1), |beta| > pi/2 (radians expected), non-positive speed or NaN.
    """
    s, b, v = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (slip, beta, speed)))
    for name, arr in (("slip", s), ("beta", b), ("speed", v)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr[~np.isfinite(arr)][:3]}")
    if np.any(s < -1.0) or np.any(s >= 1.0):
        raise ValueError(f"slip must lie in [-1, 1), got values in [{s.min()}, {s.max()}]")
    if np.any(np.abs(b) > math.pi / 2 + 1e-12):
        raise ValueError(
            f"beta must be in radians within [-pi/2, pi/2], got max |beta| = {np.abs(b).max():.4g} "
            "(did you pass degrees? use numpy.radians)"
        )
    if np.any(v <= 0):
        raise ValueError("speed must be > 0 m/s")
    rs = wheel.shearing_radius
    omega = np.where(s >= 0, v / (rs * (1.0 - s)), v * (1.0 + s) / rs)
    return v * np.cos(b), -v * np.sin(b), omega


class _DirectCall:
    """Call a casadi-generated C function through ctypes with preallocated buffers.

    The casadi Python call costs about 25 us of overhead per call; the generated C for the
    wrench and its Jacobian runs in a few microseconds. Generated-code interface:
    ``int f(const double** arg, double** res, casadi_int* iw, double* w, int mem)`` and
    ``int f_work(casadi_int*, casadi_int*, casadi_int*, casadi_int*)``.
    """

    def __init__(self, so: Path, name: str, reference: Any) -> None:
        import ctypes

        lib = ctypes.CDLL(str(so))
        self._fn = getattr(lib, name)
        work = getattr(lib, f"{name}_work")
        ci = ctypes.c_longlong
        sz = [ci(0) for _ in range(4)]
        work(*[ctypes.byref(v) for v in sz])
        n_arg, n_res, n_iw, n_w = (int(v.value) for v in sz)
        self._x = np.zeros(5)
        self._w6 = np.zeros(6)
        sp = reference.sparsity_out(1)
        self._jnz = np.zeros(sp.nnz())
        rows, cols = sp.get_triplet()
        self._rows, self._cols = np.asarray(rows, dtype=int), np.asarray(cols, dtype=int)
        dp = ctypes.POINTER(ctypes.c_double)
        self._arg = (dp * max(n_arg, 1))()
        self._res = (dp * max(n_res, 2))()
        self._arg[0] = self._x.ctypes.data_as(dp)
        self._res[0] = self._w6.ctypes.data_as(dp)
        self._res[1] = self._jnz.ctypes.data_as(dp)
        self._iw = (ci * max(n_iw, 1))()
        self._wbuf = (ctypes.c_double * max(n_w, 1))()
        self._fn.argtypes = [ctypes.POINTER(dp), ctypes.POINTER(dp), ctypes.POINTER(ci), ctypes.POINTER(ctypes.c_double),
                             ctypes.c_int]
        self._fn.restype = ctypes.c_int

    def __call__(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        self._x[:] = x
        if self._fn(self._arg, self._res, self._iw, self._wbuf, 0) != 0:
            raise RuntimeError("compiled wheel wrench function returned an error")
        J = np.zeros((6, 5))
        J[self._rows, self._cols] = self._jnz
        return self._w6.copy(), J


class WheelModel:
    """The terramechanics model of one wheel on one soil, evaluated numerically or symbolically.

    Parameters
    ----------
    soil : Soil
    wheel : Wheel
    tuning : ContactTuning
    options : ModelOptions, optional

    Examples
    --------
    >>> from offline.physics.params import (SOIL_DISSERTATION_T53_GROUSERED as soil,
    ...     WHEEL_GROUSERED_PUBLISHED_CODE as wheel, TUNING_T72_LINEAR as tuning)
    >>> m = WheelModel(soil, wheel, tuning)
    >>> w = m.wrench(vx=0.01, vy=0.0, omega=0.01 / 0.063, h=0.015)
    >>> bool(abs(w.Fy[0]) < 1e-9)
    True
    """

    def __init__(self, soil: Soil, wheel: Wheel, tuning: ContactTuning | TuningTable, options: ModelOptions | None = None) -> None:
        self.soil = soil
        self.wheel = wheel
        self.tuning = tuning
        self.options = options or ModelOptions()
        self.params = PhysParams.from_sets(soil, wheel, tuning)
        self._cas: dict[str, Any] = {}
        self._so_paths: dict[str, Path] = {}
        self._direct: Any = None

    @classmethod
    def from_parameter_set(cls, ps: ParameterSet, options: ModelOptions | None = None) -> "WheelModel":
        """Build from a :class:`offline.physics.params.ParameterSet` (e.g. a calibration TOML)."""
        return cls(ps.soil, ps.wheel, ps.tuning, options)

    # ---- limits -----------------------------------------------------------------------
    @property
    def h_max(self) -> float:
        """Largest sinkage accepted, ``1.5 r + h_g`` (eq. 7.5), m."""
        return 1.5 * self.wheel.radius + self.wheel.grouser_height

    @property
    def h_min(self) -> float:
        """Smallest sinkage used by the load solve, ``1e-4 r_s``, m."""
        return 1e-4 * self.wheel.shearing_radius

    # ---- numeric ------------------------------------------------------------------------
    def _validate(self, vx: Any, vy: Any, omega: Any, h: Any, h0s: Any) -> tuple[NDArray[np.float64], ...]:
        arrays = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (vx, vy, omega, h, h0s)))
        shape = arrays[0].shape
        out = [a.reshape(-1) for a in arrays]
        for name, a in zip(STATE_NAMES, out):
            bad = ~np.isfinite(a)
            if np.any(bad):
                raise ValueError(f"{name} must be finite; got {a[bad][:3]} at index {np.flatnonzero(bad)[:3]}")
        vxa, vya, wa, ha, h0a = out
        rs = self.wheel.shearing_radius
        for name, a in (("h", ha), ("h_zero_slip", h0a)):
            if np.any(a <= 0) or np.any(a > self.h_max + 1e-12):
                i = int(np.flatnonzero((a <= 0) | (a > self.h_max + 1e-12))[0])
                raise ValueError(
                    f"{name} must be in (0, {self.h_max:.4g}] m (sinkage, metres); got {a[i]!r} at index {i}"
                    + (" (did you pass millimetres?)" if a[i] > self.h_max else "")
                )
        counter = (np.sign(wa) * np.sign(vxa) < 0) & (np.abs(wa * rs) > 1e-9 * (np.abs(vxa) + 1e-12))
        if np.any(counter):
            i = int(np.flatnonzero(counter)[0])
            raise ValueError(
                f"omega opposes the travel direction at index {i} (omega={wa[i]!r}, vx={vxa[i]!r}): "
                "slip ratio < -1 is outside the model's domain [-1, 1)"
            )
        return vxa, vya, wa, ha, h0a, shape  # type: ignore[return-value]

    def wrench(
        self,
        vx: Any,
        vy: Any,
        omega: Any,
        h: Any,
        h_zero_slip: Any | None = None,
        *,
        chunk: int = 1024,
    ) -> Wrench:
        """Evaluate the wrench for a batch of wheel states (numpy backend).

        Parameters
        ----------
        vx, vy, omega, h : array_like
            Broadcastable wheel states (m/s, m/s, rad/s, m).
        h_zero_slip : array_like, optional
            Zero-slip sinkage for theta_m0, theta_r0 in skid; defaults to ``h`` (the
            state's own sinkage), which is exact at s = 0.
        chunk : int
            States per vectorised block (keeps temporaries in cache).

        Returns
        -------
        Wrench
            Arrays of the broadcast shape.

        Raises
        ------
        ValueError
            NaN or infinite state, sinkage outside (0, 1.5 r + h_g], counter-rotation.
        """
        vxa, vya, wa, ha, h0a, shape = self._validate(vx, vy, omega, h, h if h_zero_slip is None else h_zero_slip)
        return self._wrench_unchecked(vxa, vya, wa, ha, h0a, shape, chunk)

    def _wrench_unchecked(self, vxa: Any, vya: Any, wa: Any, ha: Any, h0a: Any, shape: Any, chunk: int = 1024) -> Wrench:
        nb = vxa.size
        cols = {k: np.empty(nb) for k in WRENCH_NAMES + DIAG_NAMES}
        with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
            for start in range(0, nb, chunk):
                sl = slice(start, min(nb, start + chunk))
                vx_, vy_, w_, h_, h0_ = (a[sl, None] for a in (vxa, vya, wa, ha, h0a))
                wr, dg = wrench_core(NUMPY, vx_, vy_, w_, h_, h0_, self.params, self.options)
                for k, val in zip(WRENCH_NAMES, wr):
                    cols[k][sl] = np.broadcast_to(val, (sl.stop - sl.start, 1))[:, 0]
                for k in DIAG_NAMES:
                    cols[k][sl] = np.broadcast_to(dg[k], (sl.stop - sl.start, 1))[:, 0]
        return Wrench(**{k: v.reshape(shape) for k, v in cols.items()})

    # ---- symbolic -----------------------------------------------------------------------
    def expressions(self, vx: Any, vy: Any, omega: Any, h: Any, h_zero_slip: Any, params: PhysParams | None = None) -> tuple[tuple[Any, ...], dict[str, Any]]:
        """casadi ``SX`` wrench and diagnostics of symbolic states (for an NLP)."""
        return wrench_core(CASADI, vx, vy, omega, h, h_zero_slip, params or self.params, self.options)

    def casadi_function(self, jacobian: bool = False) -> Any:
        """``casadi.Function`` ``f(x[5]) -> w[6]`` (and ``J[6x5]`` if ``jacobian``).

        ``x = (v_x, v_y, omega, h, h_zero_slip)``. Built once per model and cached.
        """
        key = "jac" if jacobian else "val"
        if key not in self._cas:
            import casadi as ca

            x = ca.SX.sym("x", 5)
            wr, _ = self.expressions(x[0], x[1], x[2], x[3], x[4])
            w = ca.vertcat(*wr)
            if jacobian:
                self._cas[key] = ca.Function("wheel_wrench_jac", [x], [w, ca.jacobian(w, x)], ["x"], ["w", "J"])
            else:
                self._cas[key] = ca.Function("wheel_wrench", [x], [w], ["x"], ["w"])
        return self._cas[key]

    def compiled_function(self, jacobian: bool = True, cache_dir: str | Path | None = None) -> Any:
        """The casadi function compiled to C (casadi code generation + the system C compiler).

        The shared library is cached under ``cache_dir`` (default
        ``$XDG_CACHE_HOME/offnominal`` or ``~/.cache/offnominal``), keyed by a hash of the
        parameters and options, so only the first call pays the ~6 s compile. Falls back to
        the interpreted casadi function, with a warning, when no C compiler is found.
        """
        key = "cjac" if jacobian else "cval"
        if key not in self._cas:
            self._cas[key] = self._compile(self.casadi_function(jacobian), key, cache_dir)
        return self._cas[key]

    def _compile(self, f: Any, tag: str, cache_dir: str | Path | None = None) -> Any:
        """Generate C for casadi function ``f``, compile it once (cached on disk, keyed by a
        hash of parameters, options and ``tag``) and load it; the interpreted function,
        with a warning, when no C compiler is found."""
        import casadi as ca

        # the serialised graph covers parameters, options and the code that built it
        flags = _compile_flags()
        version = str(getattr(ca, "__version__", ""))  # casadi ships no type stubs
        digest = hashlib.sha256((f.serialize() + tag + version + " ".join(flags)).encode()).hexdigest()[:16]
        root = Path(cache_dir) if cache_dir else Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "offnominal"
        so = root / f"{f.name()}_{digest}.so"
        cc = shutil.which(os.environ.get("CC", "gcc")) or shutil.which("cc")
        if not so.exists():
            if cc is None:
                warnings.warn("no C compiler found: using the interpreted casadi function (slower)", stacklevel=3)
                return f
            try:
                self._build_so(f, root, so, cc, flags)
            except (OSError, subprocess.CalledProcessError) as exc:
                warnings.warn(f"could not compile {f.name()} into {root} ({exc}): using the interpreted casadi "
                              "function (slower); set XDG_CACHE_HOME to a writable folder", stacklevel=3)
                return f
        self._so_paths[f.name()] = so
        return ca.external(f.name(), str(so))

    @staticmethod
    def _build_so(f: Any, root: Path, so: Path, cc: str, flags: tuple[str, ...] = COMPILE_FLAGS) -> None:
        """Generate C for ``f`` and compile it to ``so`` (atomic rename), saying on screen
        (stderr) what is being built, where, and how long it took: a cold build takes
        seconds to tens of seconds of CPU and happens once per parameter set."""
        import casadi as ca

        root.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(dir=root) as tmp:
            # written under a folder prefix: changing the process's working folder raced with
            # worker processes started meanwhile (they inherit it)
            cg = ca.CodeGenerator(f"{f.name()}.c")
            cg.add(f)
            src = Path(cg.generate(str(tmp) + os.sep))
            print(f"offnominal: building the compiled {f.name()} ({src.stat().st_size / 1e6:.1f} MB of generated C, "
                  f"{Path(cc).name} {' '.join(flags)}) into {root}; one-off, cached for later runs ...",
                  file=sys.stderr, flush=True)
            tmp_so = Path(tmp) / so.name
            subprocess.run([cc, *flags, "-fPIC", "-shared", str(src), "-o", str(tmp_so)], check=True, capture_output=True)
            os.replace(tmp_so, so)  # atomic: an interrupted build leaves no half file
        print(f"offnominal: built {so.name} in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)

    def wrench_and_jacobian(self, x: NDArray[np.float64], compiled: bool = True) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Wrench (6,) and its Jacobian (6, 5) at one state ``x = (vx, vy, omega, h, h_zero_slip)``.

        Exact derivatives from the casadi graph; ``compiled`` uses the C-compiled function
        (:meth:`compiled_function`). The state is checked (finite, sinkage range).

        At ``v_x = v_y = 0`` (a wheel spinning in place, or at rest) the slip angle (5.1) is
        undefined and the wrench is not differentiable in ``(v_x, v_y)``: its derivative
        along v_y grows like 1 / |v| (about 1.5e8 N s/m at |v| = 1e-9 m/s). That state is
        refused with a :class:`ValueError` (documented choice: a clear error rather than a
        finite number that depends on an arbitrary direction); evaluate at a small travel
        speed in the direction of interest instead. The wrench value itself is finite there
        (:meth:`wrench`). Any other non-finite Jacobian is refused the same way.

        Raises
        ------
        ValueError
            Wrong shape, non-finite state, sinkage out of range, counter-rotation,
            ``v_x = v_y = 0``, or a non-finite result.
        """
        xa = np.asarray(x, dtype=float).reshape(-1)
        if xa.size != 5:
            raise ValueError(f"state must have 5 entries {STATE_NAMES}, got shape {np.shape(x)}")
        if not (np.isfinite(xa).all() and 0.0 < xa[3] <= self.h_max and 0.0 < xa[4] <= self.h_max):
            self._validate(*xa)  # raises with a message naming the bad entry
        if xa[0] * xa[2] < 0 and abs(xa[2]) * self.wheel.shearing_radius > 1e-9 * abs(xa[0]):
            self._validate(*xa)
        if xa[0] == 0.0 and xa[1] == 0.0:
            raise ValueError(
                f"wrench Jacobian at v_x = v_y = 0 (omega = {xa[2]!r} rad/s: "
                f"{'spinning in place' if xa[2] != 0 else 'at rest'}) is undefined: the slip angle of eq. (5.1) "
                "has no value at zero travel speed, so d wrench / d(v_x, v_y) does not exist; evaluate at a small "
                "travel speed (e.g. v_x = 1e-6 m/s) in the direction of interest"
            )
        w_out, J_out = self._wrench_and_jacobian_raw(xa, compiled)
        if not (np.all(np.isfinite(w_out)) and np.all(np.isfinite(J_out))):
            bad = [STATE_NAMES[j] for j in range(5) if not np.all(np.isfinite(J_out[:, j]))]
            raise ValueError(f"wrench or Jacobian is not finite at state {dict(zip(STATE_NAMES, xa.tolist()))} "
                             f"(non-finite columns: {bad}); the state is at a singularity of the model")
        return w_out, J_out

    def _wrench_and_jacobian_raw(self, xa: NDArray[np.float64], compiled: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Wrench and Jacobian at a checked state, unchecked result (see :meth:`wrench_and_jacobian`)."""
        if compiled:
            if self._direct is None:
                f = self.compiled_function(True)
                so = self._so_paths.get(f.name())
                self._direct = _DirectCall(so, f.name(), self.casadi_function(True)) if so else False
            if self._direct:
                return self._direct(xa)
        f = self.compiled_function(True) if compiled else self.casadi_function(True)
        w, J = f(xa)
        return np.asarray(w).reshape(6), np.asarray(J)

    # ---- sinkage from load (5.34) ---------------------------------------------------------
    SCAN_POINTS = 12
    """Sinkages (geometric grid over [h_min, h_max]) scanned to bracket the first root."""

    def sinkage_from_load(
        self,
        load: Any,
        vx: Any,
        vy: Any,
        omega: Any,
        *,
        rtol: float = 1e-9,
        max_iter: int = 80,
    ) -> SinkageResult:
        """Sinkage at which ``F_z(h) = W``, eq. (5.34), by a vectorised bracketing solve.

        A wheel in skid needs theta_m0, theta_r0 from the zero-slip sinkage under the same
        load, so skidding states are solved twice: first at zero slip (same v_x, v_y,
        ``omega = v / r_s``), then in skid with that ``h_zero_slip``. Each solve is the
        Illinois variant of regula falsi on ``F_z(h) - W`` inside the bracket of the first
        sign change found by a coarse scan of ``[h_min, h_max]`` (F_z is not monotonic once
        theta_f passes 90 deg); it never leaves the bracket and converges superlinearly.

        Returns
        -------
        SinkageResult
            ``status`` is ``"load_exceeds_capacity"`` where ``F_z(h_max) < W``: the wheel
            cannot carry the load within the physical sinkage range. Never a silent wrong
            answer: failed states have ``h = NaN`` and ``converged = False``; ``"ok"`` only
            where ``|F_z(h) - W| <= rtol W``. An empty batch gives empty arrays.

        Raises
        ------
        ValueError
            Non-positive or non-finite load, NaN states, counter-rotation.
        """
        W = np.asarray(load, dtype=float)
        arrays = np.broadcast_arrays(W, *(np.asarray(a, dtype=float) for a in (vx, vy, omega)))
        shape = arrays[0].shape
        Wf, vxa, vya, wa = (a.reshape(-1).astype(float) for a in arrays)
        if Wf.size == 0:  # empty batch: empty answer, same shape
            empty = np.empty(shape)
            return SinkageResult(empty, empty.copy(), np.empty(shape, dtype=bool), np.empty(shape, dtype=_STATUS_DTYPE),
                                 empty.copy(), 0, self.h_max)
        if not np.all(np.isfinite(Wf)):
            raise ValueError("load must be finite (N)")
        if np.any(Wf <= 0):
            raise ValueError(f"load must be > 0 N, got {Wf[Wf <= 0][:3]}")
        ones = np.full_like(Wf, 0.5 * self.h_max)
        self._validate(vxa, vya, wa, ones, ones)
        rs = self.wheel.shearing_radius
        v = np.sqrt(vxa**2 + vya**2)
        skid = rs * np.abs(wa) < v
        w0 = np.sign(np.where(vxa == 0, 1.0, vxa)) * v / rs
        # zero-slip solve (h_zero_slip = h): needed for every skidding state
        h0, ok0, st0, res0, it0 = self._illinois(Wf, vxa, vya, np.where(skid, w0, wa), None, rtol, max_iter)
        h0s = np.where(skid, h0, np.nan)
        need = skid & ok0
        h = h0.copy()
        ok, status, res = ok0.copy(), st0.copy(), res0.copy()
        it = it0
        if np.any(need):
            idx = np.flatnonzero(need)
            h1, ok1, st1, r1, it1 = self._illinois(Wf[idx], vxa[idx], vya[idx], wa[idx], h0[idx], rtol, max_iter)
            h[idx], ok[idx], status[idx], res[idx] = h1, ok1, st1, r1
            it = max(it, it1)
        h0s = np.where(skid, h0s, h)
        h = np.where(ok, h, np.nan)
        h0s = np.where(ok, h0s, np.nan)
        return SinkageResult(h.reshape(shape), h0s.reshape(shape), ok.reshape(shape), status.reshape(shape),
                             res.reshape(shape), it, self.h_max)

    def _single_sinkage_function(self) -> Any:
        """casadi function ``[W, vx, vy, w] -> [h, h_zero_slip, g, g0, dg, dg0]`` by unrolled,
        bracketed Newton on ``g(u) = log F_z(e^u) - log W`` (nearly linear in u = log h),
        first at zero slip then (for skid) with that h_zero_slip. C-compiled when possible."""
        key = "sink1"
        if key in self._cas:
            return self._cas[key]
        import casadi as ca

        rs = self.wheel.shearing_radius
        u = ca.SX.sym("u")
        q = ca.SX.sym("q", 5)  # W, vx, vy, omega, h_zero_slip (<= 0: the state's own h)
        h = ca.exp(u)
        wr, _ = self.expressions(q[1], q[2], q[3], h, ca.if_else(q[4] > 0, q[4], h))
        g = ca.log(ca.fmax(wr[2], 1e-12)) - ca.log(q[0])
        fz = ca.Function("fz_log", [u, q], [g, ca.jacobian(g, u)])
        P = ca.MX.sym("P", 4)
        v = ca.sqrt(P[1] ** 2 + P[2] ** 2)
        skid = rs * ca.fabs(P[3]) < v
        w_first = ca.if_else(skid, ca.if_else(P[1] < 0, -1, 1) * v / rs, P[3])

        def newton(qv: Any) -> tuple[Any, Any, Any]:
            lo, hi = ca.MX(math.log(self.h_min)), ca.MX(math.log(self.h_max))
            uu = ca.MX(math.log(0.25 * rs))
            for _ in range(self.SINGLE_NEWTON_STEPS):
                gv, dg = fz(uu, qv)
                un = uu - gv / dg
                lo = ca.if_else(gv < 0, uu, lo)
                hi = ca.if_else(gv < 0, hi, uu)
                # a converged step lands on the bracket end it just set: accept it (>=, <=)
                inside = (un >= lo) * (un <= hi) * (dg > 0)
                uu = ca.if_else(inside, un, 0.5 * (lo + hi))
            gv, dg = fz(uu, qv)
            return uu, gv, dg

        u0, g0, d0 = newton(ca.vertcat(P[0], P[1], P[2], w_first, -1.0))
        u1, g1, d1 = newton(ca.vertcat(P[0], P[1], P[2], P[3], ca.exp(u0)))
        outs = [ca.if_else(skid, ca.exp(u1), ca.exp(u0)), ca.exp(u0), ca.if_else(skid, g1, g0), g0,
                ca.if_else(skid, d1, d0), d0]
        f = ca.Function("sinkage_single", [P], outs)
        self._cas[key] = self._compile(f, "sink1")
        return self._cas[key]

    SINGLE_NEWTON_STEPS = 12
    """Unrolled Newton steps per solve in :meth:`sinkage_from_load_single`."""

    def sinkage_from_load_single(self, load: float, vx: float, vy: float, omega: float, rtol: float = 1e-9) -> SinkageResult:
        """Sinkage carrying ``load`` for one wheel state, fast (compiled) path of
        :meth:`sinkage_from_load`.

        Safeguarded Newton in ``log h`` (bracket-keeping, bisection when a step leaves the
        bracket or the slope is not positive), compiled to C. The answer is accepted only
        if the load residual is below ``rtol`` and ``F_z`` rises with ``h`` there (the
        physical, first root); otherwise the robust scan-and-bracket solve of
        :meth:`sinkage_from_load` answers, so a hard case is slower but never wrong.
        """
        vals = [float(load), float(vx), float(vy), float(omega)]
        if not all(math.isfinite(x) for x in vals):
            raise ValueError(f"load and state must be finite, got {vals}")
        if vals[0] <= 0:
            raise ValueError(f"load must be > 0 N, got {vals[0]!r}")
        if vals[1] * vals[3] < 0 and abs(vals[3]) * self.wheel.shearing_radius > 1e-9 * abs(vals[1]):
            self._validate(vals[1], vals[2], vals[3], 0.5 * self.h_max, 0.5 * self.h_max)
        h, h0, g, g0, d, d0 = (float(x) for x in self._single_sinkage_function()(vals))
        tol = math.log1p(rtol)
        if abs(g) <= tol and abs(g0) <= tol and d > 0 and d0 > 0 and self.h_min < h < self.h_max:
            one = lambda x: np.array([x])  # noqa: E731
            return SinkageResult(one(h), one(h0), one(True), np.array(["ok"], dtype=_STATUS_DTYPE), one(g * vals[0]), self.SINGLE_NEWTON_STEPS,
                                 self.h_max)
        return self.sinkage_from_load(np.array([vals[0]]), np.array([vals[1]]), np.array([vals[2]]), np.array([vals[3]]),
                                      rtol=rtol)

    def _fz(self, vx: Any, vy: Any, w: Any, h: Any, h0s: Any | None, chunk: int = 1024) -> NDArray[np.float64]:
        """``F_z`` of 1-D states: the sinkage solve's only use of the wheel model, by
        :func:`rtctl.physics.terramechanics.normal_force` (the wrench's ``F_z`` bit for bit, in
        the same blocks as :meth:`_wrench_unchecked`, with about half its operations)."""
        h0 = h if h0s is None else h0s
        out = np.empty(h.size)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore", under="ignore"):
            for start in range(0, h.size, chunk):
                sl = slice(start, min(h.size, start + chunk))
                fz = normal_force(NUMPY, vx[sl, None], vy[sl, None], w[sl, None], h[sl, None], h0[sl, None], self.params,
                                  self.options)
                out[sl] = np.broadcast_to(fz, (sl.stop - sl.start, 1))[:, 0]
        return out.reshape(h.shape)

    def _illinois(self, W: Any, vx: Any, vy: Any, w: Any, h0s: Any | None, rtol: float, max_iter: int) -> tuple[Any, ...]:
        nb = W.size
        # Coarse scan first: F_z(h) is not monotonic once theta_f passes 90 deg (the rim's
        # far side pushes down), so bracket the *first* sinkage that carries the load.
        grid = np.geomspace(self.h_min, self.h_max, self.SCAN_POINTS)
        rep = lambda a: np.repeat(a, grid.size)  # noqa: E731
        hg = np.tile(grid, nb)
        fg = (self._fz(rep(vx), rep(vy), rep(w), hg, None if h0s is None else rep(h0s)) - rep(W)).reshape(nb, -1)
        above = fg >= 0
        first = np.where(above.any(axis=1), above.argmax(axis=1), -1)
        status = np.full(nb, "ok", dtype=object)
        cap = first < 0
        status[cap] = "load_exceeds_capacity"
        light = first == 0
        status[light] = "load_below_resolution"  # carried at h < h_min: not resolved
        active = first > 0
        i_hi = np.clip(first, 1, grid.size - 1)
        rows = np.arange(nb)
        lo, hi = grid[i_hi - 1], grid[i_hi]
        flo, fhi = fg[rows, i_hi - 1].copy(), fg[rows, i_hi].copy()
        lo, hi = lo.copy(), hi.copy()
        h = np.where(active, 0.5 * (lo + hi), np.nan)
        fh = np.full(nb, np.nan)
        side = np.zeros(nb, dtype=int)
        tol_f = rtol * W + 1e-12
        it = 0
        for it in range(1, max_iter + 1):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            # Illinois regula falsi step, with bisection when the secant leaves the bracket
            denom = fhi[idx] - flo[idx]
            hn = np.where(denom > 0, lo[idx] - flo[idx] * (hi[idx] - lo[idx]) / np.where(denom > 0, denom, 1.0), 0.5 * (lo[idx] + hi[idx]))
            bad = ~((hn > lo[idx]) & (hn < hi[idx]))
            hn[bad] = 0.5 * (lo[idx][bad] + hi[idx][bad])
            fn = self._fz(vx[idx], vy[idx], w[idx], hn, None if h0s is None else h0s[idx]) - W[idx]
            h[idx], fh[idx] = hn, fn
            done = (np.abs(fn) <= tol_f[idx]) | ((hi[idx] - lo[idx]) < 1e-13)
            pos = fn > 0
            # update bracket; halve the stale endpoint's value when the same side repeats
            li, hi_i = idx[~pos], idx[pos]
            lo[li], flo[li] = hn[~pos], fn[~pos]
            fhi[li] = np.where(side[li] == -1, 0.5 * fhi[li], fhi[li])
            side[li] = -1
            hi[hi_i], fhi[hi_i] = hn[pos], fn[pos]
            flo[hi_i] = np.where(side[hi_i] == 1, 0.5 * flo[hi_i], flo[hi_i])
            side[hi_i] = 1
            active[idx[done]] = False
        status[active] = "not_converged"
        res = np.where(np.isnan(fh), np.where(cap, fg.max(axis=1), np.nan), fh)
        # "ok" only within tolerance: a bracket that collapsed onto a jump of F_z(h) (the
        # soil-flow exit angle switches regime with sinkage) leaves a residual above tol_f
        jump = (status == "ok") & ~(np.abs(res) <= tol_f)
        status[jump] = "load_at_discontinuity"
        ok = status == "ok"
        return h, ok, status.astype(_STATUS_DTYPE), res, it
