"""Left-right mirror of a lookup table: a rear-right table serves rear-left (part of issue 21).

The mini rover (Table 7.2) and the wheel model are symmetric under reflection in the rover's
x-z plane. Reflection swaps the right and left wheels (FR <-> FL, RR <-> RL) and flips the
sign of every lateral quantity: steering and slip angles (``beta``), the cross slope, the
offsets of (7.26)-(7.27), the balance rows in F_y, M_x and M_z (the two rocker pitch rows
swap), and each wheel's F_y, M_x, M_z and its Jacobian in v_y. :func:`mirror_table` applies that
to every field of every grid point (a signed permutation ``x_m = M_x x``: Jacobians
``M_g J M_x^T``, Hessians ``M_x H M_x^T``; a bound whose variable flips sign swaps lower and
upper; active-set codes and multipliers follow), reverses the axes that flip sign (cross slope,
a stuck steering angle), and rewrites the header (failures and family on the mirrored wheel,
stuck angles and steering ranges negated, per-wheel world records swapped, the lateral pull
negated), so that the rover's exact residual (:mod:`rtctl.physics.steady_state`) of the
mirrored table is the mirrored rover's. The steering controllers of section 7.2.4 map as
``Mz+ <- -M(Mz-)`` (a positive offset in the mirror is a negative one in the original, per unit
offset).

A trench table is not mirrored (:class:`MirrorError`): which side of the trench is clean is
part of the soil-flow model's convention, not checked here to be symmetric.
"""

from __future__ import annotations

import copy
from typing import Any, Mapping

import numpy as np
from numpy.typing import NDArray

from .physics.rover_file import RoverFileError, rover_spec_from_record
from .table import CONTROLLER_NAMES, Table, content_hash

__all__ = ["MirrorError", "MIRROR_WHEEL", "mirror_table", "mirror_name", "mirror_wheel_map"]

MIRROR_WHEEL = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}
"""The wheel each wheel becomes in the mirror (the mini rover's; a rover file's: :func:`mirror_wheel_map`)."""
_MIRROR_TOL_M = 1e-9  # m: a wheel centre or pivot and its mirror image may differ by this
_LATERAL_PARAMETERS = ("cross_slope", "fy_offset", "mz_offset")
_LATERAL_ROWS = ("balance Fy", "balance Mx", "balance Mz", "balance My_differential")
"""Rows that change sign in the mirror (the rocker-bogie's differential row is right minus left)."""
_FLIPPED_AXES = ("cross_slope", "steer_stuck")
_WRENCH_SIGN = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])  # Fx, Fy, Fz, Mx, My, Mz
_STATE_SIGN = np.array([1.0, -1.0, 1.0, 1.0, 1.0])  # vx, vy, omega, h, h0


class MirrorError(ValueError):
    """A table that cannot be mirrored (its name says why)."""


def mirror_name(name: str, wheel_map: Mapping[str, str] = MIRROR_WHEEL) -> str:
    """``rr_steer_stuck`` -> ``rl_steer_stuck`` (a wheel prefix swapped), else ``<name>_mirror``.

    Parameters
    ----------
    name : str
        The table's name.
    wheel_map : mapping
        Wheel -> its mirror (default the mini rover's :data:`MIRROR_WHEEL`).
    """
    head, _, rest = name.partition("_")
    upper = {k.upper(): v for k, v in wheel_map.items()}
    w = head.upper()
    return f"{upper[w].lower()}_{rest}" if w in upper and rest else f"{name}_mirror"


def _rover_record(t: Any) -> Mapping[str, Any] | None:
    sc = t.header.get("scenario")
    rec = sc.get("rover_file") if isinstance(sc, Mapping) else None
    return rec if isinstance(rec, Mapping) else None


