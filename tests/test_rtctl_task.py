"""The operator's driving task (``Measurements.task``): a trench goal selects the trench table,
which is read at the declared depth (clamped and flagged outside its axis); recordings carry
the task (format 2) and still read format 1; the section 7.3 trench drive with rtctl runs on the
trench table and leaves the trench the soil-flow model predicts for the goal.

The tables are the committed test tables (``tests/data/tables``, built on the dissertation's
chapter-7 parameters, the simulator's default world): nominal, rr_speed_cap_half,
rr_steer_stuck_50 and rr_trench_clean (trench depth axis 20, 25, 30 mm).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

import rtctl.recording as recording
from offline.sim.experiments import declared_task, run_drive, scenario_by_name, trench_metrics
from offline.sim.rtctl_bridge import rtctl_factory
from offline.sim.simulator import RoverSimulator
from rtctl.config import ControllerConfig
from rtctl.controller import Controller, load_tables, table_signature
from rtctl.messages import Commands, Measurements, Pose, Task
from rtctl.recording import Recorder, RecordingError, read_recording

TABLES = Path(__file__).parent / "data" / "tables"


@pytest.fixture(scope="module")
def tables():
    return load_tables(TABLES / "index.json")


def _m(k: int, task=None, failures=()) -> Measurements:
    om = 0.03 / 0.0625
    return Measurements(t=0.2 * k, seq=k, wheel_speed=(om,) * 4, steer_angle=(0.0,) * 4, yaw_rate=0.0,
                        pose=Pose(0.2 * k, 0.006 * k, 0.0, 0.0), failures=failures, task=task)


def _run(tables, task, n=3):
    ctl = Controller(tables, ControllerConfig())
    out = [ctl.step(_m(k, task)) for k in range(n)]
    return ctl, out


def test_trench_table_signature(tables):
    assert table_signature(tables["rr_trench_clean"]) == frozenset({("RR", "trench")})
    assert table_signature(tables["nominal"]) == frozenset()


def test_task_selects_trench_table_at_declared_depth(tables):
    _, out = _run(tables, Task("trench", "RR", 0.022))
    _, d = out[-1]
    assert d.table == "rr_trench_clean"
    assert dict(d.operating_point)["trench_depth"] == pytest.approx(0.022)
    assert not d.flags
    # no task: the nominal table (a trench goal is not selected by anything else)
    _, out = _run(tables, None)
    assert out[-1][1].table == "nominal"


def test_depth_outside_axis_is_clamped_and_flagged(tables):
    for depth, edge in ((0.05, 0.03), (0.01, 0.02)):
        _, out = _run(tables, Task("trench", "RR", depth))
        _, d = out[-1]
        assert d.table == "rr_trench_clean"
        assert dict(d.operating_point)["trench_depth"] == pytest.approx(edge)
        assert any("trench_depth" in f and "outside" in f for f in d.flags), d.flags


def test_task_without_table_and_bad_tasks(tables):
    # a trench with the front-left wheel: no such table -> nominal, flagged
    _, out = _run(tables, Task("trench", "FL", 0.02))
    assert out[-1][1].table == "nominal"
    assert any("no table for the declared task" in f for f in out[-1][1].flags)
    for bad in (Task("dig", "RR", 0.02), Task("trench", "XX", 0.02), Task("trench", "RR", math.nan),
                Task("trench", "RR", -0.01), "trench"):
        ctl, out = _run(tables, bad)
        _, d = out[-1]
        assert d.table == "nominal" and d.counter("rejected_task") == 3
        assert any("rejected" in f for f in d.flags)
        assert all(c.is_valid(ctl.config.actuators.max_rim_speed, ctl.config.actuators.max_steer) for c, _ in out)


def test_recording_carries_task_and_reads_format_1(tmp_path, monkeypatch):
    m = _m(1, Task("trench", "RR", 0.025))
    with Recorder(tmp_path / "v2.mcap") as rec:
        rec.measurements(m)
        rec.commands(Commands(m.t, m.seq, (0.03,) * 4, (0.0,) * 4))
    back = read_recording(tmp_path / "v2.mcap")
    assert back.metadata["format_version"] == "2" and back.measurements[0] == m
    # a format-1 file (before tasks): read with task None
    monkeypatch.setattr(recording, "FORMAT_VERSION", "1")
    with Recorder(tmp_path / "v1.mcap") as rec:
        rec.measurements(_m(1))
    old = read_recording(tmp_path / "v1.mcap")
    assert old.metadata["format_version"] == "1" and old.measurements[0].task is None
    monkeypatch.setattr(recording, "FORMAT_VERSION", "3")
    with Recorder(tmp_path / "v3.mcap") as rec:
        rec.measurements(_m(1))
    with pytest.raises(RecordingError, match="recording format '3', this reader reads 1, 2; re-record"):
        read_recording(tmp_path / "v3.mcap")


def test_section_7_3_trench_drive_runs_on_trench_table():
    """rtctl in the simulator on the scenario of section 7.3.1 (RR digs a clean-sided trench,
    goal depth >= b/2 = 25 mm): every tick on the trench table at the declared 25 mm, and the
    trench left behind (soil-flow model from the true wheel state) is 25 mm deep with a
    rim-side pile under 2 mm; the rover holds its line within 3 deg / 3 cm."""
    sc = scenario_by_name("rr_trench_clean")
    assert declared_task(sc) == Task("trench", "RR", 0.025)
    ctl = rtctl_factory(str(TABLES))(sc)
    diags = []

    class Spy:
        name = "rtctl"

        def reset(self):
            ctl.reset()

        def step(self, m):
            assert m.task == Task("trench", "RR", 0.025)
            c, d = ctl.step(m)
            diags.append(d)
            return c, d

    sim = RoverSimulator(sc, seed=3)
    res = run_drive(sim, Spy(), distance=0.3)
    assert {d.table for d in diags} == {"rr_trench_clean"}
    # every tick solved by the QP (before the unbounded trench rows were dropped from its
    # Jacobian, OSQP stopped at its iteration budget on ~95 % of the ticks: fallbacks)
    assert [d.mode for d in diags] == ["qp"] * len(diags)
    assert all(dict(d.operating_point)["trench_depth"] == pytest.approx(0.025) for d in diags)
    m = res.metrics
    assert m["trench_depth_mm"] == pytest.approx(25.0, abs=1.0)
    assert m["trench_pile_mm"] < 2.0
    assert abs(m["max_abs_heading_deg"]) < 3.0 and abs(m["max_abs_cross_track_cm"]) < 3.0
    # the same drive without the task (the pre-task controller) digs no clean-sided trench
    ctl2 = rtctl_factory(str(TABLES))(sc)
    sim2 = RoverSimulator(sc, seed=3)

    class NoTask(Spy):
        def step(self, m):
            return ctl2.step(replace(m, task=None))

        def reset(self):
            ctl2.reset()

    res2 = run_drive(sim2, NoTask(), distance=0.3)
    m2 = trench_metrics(res2.truth, sc)
    assert m2["trench_depth_mm"] < 20.0 or m2["trench_pile_mm"] > 2.0


def test_unbounded_rows_dropped_give_the_same_qp(tables):
    """Zeroing the rows without bounds (the trench flat width, Jacobian ~1e5 in scaled units)
    leaves the QP's solution unchanged (clarabel on both) and lets OSQP converge."""
    import numpy as np

    from rtctl.allocator import QpAllocator, solve_with_qpsolvers
    from rtctl.config import QpSettings
    from rtctl.controller import _Index
    from rtctl.rti import BoundedRows as _BoundedRows

    t = tables["rr_trench_clean"]
    tp = t.at(slope=0.0, speed=0.03, trench_depth=0.025)
    ix = _Index(t.layout)
    row = {b.name: b.start for b in t.layout.constraints}["trench flat width RR"]
    assert tp.lbg[row] <= -1e20 and tp.ubg[row] >= 1e20 and np.abs(np.asarray(tp.jac_g_x)[row]).max() > 0
    sols, its = [], []
    for point in (tp, _BoundedRows(tp, ix.torque)):
        a = QpAllocator(t.layout, QpSettings())
        a.prepare(point)
        p = np.array(tp.p, dtype=float)
        p[ix.mz] += 0.1
        res = a.solve(p, (np.asarray(tp.lbx), np.asarray(tp.ubx)))
        its.append((res.ok, res.iterations))
        sols.append(solve_with_qpsolvers(a.problem(), "clarabel")[:t.layout.nx])
    assert np.max(np.abs(sols[0] - sols[1])) < 1e-5
    assert its[1][0] and its[1][1] < 1000, its


