"""A lateral passive-earth-pressure term on the wheel face with the recorded (transient) sinkage:
does it explain the single-wheel miss at 75-90 deg slip angle? (issue 14, second part)

At 75-90 deg the wheel travels nearly along its own axis: its side face is a plate pushed
sideways through the soil (a bulldozing blade), and the authors report that these runs never
reached a steady state (the sinkage still grows at the force window). The model's sidewall
term, eqs. (5.22)-(5.27), uses a unit-width blade of the *model's steady* sinkage. The term
tried here pushes the soil with the submerged part of the face -- a circular segment of the
rim disk -- at the *recorded* sinkage of the force window (the transient state the sinkage
time series shows), with Rankine passive pressure
``p(z) = rho z K_p + 2 c sqrt(K_p)``, ``K_p = tan^2(pi/4 + phi/2)``:

.. math::
    F_{face} = s \\int_0^{h} 2\\sqrt{r^2 - (r - h + z)^2}\\; p(z)\\, dz

directed against the wheel-frame lateral velocity and weighted by ``|sin beta|`` (the part
of the motion normal to the face); ``s`` is the one fitted scale.

:func:`held_out_angles` answers the question honestly: for each of 75 and 90 deg, the scale
is fitted on every other condition (the other high angle included) and the held-out angle's
rows are predicted, beside the model as given and beside the existing sidewall term with its
scale refitted the same way. The term earns its place only if it beats both on the held-out
angles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .candidates import Extension, SingleWheelModel
from .recording import SingleWheelRecording
from ..significance import dispersion, normalised

__all__ = ["face_force", "FacePressureModel", "held_out_angles", "FaceStudy"]

_GL_X, _GL_W = np.polynomial.legendre.leggauss(24)


def face_force(h: NDArray[np.float64], r: float, rho: float, c: float, phi: float) -> NDArray[np.float64]:
    """Passive earth force on the submerged circular segment of a disk of radius ``r`` sunk to
    depth ``h`` (m), N; Rankine passive pressure (module notes), 24-point Gauss-Legendre.

    Limits: 0 at ``h = 0``; for ``h >= 2 r`` the whole disk is submerged (depth capped at 2 r).
    """
    h = np.clip(np.asarray(h, dtype=float), 0.0, 2.0 * r)
    kp = math.tan(math.pi / 4 + phi / 2) ** 2
    z = 0.5 * h[..., None] * (_GL_X + 1.0)  # depth below the surface
    chord = 2.0 * np.sqrt(np.clip(r * r - (r - h[..., None] + z) ** 2, 0.0, None))
    p = rho * z * kp + 2.0 * c * math.sqrt(kp)
    return 0.5 * h * np.sum(_GL_W * chord * p, axis=-1)


@dataclass(frozen=True)
class FacePressureModel:
    """A :class:`SingleWheelModel` plus the face term, scale in ``Extension.options["face.scale"]``
    (the key is taken out before the wheel model sees the options)."""

    inner: SingleWheelModel

    @property
    def params(self) -> Any:
        """The inner model's parameter set."""
        return self.inner.params

    def predict(self, rec: SingleWheelRecording, ext: Extension | None = None) -> tuple[dict[str, NDArray[np.float64]], NDArray[np.bool_]]:
        """Inner prediction, then ``F_y += -sign(v_y) |sin beta| F_face(recorded sinkage)``."""
        ext = ext or Extension()
        opts = dict(ext.options)
        s = float(opts.pop("face.scale", 0.0))
        pred, ok = self.inner.predict(rec, replace(ext, options=opts))
        if s:
            soil, w = self.inner.params.soil, self.inner.params.wheel
            v = np.hypot(rec.vx, rec.vy)
            f = s * face_force(rec.measured["sinkage"], w.radius, soil.unit_weight, soil.cohesion, soil.friction_angle)
            pred = dict(pred)
            pred["Fy"] = pred["Fy"] - np.sign(rec.vy) * np.abs(rec.vy) / np.maximum(v, 1e-12) * f
        return pred, ok


@dataclass(frozen=True)
class FaceStudy:
    """Held-out chi-square of one held-out angle under three models (and, for reference, the face
    term's in-sample best on that angle's own rows); mean F_y residuals in N over the rows the
    model can predict; ``failed_rows``: rows where the wheel model cannot carry the load."""

    angle_deg: float
    rows: int
    chi2_model: float
    chi2_sidewall_refit: float
    sidewall_scale: float
    chi2_face: float
    face_scale: float
    fy_residual_model: float
    fy_residual_face: float
    failed_rows: int
    face_scale_in_sample: float
    chi2_face_in_sample: float


def _fit_scale(resid: Any, lo: float, hi: float) -> float:
    from scipy.optimize import minimize_scalar

    r = minimize_scalar(lambda s: float(np.sum(resid(s) ** 2)), bounds=(lo, hi), method="bounded",
                        options={"maxiter": 60, "xatol": 1e-4})
    return float(r.x)


def held_out_angles(rec: SingleWheelRecording, model: SingleWheelModel, angles: tuple[float, ...] = (75.0, 90.0)) -> list[FaceStudy]:
    """For each angle: fit on every other condition, score the angle's rows (module notes).

    Chi-square in units of the repeat noise times the model's per-channel dispersion (the
    engine's units), over Fx, Fy and sinkage. Scales: face term in [0, 20], sidewall term in
    [0, 20] (the sidewall scale multiplies the model's own eq. (5.24) term, 1 = as given).
    """
    fm = FacePressureModel(model)
    pred0, _ = model.predict(rec)
    scale = dispersion(rec, pred0)
    absb = rec.features["abs_beta_deg"]
    out = []
    for a in angles:
        te = np.flatnonzero(np.abs(absb - a) < 0.6)
        tr = np.flatnonzero(np.abs(absb - a) >= 0.6)
        if te.size == 0:
            continue
        rtr, rte = rec.subset(tr), rec.subset(te)

        def chi(m: Any, r: SingleWheelRecording, e: Extension) -> NDArray[np.float64]:
            p, _ = m.predict(r, e)
            return normalised(r, p, scale)

        def face(s: float) -> Extension:
            return Extension(options={"face.scale": s})

        def side(s: float) -> Extension:
            return Extension(options={"bulldozing_scale": s})

        s_face = _fit_scale(lambda s: chi(fm, rtr, face(s)), 0.0, 20.0)
        s_side = _fit_scale(lambda s: chi(model, rtr, side(s)), 0.0, 20.0)
        z0 = chi(model, rte, Extension())
        zf = chi(fm, rte, face(s_face))
        zs = chi(model, rte, side(s_side))
        p0, _ = model.predict(rte)
        pf, _ = fm.predict(rte, face(s_face))
        s_in = _fit_scale(lambda s: chi(fm, rte, face(s)), 0.0, 20.0)  # the best the term could do on these rows
        zi = chi(fm, rte, face(s_in))
        out.append(FaceStudy(a, int(te.size), float((z0**2).sum()), float((zs**2).sum()), s_side, float((zf**2).sum()),
                             s_face, float(np.nanmean(rte.measured["Fy"] - p0["Fy"])),
                             float(np.nanmean(rte.measured["Fy"] - pf["Fy"])), int((~np.isfinite(p0["Fy"])).sum()),
                             s_in, float((zi**2).sum())))
    return out
