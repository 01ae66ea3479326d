"""The balance of any rover file's suspension (rtctl.physics.suspension) as physics:

* the mini rover's file gives FourWheelRocker's rows (numpy and casadi, raised wheels, pull);
* an independent free-body computation written here (explicit 3-D positions, rotation matrices,
  link angles found by root finding, cross products, moments projected on the pivot axes, the
  rigid frame's plane by least squares) gives the same rows for all three suspension kinds and
  for randomly perturbed geometries;
* virtual work: every passive-joint row and the whole-rover moment rows are (minus) the
  generalised forces of their joint motions, by central finite differences of the work of the
  wheel wrenches and the weight (this derives the differential's coupling independently);
* limits and symmetry: a MER-class rover standing on flat ground with equal loads is balanced;
  the left-right mirror image mirrors the rows; casadi's exact derivatives equal finite
  differences of the numpy rows.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from offline.physics.backend import CASADI, NUMPY
from offline.physics.params import ROVER_MINI_T72
from rtctl.physics.rover_file import LinkSpec, RoverSpec, WheelSpec, shipped_rover
from rtctl.physics.statics import FourWheelRocker
from rtctl.physics.suspension import SuspensionStatics

ROVERS = ("mini_rover_t72", "mer_class_rocker_bogie", "skid_steer_4w")
TOL_ROW_ABS = 1e-12  # N, N m: the same balance by two computations (rounding only)


# ----------------------------------------------------------------------------- independent free body
def Rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def Ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def Rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class FreeBody:
    """The rover's geometry and free bodies, computed without the code under test."""

    def __init__(self, rover: RoverSpec, rs=None):
        self.rv = rover
        self.rs = rs
        self.links = {lk.name: lk for lk in rover.links}
        self.wheels = {w.name: w for w in rover.wheels}

    def side(self, link):
        return "right" if self.links[link].pivot[1] < 0 else "left"

    def rockers(self):
        return {self.side(n): n for n, lk in self.links.items() if lk.parent == "body"}

    def subtree(self, link):
        out = [w for w, s in self.wheels.items() if s.link == link]
        for n, lk in self.links.items():
            if lk.parent == link:
                out += self.subtree(n)
        return out

    def angles(self, h):
        """Absolute nose-up angle of every link (root finding) and of the body."""
        z = {w: (self.rs[w] if self.rs else 0.0) - h[w] for w in self.wheels}
        ang, pivot_z = {}, {}

        def solve(link):
            lk = self.links[link]
            sup = [(np.array(s.position), z[n]) for n, s in self.wheels.items() if s.link == link]
            for n, ch in self.links.items():
                if ch.parent == link:
                    solve(n)
                    sup.append((np.array(ch.pivot), pivot_z[n]))
            (pa, za), (pb, zb) = sup
            f = lambda phi: (Ry(-phi) @ (pa - pb))[2] - (za - zb)  # noqa: E731
            phi = brentq(f, -1.2, 1.2, xtol=1e-16, rtol=4 * np.finfo(float).eps)
            ang[link] = phi
            pivot_z[link] = za - (Ry(-phi) @ (pa - np.array(lk.pivot)))[2]

        for n, lk in self.links.items():
            if lk.parent == "body":
                solve(n)
        kind = self.rv.suspension
        if kind == "rocker":
            body = ang[self.rv.body_fixed_to]
        elif kind == "rocker_bogie":
            r = self.rockers()
            body = 0.5 * (ang[r["right"]] + ang[r["left"]])
        else:
            A = np.array([[1.0, s.position[0], s.position[1]] for s in self.wheels.values()])
            coef = np.linalg.lstsq(A, np.array([z[w] for w in self.wheels]), rcond=None)[0]
            body = math.asin(coef[1])
        return ang, body

    def place(self, ang, body):
        """Pivot points, wheel centres (with the angle each wheel turns with) and the centre of mass."""
        P = {}

        def pivot(link):
            if link not in P:
                lk = self.links[link]
                if lk.parent == "body":
                    P[link] = Ry(-body) @ np.array(lk.pivot)
                else:
                    par = self.links[lk.parent]
                    P[link] = pivot(lk.parent) + Ry(-ang[lk.parent]) @ (np.array(lk.pivot) - np.array(par.pivot))
            return P[link]

        pos, turn = {}, {}
        for n, s in self.wheels.items():
            if s.link == "body":
                pos[n], turn[n] = Ry(-body) @ np.array(s.position), body
            else:
                lk = self.links[s.link]
                pos[n] = pivot(s.link) + Ry(-ang[s.link]) @ (np.array(s.position) - np.array(lk.pivot))
                turn[n] = ang[s.link]
        for n in self.links:
            pivot(n)
        return P, pos, turn, Ry(-body) @ np.array(self.rv.centre_of_mass)

    def gravity(self, slope, cross):
        return Rx(cross).T @ Ry(-slope).T @ np.array([0.0, 0.0, -self.rv.weight])

    def rows(self, wr, beta, h, load, slope, cross, fyo, mzo, include_wheel_torque=True):
        ang, body = self.angles(h)
        P, pos, _, com = self.place(ang, body)
        g = self.gravity(slope, cross)
        f = {k: Rz(beta[k]) @ np.array(wr[k][:3]) for k in self.wheels}
        m = {k: Rz(beta[k]) @ np.array(wr[k][3:]) for k in self.wheels}
        force = sum(f.values()) + g
        moment = sum(np.cross(pos[k], f[k]) + m[k] for k in self.wheels) + np.cross(com, g)
        ey = np.array([0.0, 1.0, 0.0])

        def tau(link):  # the subtree's moment about the link's pivot axis
            return sum(ey @ (np.cross(pos[k] - P[link], f[k]) + (m[k] if include_wheel_torque else 0.0))
                       for k in self.subtree(link))

        out = {"Fx": force[0], "Fy": force[1] - fyo, "Fz": sum(load.values()) + g[2], "Mx": moment[0],
               "Mz": moment[2] - mzo}
        kind = self.rv.suspension
        if kind == "rocker":
            for side, n in self.rockers().items():
                out[f"My_{side}"] = tau(n) + (ey @ np.cross(com - P[n], g) if n == self.rv.body_fixed_to else 0.0)
        else:
            out["My"] = moment[1]
        if kind == "rocker_bogie":
            r = self.rockers()
            out["My_differential"] = tau(r["right"]) - tau(r["left"])
            for n, lk in self.links.items():
                if lk.parent != "body":
                    out[f"My_{n}"] = tau(n)
        return out

    def plane_residual(self, h):
        """Heights minus their least-squares plane (zero for a rigid frame's wheel centres)."""
        z = np.array([(self.rs[w] if self.rs else 0.0) - h[w] for w in self.wheels])
        A = np.array([[1.0, s.position[0], s.position[1]] for s in self.wheels.values()])
        return z - A @ np.linalg.lstsq(A, z, rcond=None)[0]


