"""World terms the table builder takes (issue 14): external pull (tether, anchored cable),
per-wheel rim radius, per-wheel steering offset, and the discrepancy tool's truth file
(``--world accepted_truth.toml``) through to the table header and rtctl's commands.

Physics as physics: force and yaw balances with the pull (independent free-body balance),
the sign of the drive torque, the wheel speed of a smaller wheel, physical angles unchanged
by an encoder offset, a stuck angle given in encoder terms honoured physically. Small grids
(one point) so the module stays well under a minute.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from offline.physics.backend import NUMPY
from rtctl.physics.hub_drag import SPIN_SMOOTHING, HubFace, hub_wrench
from offline.rover.primitives import SolverOptions, _problem_for, solve_primitive
from offline.rover.scenario import ExternalForce, ScenarioError, load_scenario, scenario_with_world
from offline.rover.statics import FourWheelRocker, free_body_residuals
from offline.rover.table_builder import BuildOptions, build_table, encode, table_spec

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / "tables" / "scenarios" / "nominal.toml"
STUCK = ROOT / "tables" / "scenarios" / "rr_steer_stuck.toml"
FAST = BuildOptions(trust_steps=(0.0625,), trust_search=(0.0625, 1.0), polish_sweeps=0)


@pytest.fixture(scope="module")
def flat():
    """The nominal scenario on flat ground and its primitive."""
    sc = load_scenario(NOMINAL)
    r = solve_primitive(sc)
    assert r.ok
    return sc, r


def _rover_frame_forces(r):
    """Sum of the wheels' F_x, F_y in the rover frame (wheel wrenches turned by the steer angle)."""
    fx = fy = 0.0
    for w in r.wheels.values():
        c, s = math.cos(w.steer), math.sin(w.steer)
        fx += c * w.wrench[0] - s * w.wrench[1]
        fy += s * w.wrench[0] + c * w.wrench[1]
    return fx, fy


def _free_body(r, sc):
    """Independent free-body residuals (numpy, rotation matrices) of a primitive, pull included."""
    ext = None if sc.external is None else (sc.external.fx, sc.external.fy, sc.external.mz)
    ws = r.wheels
    return free_body_residuals(sc.rover, {k: w.wrench for k, w in ws.items()}, {k: w.steer for k, w in ws.items()},
                               {k: w.sinkage for k, w in ws.items()}, {k: w.load for k, w in ws.items()}, sc.slope,
                               sc.cross_slope, sc.fy_offset, sc.mz_offset, external=ext)


def test_tether_from_behind_is_balanced_by_more_drive_force_and_torque(flat):
    """A 2 N pull along -x: the wheels' net F_x equals the pull (force balance, flat ground), the
    free-body balance with the pull closes, every wheel needs more drive torque and slips more."""
    sc, r0 = flat
    st = replace(sc, external=ExternalForce.tether(2.0))
    r1 = solve_primitive(st)
    assert r1.ok
    fx, fy = _rover_frame_forces(r1)
    assert fx == pytest.approx(2.0, abs=1e-6 * sc.rover.weight)
    assert abs(fy) < 1e-6 * sc.rover.weight
    res = _free_body(r1, st)
    W, lr = sc.rover.weight, sc.rover.rocker_length
    for n, v in res.items():
        assert abs(v) <= 1e-6 * (W if n.startswith("F") else W * lr), (n, v)
    # the same primitive does not balance without the pull: the term is really in the NLP
    assert abs(_free_body(r1, sc)["Fx"]) == pytest.approx(2.0, rel=1e-6)
    for k in r0.wheels:
        assert r1.wheels[k].torque > r0.wheels[k].torque + 0.01
        assert r1.wheels[k].slip > r0.wheels[k].slip
    # a push from behind (negative tether) needs less torque than none: the sign is physical
    r2 = solve_primitive(replace(sc, external=ExternalForce.tether(-1.0)))
    assert r2.ok and all(r2.wheels[k].torque < r0.wheels[k].torque for k in r0.wheels)


