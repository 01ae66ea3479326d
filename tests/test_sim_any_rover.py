"""The simulator of a rover from a file (issue 23): six-wheel rocker-bogie and four-wheel skid-steer.

* The plant's steady state at a table primitive is the primitive: the plant
  (:class:`offline.sim.suspension_plant.SuspensionPlant`) and the optimizer share the wheel model
  and the suspension rows (:class:`rtctl.physics.suspension.SuspensionStatics`), so at every
  optimal grid point of the test tables the plant's residual vanishes at the primitive and
  Newton's method from a straight-driving guess lands on it (body velocities, wheel speeds,
  sinkages and wheel forces).
* The plant's Jacobian is exact (central differences, away from a steady state).
* rtctl drives the simulated MER-class rover in closed loop on the six-wheel test tables (right
  front locked and driving backward, Spirit's strategy; right-front steering stuck at 7 deg,
  Opportunity's), with the body-frame sensors and commands of a backward drive, and the drive
  records and replays bit for bit with its wheel set.

Tables: ``tests/data/tables/rovers/`` (README there). Short drives (0.2-0.3 m): about 5 CPU-s in
all with the compiled wheel functions cached (a one-off compile of about 16 CPU-s for the six-wheel
batch; a four-wheel rover file shares the mini rover's).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rtctl.table import load_table

ROOT = Path(__file__).resolve().parents[1]
ROVER_TABLES = ROOT / "tests" / "data" / "tables" / "rovers"
SCENARIOS = ROOT / "offline" / "scenarios" / "rovers"

TOL_STEADY = 1e-7  # plant root vs the table primitive, relative to each quantity's scale (measured <= 1.5e-10)
TOL_RESIDUAL_AT_PRIMITIVE = 1e-9  # max scaled plant residual at the primitive (IPOPT tol 1e-9; measured <= 3e-10)
TOL_JACOBIAN = 1e-5  # central differences (step 1e-7) vs the plant's Jacobian, relative to its largest entry
HEADING_TARGET_DEG = 3.0  # issue 23's closed-loop targets
CROSSTRACK_TARGET_M = 0.05


def _plant_inputs(plant, table, sc, idx):
    """Inputs, parameters and the primitive's unknowns of the plant at an optimal grid point."""
    lay = table.layout
    op = table.grid_point(idx)
    tp = table.at(**op)
    x = tp.x
    W = lay.wheels
    col = {v: np.array([x[lay.var(v, k)] for k in W]) for v in ("omega", "beta", "h", "h0")}
    n, speed = len(W), op["speed"]
    q = plant.param_vector((sc.params.wheel.radius,) * n, sc.params.soil, op.get("slope", 0.0), op.get("cross_slope", 0.0),
                           0.0, sc.rover_file.weight / plant.gravity, 10.0, 0.0)
    mode = np.array([0.0 if sc.failure(k).unpowered else 1.0 for k in W])
    a = np.concatenate([col["omega"], mode, np.zeros(n), col["beta"], [speed, 0.0, 0.0, 0.0, 0.0], col["omega"]])
    z = np.concatenate([[speed, 0.0, 0.0], col["omega"], np.log(col["h"]), np.log(col["h0"])])
    return a, q, z, tp, speed