# ----------------------------------------------------------------------------- helpers
def _state(rover: RoverSpec, seed: int, scale: float = 1.0):
    rng = np.random.default_rng(seed)
    names = rover.wheel_names
    W = rover.weight / len(names)
    wr = {k: tuple(rng.normal(size=6) * np.array([0.3, 0.3, 1.0, 0.05, 0.05, 0.05]) * W * scale) for k in names}
    beta = {k: rng.normal(0, 0.4) for k in names}
    h = {k: rng.uniform(0.003, 0.04) for k in names}
    load = {k: rng.uniform(0.5, 1.5) * W for k in names}
    return rng, wr, beta, h, load


def _perturbed(rover: RoverSpec, seed: int) -> RoverSpec:
    """The same link tree with every pivot, wheel centre and the centre of mass moved at random
    (rocker pivots kept on one lateral axis, rigid wheel centres at one height)."""
    rng = np.random.default_rng(seed)
    d = 0.05 * max(abs(c) for w in rover.wheels for c in w.position)

    def j(v, keep_z=False):
        out = np.array(v) + rng.uniform(-d, d, 3)
        if keep_z:
            out[2] = v[2]
        return tuple(float(c) for c in out)

    rocker_shift = rng.uniform(-d, d, 3)
    links = []
    for lk in rover.links:
        if lk.parent == "body":
            p = np.array(lk.pivot) + np.array([rocker_shift[0], rng.uniform(-d, d), rocker_shift[2]])
            links.append(dataclasses.replace(lk, pivot=tuple(float(c) for c in p)))
        else:
            links.append(dataclasses.replace(lk, pivot=j(lk.pivot)))
    wheels = [dataclasses.replace(w, position=j(w.position, keep_z=rover.suspension == "rigid")) for w in rover.wheels]
    com = j(rover.centre_of_mass)
    return dataclasses.replace(rover, links=tuple(links), wheels=tuple(wheels), centre_of_mass=com)


