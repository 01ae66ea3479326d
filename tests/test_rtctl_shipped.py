"""The controller on the shipped tables (tables/index.json), each with its own failure declared."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from rtctl.config import ControllerConfig
from rtctl.controller import Controller, ControllerError, load_tables
from rtctl.messages import FailureDeclaration, Measurements, Pose

INDEX = Path(__file__).resolve().parents[1] / "tables" / "index.json"
"""The shipped tables are in the repository: a missing index fails the tests (no skip)."""

CASES = [((), "nominal"), ((FailureDeclaration("RR", "steer_stuck"),), "rr_steer_stuck"),
         ((FailureDeclaration("RR", "rim_speed_cap", 0.015),), "rr_rim_speed_cap"),
         ((FailureDeclaration("RR", "unpowered"),), "rr_unpowered")]


@pytest.fixture(scope="module")
def tables():
    return load_tables(INDEX)


@pytest.mark.parametrize("failures, table", CASES)
def test_each_failure_uses_its_table(tables, failures, table):
    cfg = ControllerConfig()
    c = Controller(tables, cfg)
    a = cfg.actuators
    steer = (0.0, 0.0, math.radians(-50.0), 0.0)
    for k in range(10):
        cmd, d = c.step(Measurements(0.2 * k, k, (0.6,) * 4, steer, 0.0, failures=failures,
                                     pose=Pose(0.2 * k, 0.0, 0.02, math.radians(2.0)) if k == 2 else None))
        assert cmd.is_valid(a.max_rim_speed, a.max_steer)
    assert d.table == table and d.mode == "qp" and d.qp_slack < 1e-3, d
    if table == "rr_steer_stuck":
        assert cmd.steer_angle[2] == pytest.approx(math.radians(-50.0))
    if table == "rr_rim_speed_cap":
        assert cmd.rim_speed[2] <= 0.015 + 1e-12


def test_table_without_primitive_is_said_unreachable_and_not_prepared(tables):
    """rr_locked has no feasible point: the controller drives the nominal table with the lock
    imposed in the QP and says why on every tick (it used to try the empty table, count a table
    error and keep the last preparation without a flag), and commands stay valid with the wheel
    stopped.
    Should rr_locked gain primitives, this test fails (it does not skip itself): it then needs a
    table without any."""
    assert not tables["rr_locked"].feasible.any(), "rr_locked gained primitives: give this test a table without any"
    c = Controller(tables, ControllerConfig())
    for k in range(5):
        cmd, d = c.step(Measurements(0.2 * k, k, (0.6,) * 4, (0.0,) * 4, 0.0, failures=(FailureDeclaration("RR", "locked"),)))
    assert d.table == "nominal" and d.counter("table_errors") == 0 and cmd.rim_speed[2] == 0.0
    assert d.counter("unreachable_preparations") >= 5
    assert any(f.startswith("unreachable: table rr_locked") for f in d.flags), d.flags


def test_default_table_from_config(tables):
    c = Controller(tables, replace(ControllerConfig(), default_table="rr_trench_clean"))
    _, d = c.step(Measurements(0.0, 0, (0.6,) * 4, (0.0,) * 4, 0.0))
    assert d.table == "rr_trench_clean"
    with pytest.raises(ControllerError, match=r"\[tables\] default = 'nope'"):
        Controller(tables, replace(ControllerConfig(), default_table="nope"))
