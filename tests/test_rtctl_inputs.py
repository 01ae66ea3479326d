"""The controller's input boundary (rtctl.inputs, issue 25 "safety first"): every field converted
once with clear rejection, time stamps and sequence numbers judged against the last accepted
measurement, recovery from a restart, and ``Controller.step`` never raising whatever arrives."""

from __future__ import annotations

import decimal
import fractions
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rtctl.config import ControllerConfig
from rtctl.controller import Controller
from rtctl.inputs import (MAX_STEP_TIME, RATE_TOLERANCE, REBASE_AFTER, SLACK_TICKS, TickClock, finite_real, integer,
                          read_measurements, real, safe_repr)
from rtctl.messages import MODES, FailureDeclaration, Measurements, Pose, Task
from rtctl_synthetic import RS, synthetic_tables

OM = 0.03 / (RS * 0.9)
BIG = 10 ** 400


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    return synthetic_tables(tmp_path_factory.mktemp("tables"))


def meas(k: int, **kw) -> Measurements:
    base = dict(t=0.2 * k, seq=k, wheel_speed=(OM,) * 4, steer_angle=(0.0,) * 4, yaw_rate=0.0)
    base.update(kw)
    return Measurements(**base)


def valid(c, cfg: ControllerConfig) -> bool:
    a = cfg.actuators
    return c.is_valid(a.max_rim_speed, a.max_steer) and min(c.rim_speed) >= a.min_rim_speed


# ---------------------------------------------------------------- conversion
@pytest.mark.parametrize("v, want", [(1, 1.0), (0.5, 0.5), (np.float32(0.25), 0.25), (np.int64(3), 3.0),
                                     (fractions.Fraction(1, 4), 0.25), (math.nan, math.nan)])
def test_real_accepts_real_numbers(v, want):
    got = real(v)
    assert got is not None and type(got) is float
    assert (math.isnan(got) and math.isnan(want)) or got == want


@pytest.mark.parametrize("v", [BIG, -BIG, "1234", "0.5", b"1", True, False, np.bool_(True), None, (1.0,), [1.0],
                               1 + 2j, decimal.Decimal("1.5"), np.array([1.0]), object()])
def test_real_rejects_everything_else(v):
    assert real(v) is None
    assert math.isnan(finite_real(v))


def test_finite_and_integer():
    assert math.isnan(finite_real(math.inf)) and finite_real(-2) == -2.0
    assert integer(5) == 5 and integer(np.uint64(7)) == 7 and integer(2 ** 62) == 2 ** 62
    for v in (True, 5.0, "5", None, 2 ** 63, -2 ** 63, BIG, np.float64(5)):
        assert integer(v) is None, v


def test_read_measurements_converts_every_field():
    m = Measurements(t=np.float64(1.0), seq=np.int32(5), wheel_speed=np.array([1.0, 2.0, 3.0, 4.0]),
                     steer_angle=[0.0, "0.1", BIG, math.inf], yaw_rate="0.1", roll=np.float32(0.5), pitch=True,
                     motor_torque=(1, 2, 3), pose=Pose(1.0, BIG, 0.0, 0.0),
                     failures=(FailureDeclaration("RR", "torque_limit", np.float64(2.0)),
                               FailureDeclaration("RR", "locked", "x"), FailureDeclaration(["RR"], "locked"),
                               FailureDeclaration("FL", "torque_limit", BIG), "locked"),
                     task=Task("trench", "RR", BIG))
    inp = read_measurements(m)
    assert inp.t == 1.0 and type(inp.t) is float and inp.seq == 5 and type(inp.seq) is int
    assert inp.wheel_speed == (1.0, 2.0, 3.0, 4.0) and all(type(v) is float for v in inp.wheel_speed)
    assert inp.steer_angle is not None and inp.steer_angle[0] == 0.0 and all(math.isnan(v) for v in inp.steer_angle[1:])
    assert math.isnan(inp.yaw_rate) and inp.roll == 0.5 and math.isnan(inp.pitch)
    assert inp.motor_torque is None  # three entries: the vector is rejected
    assert inp.pose is None and inp.pose_invalid
    assert inp.failures == (FailureDeclaration("RR", "torque_limit", 2.0),) and inp.rejected_failures == 4
    assert inp.task is None and inp.rejected_task.startswith("Task(") and len(inp.rejected_task) <= 200