# ----------------------------------------------------------------------------- the mini rover
@pytest.mark.parametrize("seed", range(8))
def test_mini_rover_file_reproduces_four_wheel_rocker(seed):
    st = SuspensionStatics(shipped_rover("mini_rover_t72"))
    ref = FourWheelRocker(ROVER_MINI_T72)
    rng, wr, beta, h, load = _state(st.rover, seed, scale=3.0)
    contact = {k: float(rng.random() > 0.3) for k in st.wheels} if seed % 2 else None
    ext = tuple(rng.normal(size=3)) if seed % 3 == 0 else None
    args = (wr, beta, h, load, rng.uniform(-0.4, 0.4), rng.normal(), rng.normal(), rng.uniform(-0.3, 0.3), contact, ext)
    a = st.balance(NUMPY, *args)
    b = ref.balance(NUMPY, *args)
    assert tuple(a) == tuple(b) == st.balance_names
    for n in a:
        assert a[n] == pytest.approx(b[n], abs=TOL_ROW_ABS), n
    for flag in (0.0, 1.0):
        assert st.pivot_rows(a, flag) == pytest.approx(ref.pivot_rows(b, flag), abs=TOL_ROW_ABS)
    c = st.balance(CASADI, *args)
    for n in a:
        assert float(c[n]) == pytest.approx(b[n], abs=TOL_ROW_ABS), n
    assert st.wheel_velocity(NUMPY, 0.03, 0.2) == ref.wheel_velocity(NUMPY, 0.03, 0.2)


def test_mini_rover_without_wheel_torque_in_pitch():
    st = SuspensionStatics(shipped_rover("mini_rover_t72"), pitch_includes_wheel_torque=False)
    ref = FourWheelRocker(ROVER_MINI_T72, pitch_includes_wheel_torque=False)
    _, wr, beta, h, load = _state(st.rover, 3)
    a = st.balance(NUMPY, wr, beta, h, load, 0.1, 0.0, 0.0)
    b = ref.balance(NUMPY, wr, beta, h, load, 0.1, 0.0, 0.0)
    for n in a:
        assert a[n] == pytest.approx(b[n], abs=TOL_ROW_ABS), n


# ----------------------------------------------------------------------------- independent free body
@pytest.mark.parametrize("name", ROVERS)
@pytest.mark.parametrize("seed", range(4))
def test_rows_equal_an_independent_free_body(name, seed):
    rover = shipped_rover(name) if seed < 2 else _perturbed(shipped_rover(name), seed)
    rs = None if seed % 2 == 0 else {w: 0.06 + 0.01 * i for i, w in enumerate(rover.wheel_names)}
    st = SuspensionStatics(rover, shearing_radius=rs)
    fb = FreeBody(rover, rs)
    rng, wr, beta, h, load = _state(rover, 100 + seed)
    slope, cross, fyo, mzo = rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.normal(), rng.normal()
    a = st.balance(NUMPY, wr, beta, h, load, slope, fyo, mzo, cross)
    b = fb.rows(wr, beta, h, load, slope, cross, fyo, mzo)
    scale = rover.weight * max(abs(c) for w in rover.wheels for c in w.position)
    for n in b:
        assert a[n] == pytest.approx(b[n], abs=TOL_ROW_ABS * max(1.0, scale)), n
    extra = set(a) - set(b)
    assert extra == {n for n in a if n.startswith("height_compatibility")}
    if rover.suspension == "rigid":
        # the compatibility rows are an orthonormal basis of the heights' distance from a plane
        c = np.array([a[n] for n in sorted(extra)])
        assert len(c) == len(rover.wheels) - 3
        assert np.linalg.norm(c) == pytest.approx(np.linalg.norm(fb.plane_residual(h)), rel=1e-12)