def test_cable_at_a_bearing_has_the_yaw_moment_of_its_attachment(flat):
    """A cable pulling 2 N at 150 deg from the rover's heading from 0.1 m behind O: F_y = T sin(150
    deg) = 1 N and a yaw moment attach_x F_y about O (cross product, computed here). The wheels'
    net F_y, and their yaw moment about O, balance it (the independent free-body residuals)."""
    sc, _ = flat
    ext = ExternalForce.cable(2.0, math.radians(150.0), -0.1)
    r_att, f = np.array([-0.1, 0.0, 0.0]), np.array([2.0 * math.cos(math.radians(150.0)), 1.0, 0.0])
    assert ext.mz == pytest.approx(np.cross(r_att, f)[2], abs=1e-12)
    assert (ext.fx, ext.fy) == pytest.approx((f[0], f[1]), abs=1e-12)
    st = replace(sc, external=ext)
    r = solve_primitive(st)
    assert r.ok
    fx, fy = _rover_frame_forces(r)
    assert fx == pytest.approx(-ext.fx, abs=1e-6 * sc.rover.weight)
    assert fy == pytest.approx(-ext.fy, abs=1e-6 * sc.rover.weight)
    res = _free_body(r, st)
    assert abs(res["Mz"]) <= 1e-6 * sc.rover.weight * sc.rover.rocker_length
    # without the moment the yaw row is off by exactly attach_x F_y
    no_m = _free_body(r, replace(st, external=ExternalForce(ext.fx, ext.fy, 0.0)))
    assert no_m["Mz"] == pytest.approx(-ext.mz, rel=1e-6)


def test_balance_graph_is_unchanged_without_external_terms(flat):
    """The statics without ``external`` and with it None give the same rows (the NLP of every
    shipped table is the old one); with a pull only F_x, F_y and M_z change, by the pull."""
    sc, r = flat
    st = FourWheelRocker(sc.rover)
    ws = r.wheels
    args = ({k: w.wrench for k, w in ws.items()}, {k: w.steer for k, w in ws.items()},
            {k: w.sinkage for k, w in ws.items()}, {k: w.load for k, w in ws.items()}, 0.1, 0.0, 0.0, 0.05)
    a = st.balance(NUMPY, *args)
    b = st.balance(NUMPY, *args, None, (1.0, -2.0, 0.3))
    for n in a:
        d = {"Fx": 1.0, "Fy": -2.0, "Mz": 0.3}.get(n, 0.0)
        assert b[n] - a[n] == pytest.approx(d, abs=1e-12)
    enc = encode(sc)  # the table header's scenario record: no new keys at the defaults
    assert not {"external", "wheel_radius", "steer_offset"} & set(enc)
    assert {"external", "wheel_radius"} <= set(encode(replace(sc, external=ExternalForce.tether(1.0), wheel_radius=(0.05,) * 4)))


def test_smaller_wheel_spins_faster_at_about_the_same_slip(flat):
    """Equal radii reproduce the old primitive exactly. The RR wheel 7 % smaller: omega_RR grows by
    the shearing-radius ratio r_s / r_s' times (1 - s) / (1 - s'); a smaller wheel sinks deeper
    (eq. 5.6 over a shorter contact) and slips a little more, so the growth is above the radius
    ratio but within 5 % of it (the rover's total drawbar pull is unchanged); the wheel's slip is
    measured on its own radius (rim speed (1 - s) = travel speed cos(beta), eq. (5.1)); the other
    wheels change by under 2 %."""
    sc, r0 = flat
    r = sc.params.wheel.radius
    same = solve_primitive(replace(sc, wheel_radius=(r,) * 4))
    np.testing.assert_array_equal(same.x, r0.x)
    small = replace(sc, wheel_radius=(r, r, 0.93 * r, r))
    r1 = solve_primitive(small)
    assert r1.ok
    hg = sc.params.wheel.grouser_height
    ratio = (r + hg) / (0.93 * r + hg)
    a, b = r0.wheels["RR"], r1.wheels["RR"]
    got = b.omega / a.omega
    assert ratio < got < 1.05 * ratio
    assert got == pytest.approx(ratio * (1 - a.slip) / (1 - b.slip), rel=1e-6)
    assert b.sinkage > a.sinkage and b.slip > a.slip
    assert b.rim_speed == pytest.approx(b.omega * (0.93 * r + hg), rel=1e-12)
    assert b.rim_speed * (1 - b.slip) == pytest.approx(sc.speed * math.cos(b.steer), rel=1e-6)
    for k in ("FR", "FL", "RL"):
        assert r1.wheels[k].omega == pytest.approx(r0.wheels[k].omega, rel=0.02)


