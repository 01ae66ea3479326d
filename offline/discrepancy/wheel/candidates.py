"""The candidate library of the discrepancy engine and the single-wheel model that carries it.

A :class:`Candidate` is a piece of physics (or of the measurement chain) the model under test
may have left out, with physical parameters, units and bounds; ``build(theta, params)`` turns
its parameters (SI) into an :class:`Extension` of the model. Candidates are of two kinds:

* ``"term"`` -- new physics or a measurement effect the model does not have (a tether, a
  sensor offset, a hub dragging in the soil, ...);
* ``"parameters"`` -- a change of parameters the model already has (cohesion, slip/skid
  sinkage exponents, the contact angles, the wheel radius, and the full recalibration
  :meth:`SingleWheelModel.recalibration` that refits every soil and contact parameter).
  When one of these explains the data as well as any term, the verdict is "parameters off".

:class:`SingleWheelModel` is the single-wheel predictor: the engine calls
``predict(observations, extension)`` and nothing else model-specific, so a rover-level
predictor (issue 14) can plug in with its own extension type.

Sign conventions (wheel frame, dissertation ch. 5): x forward along the wheel's heading, y
to the wheel's left, z up; the travel direction in the wheel frame is
``(cos beta, -sin beta)`` (``v_y = -V sin beta``). Forces are those the soil and the rig
exert on the wheel, as the force sensor reports them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

import numpy as np
from numpy.typing import NDArray

from ...physics.backend import NUMPY
from ...physics.params import ParameterError, ParameterSet
from ...physics.terramechanics import ModelOptions, WheelModel, bulldozing_resistance
from ...fit.calibration import DEFAULT_BOUNDS
from .recording import SingleWheelRecording

__all__ = [
    "Extension",
    "Candidate",
    "CANDIDATES",
    "SingleWheelModel",
    "predict_recording",
    "RECALIBRATION_KEY",
]

RECALIBRATION_KEY = "recalibration"
"""Key of the full-recalibration candidate (every soil and contact parameter refitted)."""


# ------------------------------------------------------------------------- extensions
@dataclass(frozen=True)
class Extension:
    """A model extension: changes to parameters, inputs and outputs. Defaults change nothing.

    Physics on the wheel (applied to the wrench the model computes):

    Attributes
    ----------
    soil, wheel, tuning : dict
        Field replacements (SI) of the base :class:`~offline.physics.params.Soil`, ``Wheel``,
        ``ContactTuning``.
    options : dict
        Field replacements of :class:`~offline.physics.terramechanics.ModelOptions`.
    beta_offset : float
        Steering offset added to every slip angle, rad.
    omega_max : float
        Actuator speed saturation, rad/s (the wheel turns at most this fast).
    hub_clearance, hub_width : float
        A hub or body that ploughs the soil once the sinkage passes the clearance (m): a
        passive-earth-pressure blade of that width (eq. 5.24 form) resisting the travel.
    tether_force, tether_azimuth : float
        A tether pulling with ``tether_force`` (N) along a fixed horizontal direction of the
        testbed, ``tether_azimuth`` (rad) from the travel direction (positive to the left):
        in the wheel frame ``F += T (cos(beta - psi), -sin(beta - psi))``.
    tilt : float
        Unmodelled slope or sensor tilt in the x-z plane, rad: ``F_x += F_z sin(tilt)``.
    load_offset : float
        The wheel carries ``recorded load + load_offset`` (a load-cell zero error or a
        counterweight that is off), N.
    sinkage_relaxation : float
        Sinkage relaxation length, m: the recorded sinkage is
        ``h (1 - exp(-travel / length))`` (not yet at steady state).

    Measurement chain (applied last, to what the sensors report):

    sensor_yaw : float
        The force sensor's axes turned about the vertical by this angle (rad) relative to the
        wheel: ``Fx_m = Fx cos g - Fy sin g``, ``Fy_m = Fx sin g + Fy cos g``.
    force_gain : float
        Relative gain error of the force sensor: ``F_m = (1 + g) F`` on both axes.
    sensor_force : tuple
        Constant offset ``(Fx0, Fy0)`` in the wheel (sensor) frame, N (a zero offset, or a
        force that turns with the wheel such as a cable fixed to the wheel carriage).
    sinkage_offset : float
        Zero offset of the sinkage sensor, m.
    """

    soil: Mapping[str, float] = field(default_factory=dict)
    wheel: Mapping[str, float] = field(default_factory=dict)
    tuning: Mapping[str, float] = field(default_factory=dict)
    options: Mapping[str, Any] = field(default_factory=dict)
    beta_offset: float = 0.0
    omega_max: float = math.inf
    hub_clearance: float = math.inf
    hub_width: float = 0.0
    tether_force: float = 0.0
    tether_azimuth: float = 0.0
    tilt: float = 0.0
    load_offset: float = 0.0
    sinkage_relaxation: float = 0.0
    sensor_yaw: float = 0.0
    force_gain: float = 0.0
    sensor_force: tuple[float, float] = (0.0, 0.0)
    sinkage_offset: float = 0.0

    def merge(self, other: "Extension") -> "Extension":
        """Both extensions at once (the other's non-default fields win)."""
        d = Extension()
        kw: dict[str, Any] = {}
        for f in ("soil", "wheel", "tuning", "options"):
            kw[f] = {**getattr(self, f), **getattr(other, f)}
        for f in ("beta_offset", "omega_max", "hub_clearance", "hub_width", "tether_force", "tether_azimuth", "tilt",
                  "load_offset", "sinkage_relaxation", "sensor_yaw", "force_gain", "sensor_force", "sinkage_offset"):
            kw[f] = getattr(other, f) if getattr(other, f) != getattr(d, f) else getattr(self, f)
        return Extension(**kw)


@dataclass(frozen=True)
class _Physics:
    """The wheel's own response (before wheel-external terms and the measurement chain)."""

    soil: Any
    vx: NDArray[np.float64]
    vy: NDArray[np.float64]
    ok: NDArray[np.bool_]
    h: NDArray[np.float64]
    fx: NDArray[np.float64]
    fy: NDArray[np.float64]
    fz: NDArray[np.float64]


def _physics_key(rec: SingleWheelRecording, ext: Extension) -> tuple[Any, ...]:
    """What the wheel's own response depends on: the rows and the extension's physics fields."""
    rows = hash((rec.vx.tobytes(), rec.vy.tobytes(), rec.omega.tobytes(), rec.load.tobytes()))
    return (rows, tuple(sorted(ext.soil.items())), tuple(sorted(ext.wheel.items())), tuple(sorted(ext.tuning.items())),
            tuple(sorted((k, repr(v)) for k, v in ext.options.items())), ext.beta_offset, ext.omega_max, ext.load_offset)


def _kw(changes: Mapping[str, float]) -> dict[str, Any]:
    """An extension's field changes as keyword arguments of ``dataclasses.replace``."""
    return dict(changes)


def _solve_physics(params: ParameterSet, options: ModelOptions, rec: SingleWheelRecording, ext: Extension) -> _Physics | None:
    n = len(rec)
    try:
        soil = replace(params.soil, **_kw(ext.soil))
        wheel = replace(params.wheel, **_kw(ext.wheel))
        tuning = replace(params.tuning, **_kw(ext.tuning))
        opts = replace(options, **ext.options)
        model = WheelModel(soil, wheel, tuning, opts)
    except (ParameterError, ValueError):
        return None  # outside the physical range: every row fails
    vx, vy, w = rec.vx, rec.vy, rec.omega
    if ext.beta_offset:
        c, s = math.cos(ext.beta_offset), math.sin(ext.beta_offset)
        # travel fixed, wheel turned by the offset: rotate the velocity into the new heading
        vx, vy = c * vx - s * vy, s * vx + c * vy
        vx = np.maximum(vx, 0.0)
    if math.isfinite(ext.omega_max):
        w = np.sign(w) * np.minimum(np.abs(w), ext.omega_max)
    load = rec.load + ext.load_offset
    good = load > 0
    ok = np.zeros(n, dtype=bool)
    h = np.full(n, np.nan)
    h0 = np.full(n, np.nan)
    if good.any():
        sol = model.sinkage_from_load(load[good], vx[good], vy[good], w[good])
        ok[good] = sol.converged
        h[good], h0[good] = sol.h, sol.h_zero_slip
    fx, fy, fz = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    if ok.any():
        wr = model.wrench(vx[ok], vy[ok], w[ok], h[ok], h0[ok])
        fx[ok], fy[ok], fz[ok] = wr.Fx, wr.Fy, wr.Fz
    return _Physics(soil, vx, vy, ok, h, fx, fy, fz)


def _apply_terms(ph: _Physics | None, rec: SingleWheelRecording, ext: Extension) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
    """Wheel-external terms and the measurement chain on top of the wheel's own response."""
    out = {ch: np.full(len(rec), np.nan) for ch in ("Fx", "Fy", "sinkage")}
    if ph is None or not ph.ok.any():
        return out, np.zeros(len(rec), dtype=bool)
    ok = ph.ok
    vx, vy = ph.vx[ok], ph.vy[ok]
    fx, fy, fz, hk = ph.fx[ok].copy(), ph.fy[ok].copy(), ph.fz[ok], ph.h[ok]
    v = np.hypot(vx, vy)
    if ext.hub_width > 0 and math.isfinite(ext.hub_clearance):
        depth = np.maximum(hk - ext.hub_clearance, 0.0)
        drag = ext.hub_width * bulldozing_resistance(NUMPY, depth, ph.soil.unit_weight, ph.soil.cohesion, ph.soil.friction_angle, "pavlov")
        fx -= drag * vx / v
        fy -= drag * vy / v
    if ext.tether_force:
        beta = np.arctan2(-vy, vx)
        fx += ext.tether_force * np.cos(beta - ext.tether_azimuth)
        fy -= ext.tether_force * np.sin(beta - ext.tether_azimuth)
    if ext.tilt:
        fx += fz * math.sin(ext.tilt)
    if ext.sinkage_relaxation > 0:
        hk = hk * (1.0 - np.exp(-rec.travel[ok] / ext.sinkage_relaxation))
    # measurement chain
    if ext.sensor_yaw:
        c, s = math.cos(ext.sensor_yaw), math.sin(ext.sensor_yaw)
        fx, fy = c * fx - s * fy, s * fx + c * fy
    if ext.force_gain:
        fx, fy = (1.0 + ext.force_gain) * fx, (1.0 + ext.force_gain) * fy
    out["Fx"][ok] = fx + ext.sensor_force[0]
    out["Fy"][ok] = fy + ext.sensor_force[1]
    out["sinkage"][ok] = hk + ext.sinkage_offset
    return out, ok.copy()


def predict_recording(
    params: ParameterSet, options: ModelOptions, rec: SingleWheelRecording, ext: Extension | None = None
) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
    """Predict every row of ``rec`` with the (extended) model, the load given (eq. 5.34).

    Returns
    -------
    predicted : dict
        ``Fx``, ``Fy`` (N), ``sinkage`` (m); NaN where the model cannot carry the load or an
        extension's parameters leave the model's valid range.
    ok : ndarray of bool
    """
    ext = ext or Extension()
    return _apply_terms(_solve_physics(params, options, rec, ext), rec, ext)


# ------------------------------------------------------------------------- candidates
@dataclass(frozen=True)
class Candidate:
    """One candidate piece of missing physics, or one group of the model's own parameters.

    Attributes
    ----------
    key : str
        Identifier.
    physics : str
        What physics the base model left out (report text).
    params : tuple
        ``(name, unit, lower, upper, start, to_si)``; ``to_si`` converts the reported unit
        to SI.
    build : callable
        ``(theta (SI), ParameterSet) -> extension`` of the model's type: :class:`Extension` for
        the single-wheel model, :class:`offline.discrepancy.drive.candidates.RoverExtension` for drives
        (anything with ``merge``; the engine starts from ``model.empty_extension()``).
    channels : tuple of str
        Channels the term acts on (for the report).
    family : str
        Candidates of one family change the same model part and are never combined.
    kind : {"term", "parameters"}
        New physics, or a change of parameters the model already has ("parameters off").
    starts : tuple of tuples
        Extra starting points (reported units) for the least-squares fit, for parameters
        with a threshold (a clearance) or a periodic effect (a direction).
    threshold : bool
        A parameter places where the effect switches on (a clearance, a saturation): the
        one-step held-out score would inherit its placement from the held-out rows, so the
        candidate is scored with a full refit per fold.
    null : tuple of float or None
        Parameter values (reported units) at which the term is absent, i.e. the believed model
        (0 for an offset, 1 for a scale). With it the engine can test whether the data determine
        the term at all (its fitted values against these, Wald test) and starts the forward
        step's score test there; None: no such point inside the box (a clearance, a lag). A NaN
        entry: the parameter means nothing once the term is absent (a tether's anchor when its
        tension is zero); it is left out of the Wald test and the score test starts it at its start.
    nuisance : tuple of str
        Parameters of the term's form that the data need not determine for the term to be named
        (an anchor's distance when the rover drove a metre: the pull's tension and direction are
        what the drive shows). Their intervals are reported, but a wide one does not make the
        verdict ambiguous.
    screened : bool
        Fitted only when the observations' screen admits it (``observations.screen``: the drive's
        per-wheel actuator terms, admitted on the wheels the located regions or their own
        encoders implicate, :meth:`offline.discrepancy.drive.diagnosis.DriveRecording.screen`);
        with observations that have no screen it is always fitted.
    """

    key: str
    physics: str
    params: tuple[tuple[str, str, float, float, float, float], ...]
    build: Callable[[NDArray[np.float64], ParameterSet], Any]  # the model's extension type (Extension, RoverExtension)
    channels: tuple[str, ...] = ("Fx", "Fy", "sinkage")
    family: str = ""
    kind: str = "term"
    starts: tuple[tuple[float, ...], ...] = ()
    threshold: bool = False
    null: tuple[float, ...] | None = None
    nuisance: tuple[str, ...] = ()
    screened: bool = False

    @property
    def k(self) -> int:
        """Number of fitted parameters."""
        return len(self.params)

    @property
    def lower(self) -> NDArray[np.float64]:
        """Lower bounds (reported units)."""
        return np.array([q[2] for q in self.params])

    @property
    def upper(self) -> NDArray[np.float64]:
        """Upper bounds (reported units)."""
        return np.array([q[3] for q in self.params])

    @property
    def to_si(self) -> NDArray[np.float64]:
        """Factors from reported units to SI."""
        return np.array([q[5] for q in self.params])


def _deg(x: float) -> float:
    return math.radians(x)


CANDIDATES: tuple[Candidate, ...] = (
    # --- new physics on the wheel
    Candidate(
        "sidewall_bulldozing",
        "sidewall bulldozing: passive earth pressure on the wheel face, eqs. (5.22)-(5.27); "
        "scale 1 is the published form, 0 is no sidewall force",
        (("scale", "-", 0.0, 4.0, 1.0, 1.0),),
        lambda t, p: Extension(options={"bulldozing": "pavlov", "bulldozing_scale": float(t[0])}),
        ("Fy", "Fx"), "bulldozing",
    ),
    Candidate(
        "sidewall_bulldozing_ishigami",
        "sidewall bulldozing in the Ishigami 2007 form, eq. (5.29)",
        (("scale", "-", 0.0, 4.0, 1.0, 1.0),),
        lambda t, p: Extension(options={"bulldozing": "ishigami", "bulldozing_scale": float(t[0])}),
        ("Fy", "Fx"), "bulldozing",
    ),
    Candidate(
        "hub_drag",
        "a hub or body dragging in the soil once the sinkage passes a clearance "
        "(passive-pressure blade, eq. 5.24 form, resisting the travel)",
        (("clearance", "mm", 0.0, 120.0, 40.0, 1e-3), ("width", "mm", 0.0, 300.0, 30.0, 1e-3)),
        lambda t, p: Extension(hub_clearance=float(t[0]), hub_width=float(t[1])),
        ("Fx", "Fy"), starts=tuple((float(c), 30.0) for c in range(10, 100, 10)), threshold=True,
    ),
    Candidate(
        "tether",
        "a tether, cable or towing rig pulling along a fixed horizontal direction of the testbed "
        "(azimuth from the travel direction, positive to the left)",
        (("force", "N", -30.0, 30.0, 0.0, 1.0), ("azimuth", "deg", -90.0, 90.0, 0.0, math.pi / 180)),
        lambda t, p: Extension(tether_force=float(t[0]), tether_azimuth=float(t[1])),
        ("Fx", "Fy"), starts=((1.0, 40.0), (1.0, -40.0)),
    ),
    Candidate(
        "slope_or_tilt",
        "an unmodelled slope or sensor tilt: the measured F_x picks up F_z sin(angle)",
        (("angle", "deg", -15.0, 15.0, 0.0, math.pi / 180),),
        lambda t, p: Extension(tilt=float(t[0])),
        ("Fx",),
    ),
    Candidate(
        "steering_offset",
        "a steering offset: the wheel's true slip angle differs from the recorded one",
        (("offset", "deg", -15.0, 15.0, 0.0, math.pi / 180),),
        lambda t, p: Extension(beta_offset=float(t[0])),
    ),
    Candidate(
        "speed_saturation",
        "actuator speed saturation: the wheel cannot turn faster than a limit",
        (("omega_max", "rad/s", 0.05, 5.0, 1.0, 1.0),),
        lambda t, p: Extension(omega_max=float(t[0])),
        starts=((0.5,), (2.0,)), threshold=True,
    ),
    Candidate(
        "sinkage_transient",
        "sinkage not at steady state: recorded sinkage h (1 - exp(-travel / length))",
        (("length", "m", 0.01, 5.0, 0.3, 1.0),),
        lambda t, p: Extension(sinkage_relaxation=float(t[0])),
        ("sinkage",),
    ),
    Candidate(
        "load_offset",
        "the wheel carries a different load than recorded (load-cell zero error, counterweight off)",
        (("offset", "N", -10.0, 10.0, 0.0, 1.0),),
        lambda t, p: Extension(load_offset=float(t[0])),
    ),
    # --- measurement chain
    Candidate(
        "sensor_offset",
        "a constant force offset in the wheel (sensor) frame: force-sensor zero offset, or a force "
        "that turns with the wheel",
        (("Fx0", "N", -30.0, 30.0, 0.0, 1.0), ("Fy0", "N", -30.0, 30.0, 0.0, 1.0)),
        lambda t, p: Extension(sensor_force=(float(t[0]), float(t[1]))),
        ("Fx", "Fy"),
    ),
    Candidate(
        "sensor_yaw",
        "force-sensor axes turned about the vertical relative to the wheel (mounting misalignment)",
        (("angle", "deg", -20.0, 20.0, 0.0, math.pi / 180),),
        lambda t, p: Extension(sensor_yaw=float(t[0])),
        ("Fx", "Fy"),
    ),
    Candidate(
        "force_gain",
        "force-sensor gain error: F_x and F_y read (1 + g) times the true force",
        (("gain_error", "%", -50.0, 50.0, 0.0, 1e-2),),
        lambda t, p: Extension(force_gain=float(t[0])),
        ("Fx", "Fy"),
    ),
    Candidate(
        "sinkage_offset",
        "sinkage-sensor zero offset",
        (("offset", "mm", -20.0, 20.0, 0.0, 1e-3),),
        lambda t, p: Extension(sinkage_offset=float(t[0])),
        ("sinkage",),
    ),
    # --- the model's own parameters (a verdict of "parameters off")
    Candidate(
        "slip_skid_sinkage",
        "slip- and skid-sinkage exponents of eq. (5.6) (n1, n2) off",
        (("n1", "-", 0.0, 2.0, 0.1, 1.0), ("n2", "-", 0.0, 2.0, 0.5, 1.0)),
        lambda t, p: Extension(soil={"n1": float(t[0]), "n2": float(t[1])}),
        ("sinkage", "Fx"), kind="parameters",
    ),
    Candidate(
        "rear_contact",
        "rear contact angle theta_r = theta_f (b0 + b1 s) of eq. (5.4) off",
        (("b0", "-", -1.0, 0.0, -0.5, 1.0), ("b1", "-", -1.0, 0.0, -0.2, 1.0)),
        lambda t, p: Extension(tuning={"b0": float(t[0]), "b1": float(t[1])}),
        kind="parameters",
    ),
    Candidate(
        "grouser_shearing_radius",
        "grouser height (shearing radius r_s = r + h_g, section 5.2) off",
        (("h_g", "mm", 0.0, 20.0, 5.0, 1e-3),),
        lambda t, p: Extension(wheel={"grouser_height": float(t[0])}),
        kind="parameters",
    ),
    Candidate(
        "cohesion",
        "soil cohesion c in the shear strength (5.10) and passive pressure (5.22) off",
        (("c", "kPa", 0.0, 10.0, 1.0, 1e3),),
        lambda t, p: Extension(soil={"cohesion": float(t[0])}),
        kind="parameters",
    ),
    Candidate(
        "wheel_radius",
        "effective wheel radius off (wear, deflection, wrong geometry)",
        (("radius_change", "%", -20.0, 20.0, 0.0, 1e-2),),
        lambda t, p: Extension(wheel={"radius": p.wheel.radius * (1.0 + float(t[0]))}),
        kind="parameters",
    ),
)

# Recalibration: (reported name, unit, lower, upper, to_si, section, field)
_RECAL: tuple[tuple[str, str, float, float, float, str, str], ...] = (
    ("k", "kN/m^(n+2)", DEFAULT_BOUNDS["k"][0] / 1e3, DEFAULT_BOUNDS["k"][1] / 1e3, 1e3, "soil", "k"),
    ("n0", "-", *DEFAULT_BOUNDS["n0"], 1.0, "soil", "n0"),
    ("n1", "-", *DEFAULT_BOUNDS["n1"], 1.0, "soil", "n1"),
    ("n2", "-", *DEFAULT_BOUNDS["n2"], 1.0, "soil", "n2"),
    ("phi", "deg", 15.0, 50.0, math.pi / 180, "soil", "friction_angle"),
    ("c", "kPa", DEFAULT_BOUNDS["c"][0] / 1e3, DEFAULT_BOUNDS["c"][1] / 1e3, 1e3, "soil", "cohesion"),
    ("K", "mm", DEFAULT_BOUNDS["K"][0] * 1e3, DEFAULT_BOUNDS["K"][1] * 1e3, 1e-3, "soil", "shear_modulus"),
    ("a0", "-", *DEFAULT_BOUNDS["a0"], 1.0, "tuning", "a0"),
    ("a1", "-", *DEFAULT_BOUNDS["a1"], 1.0, "tuning", "a1"),
    ("b0", "-", *DEFAULT_BOUNDS["b0"], 1.0, "tuning", "b0"),
    ("b1", "-", *DEFAULT_BOUNDS["b1"], 1.0, "tuning", "b1"),
    ("a0_per_rad", "1/rad", *DEFAULT_BOUNDS["a0_beta"], 1.0, "tuning", "a0_per_rad"),
    ("a1_per_rad", "1/rad", *DEFAULT_BOUNDS["a1_beta"], 1.0, "tuning", "a1_per_rad"),
    ("b0_per_rad", "1/rad", *DEFAULT_BOUNDS["b0_beta"], 1.0, "tuning", "b0_per_rad"),
    ("b1_per_rad", "1/rad", *DEFAULT_BOUNDS["b1_beta"], 1.0, "tuning", "b1_per_rad"),
)


@dataclass(frozen=True)
class SingleWheelModel:
    """The single-wheel model under test: a parameter set and model options.

    Parameters
    ----------
    params : ParameterSet
    options : ModelOptions
    cache_size : int
        Wheel responses kept (sinkage solve and wrench, keyed by the rows and the extension's
        physics fields), oldest dropped first.
    """

    params: ParameterSet
    options: ModelOptions = field(default_factory=ModelOptions)
    cache_size: int = 64
    _cache: dict[Any, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def predict(self, rec: SingleWheelRecording, ext: Extension | None = None) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
        """Predicted channels of every row (same numbers as :func:`predict_recording`).

        The wheel's own response (sinkage solve and wrench) is cached per rows and physics
        fields of the extension, so candidates acting outside the wheel (a tether, a sensor
        offset, a hub drag) cost no new sinkage solve.
        """
        ext = ext or Extension()
        key = _physics_key(rec, ext)
        ph = self._cache.get(key)
        if ph is None and key not in self._cache:
            ph = _solve_physics(self.params, self.options, rec, ext)
            if len(self._cache) >= self.cache_size:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = ph
        return _apply_terms(ph, rec, ext)

    def recalibration(self) -> Candidate:
        """The full recalibration as a candidate: k, n0, n1, n2, phi, c, K and the eight contact
        coefficients a0..b1 with their slopes in |beta| (eqs. 5.3-5.6, 7.8-7.9), starting at
        the model's own values (clipped into the bounds of
        :data:`offline.fit.calibration.DEFAULT_BOUNDS`)."""
        p = self.params
        specs = []
        for name, unit, lo, hi, to_si, sec, fld in _RECAL:
            cur = getattr(getattr(p, sec), fld) / to_si
            specs.append((name, unit, lo, hi, float(np.clip(cur, lo, hi)), to_si))

        def build(theta: NDArray[np.float64], ps: ParameterSet) -> Extension:
            soil: dict[str, float] = {}
            tuning: dict[str, float] = {}
            for (name, _u, _l, _h, _s, sec, fld), v in zip(_RECAL, theta):
                (soil if sec == "soil" else tuning)[fld] = float(v)
            return Extension(soil=soil, tuning=tuning)

        return Candidate(RECALIBRATION_KEY, "the model's own parameters are off: every soil and contact parameter "
                         "refitted (k, n0, n1, n2, phi, c, K, a0..b1 and their slopes in |beta|)",
                         tuple(specs), build, kind="parameters", family="recalibration")

    def parameter_set(self, ext: Extension, note: str = "") -> ParameterSet:
        """The parameter set with the extension's soil, wheel and tuning changes applied."""
        p = self.params
        return ParameterSet(replace(p.soil, **_kw(ext.soil), name=f"{p.soil.name}_recalibrated", source="offline.discrepancy.engine"),
                            replace(p.wheel, **_kw(ext.wheel)),
                            replace(p.tuning, **_kw(ext.tuning), name=f"{p.tuning.name}_recalibrated", source="offline.discrepancy.engine"),
                            note or p.notes)

    def describe(self) -> str:
        """One line naming the parameter set and options."""
        p = self.params
        return f"soil `{p.soil.name}`, wheel `{p.wheel.name}`, tuning `{p.tuning.name}`, options `{self.options}`"