def test_rigid_compatibility_is_zero_exactly_on_a_plane():
    rover = shipped_rover("skid_steer_4w")
    st = SuspensionStatics(rover)
    rng = np.random.default_rng(5)
    for _ in range(5):
        z0, pitch, roll = rng.uniform(-0.02, 0.02), rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2)
        R = Ry(-pitch) @ Rx(roll)
        # wheel centres of a rigid frame in a pitched and rolled pose: heights from the pose
        h = {w.name: -(z0 + (R @ np.array(w.position))[2]) for w in rover.wheels}
        rows = st.balance(NUMPY, {k: (0.0,) * 6 for k in st.wheels}, {k: 0.0 for k in st.wheels}, h,
                          {k: 0.0 for k in st.wheels}, 0.0, 0.0, 0.0)
        assert abs(rows["height_compatibility_0"]) < 1e-15
        # roll neglected, the body pitch is the plane's slope along x at zero roll
        _, body = st.link_angles(NUMPY, h)
        if abs(roll) < 1e-12:
            assert body == pytest.approx(pitch, abs=1e-12)
        h["FR"] += 1e-3  # one wheel 1 mm deeper: off the plane by the projection of that step
        rows = st.balance(NUMPY, {k: (0.0,) * 6 for k in st.wheels}, {k: 0.0 for k in st.wheels}, h,
                          {k: 0.0 for k in st.wheels}, 0.0, 0.0, 0.0)
        assert abs(rows["height_compatibility_0"]) == pytest.approx(0.5e-3, rel=1e-9)  # rectangle: (1,-1,-1,1)/2


def test_rigid_pitch_from_the_plane():
    rover = shipped_rover("skid_steer_4w")
    st = SuspensionStatics(rover)
    pitch = 0.07
    h = {w.name: -(Ry(-pitch) @ np.array(w.position))[2] for w in rover.wheels}
    _, body = st.link_angles(NUMPY, h)
    assert body == pytest.approx(pitch, abs=1e-14)


# ----------------------------------------------------------------------------- virtual work
def _virtual_work(fb: FreeBody, ang, body, f, m, g, motion):
    """Work of the wheel forces (at the centres), the wheel moments and the weight at a
    configuration given by ``motion(ang, body) -> (ang, body, R_extra, rotation_vector)``: R_extra
    rotates everything about O afterwards (about x or z, for the roll and yaw rows)."""
    ang2, body2, R, rot = motion(dict(ang), body)
    _, pos, turn, com = fb.place(ang2, body2)
    _, _, turn0, _ = fb.place(ang, body)
    # a nose-up turn by d is a rotation by -d about +y; ``rot`` the rotation vector of R
    w = sum(f[k] @ (R @ pos[k]) - m[k][1] * (turn[k] - turn0[k]) + m[k] @ rot for k in pos) + g @ (R @ com)
    return w