def test_steering_offset_leaves_physics_and_moves_encoder_failures(flat):
    """An offset changes nothing physical on flat ground (the NLP is the same), and a stuck angle
    given in encoder terms (-50 deg) holds the wheel at -50 + offset physically."""
    sc, r0 = flat
    d = math.radians(3.0)
    r1 = solve_primitive(replace(sc, steer_offset=(0.0, 0.0, d, 0.0)))
    assert r1.ok
    for k in r0.wheels:
        assert r1.wheels[k].steer == pytest.approx(r0.wheels[k].steer, abs=1e-7)
    stuck = load_scenario(STUCK)
    stuck = replace(stuck, slope=0.0, failures={"RR": replace(stuck.failure("RR"), steer_stuck=math.radians(-50.0))},
                    steer_offset=(0.0, 0.0, d, 0.0))
    r2 = solve_primitive(stuck)
    assert r2.ok
    assert r2.wheels["RR"].steer == pytest.approx(math.radians(-47.0), abs=1e-9)


def test_scenario_file_keys_and_their_errors(tmp_path):
    p = tmp_path / "w.toml"
    p.write_text('[scenario]\ntether_force_N = 1.5\n[tether]\ntension_N = 2.0\nbearing_deg = 90.0\nattach_x_m = -0.1\n'
                 '[wheels.RR]\nradius_mm = 54.0\nsteer_offset_deg = 2.0\n[wheels.FL]\nlocked = true\n')
    sc = load_scenario(p)
    assert sc.external.fx == pytest.approx(-1.5 + 2.0 * math.cos(math.pi / 2))
    assert sc.external.fy == pytest.approx(2.0) and sc.external.mz == pytest.approx(-0.2)
    assert sc.wheel_radius[2] == pytest.approx(0.054) and sc.steer_offset[2] == pytest.approx(math.radians(2.0))
    assert sc.failure("FL").locked and sc.failure("RR").nominal
    for text, msg in (("[scenario]\ntether_force_N = 5000\n", "newtons"),
                      ("[tether]\nbearing_deg = 10\n", "tension_N"),
                      ("[tether]\ntension_N = -1\n", "only pulls"),
                      ("[wheels.RR]\nradius_mm = 0.054\n", "millimetres"),
                      ("[wheels.RR]\nsteer_offset_deg = 45\n", "degrees")):
        p.write_text("[scenario]\n" + text.replace("[scenario]\n", ""))
        with pytest.raises(ScenarioError, match=msg):
            load_scenario(p)


def _accepted_truth(tmp_path: Path) -> Path:
    """accepted_truth.toml as the discrepancy tool writes it: a 2 N tether, RR 7 % smaller, RR
    steering offset 3 deg, an anchored cable."""
    from offline.discrepancy.drive.candidates import write_truth_toml
    from offline.sim.truth import Truth

    sc = load_scenario(NOMINAL)
    believed = Truth.nominal(sc.params, sc.rover)
    r = sc.params.wheel.radius
    truth = replace(believed, tether_force=2.0, wheel_radius=(r, r, 0.93 * r, r),
                    steer_offset=(0.0, 0.0, math.radians(3.0), 0.0))
    dist = {"anchor_tension_N": 0.5, "anchor_bearing_rad": math.radians(180.0), "anchor_inverse_distance_per_m": 0.2,
            "anchor_attach_x_m": -0.1, "hub_clearance_m": 0.004}
    params = str(ROOT / "offline" / "data" / "calibrated_grousered.toml")  # the scenario's parameter file
    return write_truth_toml(tmp_path / "accepted_truth.toml", params, truth, believed, {}, None,
                            {"test": "issue 14"}, dist)