@pytest.mark.parametrize("table_name", ["mer_rf_locked_backward", "mer_rf_steer_stuck_7", "skid_fr_unpowered"])
def test_plant_steady_state_is_the_table_primitive(table_name):
    """At every optimal grid point: the plant's residual at the primitive is zero, and its root from a
    straight-driving guess (equal loads, zero slip) is the primitive: forward speed the table's, no
    lateral velocity or yaw rate, each wheel's speed, sinkage and wrench the primitive's."""
    from offline.rover.table_verify import spec_from_table
    from offline.sim.simulator import suspension_plant_for

    t = load_table(ROVER_TABLES / f"{table_name}.npz")
    sc = spec_from_table(t).scenario
    plant = suspension_plant_for(sc.params, sc.rover_file, sc.exit_angle)
    assert plant.wheels == t.layout.wheels
    checked = 0
    for idx in np.ndindex(*t.status.shape):
        if t.status_at(idx) != "optimal":
            continue
        a, q, z_prim, tp, speed = _plant_inputs(plant, t, sc, idx)
        res = plant.evaluate(z_prim, a, q)[0]
        assert np.max(np.abs(res)) <= TOL_RESIDUAL_AT_PRIMITIVE, (idx, plant.balance_names, res)
        z, sol = plant.solve(plant.initial_guess(speed, q), a, q)
        n = plant.n
        assert abs(sol.u - speed) <= TOL_STEADY * speed and abs(sol.v) <= TOL_STEADY * speed
        assert abs(sol.r) * plant.wheelbase <= TOL_STEADY * speed
        om_scale = np.max(np.abs(tp.x[[t.layout.var("omega", k) for k in plant.wheels]]))
        assert np.max(np.abs(z[3:3 + n] - z_prim[3:3 + n])) <= TOL_STEADY * om_scale  # wheel speeds (free for unpowered)
        assert np.max(np.abs(z[3 + n:] - z_prim[3 + n:])) <= TOL_STEADY  # log sinkages: relative
        assert np.max(np.abs(sol.wrench - tp.wrench)) <= TOL_STEADY * np.max(np.abs(tp.wrench))
        checked += 1
    assert checked == int(np.sum([t.status_at(i) == "optimal" for i in np.ndindex(*t.status.shape)])) >= 4


def _hook_vector(n):
    """A disturbance vector on ``n`` wheels: body force and moment, a force at every wheel, a hub torque on two."""
    fx, fy = 0.4 * np.cos(np.arange(n)), -0.3 * np.sin(1.0 + np.arange(n))
    tq = np.zeros(n)
    tq[2], tq[5 % n] = 0.7, -0.4
    return np.concatenate([[-2.0, 1.5, 0.8], fx, fy, tq])


@pytest.mark.parametrize("disturbed", [False, True])
def test_plant_jacobian_is_exact_off_the_steady_state(disturbed):
    """The six-wheel plant's Jacobian (wheel Jacobians through the suspension rows' exact casadi
    Jacobian) against central differences at a point with yaw rate, lateral velocity, a step in
    time (inertia terms) and a wheel in torque mode; and with a disturbance hook's forces (body
    force and moment, a force at every wheel, hub torques: the rows evaluated at the loaded wrenches)."""
    from offline.rover.table_verify import spec_from_table
    from offline.sim.simulator import suspension_plant_for

    t = load_table(ROVER_TABLES / "mer_rf_steer_stuck_7.npz")
    sc = spec_from_table(t).scenario
    plant = suspension_plant_for(sc.params, sc.rover_file, sc.exit_angle)
    a, q, z, _, speed = _plant_inputs(plant, t, sc, next(np.ndindex(*t.status.shape)))
    n = plant.n
    a = a.copy()
    a[n + 2] = 0.0  # RM in torque mode (zero torque)
    a[4 * n + 3], a[4 * n + 4] = 0.3, 5.0  # heading 0.3 rad, dt 0.2 s
    q = q.copy()
    q[n + 9], q[n + 10], q[n + 14] = 0.05, 0.03, 0.5  # slope, cross slope, wheel inertia
    z = z + np.concatenate([[0.002, 0.004, 0.01], 0.02 * np.arange(1, n + 1), 0.03 * np.sin(np.arange(2 * n))])
    d = _hook_vector(n) if disturbed else None
    res, J = plant.evaluate(z, a, q, d)[:2]
    if disturbed:
        assert np.max(np.abs(res - plant.evaluate(z, a, q)[0])) > 1e-3  # the hook's forces enter the rows
    eps = 1e-7
    fd = np.empty_like(J)
    for j in range(len(z)):
        dz = np.zeros(len(z))
        dz[j] = eps
        fd[:, j] = (plant.evaluate(z + dz, a, q, d, jacobian=False)[0]
                    - plant.evaluate(z - dz, a, q, d, jacobian=False)[0]) / (2 * eps)
    assert np.max(np.abs(fd - J)) <= TOL_JACOBIAN * np.max(np.abs(J)), np.unravel_index(np.argmax(np.abs(fd - J)), J.shape)
    assert np.max(np.abs(res)) > 1e-3  # away from a steady state: the inertia and yaw columns matter