@pytest.mark.parametrize("name", ROVERS)
def test_rows_are_generalised_forces_of_the_joint_motions(name):
    """Central finite differences of the virtual work (eps = 1e-6 rad) against the rows: the
    passive joints' rows, the whole rover's roll, pitch and yaw."""
    rover = _perturbed(shipped_rover(name), 7)
    st, fb = SuspensionStatics(rover), FreeBody(rover)
    rng, wr, beta, h, load = _state(rover, 21)
    slope, cross = 0.2, -0.1
    rows = st.balance(NUMPY, wr, beta, h, load, slope, 0.0, 0.0, cross)
    ang, body = fb.angles(h)
    f = {k: Rz(beta[k]) @ np.array(wr[k][:3]) for k in rover.wheel_names}
    m = {k: Rz(beta[k]) @ np.array(wr[k][3:]) for k in rover.wheel_names}
    g = fb.gravity(slope, cross)
    eps = 1e-6
    eye = np.eye(3)
    zero3 = np.zeros(3)

    def turn_links(names, d, body_d=0.0):
        def motion(a, b):
            for n in names:
                a[n] += d
            return a, b + body_d, eye, zero3
        return motion

    def gen(make):
        return (_virtual_work(fb, ang, body, f, m, g, make(eps)) - _virtual_work(fb, ang, body, f, m, g, make(-eps))) / (2 * eps)

    # a rotation of the whole rover about O: x (roll), y (nose down = -pitch), z (yaw)
    m_tot = {"Mx": gen(lambda d: (lambda a, b: (a, b, Rx(d), np.array([d, 0.0, 0.0])))),
             "Mz": gen(lambda d: (lambda a, b: (a, b, Rz(d), np.array([0.0, 0.0, d]))))}
    expected = {"Mx": m_tot["Mx"], "Mz": m_tot["Mz"]}
    everything = list(fb.links)
    pitch_all = -gen(lambda d: turn_links(everything, d, d))
    kind = rover.suspension
    if kind == "rocker":
        r = fb.rockers()
        fixed = rover.body_fixed_to
        free = r["left"] if fixed == r["right"] else r["right"]
        P0, pos0, _, com0 = fb.place(ang, body)

        def about_axis(link, with_body, d):
            """Work after turning one rocker (and the body, if fixed to it) nose-up by d about
            the common pivot axis, the other rocker still."""
            R, point = Ry(-d), P0[link]
            out = 0.0
            for k, p in pos0.items():
                moved = k in fb.subtree(link)
                out += f[k] @ (point + R @ (p - point) if moved else p) - (m[k][1] * d if moved else 0.0)
            return out + g @ (point + R @ (com0 - point) if with_body else com0)

        for link, with_body in ((free, False), (fixed, True)):
            q = (about_axis(link, with_body, eps) - about_axis(link, with_body, -eps)) / (2 * eps)
            expected[f"My_{fb.side(link)}"] = -q
        # together: the whole rover's pitch about the common pivot axis (not about O, when the
        # axis misses O and the net force is not zero)
        P = fb.place(ang, body)[0][fixed]
        net = sum(f.values()) + g
        assert rows["My_right"] + rows["My_left"] == pytest.approx(pitch_all - (P[2] * net[0] - P[0] * net[2]), rel=1e-7, abs=1e-9)
    else:
        expected["My"] = pitch_all
    if kind == "rocker_bogie":
        r = fb.rockers()
        # the differential: right rocker (and its bogie) nose up, left nose down, body still
        def diff(d):
            def motion(a, b):
                for n in [r["right"], *[x for x in fb.links if fb.links[x].parent == r["right"]]]:
                    a[n] += d
                for n in [r["left"], *[x for x in fb.links if fb.links[x].parent == r["left"]]]:
                    a[n] -= d
                return a, b, eye, zero3
            return motion
        expected["My_differential"] = -gen(diff)
        for n, lk in fb.links.items():
            if lk.parent != "body":
                expected[f"My_{n}"] = -gen(lambda d, n=n: turn_links([n], d))
    scale = rover.weight * 1.0
    for n, v in expected.items():
        assert rows[n] == pytest.approx(v, rel=1e-6, abs=1e-7 * scale), n


# ----------------------------------------------------------------------------- limits, symmetry, derivatives
def test_mer_class_standing_on_flat_ground_with_equal_loads_is_balanced():
    """Centre of mass over the rocker pivot axis, bogie pivots midway, front lever twice the
    bogie's: a sixth of the weight on each wheel balances every row (file comments)."""
    rover = shipped_rover("mer_class_rocker_bogie")
    st = SuspensionStatics(rover)
    W6 = rover.weight / 6
    wr = {k: (0.0, 0.0, W6, 0.0, 0.0, 0.0) for k in st.wheels}
    zero = {k: 0.0 for k in st.wheels}
    rows = st.balance(NUMPY, wr, zero, {k: 0.01 for k in st.wheels}, {k: W6 for k in st.wheels}, 0.0, 0.0, 0.0)
    for n, v in rows.items():
        assert abs(v) < 1e-12, (n, v)
    # moving the load from the rear to the front wheel unbalances the bogie and the rocker alike
    wr["RR"] = (0.0, 0.0, W6 - 1.0, 0.0, 0.0, 0.0)
    wr["RF"] = (0.0, 0.0, W6 + 1.0, 0.0, 0.0, 0.0)
    rows = st.balance(NUMPY, wr, zero, {k: 0.01 for k in st.wheels}, {k: W6 for k in st.wheels}, 0.0, 0.0, 0.0)
    assert rows["My_bogie_right"] == pytest.approx(-0.325, abs=1e-12)  # +1 N at the rear, 0.325 m behind the pivot
    assert rows["My_differential"] == pytest.approx(-(0.65 + 0.65), abs=1e-12)