def test_read_measurements_of_a_string_wheel_vector_and_a_foreign_object():
    inp = read_measurements(meas(1, wheel_speed="1234"))
    assert inp.wheel_speed is None  # a string of four characters is not four wheel speeds
    inp = read_measurements(object())
    assert inp.t is None and inp.seq is None and inp.wheel_speed is None and inp.failures == ()
    assert inp.rejected_failures == 0 and inp.pose is None and not inp.pose_invalid


def test_safe_repr_never_raises():
    assert safe_repr(10 ** 5000)  # str() of an int this long raises ValueError in Python >= 3.11

    class Bad:
        def __repr__(self):
            raise RuntimeError("no")

    assert safe_repr(Bad()) == "<Bad>"


# ---------------------------------------------------------------- the time rule
def test_tick_clock_rule():
    c = TickClock(0.2)
    assert c.judge(0.0, 0) == "first"
    assert c.judge(0.2, 1) == "ok"
    assert c.judge(0.2, 1) == "duplicate"
    assert c.judge(0.1, 2) == "out_of_order" and c.judge(0.4, 1) == "out_of_order"
    assert c.judge(10.2, 51) == "gap"  # a 10 s dropout of the link: t and seq agree
    assert c.judge(10.2 + 3600.0, 52) == "jump"  # the clock alone jumped
    assert c.judge(10.4, 52 + 10 ** 6) == "jump"  # the counter alone jumped
    assert (c.t, c.seq) == (10.2, 51)  # neither became the reference
    assert c.judge(10.6, 53) == "gap"  # the next valid one is judged against the last good one
    # the band: RATE_TOLERANCE times the count plus SLACK_TICKS periods, either way
    c = TickClock(0.2)
    c.judge(0.0, 0)
    edge = RATE_TOLERANCE * 0.2 + SLACK_TICKS * 0.2
    assert c.judge(edge * 0.999, 1) == "ok"
    c = TickClock(0.2)
    c.judge(0.0, 0)
    assert c.judge(edge * 1.001, 1) == "jump"
    c = TickClock(0.2)
    c.judge(0.0, 0)
    assert c.judge(MAX_STEP_TIME * 1.01, int(MAX_STEP_TIME * 1.01 / 0.2)) == "jump"  # consistent but too long


def test_tick_clock_rebases_after_consistent_rejections_only():
    c = TickClock(0.2)
    c.judge(100.0, 500)
    out = [c.judge(0.2 * k, k) for k in range(REBASE_AFTER)]  # a restart near zero
    assert out == ["out_of_order"] * (REBASE_AFTER - 1) + ["rebase"]
    assert (c.t, c.seq) == (0.2 * (REBASE_AFTER - 1), REBASE_AFTER - 1)
    # glitches that do not agree with each other never add up to a rebase
    c = TickClock(0.2)
    c.judge(0.0, 0)
    for k in range(1, 40):
        assert c.judge(1e6 * k, k + 10 ** 7 * (k % 3)) != "rebase"
    assert len(c.candidates) <= REBASE_AFTER
    # an accepted measurement clears the run: a consistent glitch (the clock an hour ahead) on
    # every other tick, valid ticks between, never takes over
    c = TickClock(0.2)
    c.judge(0.0, 0)
    for k in range(1, 41):
        if k % 2:
            assert c.judge(3600.0 + 0.2 * k, k) == "jump"
        else:
            assert c.judge(0.2 * k, k) == "gap"
    assert (c.t, c.seq) == (8.0, 40)


# ---------------------------------------------------------------- the controller
POISONS = {
    "t = 1e300": lambda m: replace(m, t=1e300),
    "t one hour ahead": lambda m: replace(m, t=m.t + 3600.0),
    "t 1e6 s ahead": lambda m: replace(m, t=m.t + 1e6),
    "t one hour back": lambda m: replace(m, t=m.t - 3600.0),
    "seq + 2**62": lambda m: replace(m, seq=m.seq + 2 ** 62),
    "seq + 1e6": lambda m: replace(m, seq=m.seq + 10 ** 6),
    "seq - 1e6": lambda m: replace(m, seq=m.seq - 10 ** 6),
    "t = 10**400": lambda m: replace(m, t=BIG),
    "seq = 10**400": lambda m: replace(m, seq=BIG),
    "t a string": lambda m: replace(m, t=str(m.t)),
}