def _rtctl(table, speed):
    from rtctl.config import ControllerConfig
    from rtctl.controller import Controller

    cfg = ControllerConfig()
    ctl = Controller({table.name if hasattr(table, "name") else "table": table},
                     replace(cfg, drive=replace(cfg.drive, speed=speed)))
    setattr(ctl, "name", "rtctl")
    return ctl


def _drive(scenario, table, speed, distance, recorder=None):
    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.simulator import RoverSimulator

    sc = load_scenario(SCENARIOS / f"{scenario}.toml").with_(speed=speed)
    sim = RoverSimulator(sc, seed=1)
    ctl = _rtctl(load_table(ROVER_TABLES / f"{table}.npz"), speed)
    return sim, run_drive(sim, ctl, distance=distance, recorder=recorder)


def test_rtctl_drives_the_six_wheel_rover_backward_with_the_dead_wheel_trailing_and_the_drive_replays(tmp_path):
    """Spirit's strategy: MER-class, right-front wheel locked, driving backward (the table is in
    the travel frame; sensors and commands in the body frame, the controller turns them). 0.3 m
    at 2 cm/s: heading and cross-track within the issue's targets, the speed within 10 %, the
    locked wheel at rest; the recording carries the six wheels and the truth, the measured wheel
    speeds of the driven wheels are negative (body frame, backward) and the drive replays bit for
    bit on a fresh controller."""
    from rtctl.recording import Recorder, read_recording
    from rtctl.replay import replay

    path = tmp_path / "mer_backward.mcap"
    wheels = ("RF", "LF", "RM", "LM", "RR", "LR")
    with Recorder(path, {"scenario": "mer_rf_locked_backward"}, truth=True, wheels=wheels) as rec:
        sim, res = _drive("mer_rf_locked_backward", "mer_rf_locked_backward", 0.02, 0.3, rec)
    assert sim.backward and sim.wheels == wheels and not res.ended
    m = res.metrics
    assert m["max_abs_heading_deg"] <= HEADING_TARGET_DEG and m["max_abs_cross_track_cm"] <= 100 * CROSSTRACK_TARGET_M
    assert abs(m["speed_error_pct"]) <= 10.0 and m["distance_m"] >= 0.3
    assert all(abs(s.omega[0]) < 1e-9 for s in res.truth)  # RF locked
    r = read_recording(path)
    assert r.wheels == wheels and len(r.measurements) == len(res.truth) and len(r.truth[0]["omega"]) == 6
    assert all(all(v < 0 for v in mm.wheel_speed[1:]) for mm in r.measurements)  # backward, body frame
    assert all(all(v <= 0 for v in c.rim_speed) for c in r.commands)
    rep = replay(r, _rtctl(load_table(ROVER_TABLES / "mer_rf_locked_backward.npz"), 0.02))
    assert rep.identical and rep.steps == len(r.measurements), rep.summary()


def test_rtctl_drives_the_six_wheel_rover_with_its_right_front_steering_stuck_at_7_deg():
    """Opportunity's failure: MER-class, right-front steering stuck at 7 deg, 0.3 m at 3 cm/s."""
    sim, res = _drive("mer_rf_steer_stuck_7", "mer_rf_steer_stuck_7", 0.03, 0.3)
    m = res.metrics
    assert not res.ended and m["distance_m"] >= 0.3
    assert m["max_abs_heading_deg"] <= HEADING_TARGET_DEG and m["max_abs_cross_track_cm"] <= 100 * CROSSTRACK_TARGET_M
    assert all(abs(s.steer[0] - math.radians(7.0)) < 1e-12 for s in res.truth)  # the stuck wheel stays at 7 deg