def test_mer_class_mirror_image():
    st = SuspensionStatics(_perturbed(shipped_rover("mer_class_rocker_bogie"), 3))
    mirror_rv = dataclasses.replace(
        st.rover,
        links=tuple(dataclasses.replace(lk, pivot=(lk.pivot[0], -lk.pivot[1], lk.pivot[2])) for lk in st.rover.links),
        wheels=tuple(dataclasses.replace(w, position=(w.position[0], -w.position[1], w.position[2])) for w in st.rover.wheels),
        centre_of_mass=(st.rover.centre_of_mass[0], -st.rover.centre_of_mass[1], st.rover.centre_of_mass[2]))
    sm = SuspensionStatics(mirror_rv)
    rng, wr, beta, h, load = _state(st.rover, 8)
    flip = np.array([1, -1, 1, -1, 1, -1])
    a = st.balance(NUMPY, wr, beta, h, load, 0.1, 0.3, 0.2, -0.15)
    b = sm.balance(NUMPY, {k: tuple(flip * np.array(v)) for k, v in wr.items()}, {k: -v for k, v in beta.items()}, h, load,
                   0.1, -0.3, -0.2, 0.15)
    # the mirror rover's right rocker is the original's left one (link names kept)
    for n in ("Fx", "Fz", "My"):
        assert b[n] == pytest.approx(a[n], abs=1e-12), n
    for n in ("Fy", "Mx", "Mz", "My_differential"):
        assert b[n] == pytest.approx(-a[n], abs=1e-12), n
    assert b["My_bogie_right"] == pytest.approx(a["My_bogie_right"], abs=1e-12)


@pytest.mark.parametrize("name", ROVERS)
def test_casadi_graph_equals_numpy_and_its_derivatives_equal_finite_differences(name):
    import casadi as ca

    st = SuspensionStatics(_perturbed(shipped_rover(name), 11))
    rng, wr, beta, h, load = _state(st.rover, 31)
    names = st.wheels
    hs = ca.SX.sym("h", len(names))
    bs = ca.SX.sym("beta", len(names))
    sl = ca.SX.sym("slope")
    rows = st.balance(CASADI, wr, {k: bs[i] for i, k in enumerate(names)}, {k: hs[i] for i, k in enumerate(names)},
                      load, sl, 0.3, -0.2, 0.1)
    g = ca.vertcat(*rows.values())
    fun = ca.Function("g", [hs, bs, sl], [g, ca.jacobian(g, ca.vertcat(hs, bs, sl))])
    x_h = np.array([h[k] for k in names])
    x_b = np.array([beta[k] for k in names])
    val, jac = fun(x_h, x_b, 0.12)

    def numpy_rows(xh, xb, s):
        r = st.balance(NUMPY, wr, dict(zip(names, xb)), dict(zip(names, xh)), load, s, 0.3, -0.2, 0.1)
        return np.array(list(r.values()), dtype=float)

    assert np.asarray(val).ravel() == pytest.approx(numpy_rows(x_h, x_b, 0.12), abs=1e-11)
    x = np.concatenate([x_h, x_b, [0.12]])
    n = len(names)
    fd = np.empty((len(rows), len(x)))
    for j in range(len(x)):
        step = 1e-7 if j < n else 1e-6
        xp, xm = x.copy(), x.copy()
        xp[j] += step
        xm[j] -= step
        fd[:, j] = (numpy_rows(xp[:n], xp[n:2 * n], xp[-1]) - numpy_rows(xm[:n], xm[n:2 * n], xm[-1])) / (2 * step)
    J = np.asarray(jac)
    assert np.abs(J - fd).max() <= 1e-5 * max(1.0, np.abs(J).max())