def test_truth_file_carries_anchor_and_hub_sections(tmp_path):
    from offline.sim.truth import load_truth

    sc = load_scenario(NOMINAL)
    t = load_truth(_accepted_truth(tmp_path), sc.rover, sc.params)
    assert t.anchor == pytest.approx({"tension": 0.5, "bearing": math.pi, "inverse_distance": 0.2, "attach_x": -0.1})
    assert t.hub == pytest.approx({"clearance": 0.004})
    w = scenario_with_world(sc, t)
    assert w.external.fx == pytest.approx(-2.0 - 0.5) and w.external.mz == pytest.approx(0.0, abs=1e-12)
    # offnominal drive --truth applies both hooks (the anchored cable pulls back at the start)
    from offline.cli.sim import _truth_hooks
    from offline.discrepancy.drive.candidates import AnchoredTether, HubContact, Hooks

    hooks = _truth_hooks(t, sc.rover)
    assert isinstance(hooks, Hooks) and {type(h) for h in hooks.hooks} == {AnchoredTether, HubContact}
    anchor = next(h for h in hooks.hooks if isinstance(h, AnchoredTether))
    assert (anchor.tension, anchor.attach_x, anchor.inverse_distance) == pytest.approx((0.5, -0.1, 0.2))
    assert _truth_hooks(replace(t, anchor=None, hub=None), sc.rover) is None
    assert t.describe()["tether_anchor_SI"]["tension"] == pytest.approx(0.5)


def test_world_file_to_table_header_and_rtctl_commands(tmp_path, capsys):
    """End to end: accepted_truth.toml -> a one-point table built with ``--world`` -> header shows
    the terms; the primitive drives harder than nominal (the tether), the small RR wheel spins
    faster; rtctl commands rim speed omega_i r_s (the command radius; the per-wheel radii serve its
    odometry) and steer beta - offset, and reads encoders + offset."""
    from offline.cli import main
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.messages import Measurements
    from rtctl.table import load_table

    truth = _accepted_truth(tmp_path)
    out = tmp_path / "tables"
    assert main(["tables", "build", str(NOMINAL), "--grid", "slope=0;cross_slope=0;speed=3", "--world", str(truth),
                 "--out", str(out), "--quiet", "--no-index"]) == 0
    t = load_table(out / "nominal.npz")
    world = t.header["world"]
    r = load_scenario(NOMINAL).params.wheel.radius
    hg = load_scenario(NOMINAL).params.wheel.grouser_height
    assert world["wheel_radius_m"][2] == pytest.approx(0.93 * r)
    assert world["steer_offset_rad"] == pytest.approx([0.0, 0.0, math.radians(3.0), 0.0])
    assert world["external_force"]["fx_N"] == pytest.approx(-2.5)
    assert t.header["sources"]["world_file"]["name"] == "accepted_truth.toml"
    assert main(["tables", "info", str(out / "nominal.npz")]) == 0
    assert "world terms: rim radius" in capsys.readouterr().out
    # the stored Jacobians are those of each wheel's own model (radius) and of the NLP with the pull
    from offline.rover.table_verify import check_jacobians, spec_from_table

    errs = check_jacobians(t, spec_from_table(t), [0])
    assert max(errs.values()) < 1e-5, errs
    tp = t.at(slope=0.0, cross_slope=0.0, speed=0.03)
    nom = solve_primitive(replace(load_scenario(NOMINAL), speed=0.03))
    lay = t.layout
    om = np.array([tp.x[lay.var("omega", k)] for k in lay.wheels])
    assert np.all(tp.torque > np.array([w.torque for w in nom.wheels.values()]) + 0.01)
    assert om[2] / nom.wheels["RR"].omega > 1.04
    # rtctl: per-wheel radius and offset from the header
    c = Controller({"w": t}, ControllerConfig())
    rs = np.array(world["shearing_radius_m"])
    np.testing.assert_allclose(c.wheel_radii, rs)
    beta = np.array([tp.x[lay.var("beta", k)] for k in lay.wheels])
    enc = tuple((beta - np.array(world["steer_offset_rad"])).tolist())
    cmd, d = c.step(Measurements(t=0.2, seq=1, wheel_speed=tuple(om.tolist()), steer_angle=enc, yaw_rate=0.0))
    assert d.mode == "qp"
    # rim-speed commands use the command radius (the parameter set's wheel, as the rover's software
    # and the simulator's actuator convert them), not the worn wheel's own radius
    assert c.wheel_radius == pytest.approx(r + hg) and c.wheel_radius != pytest.approx(rs[2])
    np.testing.assert_allclose(cmd.rim_speed, om * (r + hg), rtol=2e-3)
    # closed loop: the simulator's actuator (the rover's conversion) turns them into the table's omega,
    # the worn RR wheel included
    from offline.sim.actuators import ActuatorConfig, Actuators

    act = Actuators(ActuatorConfig(max_rim_speed=1.0), {}, load_scenario(NOMINAL).params.wheel.shearing_radius)
    act.command(cmd.rim_speed, cmd.steer_angle)
    np.testing.assert_allclose(act.omega_cmd, om, rtol=2e-3)
    np.testing.assert_allclose(cmd.steer_angle, enc, atol=2e-3)
    assert cmd.steer_angle[2] == pytest.approx(beta[2] - math.radians(3.0), abs=2e-3)
    assert abs(rs[2] - (0.93 * r + hg)) < 1e-12