def _mirror_maps(t: Any) -> tuple[dict[str, str], dict[str, str]]:
    """``(wheel map, name-token map)`` of a table's mirror (:func:`mirror_wheel_map`); the token map
    also swaps the balance rows of mirrored links (``My_right`` <-> ``My_left``,
    ``My_bogie_right`` <-> ``My_bogie_left``)."""
    rec = _rover_record(t)
    name = getattr(t, "name", "?")
    if rec is None:  # the mini rover of Table 7.2
        wheels = tuple(t.layout.wheels)
        if not set(wheels) <= set(MIRROR_WHEEL):
            raise MirrorError(f"table {name}: wheels {list(wheels)} without a rover record: no mirror map")
        return dict(MIRROR_WHEEL), {**MIRROR_WHEEL, "My_right": "My_left", "My_left": "My_right"}
    try:
        spec = rover_spec_from_record(rec, f"table {name}")
    except RoverFileError as exc:
        raise MirrorError(str(exc)) from None
    if spec.suspension == "rigid":
        raise MirrorError(f"table {name}: a rigid (skid-steer) rover's height-compatibility rows are a basis of "
                          "the wheel heights' null space, not a signed permutation under the mirror; build the "
                          "mirrored table")
    if spec.suspension == "rocker" and any(c != 0.0 for c in spec.centre_of_mass):
        raise MirrorError(f"table {name}: the body of this rocker rover is fixed to one rocker and its centre of "
                          "mass is off O, so its mirror is another rover; build the mirrored table")
    tol = _MIRROR_TOL_M

    def image(v: tuple[float, float, float]) -> tuple[float, float, float]:
        return v[0], -v[1], v[2]

    def near(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
        return all(abs(x - y) <= tol for x, y in zip(a, b))

    why = f"table {name}: rover {spec.name} is not left-right symmetric"
    if abs(spec.centre_of_mass[1]) > tol:
        raise MirrorError(f"{why} (centre of mass y = {spec.centre_of_mass[1]} m); build the mirrored table")
    wmap: dict[str, str] = {}
    for w in spec.wheels:
        match = [v for v in spec.wheels if near(v.position, image(w.position))]
        if len(match) != 1 or (match[0].steerable, match[0].driven) != (w.steerable, w.driven) \
                or abs(match[0].steer_min + w.steer_max) > tol or abs(match[0].steer_max + w.steer_min) > tol:
            raise MirrorError(f"{why} (wheel {w.name} has no mirror image of the same kind); build the mirrored table")
        wmap[w.name] = match[0].name
    tokens = dict(wmap)
    for lk in spec.links:
        match_l = [m for m in spec.links if near(m.pivot, image(lk.pivot))]
        if len(match_l) != 1:
            raise MirrorError(f"{why} (link {lk.name} has no mirror image); build the mirrored table")
        tokens[f"My_{lk.name}"] = f"My_{match_l[0].name}"
    tokens.update({"My_right": "My_left", "My_left": "My_right"})
    return wmap, tokens


def mirror_wheel_map(t: Any) -> dict[str, str]:
    """The wheel each wheel of a table becomes in its left-right mirror.

    The mini rover's :data:`MIRROR_WHEEL` for a table without a rover record; for a table built
    from a rover file, from its wheel positions (the header's ``scenario.rover_file``): the wheel
    at ``(x, -y, z)`` with the same steerable and driven flags and the mirrored steering range.

    Parameters
    ----------
    t : Table
        The table.

    Returns
    -------
    dict

    Raises
    ------
    MirrorError
        No mirror within this rover: not left-right symmetric, or a rigid frame (its
        height-compatibility rows do not map to rows), or a one-sided rocker body off O.
    """
    return _mirror_maps(t)[0]


def _names_map(names: list[str], tokens: Mapping[str, str]) -> NDArray[np.intp]:
    """Index of each name's mirror in the same list (``'load RR'`` <-> ``'load RL'``, ...)."""
    out = []
    for n in names:
        m = " ".join(tokens.get(p, p) for p in n.split(" "))
        out.append(names.index(m))
    return np.array(out, dtype=np.intp)


def _signed_permutation(names: list[str], flipped: Any, tokens: Mapping[str, str]
                        ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
    """``(source index, sign)`` per entry: entry ``i`` of the mirror is ``sign[i] * v[src[i]]``."""
    src = _names_map(names, tokens)
    sign = np.array([-1.0 if flipped(names[j]) else 1.0 for j in src])
    return src, sign


def mirror_table(t: Table) -> Table:
    """The mirror image of ``t`` (module docstring), a new in-memory :class:`Table`.

    Raises
    ------
    MirrorError
        For a trench table, or a layout whose names have no mirror.
    """
    h = t.header
    sc = h.get("scenario") or {}
    if isinstance(sc.get("trench"), dict):
        raise MirrorError(f"table {t.name}: a trench table is not mirrored (the clean side is a convention of the "
                          "soil-flow model); build the mirrored trench table")
    lay = t.layout
    wmap, tokens = _mirror_maps(t)
    try:
        vs, vsign = _signed_permutation(list(lay.variable_names), lambda n: n.startswith("beta "), tokens)
        ps, psign = _signed_permutation(list(lay.parameter_names), lambda n: n in _LATERAL_PARAMETERS, tokens)
        gs, gsign = _signed_permutation(list(lay.constraint_names), lambda n: n in _LATERAL_ROWS, tokens)
        wheels = list(lay.wheels)
        ws = np.array([wheels.index(wmap[w]) for w in wheels])
    except (ValueError, KeyError) as exc:
        raise MirrorError(f"table {t.name}: a name of its layout has no mirror ({exc})") from None
    flip_axes = [i for i, k in enumerate(t.axis_order) if k in _FLIPPED_AXES and len(t.axes[k]) > 1]
    nd = len(t.shape)

    def grid(a: NDArray[Any]) -> NDArray[Any]:  # reverse the axes whose values flip sign
        for i in flip_axes:
            a = np.flip(a, axis=i)
        return np.ascontiguousarray(a)

    def vec(a: NDArray[Any], src: NDArray[np.intp], sign: NDArray[np.float64], axis: int) -> NDArray[Any]:
        a = np.take(a, src, axis=nd + axis)
        shape = [1] * a.ndim
        shape[nd + axis] = len(sign)
        return a * sign.reshape(shape)

    def bounds(lo: NDArray[Any], hi: NDArray[Any], src: NDArray[np.intp], sign: NDArray[np.float64]
               ) -> tuple[NDArray[Any], NDArray[Any]]:
        a, b = vec(lo, src, sign, 0), vec(hi, src, sign, 0)
        neg = (sign < 0).reshape((1,) * nd + (-1,))
        return np.where(neg, b, a), np.where(neg, a, b)

    def active(code: NDArray[Any], src: NDArray[np.intp], sign: NDArray[np.float64]) -> NDArray[Any]:
        c = np.take(code, src, axis=nd)
        neg = (sign < 0).reshape((1,) * nd + (-1,))
        return np.where(neg & (np.abs(c) == 1), -c, c).astype(code.dtype)

    A = {k: np.asarray(v) for k, v in t.arrays.items()}
    out: dict[str, NDArray[Any]] = {}
    out["x"] = vec(A["x"], vs, vsign, 0)
    out["lbx"], out["ubx"] = bounds(A["lbx"], A["ubx"], vs, vsign)
    out["lam_x"] = vec(A["lam_x"], vs, vsign, 0)
    out["grad_f"] = vec(A["grad_f"], vs, vsign, 0)
    out["p"] = vec(A["p"], ps, psign, 0)
    out["trust_radius"] = vec(A["trust_radius"], ps, np.abs(psign), 0)
    out["trust_unverified"] = vec(A["trust_unverified"], ps, np.abs(psign), 0)
    out["g"] = vec(A["g"], gs, gsign, 0)
    out["lbg"], out["ubg"] = bounds(A["lbg"], A["ubg"], gs, gsign)
    out["lam_g"] = vec(A["lam_g"], gs, gsign, 0)
    out["jac_g_x"] = vec(vec(A["jac_g_x"], gs, gsign, 0), vs, vsign, 1)
    out["jac_g_p"] = vec(vec(A["jac_g_p"], gs, gsign, 0), ps, psign, 1)
    out["hess_lag"] = vec(vec(A["hess_lag"], vs, vsign, 0), vs, vsign, 1)
    out["hess_lag_xp"] = vec(vec(A["hess_lag_xp"], vs, vsign, 0), ps, psign, 1)
    out["dx_dp"] = vec(vec(A["dx_dp"], vs, vsign, 0), ps, psign, 1)
    one = np.ones(len(wheels))
    out["wrench"] = vec(vec(A["wrench"], ws, one, 0), np.arange(6), _WRENCH_SIGN, 1)
    out["wrench_jac"] = vec(vec(vec(A["wrench_jac"], ws, one, 0), np.arange(6), _WRENCH_SIGN, 1), np.arange(5), _STATE_SIGN, 2)
    out["slip"] = vec(A["slip"], ws, one, 0)
    out["slip_angle"] = vec(A["slip_angle"], ws, -one, 0)
    out["torque"] = vec(A["torque"], ws, one, 0)
    out["power"] = vec(A["power"], ws, one, 0)
    # controllers (4, wheels, (d rim, d steer)) per unit offset: Mz+ of the mirror is -(mirrored Mz-)
    c = vec(vec(A["controllers"], ws, one, 1), np.arange(2), np.array([1.0, -1.0]), 2)
    order = [CONTROLLER_NAMES.index(n) for n in ("Mz-", "Mz+", "Fy-", "Fy+")]
    out["controllers"] = -np.take(c, order, axis=nd)
    out["objective"] = A["objective"]
    out["status"] = A["status"]
    out["active_x"] = active(A["active_x"], vs, vsign)
    out["active_g"] = active(A["active_g"], gs, gsign)
    shape = t.shape

    def flat_index(k: int) -> int:  # a grid point's flat index in the mirror
        idx = list(np.unravel_index(int(k), shape))
        for i in flip_axes:
            idx[i] = shape[i] - 1 - idx[i]
        return int(np.ravel_multi_index(tuple(idx), shape))

    for k, v in A.items():  # the builder's per-point diagnostics
        if k in out:
            continue
        if k == "controller_source" and v.shape == shape + (len(CONTROLLER_NAMES),):
            out[k] = np.take(v, order, axis=nd)
        elif k in ("polished_from", "retried_from") and v.shape == shape:
            out[k] = np.vectorize(lambda i: flat_index(i) if i >= 0 else i, otypes=[v.dtype])(v) if v.size else v
        elif v.shape[:nd] == shape and v.ndim == nd:
            out[k] = v
        else:
            raise MirrorError(f"table {t.name}: array {k!r} of shape {v.shape} has no known mirror")
    arrays = {k: grid(np.asarray(v)) for k, v in out.items()}

    hm = copy.deepcopy(h)
    name = mirror_name(t.name, wmap)
    hm["name"] = name
    hm["description"] = f"Left-right mirror of table {t.name} (rtctl.mirror): {h.get('description', '')}"
    hm["mirror_of"] = {"name": t.name, "content_hash": h.get("content_hash")}
    for k in _FLIPPED_AXES:
        if k in hm.get("axes", {}):
            hm["axes"][k]["values"] = [-float(v) for v in reversed(hm["axes"][k]["values"])]
    fam = hm.get("family")
    if isinstance(fam, dict) and fam.get("wheel") in wmap:
        fam["wheel"] = wmap[fam["wheel"]]
    scm = hm.get("scenario")
    if isinstance(scm, dict):
        scm["name"] = name
        for key in ("cross_slope", "fy_offset", "mz_offset"):
            if isinstance(scm.get(key), (int, float)):
                scm[key] = -float(scm[key])
        fails = scm.get("failures")
        if isinstance(fails, dict):
            new = {}
            for w, f in fails.items():
                if isinstance(f, dict):
                    f = dict(f)
                    lo, hi = f.get("steer_min"), f.get("steer_max")
                    if isinstance(lo, (int, float)) and isinstance(hi, (int, float)):
                        f["steer_min"], f["steer_max"] = -float(hi), -float(lo)
                    if isinstance(f.get("steer_stuck"), (int, float)):
                        f["steer_stuck"] = -float(f["steer_stuck"])
                new[wmap.get(w, w)] = f
            scm["failures"] = new
    recs = hm.get("failures")  # the failure description (rtctl.failures): wheels swapped, values by their kind's rule
    if isinstance(recs, list):
        fk = hm.get("failure_kinds")
        kinds: dict[str, Any] = fk if isinstance(fk, dict) else {}
        new_recs = []
        for r in recs:
            if isinstance(r, dict):
                r = dict(r)
                w0 = str(r.get("wheel"))
                r["wheel"] = wmap.get(w0, w0)
                kd = kinds.get(str(r.get("kind")))
                mv = kd.get("mirror_value") if isinstance(kd, dict) else None
                if isinstance(r.get("value"), (int, float)) and isinstance(mv, (int, float)):
                    r["value"] = float(mv) * float(r["value"])
                if isinstance(r.get("text"), str):  # the text names the original's value: say so (twice = back)
                    txt = r["text"]
                    r["text"] = txt[len("mirror of: "):] if txt.startswith("mirror of: ") else "mirror of: " + txt
            new_recs.append(r)
        hm["failures"] = new_recs
    task = hm.get("task")
    if isinstance(task, dict) and task.get("wheel") in wmap:
        hm["task"] = {**task, "wheel": wmap[task["wheel"]]}
    world = hm.get("world")
    if isinstance(world, dict):
        for key in ("wheel_radius_m", "shearing_radius_m", "steer_offset_rad"):
            wv = world.get(key)
            if isinstance(wv, list) and len(wv) == len(wheels):
                world[key] = [(-1.0 if key == "steer_offset_rad" else 1.0) * float(wv[int(j)]) for j in ws]
        ext = world.get("external_force")
        if isinstance(ext, dict):
            for key in ("fy_N", "mz_Nm"):
                if isinstance(ext.get(key), (int, float)):
                    ext[key] = -float(ext[key])
    hm["evidence"] = {str(flat_index(int(k))): v for k, v in (h.get("evidence") or {}).items()}
    hm.pop("content_hash", None)
    hm["content_hash"] = content_hash(hm, arrays)
    return Table(hm, arrays, source=f"mirror of {t.source}")