@pytest.mark.parametrize("name", sorted(POISONS))
def test_one_poisoned_time_costs_at_most_one_tick(tables, name):
    c = Controller(tables, ControllerConfig())
    modes = []
    for k in range(40):
        m = meas(k)
        _, d = c.step(POISONS[name](m) if k == 20 else m)
        modes.append(d.mode)
    assert modes[20] == "hold"
    assert modes.count("hold") == 1 and set(modes[21:]) == {"qp"}, modes


@pytest.mark.parametrize("field, value", [("yaw_rate", BIG), ("roll", BIG), ("pitch", -BIG),
                                          ("wheel_speed", (BIG, OM, OM, OM)), ("steer_angle", (0.0, 0.0, "0", 0.0)),
                                          ("pose", Pose(0.0, BIG, 0.0, 0.0)), ("pose", Pose(BIG, 0.0, 0.0, 0.0)),
                                          ("failures", (FailureDeclaration("RR", "torque_limit", BIG),)),
                                          ("task", Task("trench", "RR", BIG))])
def test_huge_int_in_a_field_is_rejected_not_raised(tables, field, value):
    cfg = ControllerConfig()
    c = Controller(tables, cfg)
    c.step(meas(0))
    cmd, d = c.step(meas(1, **{field: value}))
    assert valid(cmd, cfg) and d.mode == "qp"
    assert sum(v for k, v in d.counters if k.startswith("rejected_")) >= 1, d.counters


def test_int_too_long_to_print_is_rejected(tables):
    """An int whose repr raises (over 4300 digits, Python >= 3.11) in the time, a field and the
    task: rejected, and the rejected task's flag still has a text."""
    cfg = ControllerConfig()
    c = Controller(tables, cfg)
    c.step(meas(0))
    huge = 10 ** 5000
    cmd, d = c.step(meas(1, t=huge))
    assert d.mode == "hold" and d.counter("rejected_bad_time_or_seq") == 1 and valid(cmd, cfg)
    cmd, d = c.step(meas(2, yaw_rate=huge, task=Task("trench", "RR", huge)))
    assert d.mode == "qp" and d.counter("rejected_yaw_rate") == 1 and d.counter("rejected_task") == 1
    assert any("<Task>" in f for f in d.flags)


def test_string_wheel_speed_is_rejected_not_parsed(tables):
    """A plausible wheel speed as a string ('0.52...') was accepted through float(); now the
    wheel is taken out of the odometry and counted."""
    c = Controller(tables, ControllerConfig())
    c.step(meas(0))
    _, d = c.step(meas(1, wheel_speed=(str(OM), OM, OM, OM)))
    assert d.counter("rejected_wheel_FR") == 1 and d.mode == "qp"
    _, d = c.step(meas(2, wheel_speed="1234"))
    assert d.counter("rejected_wheel_vectors") == 1


@pytest.mark.parametrize("t0, seq0", [(0.0, 0), (3600.0, 7)])
def test_restart_and_pause_recover(tables, t0, seq0):
    """A reboot (t and seq start again near zero) or a paused process (t an hour later, seq one
    higher) is taken up after REBASE_AFTER consistent measurements, as a stale gap."""
    cfg = ControllerConfig()
    c = Controller(tables, cfg)
    for k in range(30):
        c.step(meas(k))
    base_t = t0 if t0 == 0.0 else 0.2 * 29 + t0
    base_seq = seq0 if t0 == 0.0 else 29 + 1
    modes = []
    for j in range(20):
        cmd, d = c.step(meas(0, t=base_t + 0.2 * j, seq=base_seq + j))
        assert valid(cmd, cfg)
        modes.append(d.mode)
    assert modes[:REBASE_AFTER - 1] == ["hold"] * (REBASE_AFTER - 1)
    assert set(modes[REBASE_AFTER - 1:]) == {"qp"}, modes
    assert d.counter("clock_rebases") == 1 and d.counter("stale_gaps") == 1