# ------------------------------------------------------------------ hub contact
HUB = HubFace(clearance=0.006, face_width=0.02, arm=0.02)
"""A face 6 mm above the rim's lowest point, 20 mm wide, 20 mm lever: the nominal primitive sinks
7.5-8.4 mm, so every wheel bulldozes 1.5-2.4 mm of soil."""


@pytest.fixture(scope="module")
def hub(flat):
    """The nominal scenario with :data:`HUB` on every wheel and its primitive."""
    sc, _ = flat
    sh = replace(sc, hub_contact=HUB)
    r = solve_primitive(sh)
    assert r.ok, r.status
    return sh, r


def test_hub_contact_below_the_sinkage_needs_more_torque_and_balances_its_drag(flat, hub):
    """Every wheel sinks past the clearance: each needs more drive torque than without the face;
    the free-body balance closes with the drag in the wheel wrenches, and without it the wheels'
    net F_x is exactly the total Rankine drag (the wheels push the faces through the soil); the
    drag is the simulator hook's (HubContact) at the same sinkage."""
    from offline.discrepancy.drive.candidates import HubContact

    sc, r0 = flat
    sh, r1 = hub
    for k in r0.wheels:
        assert r1.wheels[k].sinkage > HUB.clearance + 1e-3
        assert r1.wheels[k].torque > r0.wheels[k].torque + 0.005, k
    W, lr = sc.rover.weight, sc.rover.rocker_length
    for n, v in _free_body(r1, sh).items():
        assert abs(v) <= 1e-6 * (W if n.startswith("F") else W * lr), (n, v)
    pb = _problem_for(sh, SolverOptions())
    soil_only = {}
    for k, w in r1.wheels.items():
        vx, vy = pb.statics.wheel_velocity(NUMPY, sh.speed, w.steer)
        soil_only[k] = tuple(float(np.ravel(q)[0]) for q in pb.model_of[k].wrench(vx, vy, w.omega, w.sinkage, w.sinkage_zero_slip).as_array())
    ws = r1.wheels
    bare = free_body_residuals(sh.rover, soil_only, {k: w.steer for k, w in ws.items()}, {k: w.sinkage for k, w in ws.items()},
                               {k: w.load for k, w in ws.items()}, sh.slope, sh.cross_slope)
    sim = HubContact(HUB.clearance, HUB.face_width, HUB.arm, sh.params.soil, sh.rover)
    drag = sim.force(np.array([w.sinkage for w in ws.values()]))
    assert drag.sum() > 0.5
    # the NLP's smooth depth exceeds the exact one by eps^2 / (4 d) < 2 um at d >= 1.5 mm: < 0.1 % of F
    assert bare["Fx"] == pytest.approx(drag.sum(), rel=1e-3)
    # the motor torque carries the face's torque on top of the soil's: -M_y,soil + F arm sgn(omega)
    # (sgn smoothed over SPIN_SMOOTHING, as in the simulator hook)
    for i, (k, w) in enumerate(ws.items()):
        spin = w.omega / math.hypot(w.omega, SPIN_SMOOTHING)
        assert w.torque == pytest.approx(-soil_only[k][4] + drag[i] * HUB.arm * spin, abs=1e-3 * drag[i] * HUB.arm)