def test_the_skid_steer_table_primitive_drives_straight_in_the_simulator():
    """The rigid skid-steer with FR unpowered: the table's primitive at 3 cm/s on the flat, open loop
    (the unpowered wheel free in the plant), keeps the rover on the line, every wheel at the
    primitive's speed: the plant's rigid-frame loads (height compatibility) and skid-steer yaw
    balance are the optimizer's."""
    from rtctl.messages import Commands

    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.simulator import RoverSimulator

    t = load_table(ROVER_TABLES / "skid_fr_unpowered.npz")
    sc = load_scenario(SCENARIOS / "skid_fr_unpowered.toml").with_(speed=0.03)
    lay, rs = t.layout, sc.params.wheel.shearing_radius
    x = t.at(slope=0.0, cross_slope=0.0, speed=0.03).x
    rim = tuple(float(x[lay.var("omega", k)]) * rs for k in lay.wheels)

    class Primitive:
        name = "table FF"

        def step(self, m):
            return Commands(m.t, m.seq, rim, (0.0,) * 4), {}

    res = run_drive(RoverSimulator(sc, seed=1), Primitive(), distance=0.3)
    m = res.metrics
    assert m["max_abs_heading_deg"] <= 0.01 and m["max_abs_cross_track_cm"] <= 0.01 and abs(m["speed_error_pct"]) <= 0.1
    assert np.allclose(res.truth[-1].omega, [x[lay.var("omega", k)] for k in lay.wheels], rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("table_name", ["mer_rf_locked_backward", "skid_fr_unpowered"])
def test_plant_balance_rows_are_the_rovers_exact_residual_off_the_primitive(table_name):
    """Away from a primitive too, the plant (quasi-static, straight at the table's speed) and the
    rover's exact residual (:class:`rtctl.physics.steady_state.SteadyStateResidual`, the NLP's rows)
    give the same balance rows for the same wheel speeds, steering and sinkages: every row but
    ``Fz`` (the plant's loads are the wheels' soil ``F_z``, the NLP's its load variables), to
    1e-9 of the row scale, at seeded perturbations of each optimal grid point."""
    from rtctl.physics.steady_state import SteadyStateModel, SteadyStateResidual

    from offline.rover.table_verify import spec_from_table
    from offline.sim.simulator import suspension_plant_for

    t = load_table(ROVER_TABLES / f"{table_name}.npz")
    lay = t.layout
    sc = spec_from_table(t).scenario
    plant = suspension_plant_for(sc.params, sc.rover_file, sc.exit_angle)
    rover = SteadyStateResidual(SteadyStateModel.from_table_header(t.header, lay.wheels), lay)
    rng = np.random.default_rng(23)
    names, cn = lay.parameter_names, lay.constraint_names
    scale = np.asarray(lay.variable_scale)
    for idx in np.ndindex(*t.status.shape):
        if t.status_at(idx) != "optimal":
            continue
        tp = t.at(**t.grid_point(idx))
        x = np.clip(tp.x + 0.05 * scale * rng.standard_normal(len(scale)), tp.lbx, tp.ubx)
        for k in lay.wheels:  # sinkages stay positive
            for v in ("h", "h0"):
                x[lay.var(v, k)] = abs(x[lay.var(v, k)])
        g = rover.residual(x, np.asarray(tp.p))[0]
        speed, slope = tp.p[names.index("speed")], tp.p[names.index("slope")]
        W = lay.wheels
        col = {v: np.array([x[lay.var(v, k)] for k in W]) for v in ("omega", "beta", "h", "h0")}
        q = plant.param_vector((sc.params.wheel.radius,) * len(W), sc.params.soil, slope, tp.p[names.index("cross_slope")],
                               0.0, sc.rover_file.weight / plant.gravity, 1.0, 0.0)
        a = np.concatenate([col["omega"], np.ones(len(W)), np.zeros(len(W)), col["beta"], [speed, 0.0, 0.0, 0.0, 0.0],
                            col["omega"]])
        z = np.concatenate([[speed, 0.0, 0.0], col["omega"], np.log(col["h"]), np.log(col["h0"])])
        res = plant.evaluate(z, a, q, jacobian=False)[0]
        for i, n in enumerate(plant.balance_names):
            if n == "Fz":
                continue
            row_scale = lay[f"balance {n}"].scale
            unit = (plant.rs_nominal if n.startswith("height") else
                    sc.rover_file.weight * (1.0 if n in ("Fx", "Fy") else plant.wheelbase))
            assert abs(res[i] * unit - g[cn.index(f"balance {n}")]) <= 1e-9 * row_scale, (idx, n)


def test_the_mini_rover_through_its_rover_file_drives_as_the_mini_rovers_own_plant(tmp_path):
    """The ``rocker`` kind: the mini rover's rover file (``rover = "mini_rover_t72"``) runs on
    :class:`~offline.sim.suspension_plant.SuspensionPlant` (rows from the file's link tree), the
    mini rover's own scenario on :class:`~offline.sim.plant.PlantModel` (its own rocker statics,
    written independently). Same world, servos and commands (steered, RL unpowered), 2 s: the same
    motion to 1e-4 of each quantity's scale, the yaw to 1e-3. They differ by design in the yaw
    row's lever arms: the rover file's statics take each wheel where its rocker's pitch ``phi``
    puts it (``x = +-l_r/2 cos phi + h_r sin phi``), PlantModel's yaw row the nominal
    ``+-l_r / 2``; a relative difference of order ``h_r phi / (l_r / 2)`` (1.4e-3 at the
    2 mrad pitch here), measured 1.4e-4 in the yaw rate."""
    from rtctl.messages import Commands

    from offline.rover.scenario import load_scenario
    from offline.sim.simulator import RoverSimulator

    p = tmp_path / "mini_file_rl_unpowered.toml"
    p.write_text('[scenario]\nname = "mini_file_rl_unpowered"\nrover = "mini_rover_t72"\nparams = "dissertation-ch7"\n'
                 'speed_m_s = 0.03\n\n[wheels.RL]\nunpowered = true\n')
    own = RoverSimulator(load_scenario(ROOT / "offline" / "scenarios" / "rl_unpowered.toml"), seed=1)
    via = RoverSimulator(load_scenario(p), truth=own.truth, actuators=own.act.config, seed=1)
    assert type(via.plant).__name__ == "SuspensionPlant" and type(own.plant).__name__ == "PlantModel"
    assert via.wheels == own.wheels and via.weight == pytest.approx(own.weight, rel=1e-12)
    rim, steer = (0.034, 0.036, 0.033, 0.035), (0.05, 0.02, -0.03, 0.0)
    for sim in (own, via):
        sim.start(Commands(0.0, 0, rim, steer))
        sim.advance(2.0)
    z0, z1 = own.z, via.z
    assert abs(z1[0] - z0[0]) <= 1e-4 * 0.03 and abs(z1[1] - z0[1]) <= 1e-4 * 0.03 and abs(z1[2] - z0[2]) <= 1e-3 * abs(z0[2])
    assert np.max(np.abs(z1[3:7] - z0[3:7])) <= 1e-4 * np.max(np.abs(z0[3:7]))  # wheel speeds (RL free)
    assert np.max(np.abs(z1[7:] - z0[7:])) <= 1e-4  # log sinkages
    assert abs(via.heading - own.heading) <= 1e-3 * abs(own.heading) and abs(via.y - own.y) <= 1e-3 * abs(own.y)
    assert abs(z0[2]) > 1e-3 and abs(z0[3 + 3] - rim[3] / own.scenario.params.wheel.shearing_radius) > 1e-3  # turning; RL free


def test_offnominal_drive_on_a_rover_file_records_its_wheel_set(tmp_path, capsys):
    """``offnominal drive`` on a six-wheel scenario with rtctl on one table: the drive on the path,
    the recording with the six wheels and the truth; the mini rover's section 7.2.4 PID
    controllers are refused for a rover file with the reason."""
    from rtctl.recording import read_recording

    from offline.cli import main

    scen = str(SCENARIOS / "mer_rf_steer_stuck_7.toml")
    rc = main(["drive", scen, "--controllers", "rtctl", "--tables", str(ROVER_TABLES / "mer_rf_steer_stuck_7.npz"),
               "--distance", "0.2", "--out", str(tmp_path / "a"), "--quiet"])
    assert rc == 0
    r = read_recording(tmp_path / "a" / "mer_rf_steer_stuck_7_rtctl.mcap")
    assert r.wheels == ("RF", "LF", "RM", "LM", "RR", "LR") and len(r.truth[-1]["omega"]) == 6
    assert abs(math.degrees(r.truth[-1]["heading"])) <= HEADING_TARGET_DEG
    assert main(["drive", scen, "--controllers", "fb", "--out", str(tmp_path / "b"), "--quiet"]) == 2
    assert "section 7.2.4 steering controllers are built for the mini rover's four wheels" in capsys.readouterr().err


def test_rtctl_drives_the_skid_steer_with_its_unpowered_wheel_on_the_line():
    """rtctl on the rigid skid-steer (no steering, FR unpowered), 1 m at 3 cm/s with the default
    sensors: heading and cross-track within the issue's targets, the speed within 10 %, every tick
    the QP's, nearly all solved by the exact active set, and the free-rolling FR wheel's command
    steady (see the assertions). The table has no lateral authority (:func:`rtctl.controller.lateral_authority`), so
    no F_y offset is asked for and the cross-track error is corrected through the heading. Before
    (the crab bias's F_y and M_z fed to a QP that cannot make F_y): 10.2 deg after 1 m, 180 deg
    and 0.2 cm/s over 5 m. About 4 CPU-s."""
    from rtctl.controller import lateral_authority

    t = load_table(ROVER_TABLES / "skid_fr_unpowered.npz")
    assert not lateral_authority(t.at(slope=0.0, cross_slope=0.0, speed=0.03), t.layout)
    from offline.rover.scenario import load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.simulator import RoverSimulator

    diags, rims = [], []
    sc = load_scenario(SCENARIOS / "skid_fr_unpowered.toml").with_(speed=0.03)
    ctl = _rtctl(t, 0.03)
    step = ctl.step

    def logged(m):
        cmd, d = step(m)
        diags.append(d)
        rims.append(cmd.rim_speed)
        return cmd, d

    ctl.step = logged  # type: ignore[method-assign]
    res = run_drive(RoverSimulator(sc, seed=1), ctl, distance=1.0)
    m = res.metrics
    assert not res.ended and m["distance_m"] >= 1.0
    assert m["max_abs_heading_deg"] <= HEADING_TARGET_DEG and m["max_abs_cross_track_cm"] <= 100 * CROSSTRACK_TARGET_M, m
    assert abs(m["speed_error_pct"]) <= 10.0
    # No F_y offset is ever asked for, no tick's QP is refused, and the exact active set solves
    # nearly all of them. The measured cross slope's lateral weight leaves the F_y row, which no
    # free variable moves, a slack of about 1e-3 scaled. That row is left out of the solve
    # (rtctl.allocator's _unreachable_rows). Before, the active set refused every such QP
    # (multiplier violation / 1e-12): OSQP took 167 of 168 ticks in 50-2575 iterations, and one
    # ran past its budget to the fallback. OSQP is left for ticks whose balance needs slack
    # within the rate limits. Measured with the slip dead band, 1 m: seeds 1, 2 and 5, all 168
    # ticks exact; seed 3, 154 of 168 (tests/bench/results_any_rover_drives.md, i23-skid).
    ticks = diags[1:]
    assert all(d.fy_offset == 0.0 for d in ticks)
    assert [d.reason for d in ticks if d.mode != "qp"] == []
    exact = sum(d.qp_status.startswith("solved (active set)") for d in ticks)
    assert exact >= 0.8 * len(ticks), (exact, len(ticks))
    assert not any("unreachable" in f for d in diags for f in d.flags)
    # The free-rolling FR wheel's command does not chatter. Before the slip correction's dead band
    # (rtctl.controller, on a table without lateral authority), the speed shift passed the EKF
    # slip noise to every wheel each tick: FR moved 0.108 mm/s a tick on average on this drive,
    # and over 5 m the commands chattered at the 4 mm/s rate limit. Now it moves less than
    # 0.001 mm/s. A start whose slip estimate settles more slowly lets the shift act
    # longer: seed 3 moves 0.37 mm/s a tick over its first metre, and 0.075 over 5 m.
    fr = list(t.layout.wheels).index("FR")
    change = np.abs(np.diff(np.asarray(rims, dtype=float)[:, fr]))
    assert float(change.mean()) < 1e-5, float(change.mean())


@pytest.mark.parametrize("path", sorted((ROOT / "tests" / "data" / "tables").glob("**/*.npz")), ids=lambda p: p.stem)
def test_lateral_authority_only_the_skid_steer_lacks_it(path):
    """Every steered test table can move its F_y balance row; the skid-steer's cannot."""
    from rtctl.controller import lateral_authority

    t = load_table(path)
    tp = t.at(**{a: float(v[len(v) // 2]) for a, v in t.axes.items()})
    assert lateral_authority(tp, t.layout) is (path.stem != "skid_fr_unpowered")


def test_hook_forces_on_the_six_wheel_plant_are_balanced_where_they_act():
    """A disturbance hook on the MER-class plant (quasi-static root, RF unpowered, the others at their
    servo speed): the soil's wrenches at the root balance the hook's forces as a free body does --
    planar forces and the yaw moment about O summed independently of the plant's rows (each wheel's
    soil force turned by its steering, plus the hook's force at that wheel's plan position, plus the
    body force and moment) are zero; the unpowered wheel's soil axle moment equals the hub torque on it
    (``M_y + T - tau = 0``, ``T = 0``); a zero vector is bit for bit no hook; and a body force
    ``(-k, 0)`` is the truth's tether ``k`` (the same root to rounding)."""
    from offline.rover.table_verify import spec_from_table
    from offline.sim.simulator import suspension_plant_for

    t = load_table(ROVER_TABLES / "mer_rf_steer_stuck_7.npz")
    sc = spec_from_table(t).scenario
    plant = suspension_plant_for(sc.params, sc.rover_file, sc.exit_angle)
    a, q, z0, _, speed = _plant_inputs(plant, t, sc, next(np.ndindex(*t.status.shape)))
    n, W = plant.n, plant.wheels
    a = a.copy()
    rf = W.index("RF")
    a[n + rf] = 0.0  # RF unpowered: torque mode, zero motor torque
    d = _hook_vector(n)
    d[3 + 2 * n + rf] = 0.6  # hub torque on the unpowered wheel, N m
    z, sol = plant.solve(plant.initial_guess(speed, q), a, q, d)
    steer = a[3 * n:4 * n]
    c, s_ = np.cos(steer), np.sin(steer)
    Fx = c * sol.wrench[:, 0] - s_ * sol.wrench[:, 1] + d[3:3 + n]
    Fy = s_ * sol.wrench[:, 0] + c * sol.wrench[:, 1] + d[3 + n:3 + 2 * n]
    from offline.physics.backend import NUMPY

    pos = plant.statics.positions(NUMPY, {k: sol.sinkage[i] for i, k in enumerate(W)})[0]  # wheel centres at these sinkages
    xs, ys = np.array([pos[k][0] for k in W]), np.array([pos[k][1] for k in W])
    weight, m = sc.rover_file.weight, q[n + 12]
    assert q[n + 9] == 0.0 and q[n + 10] == 0.0  # flat ground: no weight in the planar rows
    # steady turning: the centripetal terms m r v, m r u of the planar rows
    assert abs(Fx.sum() + d[0] + m * sol.r * sol.v) <= 1e-7 * weight
    assert abs(Fy.sum() + d[1] - m * sol.r * sol.u) <= 1e-7 * weight
    mz = (sol.wrench[:, 5] + xs * Fy - ys * Fx).sum() + d[2]
    assert abs(mz) <= 1e-7 * weight * plant.wheelbase, mz
    assert sol.wrench[rf, 4] == pytest.approx(0.6, abs=1e-7 * weight * sc.params.wheel.shearing_radius)
    assert abs(sol.r) > 1e-4  # the hook turns the rover: a real yaw balance, not a trivial one
    # no hook, a zero hook, a tether
    r0 = plant.evaluate(z0, a, q)
    rz = plant.evaluate(z0, a, q, np.zeros(3 + 3 * n))
    assert all(np.array_equal(x, y) for x, y in zip(r0, rz))
    k = 3.0
    qt = q.copy()
    qt[n + 11] = k  # the truth's tether
    _, s_t = plant.solve(plant.initial_guess(speed, q), a, qt)
    _, s_h = plant.solve(plant.initial_guess(speed, q), a, q, np.array([-k, 0.0, 0.0] + [0.0] * (3 * n)))
    assert np.allclose(s_t.wrench, s_h.wrench, rtol=0, atol=1e-9 * weight) and s_t.u == pytest.approx(s_h.u, rel=1e-9)
    with pytest.raises(Exception, match=r"3 \+ 3 N = 21"):
        plant.evaluate(z0, a, q, np.zeros(3 + 3 * 4))


def test_a_six_wheel_drive_takes_a_hook_and_its_forces_per_wheel():
    """The simulator of a rover file takes a disturbance hook (contract C5): a hub torque on the
    unpowered RF wheel slows it against its free-rolling twin drive; the applied forces are in the truth
    state with one entry per wheel; a hook giving the mini rover's four wheels a non-zero force is an
    error naming the wheel count; a body-only hook (default per-wheel zeros) serves six wheels."""
    from offline.rover.scenario import load_scenario
    from offline.sim.simulator import DisturbanceError, DisturbanceForces, RoverSimulator
    from rtctl.messages import Commands

    sc = load_scenario(SCENARIOS / "mer_rf_unpowered.toml").with_(speed=0.03)
    go = Commands(0.0, 0, (0.03,) * 6, (0.0,) * 6)
    runs = {}
    for name, hook in (("none", None), ("hub torque RF", lambda t, s: DisturbanceForces(wheel_torque=(2.0,) + (0.0,) * 5)),
                       ("body", lambda t, s: DisturbanceForces(body_force=(-5.0, 0.0)))):
        sim = RoverSimulator(sc, seed=1, disturbance=hook)
        sim.start(go)
        sim.advance(1.0)
        runs[name] = sim.truth_state()
    assert runs["hub torque RF"].omega[0] < 0.9 * runs["none"].omega[0]  # the unpowered wheel slowed by its hub
    assert runs["hub torque RF"].disturbance.wheel_torque == (2.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert runs["body"].u < runs["none"].u and runs["body"].disturbance.vector(6)[0] == -5.0
    sim = RoverSimulator(sc, seed=1, disturbance=lambda t, s: DisturbanceForces(wheel_torque=(1.0, 0.0, 0.0, 0.0)))
    with pytest.raises(DisturbanceError, match="wheel_torque has 4 entries; the simulated rover has 6 wheels"):
        sim.start(go)
