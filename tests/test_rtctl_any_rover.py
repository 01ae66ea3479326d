"""rtctl on a rover from a file (issue 23): the six-wheel MER-class table of
``tests/data/tables/rovers/`` (right-front wheel locked, driving backward; README there).

* The exact residual a rover file's table gets on the rover
  (:meth:`rtctl.physics.steady_state.SteadyStateModel.from_table_header`: the suspension statics of
  the header's rover record, :class:`rtctl.physics.suspension.SuspensionStatics`, torque scale
  ``W / 6 r_s``) equals the offline NLP's own rows (casadi graph rebuilt from the decoded scenario)
  at every grid point of the table: the values to rounding, the Jacobian (forward differences on
  the rover) to the differences' truncation on the columns the bounds leave free.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtctl.physics.rover_file import driving_backward, rover_spec_from_record, shipped_rover
from rtctl.physics.steady_state import SteadyStateModel, SteadyStateResidual
from rtctl.physics.suspension import SuspensionStatics
from rtctl.table import load_table

MER_TABLE = Path(__file__).resolve().parent / "data" / "tables" / "rovers" / "mer_rf_locked_backward.npz"

TOL_ROWS = 1e-9  # |g_numpy - g_casadi| / row scale: the same expressions, two backends (measured ~1e-15)
TOL_JAC_FD = 1e-5  # forward differences of step 1e-7 variable scales vs casadi's exact Jacobian, per
# row and variable scale, on the free columns (measured ~1.4e-6)
TOL_GRAD_FD = 2e-6  # objective gradient, relative to its largest entry, free columns (measured ~3e-7)
TOL_EQ_AT_PRIMITIVE = 1e-8  # |g| / row scale on the equality rows at the table's primitive (IPOPT tol 1e-9)


@pytest.fixture(scope="module")
def mer_table():
    return load_table(MER_TABLE)


def test_header_rover_record_is_the_turned_rover_file(mer_table):
    spec = rover_spec_from_record(mer_table.header["scenario"]["rover_file"])
    ref = driving_backward(shipped_rover("mer_class_rocker_bogie"))
    assert spec.wheels == ref.wheels and spec.links == ref.links and spec.weight == ref.weight
    assert spec.centre_of_mass == ref.centre_of_mass and spec.actuators == ref.actuators


def test_model_from_header_is_the_suspension_statics(mer_table):
    lay = mer_table.layout
    model = SteadyStateModel.from_table_header(mer_table.header, lay.wheels)
    assert isinstance(model.statics, SuspensionStatics)
    assert model.statics.balance_names == tuple(b.name[len("balance "):] for b in lay.constraints
                                                if b.name.startswith("balance "))
    rs = model.shearing_radius[0]
    assert model.torque_scale == pytest.approx(645.54 / 6 * rs, rel=1e-15)
    assert lay["wheel torque RF"].scale == pytest.approx(model.torque_scale, rel=1e-12)  # the NLP's W / N


def test_numpy_residual_equals_the_offline_nlp_at_the_grid_points(mer_table):
    import casadi as ca

    from offline.rover.table_builder import _problem
    from offline.rover.table_verify import spec_from_table

    t = mer_table
    lay = t.layout
    res = SteadyStateResidual(SteadyStateModel.from_table_header(t.header, lay.wheels), lay)
    spec = spec_from_table(t)
    pb = _problem(spec.scenario, spec.solver)
    xs, ps = pb.symbols["x"], pb.symbols["p"]
    grad = ca.Function("grad", [xs, ps], [ca.gradient(pb.symbols["f"], xs), ca.jacobian(pb.symbols["g"], xs)])
    xsc, gsc = np.asarray(lay.variable_scale), np.asarray(lay.constraint_scale)
    points = np.argwhere(t.feasible)
    assert len(points) == 6
    worst = {"g": 0.0, "jac": 0.0, "grad": 0.0, "eq": 0.0}
    for k in points:
        tp = t.at(**t.grid_point(tuple(k)))
        x, p = np.array(tp.x, dtype=float), np.array(tp.p, dtype=float)
        g, f, gf, jac = res.evaluate(x, p, jacobian=True)
        g_ref, f_ref = (np.asarray(v, dtype=float).ravel() for v in pb.eval_g(x / xsc, p))
        g_ref = g_ref * gsc
        gf_ref, jac_ref = (np.asarray(v, dtype=float) for v in grad(x / xsc, p))
        gf_ref = gf_ref.ravel() / xsc
        jac_ref = jac_ref * gsc[:, None] / xsc[None, :]
        assert np.max(np.abs(np.asarray(tp.jac_g_x) - jac_ref) * xsc[None, :] / gsc[:, None]) < TOL_ROWS  # the table's
        free = np.asarray(tp.lbx) < np.asarray(tp.ubx)  # the locked omega and the fixed middle steering: bound
        assert (~free).sum() == 3
        eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
        worst["g"] = max(worst["g"], float(np.max(np.abs(g - g_ref) / gsc)))
        worst["jac"] = max(worst["jac"], float(np.max((np.abs(jac - jac_ref) * xsc[None, :] / gsc[:, None])[:, free])))
        worst["grad"] = max(worst["grad"], float(np.max(np.abs(gf - gf_ref)[free]) / np.max(np.abs(gf_ref))))
        worst["eq"] = max(worst["eq"], float(np.max(np.abs(g[eq]) / gsc[eq])))
        assert f == pytest.approx(float(f_ref[0]), rel=1e-12)
        assert f == pytest.approx(float(np.asarray(tp.objective).ravel()[0]), rel=1e-9)  # the stored optimum
    assert worst["g"] < TOL_ROWS, worst
    assert worst["jac"] < TOL_JAC_FD, worst
    assert worst["grad"] < TOL_GRAD_FD, worst
    assert worst["eq"] < TOL_EQ_AT_PRIMITIVE, worst


# --- mirror and recordings (step 3) ---------------------------------------------------------

def test_mirror_map_from_wheel_positions(mer_table):
    from rtctl.mirror import MIRROR_WHEEL, mirror_wheel_map

    assert mirror_wheel_map(mer_table) == {"RF": "LF", "LF": "RF", "RM": "LM", "LM": "RM", "RR": "LR", "LR": "RR"}
    nominal = load_table(Path(__file__).resolve().parents[1] / "tables" / "nominal.npz")
    assert mirror_wheel_map(nominal) == MIRROR_WHEEL  # the mini rover's, unchanged


def test_mirrored_six_wheel_table_is_the_mirrored_rovers_steady_state(mer_table):
    """The mirror (locked LF) is checked by the physics, not by its own construction: the exact
    residual of the mirrored table (its header's model) at its mirrored primitives vanishes on
    the equality rows and equals the mirrored stored rows (the differential row flips sign, the
    bogie rows swap)."""
    from rtctl.mirror import mirror_table

    m = mirror_table(mer_table)
    assert m.name == "mer_rf_locked_backward_mirror"
    assert [f["wheel"] for f in m.header["failures"]] == ["LF"]
    lay = m.layout
    res = SteadyStateResidual(SteadyStateModel.from_table_header(m.header, lay.wheels), lay)
    gsc = np.asarray(lay.constraint_scale)
    worst_eq = worst_g = 0.0
    for k in np.argwhere(m.feasible):
        tp = m.at(**m.grid_point(tuple(k)))
        g, f = res.residual(np.array(tp.x, dtype=float), np.array(tp.p, dtype=float))
        eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
        worst_eq = max(worst_eq, float(np.max(np.abs(g[eq]) / gsc[eq])))
        worst_g = max(worst_g, float(np.max(np.abs(g - np.asarray(tp.g)) / gsc)))
        assert f == pytest.approx(float(np.ravel(tp.objective)[0]), rel=1e-12)
        assert float(np.asarray(tp.x)[lay.var("omega", "LF")]) == 0.0  # the locked wheel, mirrored
    assert worst_eq < TOL_EQ_AT_PRIMITIVE and worst_g < TOL_ROWS, (worst_eq, worst_g)


def test_six_wheel_recording_round_trip_and_old_recordings_read_as_mini_rover(tmp_path):
    from rtctl.messages import Commands, Measurements
    from rtctl.recording import MINI_ROVER_WHEELS, Recorder, RecordingError, read_recording

    wheels = ("RF", "LF", "RM", "LM", "RR", "LR")
    m = Measurements(t=0.2, seq=1, wheel_speed=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6), steer_angle=(0.0,) * 6, yaw_rate=0.0)
    c = Commands(0.2, 1, (0.01,) * 6, (0.0, 0.0, 0.0, 0.0, 0.1, -0.1))
    with Recorder(tmp_path / "six.mcap", {"seed": 1}, wheels=wheels) as rec:
        rec.measurements(m)
        rec.commands(c)
    back = read_recording(tmp_path / "six.mcap")
    assert back.wheels == wheels and back.measurements == [m] and back.commands == [c]
    with Recorder(tmp_path / "four.mcap", {"seed": 1}) as rec:  # no wheel set given: as before
        rec.measurements(Measurements(0.2, 1, (0.1,) * 4, (0.0,) * 4, 0.0))
    four = read_recording(tmp_path / "four.mcap")
    assert "wheels" not in four.metadata and four.wheels == MINI_ROVER_WHEELS
    with Recorder(tmp_path / "bad.mcap", wheels=wheels) as rec:  # a vector of the wrong count
        rec.measurements(Measurements(0.2, 1, (0.1,) * 4, (0.0,) * 4, 0.0))
    with pytest.raises(RecordingError, match=r"expected 6 values \(RF, LF, RM, LM, RR, LR\)"):
        read_recording(tmp_path / "bad.mcap")


# --- the controller on a six-wheel table (steps 1 and 4) --------------------------------------

TOL_CMD_AT_GRID = 1e-6  # |command - primitive| / variable scale after 30 ticks at a grid point
TOL_RESIDUAL_AT_GRID = 1e-8  # |exact residual| / row scale on the equality rows at the final iterate


def _mer_controller(t, speed=0.02):
    from dataclasses import replace

    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller

    cfg = ControllerConfig()
    return Controller({t.name: t}, replace(cfg, drive=replace(cfg.drive, speed=speed)))


def test_controller_drives_the_six_wheel_table_open_loop_to_its_primitive(mer_table):
    """Synthetic body-frame measurements of the backward-driving rover at the grid point
    (slope 0, speed 2 cm/s; wheel speeds negative: the rover drives backward) with the dead
    wheel declared: every tick the QP, commands finite and within the rover file's limits, and
    the commands (turned back into the travel frame) converge to the table's primitive, where the
    exact residual vanishes."""
    import math

    from rtctl.controller import wheel_radius_of
    from rtctl.messages import FailureDeclaration, Measurements

    t = mer_table
    c = _mer_controller(t)
    assert c.wheels == ("RF", "LF", "RM", "LM", "RR", "LR") and c.wheel_set.drive_direction == "backward"
    assert t.name in c.tables and not c.unavailable
    assert c.mirrored == {"mer_rf_locked_backward_mirror": t.name}  # the locked left-front, from the positions
    lay = t.layout
    tp = t.at(slope=0.0, cross_slope=0.0, speed=0.02)
    om = np.array([tp.x[lay.var("omega", w)] for w in lay.wheels])
    be = np.array([tp.x[lay.var("beta", w)] for w in lay.wheels])
    rs = wheel_radius_of(t)
    spec = rover_spec_from_record(t.header["scenario"]["rover_file"])
    fails = (FailureDeclaration("RF", "locked", math.nan),)
    sx = lay.variable_scale
    for k in range(30):
        cmd, d = c.step(Measurements(0.2 * k, k, tuple(-om), tuple(be), 0.0, failures=fails))
        assert d.mode == "qp" and d.table == t.name, (k, d.mode, d.reason)
        rim, steer = np.array(cmd.rim_speed), np.array(cmd.steer_angle)
        assert len(rim) == len(steer) == 6 and np.all(np.isfinite(rim)) and np.all(np.isfinite(steer))
        omega = -rim / rs  # body frame -> travel frame
        assert np.all(np.abs(omega) <= spec.actuators.drive_speed_max + 1e-12)
        for i, w in enumerate(spec.wheels):
            assert w.steer_min - 1e-12 <= steer[i] <= w.steer_max + 1e-12, (w.name, steer[i])
        assert omega[0] == 0.0  # the locked wheel
    err_om = np.max(np.abs(omega - om) / sx[[lay.var("omega", w) for w in lay.wheels]])
    err_be = np.max(np.abs(steer - be) / sx[[lay.var("beta", w) for w in lay.wheels]])
    assert max(err_om, err_be) < TOL_CMD_AT_GRID, (err_om, err_be)
    res = SteadyStateResidual(SteadyStateModel.from_table_header(t.header, lay.wheels), lay)
    g, _ = res.residual(c._rtis[t.name].iterate, np.array(tp.p, dtype=float))
    eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
    assert np.max(np.abs(g[eq]) / lay.constraint_scale[eq]) < TOL_RESIDUAL_AT_GRID


def test_measurements_of_another_wheel_count_are_rejected_with_the_expected_count(mer_table):
    from rtctl.messages import Measurements

    c = _mer_controller(mer_table)
    cmd, d = c.step(Measurements(0.0, 0, (0.1,) * 4, (0.0,) * 4, 0.0))
    assert len(cmd.rim_speed) == 6 and all(np.isfinite(cmd.rim_speed))
    assert any("wheel_speed rejected: 4 entries, expected 6: one per wheel RF, LF, RM, LM, RR, LR" in f for f in d.flags)
    assert dict(d.counters).get("rejected_wheel_vectors", 0) == 1


def test_tables_of_two_wheel_sets_are_a_start_up_error(mer_table):
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller, ControllerError

    nominal = load_table(Path(__file__).resolve().parents[1] / "tables" / "nominal.npz")
    with pytest.raises(ControllerError, match=r"different wheel sets: mer_rf_locked_backward: 6 wheels RF.*; nominal: 4 "
                                              r"wheels FR, FL, RR, RL"):
        Controller({"nominal": nominal, "mer_rf_locked_backward": mer_table}, ControllerConfig())


def _with_rover(t, spec, name):
    import copy
    import dataclasses

    from rtctl.table import Table, content_hash

    h = copy.deepcopy(t.header)
    h["name"] = name
    h["scenario"]["rover_file"] = dataclasses.asdict(spec)
    h["wheel_set"] = {**h["wheel_set"], "suspension": spec.suspension, "rover": spec.name}
    h.pop("content_hash", None)
    arrays = {k: np.asarray(v) for k, v in t.arrays.items()}
    h["content_hash"] = content_hash(h, arrays)
    return Table(h, arrays, source="test")


def test_skid_steer_and_headerless_rover_tables_stay_refused_with_their_reason(mer_table):
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.wheel_set import unsupported_reason

    assert unsupported_reason(mer_table.header, mer_table.layout) is None
    skid = _with_rover(mer_table, shipped_rover("skid_steer_4w"), "skid_header")
    why = unsupported_reason(skid.header, skid.layout)
    assert why is not None and "'rigid' (skid-steer) rover is refused" in why and "unverified" in why
    h = dict(mer_table.header)
    h["scenario"] = {k: v for k, v in h["scenario"].items() if k != "rover_file"}
    why2 = unsupported_reason(h, mer_table.layout)
    assert why2 is not None and "no rover record" in why2
    c = Controller({"mer_rf_locked_backward": mer_table, "skid_header": skid}, ControllerConfig())
    assert "skid_header" in c.unavailable and "skid-steer" in c.unavailable["skid_header"]
    assert c.wheels == ("RF", "LF", "RM", "LM", "RR", "LR")  # the refused table does not enter the wheel set


def test_backward_table_turns_heading_and_tilt_at_the_boundary(mer_table):
    """The rover drives backward: its body heading is the travel heading plus pi and it backs
    uphill nose down. A body heading of pi + 3 deg is a travel heading 3 deg to the left (the
    yaw-moment offset turns right, negative, as on the mini rover, tests/test_rtctl_real_table.py);
    a body pitch of -2.5 deg (nose down) is the table's uphill slope +2.5 deg, +2.5 deg (nose up) a
    downhill slope, read at the table's axis end 0."""
    import math

    from rtctl.messages import FailureDeclaration, Measurements, Pose

    t = mer_table
    lay = t.layout
    tp = t.at(slope=0.0, cross_slope=0.0, speed=0.02)
    om = tuple(-float(tp.x[lay.var("omega", w)]) for w in lay.wheels)
    be = tuple(float(tp.x[lay.var("beta", w)]) for w in lay.wheels)
    fails = (FailureDeclaration("RF", "locked", math.nan),)
    for dh, sign in ((0.0, 0.0), (3.0, -1.0), (-3.0, 1.0)):
        c = _mer_controller(t)
        c.step(Measurements(0.0, 0, om, be, 0.0, failures=fails))
        c.step(Measurements(0.2, 1, om, be, 0.0, failures=fails, pose=Pose(0.2, 0.0, 0.0, math.pi + math.radians(dh))))
        _, d = c.step(Measurements(0.4, 2, om, be, 0.0, failures=fails))
        assert d.mode == "qp" and math.degrees(d.heading_error) == pytest.approx(-dh, abs=1e-9)
        assert np.sign(d.mz_offset) == sign
    slopes = []
    for pitch in (-2.5, 2.5):
        c = _mer_controller(t)
        for k in range(30):
            _, d = c.step(Measurements(0.2 * k, k, om, be, 0.0, failures=fails, pitch=math.radians(pitch)))
        slopes.append(dict(d.operating_point)["slope"])
    assert slopes[0] == pytest.approx(math.radians(2.5), rel=0.05) and slopes[1] == 0.0
