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

ROVER_TABLES = Path(__file__).resolve().parent / "data" / "tables" / "rovers"
MER_TABLE = ROVER_TABLES / "mer_rf_locked_backward.npz"
SKID_TABLE = ROVER_TABLES / "skid_fr_unpowered.npz"
SLIP_SWITCH = 1e-3  # |slip| below this: a wheel at the slip/skid switch, where the wheel model has a kink

TOL_ROWS = 1e-9  # |g_numpy - g_casadi| / row scale: the same expressions, two backends (measured ~1e-15)
TOL_JAC_FD = 1e-4  # forward differences of step 1e-7 variable scales vs casadi's exact Jacobian, per
# row and variable scale, on the free columns (measured 1.4e-6 six-wheel, 2.2e-5 skid-steer)
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


@pytest.mark.parametrize("path, points, fixed, jacobian_points", [
    (MER_TABLE, 6, 3, 6),  # fixed: the locked omega RF, the middle wheels' steering (not steerable)
    (SKID_TABLE, 6, 4, 6),  # fixed: every wheel's steering; -1, 0, 1 deg: every wheel off the slip/skid switch
])
def test_numpy_residual_equals_the_offline_nlp_at_the_grid_points(path, points, fixed, jacobian_points):
    """Values at every grid point; the Jacobian and gradient on the columns the bounds leave free,
    at the points where no wheel sits on the slip/skid switch (there the forward differences
    straddle the wheel model's kink: measured up to 6 row scales per variable scale on the former
    skid-steer table's FL at slope 5 deg, which the optimizer put at slip 0; the table's slope axis
    is now -1, 0, 1 deg, on the flat-ground branch, with every wheel off the switch)."""
    import casadi as ca

    from offline.rover.table_builder import _problem
    from offline.rover.table_verify import spec_from_table

    t = load_table(path)
    lay = t.layout
    res = SteadyStateResidual(SteadyStateModel.from_table_header(t.header, lay.wheels), lay)
    spec = spec_from_table(t)
    pb = _problem(spec.scenario, spec.solver)
    xs, ps = pb.symbols["x"], pb.symbols["p"]
    grad = ca.Function("grad", [xs, ps], [ca.gradient(pb.symbols["f"], xs), ca.jacobian(pb.symbols["g"], xs)])
    xsc, gsc = np.asarray(lay.variable_scale), np.asarray(lay.constraint_scale)
    grid = np.argwhere(t.feasible)
    assert len(grid) == points
    worst = {"g": 0.0, "jac": 0.0, "grad": 0.0, "eq": 0.0}
    smooth = 0
    for k in grid:
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
        assert (~free).sum() == fixed
        eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
        worst["g"] = max(worst["g"], float(np.max(np.abs(g - g_ref) / gsc)))
        if np.min(np.abs(np.asarray(tp.slip))) > SLIP_SWITCH:
            smooth += 1
            worst["jac"] = max(worst["jac"], float(np.max((np.abs(jac - jac_ref) * xsc[None, :] / gsc[:, None])[:, free])))
            worst["grad"] = max(worst["grad"], float(np.max(np.abs(gf - gf_ref)[free]) / np.max(np.abs(gf_ref))))
        worst["eq"] = max(worst["eq"], float(np.max(np.abs(g[eq]) / gsc[eq])))
        assert f == pytest.approx(float(f_ref[0]), rel=1e-12)
        assert f == pytest.approx(float(np.asarray(tp.objective).ravel()[0]), rel=1e-9)  # the stored optimum
    assert smooth == jacobian_points
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


def test_unsupported_rover_tables_stay_refused_with_their_reason(mer_table):
    """Refused, by name: a suspension kind the rover has no statics for, a rover record whose
    wheels are not the layout's, a rover-file table without the record (built before it)."""
    import dataclasses

    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller
    from rtctl.wheel_set import unsupported_reason

    assert unsupported_reason(mer_table.header, mer_table.layout) is None
    tracked = _with_rover(mer_table, dataclasses.replace(driving_backward(shipped_rover("mer_class_rocker_bogie")),
                                                         suspension="tracked"), "tracked")
    why = unsupported_reason(tracked.header, tracked.layout)
    assert why is not None and "rtctl drives rover files with suspension rocker, rocker_bogie, rigid, not 'tracked'" in why
    other = _with_rover(mer_table, shipped_rover("skid_steer_4w"), "other_wheels")
    assert "table's rover record has wheels FR, FL, RR, RL, its layout RF, LF, RM, LM, RR, LR: rebuild the table" in \
        unsupported_reason(other.header, other.layout)
    h = dict(mer_table.header)
    h["scenario"] = {k: v for k, v in h["scenario"].items() if k != "rover_file"}
    why2 = unsupported_reason(h, mer_table.layout)
    assert why2 is not None and "no rover record" in why2
    c = Controller({"mer_rf_locked_backward": mer_table, "tracked": tracked}, ControllerConfig())
    assert set(c.unavailable) == {"tracked"} and "not 'tracked'" in c.unavailable["tracked"]
    assert c.wheels == ("RF", "LF", "RM", "LM", "RR", "LR")  # the refused table does not enter the wheel set
    _, d = c.step(__import__("rtctl.messages", fromlist=["Measurements"]).Measurements(0.0, 0, (-0.1,) * 6, (0.0,) * 6, 0.0))
    assert any(f.startswith("table tracked unavailable since start-up") for f in d.flags)