def test_unreachable_speed_cap_on_slope_is_flagged(tables):
    """RR rim speed capped at 1.5 cm/s (half the target 3 cm/s) on a 5 deg uphill: the test
    table (the simulator's model) has no primitive at fraction 0.5 there (fractions 0.4 and 0.5
    not found / infeasible at 5 deg, 0.6 optimal). The controller says so and reads the table at
    the fastest reachable speed, 2.5 cm/s (fraction 0.6); on flat ground it does not."""
    from rtctl.messages import FailureDeclaration

    cap = (FailureDeclaration("RR", "rim_speed_cap", 0.015),)
    for pitch, unreachable in ((math.radians(5.0), True), (0.0, False)):
        ctl = Controller(tables, ControllerConfig())
        for k in range(40):  # the tilt filter (1 s) settles on the slope; no pose: no slip correction
            m = replace(_m(k, failures=cap), pitch=pitch, pose=None)
            c, d = ctl.step(m)
            assert c.rim_speed[2] <= 0.015 + 1e-12
        assert d.table == "rr_speed_cap_half"
        flagged = [f for f in d.flags if f.startswith("target unreachable")]
        assert bool(flagged) == unreachable, d.flags
        if unreachable:
            assert dict(d.operating_point)["speed"] == pytest.approx(0.025)
            assert dict(d.operating_point)["rim_speed_cap_fraction"] == pytest.approx(0.6)
            assert "2.50 cm/s (-17 % of the target)" in flagged[0]