def test_hub_contact_above_every_sinkage_leaves_the_primitive(flat):
    """A clearance of 30 mm (every wheel sinks 7.5-8.4 mm): the smooth depth is ~eps^2 / (4 |d|)
    = 1e-7 m (a drag of 2e-8 N), so the primitive is the one without the face to solver tolerance
    (two IPOPT runs to tol 1e-8 on the scaled problem agree to ~1e-5 relative here; the 6 mm face
    of the test above moves the torques by ~4 %)."""
    sc, r0 = flat
    r = solve_primitive(replace(sc, hub_contact=HubFace(0.03, 0.02, 0.02)))
    assert r.ok
    for k, w0 in r0.wheels.items():
        w = r.wheels[k]
        for f in ("omega", "steer", "load", "sinkage", "sinkage_zero_slip", "torque"):
            assert getattr(w, f) == pytest.approx(getattr(w0, f), rel=1e-4, abs=1e-9), (k, f)


def test_hub_drag_derivative_in_the_wheel_jacobian_is_a_central_difference(hub):
    """The table's wrench Jacobian with the face minus the soil model's alone is the drag's own
    derivative: equal to a central difference of the numpy drag (F_x, F_y, M_y rows) and not
    zero; the other rows are unchanged."""
    sh, r = hub
    pb = _problem_for(sh, SolverOptions())
    for k, w in r.wheels.items():
        vx, vy = pb.statics.wheel_velocity(NUMPY, sh.speed, w.steer)
        z = np.array([vx, vy, w.omega, w.sinkage, w.sinkage_zero_slip])
        full = np.asarray(pb.wheel_function(k)(z)[1])
        soil = np.asarray(pb.model_of[k].casadi_function(jacobian=True)(z)[1])
        step = 1e-6 * np.maximum(np.abs(z), 1e-3)
        fd = np.zeros((3, 5))
        for j in range(5):
            dz = np.zeros(5)
            dz[j] = step[j]
            up = hub_wrench(NUMPY, HUB, sh.params.soil, *(z + dz)[:4])
            dn = hub_wrench(NUMPY, HUB, sh.params.soil, *(z - dz)[:4])
            fd[:, j] = (np.array(up) - np.array(dn)) / (2 * step[j])
        drag = (full - soil)[[0, 1, 4]]
        assert np.abs(drag[:, 3]).max() > 10.0  # dF/dh of a submerged face (N/m): the term is there
        np.testing.assert_allclose(drag, fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
        np.testing.assert_allclose((full - soil)[[2, 3, 5]], 0.0, atol=1e-12)


def test_scenario_hub_contact_section_and_its_errors(tmp_path):
    p = tmp_path / "h.toml"
    p.write_text("[scenario]\n[hub_contact]\nclearance_mm = 6.0\nface_width_mm = 20\narm_mm = 20.0\n")
    assert load_scenario(p).hub_contact == HubFace(0.006, 0.02, 0.02)
    assert load_scenario(NOMINAL).hub_contact is None
    for text, msg in (("[hub_contact]\nface_width_mm = 20.0\n", "clearance_mm"),
                      ("[hub_contact]\nclearance_mm = 0.006\nface_width_mm = 5000\n", "millimetres"),
                      ("[hub_contact]\nclearance_mm = 6\nwidth_mm = 20\n", "unknown key")):
        p.write_text("[scenario]\n" + text)
        with pytest.raises(ScenarioError, match=msg):
            load_scenario(p)


def test_world_file_with_hub_contact_to_table_header(tmp_path, capsys, hub):
    """accepted_truth.toml with a [hub_contact] section -> a one-point table (--world): the header's
    world record and tables info show the face, the stored torques are the hub primitive's, and
    the stored wheel Jacobians (drag included) pass tables verify's central differences."""
    from offline.cli import main
    from offline.discrepancy.drive.candidates import write_truth_toml
    from offline.rover.table_verify import check_jacobians, spec_from_table
    from offline.sim.truth import Truth
    from rtctl.table import load_table

    sc = load_scenario(NOMINAL)
    believed = Truth.nominal(sc.params, sc.rover)
    params = str(ROOT / "offline" / "data" / "calibrated_grousered.toml")
    truth = write_truth_toml(tmp_path / "accepted_truth.toml", params, believed, believed, {}, None, {"test": "hub"},
                             {"hub_clearance_m": HUB.clearance, "hub_face_width_m": HUB.face_width, "hub_arm_m": HUB.arm})
    assert "[hub_contact]" in truth.read_text()
    out = tmp_path / "tables"
    assert main(["tables", "build", str(NOMINAL), "--grid", "slope=0;cross_slope=0;speed=3", "--world", str(truth),
                 "--out", str(out), "--quiet", "--no-index"]) == 0
    t = load_table(out / "nominal.npz")
    assert t.header["world"]["hub_contact"] == pytest.approx({"clearance_m": 0.006, "face_width_m": 0.02, "arm_m": 0.02})
    assert main(["tables", "info", str(out / "nominal.npz")]) == 0
    assert "hub contact clearance 6.00 mm, face width 20.00 mm, arm 20.00 mm" in capsys.readouterr().out
    _, r = hub
    np.testing.assert_allclose(t.arrays["torque"].ravel(), [w.torque for w in r.wheels.values()], rtol=1e-5)
    errs = check_jacobians(t, spec_from_table(t), [0])
    assert max(errs.values()) < 1e-5, errs


def test_hub_primitive_is_the_simulators_steady_state_under_the_hub_hook(flat):
    """Two implementations of the same drag: the NLP's (hub_wrench in the wheel wrench) and the
    simulator's disturbance hook (HubContact, a body-frame force at the wheel from the plant's
    own statics). Driven at the hub primitive's rim speeds, the simulator settles at the travel
    speed with the primitive's slips, loads and sinkages; the residual differences are the smooth
    depth's eps^2 / (4 d) ~ 2 um (0.07 % of the drag). ``arm = 0``: the plant keeps the hook's
    spin torque out of its rocker-pitch balance, the NLP includes it with the soil's M_y."""
    from offline.discrepancy.drive.candidates import HubContact
    from offline.sim.simulator import RoverSimulator
    from rtctl.messages import Commands

    sc, r0 = flat
    face = HubFace(0.006, 0.02, 0.0)
    prim = solve_primitive(replace(sc, hub_contact=face))
    assert prim.ok
    ws = [prim.wheels[k] for k in ("FR", "FL", "RR", "RL")]
    cmd = Commands(0.0, 0, tuple(w.rim_speed for w in ws), tuple(w.steer for w in ws))
    sim = RoverSimulator(sc, seed=3, disturbance=HubContact(face.clearance, face.face_width, face.arm, sc.params.soil,
                                                            sc.rover))
    sim.start(cmd)
    for _ in range(20):
        sim.measure()
        sim.apply(cmd)
        sim.advance(0.2)
    ts = sim.truth_state()
    assert ts.u == pytest.approx(sc.speed, rel=1e-4)
    for i, w in enumerate(ws):
        assert w.slip > r0.wheels[w.name].slip + 0.03  # the drag makes every wheel slip more ...
        assert ts.slip[i] == pytest.approx(w.slip, abs=1e-4)  # ... by the same amount in both
        assert ts.load[i] == pytest.approx(w.load, rel=1e-4)
        assert ts.sinkage[i] == pytest.approx(w.sinkage, rel=1e-4)