def test_poisoned_first_measurement_recovers(tables):
    c = Controller(tables, ControllerConfig())
    c.step(meas(0, t=5e8, seq=2 ** 62))
    modes = [c.step(meas(k))[1].mode for k in range(1, 20)]
    assert modes[:REBASE_AFTER - 1] == ["hold"] * (REBASE_AFTER - 1) and set(modes[REBASE_AFTER - 1:]) == {"qp"}


# ---------------------------------------------------------------- property: never raises
scalars = st.one_of(
    st.none(), st.booleans(), st.integers(), st.sampled_from([BIG, -BIG, 2 ** 62, 2 ** 63, -2 ** 63]),
    st.floats(), st.text(max_size=6), st.binary(max_size=3), st.complex_numbers(max_magnitude=1e3),
    st.floats(width=32).map(np.float32), st.floats().map(np.float64), st.integers(-2 ** 63, 2 ** 63 - 1).map(np.int64),
    st.booleans().map(np.bool_), st.just(decimal.Decimal("1.5")), st.just(np.array([1.0, 2.0])))
anything = st.recursive(scalars, lambda inner: st.one_of(st.tuples(inner, inner), st.lists(inner, max_size=5),
                                                         st.tuples(inner, inner, inner, inner)), max_leaves=8)
wheels = st.sampled_from(["FR", "FL", "RR", "RL", "??", ""])
failure = st.one_of(anything, st.builds(FailureDeclaration, st.one_of(wheels, anything),
                                        st.one_of(st.sampled_from(["steer_stuck", "rim_speed_cap", "locked", "unpowered",
                                                                   "raised", "torque_limit"]), anything),
                                        st.one_of(st.floats(-1.0, 1.0), anything)))
task = st.one_of(st.none(), anything, st.builds(Task, st.one_of(st.just("trench"), anything), st.one_of(wheels, anything),
                                                st.one_of(st.floats(0.0, 0.1), anything)))
pose = st.one_of(st.none(), anything, st.builds(Pose, anything, anything, anything, anything),
                 st.builds(Pose, st.floats(-1, 10), st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
quad = st.one_of(st.just((OM,) * 4), anything, st.tuples(anything, anything, anything, anything),
                 st.lists(st.floats(-2, 2), min_size=4, max_size=4).map(np.array))
tick = st.fixed_dictionaries({
    "time": st.one_of(st.just("next"), st.just("next"), anything,
                      st.tuples(st.floats(-1e12, 1e12), st.integers(-2 ** 64, 2 ** 64))),
    "wheel_speed": quad, "steer_angle": st.one_of(st.just((0.0,) * 4), quad),
    "yaw_rate": st.one_of(st.just(0.0), anything), "roll": st.one_of(st.just(0.0), anything),
    "pitch": st.one_of(st.just(0.0), anything), "motor_torque": st.one_of(st.none(), quad), "pose": pose,
    "failures": st.one_of(st.just(()), st.lists(failure, max_size=3).map(tuple), anything), "task": task})


@settings(max_examples=50, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.lists(tick, min_size=1, max_size=12))
def test_property_step_never_raises_on_arbitrary_values(tables, ticks):
    """Whatever Python value arrives in any field (huge ints, strings, None, nested tuples, numpy
    scalars and arrays, bools, complex, Decimal) step returns valid commands and diagnostics."""
    cfg = ControllerConfig()
    c = Controller(tables, cfg)
    k = 0
    for tk in ticks:
        fields = dict(tk)
        tm = fields.pop("time")
        if isinstance(tm, str) and tm == "next":
            k += 1
            t, seq = 0.2 * k, k
        elif isinstance(tm, tuple) and len(tm) == 2 and isinstance(tm[1], int) and not isinstance(tm[1], bool):
            t, seq = tm
        else:
            t, seq = tm, tm
        cmd, d = c.step(Measurements(t=t, seq=seq, **fields))
        assert valid(cmd, cfg), (cmd, d)
        assert d.mode in MODES and type(cmd.t) is float and type(cmd.seq) is int
        assert all(math.isfinite(v) for v in d.state)