def test_batched_numpy_columns_equal_single_states():
    st = SuspensionStatics(shipped_rover("mer_class_rocker_bogie"))
    states = [_state(st.rover, s) for s in range(4)]
    col = lambda key, k: np.array([[s[key][k]] for s in states])  # noqa: E731
    wr = {k: tuple(np.array([[s[1][k][i]] for s in states]) for i in range(6)) for k in st.wheels}
    beta = {k: np.array([[s[2][k]] for s in states]) for k in st.wheels}
    h = {k: np.array([[s[3][k]] for s in states]) for k in st.wheels}
    load = {k: np.array([[s[4][k]] for s in states]) for k in st.wheels}
    del col
    batch = st.balance(NUMPY, wr, beta, h, load, 0.1, 0.0, 0.0)
    for i, (_, w1, b1, h1, l1) in enumerate(states):
        one = st.balance(NUMPY, w1, b1, h1, l1, 0.1, 0.0, 0.0)
        for n in one:
            assert batch[n][i, 0] == pytest.approx(one[n], abs=1e-12)


def test_raised_wheels_only_for_the_rocker():
    st = SuspensionStatics(shipped_rover("mer_class_rocker_bogie"))
    _, wr, beta, h, load = _state(st.rover, 1)
    with pytest.raises(ValueError, match="implemented for the 'rocker' suspension only"):
        st.balance(NUMPY, wr, beta, h, load, 0.0, 0.0, 0.0, contact={k: 1.0 for k in st.wheels})


def test_links_and_wheels_other_than_the_file_are_refused():
    rover = shipped_rover("mini_rover_t72")
    with pytest.raises(ValueError, match=r"shearing_radius has no value for wheel\(s\) \['RL'\]"):
        SuspensionStatics(rover, shearing_radius={"FR": 0.06, "FL": 0.06, "RR": 0.06})
    assert isinstance(rover.links[0], LinkSpec) and isinstance(rover.wheels[0], WheelSpec)


@pytest.mark.parametrize("seed", range(3))
def test_mini_rover_file_swaps_into_the_steady_state_rows(seed):
    """The rows and objective of (7.25) (rtctl.physics.steady_state.steady_state_rows, wheel model
    included) with the mini rover file's statics in place of FourWheelRocker: equal to 1e-12
    (raised wheel, locked pivot, cross slope, offsets, pull)."""
    from offline.rover.scenario import PARAM_PRESETS
    from rtctl.physics.steady_state import SteadyStateModel, steady_state_rows
    from rtctl.physics.terramechanics import ModelOptions, PhysParams

    ps = PARAM_PRESETS["dissertation-ch7"]
    wheels = ("FR", "FL", "RR", "RL")
    rs = ps.wheel.radius + ps.wheel.grouser_height
    phys = PhysParams.from_sets(ps.soil, ps.wheel, ps.tuning)
    ext = (0.3, -0.2, 0.05)
    ref = SteadyStateModel(wheels, (phys,) * 4, (rs,) * 4, ModelOptions(), FourWheelRocker(ROVER_MINI_T72), ps.soil,
                           external=ext, torque_scale=ROVER_MINI_T72.weight / 4 * rs)
    new = dataclasses.replace(ref, statics=SuspensionStatics(shipped_rover("mini_rover_t72")))
    rng = np.random.default_rng(seed)
    v = 0.03
    x = {k: (v / rs * rng.uniform(1.0, 1.4), rng.normal(0, 0.2), rng.uniform(5, 12), rng.uniform(0.005, 0.02),
             rng.uniform(0.005, 0.02)) for k in wheels}
    P = {"speed": v, "slope": rng.uniform(-0.2, 0.2), "cross_slope": rng.uniform(-0.1, 0.1), "fy_offset": rng.normal(),
         "mz_offset": rng.normal(), "pivot_locked": float(seed == 1),
         **{f"contact {k}": (0.0 if (seed == 2 and k == "RR") else 1.0) for k in wheels}}
    a_rows, a_f, _ = steady_state_rows(NUMPY, ref, x, P)
    b_rows, b_f, _ = steady_state_rows(NUMPY, new, x, P)
    val = lambda q: float(np.asarray(q, dtype=float).reshape(-1)[0])  # noqa: E731
    assert list(a_rows) == list(b_rows)
    for n in a_rows:
        assert val(b_rows[n]) == pytest.approx(val(a_rows[n]), abs=TOL_ROW_ABS), n
    assert val(b_f) == val(a_f)  # the objective does not involve the statics