def test_skid_steer_table_holds_one_branch():
    """Every grid point of the skid-steer table is on the flat-ground branch: all four wheels
    rolling, none near its wheel-speed bound (at most half of it). The former table (slope 0 and
    5 deg) had RL spinning at its 4.817 rad/s drive limit at 5 deg, a second branch of the
    primitive, and rtctl's online step failed ``tables verify`` check 4 between the two
    (``results_any_rover_audit.md``, T2); this fails on it (RL at 1.0 of its bound)."""
    t = load_table(SKID_TABLE)
    lay = t.layout
    for k in np.argwhere(t.feasible):
        tp = t.at(**t.grid_point(tuple(k)))
        x, ub = np.asarray(tp.x, dtype=float), np.asarray(tp.ubx, dtype=float)
        ratio = {w: x[lay.var("omega", w)] / ub[lay.var("omega", w)] for w in lay.wheels}
        assert max(ratio.values()) < 0.5, (t.grid_point(tuple(k)), ratio)


def test_controller_drives_the_skid_steer_table_open_loop_to_its_primitive():
    """The four-wheel skid-steer (rigid frame, no steering), front-right wheel unpowered, at the
    grid point slope 0, 2 cm/s: the QP every tick, steering 0, wheel speeds within the rover file's
    limit and converging to the primitive, the exact residual (with the rigid frame's
    height-compatibility row) vanishing there; not mirrored (its height-compatibility row is no
    signed permutation of rows, rtctl.mirror); a heading 3 deg to the left slows the right side
    against the left (no steering: the yaw moment comes from the wheel speeds alone)."""
    import math
    from dataclasses import replace

    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller, wheel_radius_of
    from rtctl.messages import FailureDeclaration, Measurements, Pose

    t = load_table(SKID_TABLE)
    cfg = ControllerConfig()
    cfg = replace(cfg, drive=replace(cfg.drive, speed=0.02))
    lay = t.layout
    assert "balance height_compatibility_0" in lay.constraint_names
    tp = t.at(slope=0.0, cross_slope=0.0, speed=0.02)
    om = np.array([tp.x[lay.var("omega", w)] for w in lay.wheels])
    rs = wheel_radius_of(t)
    spec = rover_spec_from_record(t.header["scenario"]["rover_file"])
    fails = (FailureDeclaration("FR", "unpowered", math.nan),)
    c = Controller({t.name: t}, cfg)
    assert c.wheels == ("FR", "FL", "RR", "RL") and c.wheel_set.suspension == "rigid" and c.mirrored == {}
    for k in range(30):
        cmd, d = c.step(Measurements(0.2 * k, k, tuple(om), (0.0,) * 4, 0.0, failures=fails))
        assert d.mode == "qp" and d.table == t.name, (k, d.mode, d.reason)
        omega = np.array(cmd.rim_speed) / rs
        assert np.all(np.isfinite(omega)) and np.all(np.abs(omega) <= spec.actuators.drive_speed_max + 1e-12)
        assert cmd.steer_angle == (0.0,) * 4
    sx = lay.variable_scale[[lay.var("omega", w) for w in lay.wheels]]
    assert np.max(np.abs(omega - om) / sx) < TOL_CMD_AT_GRID
    res = SteadyStateResidual(SteadyStateModel.from_table_header(t.header, lay.wheels), lay)
    g, _ = res.residual(c._rtis[t.name].iterate, np.array(tp.p, dtype=float))
    eq = np.asarray(tp.lbg) == np.asarray(tp.ubg)
    assert np.max(np.abs(g[eq]) / lay.constraint_scale[eq]) < TOL_RESIDUAL_AT_GRID
    c = Controller({t.name: t}, cfg)
    c.step(Measurements(0.0, 0, tuple(om), (0.0,) * 4, 0.0, failures=fails))
    c.step(Measurements(0.2, 1, tuple(om), (0.0,) * 4, 0.0, failures=fails, pose=Pose(0.2, 0.0, 0.0, math.radians(3.0))))
    cmd, d = c.step(Measurements(0.4, 2, tuple(om), (0.0,) * 4, 0.0, failures=fails))
    assert d.mode == "qp" and d.mz_offset < 0
    drim = np.array(cmd.rim_speed) - om * rs
    assert drim[0] + drim[2] < drim[1] + drim[3]  # right (FR, RR) against left (FL, RL)