# ---------------------------------------------------------------- tasks as data (issue 21)
def _retasked(tables, tmp_path, task):
    """The trench table with its header's ``task`` replaced (re-hashed, arrays unchanged)."""
    from rtctl.table import load_table, table_bytes

    old = tables["rr_trench_clean"]
    head = {k: v for k, v in old.header.items() if k != "content_hash"}
    head["task"] = task
    head["family"] = dict(head["family"], declares={"task": task["kind"]})  # the axis follows the task's value
    f = tmp_path / "rr_trench_clean.npz"
    f.write_bytes(table_bytes(head, old.arrays))
    return load_table(f)


def test_task_kind_is_the_offline_classes_description(tables):
    """The trench table's header carries the task kind as data written by the goal's own class
    (``TrenchGoal.rover_description``), and rtctl takes its kinds from there only."""
    from offline.rover.failures import TrenchGoal

    task = tables["rr_trench_clean"].header["task"]
    assert task["kind"] == "trench" and task["description"] == TrenchGoal.rover_description()
    ctl = Controller(tables, ControllerConfig())
    assert set(ctl.task_kinds) == {"trench"}
    spec = ctl.task_kinds["trench"]
    assert (spec.value_unit, spec.value_lo, spec.value_hi, spec.odometry) == ("m", 0.0, 0.5, False)
    import rtctl.messages

    assert not hasattr(rtctl.messages, "TASK_KINDS")  # no list of its own


def test_a_task_kind_new_to_the_rover_works_from_its_description(tables, tmp_path):
    """A task table whose header describes another kind (here the trench table relabelled
    "furrow", depth range [0, 0.04] m, its wheel still in the odometry): rtctl serves a
    ``Task("furrow", ...)`` from it with no change to rtctl, range-checks it by the description,
    keeps the wheel in the odometry as described, and refuses "trench" (no table describes it)."""
    from offline.rover.failures import TrenchGoal

    desc = dict(TrenchGoal.rover_description(), kind="furrow", odometry=True,
                value={"name": "depth", "unit": "m", "lo": 0.0, "hi": 0.04})
    t = _retasked(tables, tmp_path, {"kind": "furrow", "wheel": "RR", "description": desc})
    tabs = {"nominal": tables["nominal"], "rr_furrow": t}
    ctl, out = _run(tabs, Task("furrow", "RR", 0.022))
    d = out[-1][1]
    assert d.table == "rr_furrow" and not d.flags
    assert dict(d.operating_point)["trench_depth"] == pytest.approx(0.022)
    assert ctl._odometry_wheels() == [True, True, True, True]
    ctl, out = _run(tabs, Task("furrow", "RR", 0.05))  # outside the described range
    d = out[-1][1]
    assert d.table == "nominal" and d.counter("rejected_task") == 3
    assert any("furrow depth 0.05 m outside [0, 0.04]" in f for f in d.flags), d.flags
    ctl, out = _run(tabs, Task("trench", "RR", 0.022))
    d = out[-1][1]
    assert d.table == "nominal" and d.counter("rejected_task") == 3
    assert any("no loaded table describes task kind 'trench'" in f for f in d.flags), d.flags
    # the trench's own description keeps its digging wheel out of the odometry
    ctl, _ = _run(tables, Task("trench", "RR", 0.022))
    assert ctl._odometry_wheels() == [True, True, False, True]


def test_a_task_table_without_description_is_unavailable(tables, tmp_path):
    """A trench table built before task kinds were data (``task`` without ``description``) is not
    driven: unavailable at start-up with the command that fixes it, and the task is refused."""
    t = _retasked(tables, tmp_path, {"kind": "trench", "wheel": "RR"})
    ctl = Controller({"nominal": tables["nominal"], "rr_trench_clean": t}, ControllerConfig())
    assert "offnominal tables describe" in ctl.unavailable["rr_trench_clean"]
    out = [ctl.step(_m(k, Task("trench", "RR", 0.022))) for k in range(2)]
    assert out[-1][1].table == "nominal" and out[-1][1].counter("rejected_task") == 2
