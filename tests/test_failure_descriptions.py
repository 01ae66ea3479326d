"""Declared failures are data on the rover (issue 21): what each failure kind constrains is written
into the table header by the optimizer's own failure-kind objects, and rtctl reads it.

* every kind's rules (:mod:`rtctl.failures`) impose exactly what its ``apply`` imposes on the
  optimizer's bounds, over seeded values (the description cannot drift from the physics);
* a failure kind defined HERE, in the test module (rtctl and offline have never heard of it), is
  built into a table by the optimizer and driven by rtctl in the simulator: the table is chosen
  by its signature, its rule holds in every command, and on a wheel no table serves the same
  kind is imposed on the nominal table from its description, flagged;
* the silent cases of the issue fail here if put back: an undescribed failure table is never
  driven as nominal, an unknown kind is flagged and counted, a value outside its kind's range is
  rejected and said, conflicting descriptions do not both drive.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Mapping

import numpy as np
import pytest

from offline.rover.failures import KINDS, FailureKind, WheelBounds
from rtctl.config import ControllerConfig
from rtctl.controller import Controller, wheel_radius_of
from rtctl.failures import FailureDescriptionError, apply_rules, read_kinds
from rtctl.messages import FailureDeclaration
from drive_helpers import ticks
from rtctl.table import load_index, load_table, table_bytes

ROOT = Path(__file__).resolve().parents[1]
TABLES = ROOT / "tables"
DEG = math.pi / 180


@pytest.fixture(scope="module")
def tables():
    return {k: v.load() for k, v in load_index(TABLES / "index.json").items()}


def _bounds(speed: float = 0.03, rim_radius: float = 0.065) -> WheelBounds:
    return WheelBounds(lo={"omega": 0.0, "beta": -1.553, "W": 0.0, "h": 0.005, "h0": 0.005},
                       hi={"omega": 3.0 * speed / rim_radius, "beta": 1.553, "W": 17.0, "h": 0.1, "h0": 0.1},
                       torque=(-math.inf, math.inf), rim_radius=rim_radius, speed=speed)


@pytest.mark.parametrize("cls", [c for c in KINDS if c.ROVER_KIND])
def test_every_kinds_rules_impose_what_its_apply_imposes(cls):
    """The rover's reading of the header (rules) against the optimizer's ``apply`` on the same
    bounds, at seeded values across each kind's range and two travel speeds."""
    spec = read_kinds({"failure_kinds": {cls.ROVER_KIND: cls.rover_description()}})[cls.ROVER_KIND]
    rng = np.random.default_rng(21)
    values = [math.nan] if cls.ROVER_VALUE is None else \
        list(rng.uniform(spec.value_lo, min(spec.value_hi, 50.0), 6))
    for speed in (0.03, 0.05):
        for v in values:
            b = _bounds(speed)
            kind = cls.from_declared(v)
            kind.apply(b)
            lo = dict(_bounds(speed).lo, torque=-math.inf, contact=1.0, pivot_locked=0.0)
            hi = dict(_bounds(speed).hi, torque=math.inf, contact=1.0, pivot_locked=0.0)
            apply_rules(spec, v, speed, b.rim_radius, lo, hi)
            for var in ("omega", "beta", "W", "h", "h0"):
                assert lo[var] == pytest.approx(b.lo[var], rel=1e-12, abs=1e-15), (cls, var, v)
                assert hi[var] == pytest.approx(b.hi[var], rel=1e-12, abs=1e-15), (cls, var, v)
            assert (lo["torque"], hi["torque"]) == pytest.approx(b.torque), (cls, v)
            assert lo["contact"] == hi["contact"] == b.contact
            assert (lo["pivot_locked"] == 1.0) == (b.contact == 0.0)  # the optimizer locks the pivot of a raised wheel


def test_mirror_value_follows_the_kinds_mirror():
    d = {c.ROVER_KIND: c.rover_description() for c in KINDS if c.ROVER_KIND}
    assert d["steer_stuck"]["mirror_value"] == -1.0 and d["rim_speed_cap"]["mirror_value"] == 1.0
    assert d["locked"]["mirror_value"] is None


@pytest.mark.parametrize("bad, says", [
    ({"k": {"value": None, "rules": [{"on": "gearbox", "fix": {"const": 0}}]}}, "vocabulary"),
    ({"k": {"value": None, "rules": [{"on": "omega", "fix": {"value": 1}}]}}, "takes none"),
    ({"k": {"value": None, "rules": [{"on": "omega", "fix": {"const": 0}, "hi": {"const": 1}}]}}, "'fix'"),
    ({"k": {"value": None, "rules": [{"on": "omega", "fix": {"cubic": 1}}]}}, "unknown expression"),
    ({"K!": {"value": None, "rules": []}}, "lower case"),
])
def test_malformed_descriptions_are_refused_by_name(bad, says):
    assert read_kinds({"failure_kinds": {"k": {"value": None, "rules": [{"on": "omega", "fix": {"const": 0}}]}}})
    with pytest.raises(FailureDescriptionError, match=says):
        read_kinds({"failure_kinds": bad})


_ticks = ticks


def test_a_failure_table_without_description_is_never_driven_as_nominal(tables, tmp_path):
    """Before: a table whose failures rtctl could not read got an empty signature and became a
    nominal candidate. Now it is unavailable, flagged on every tick, and its failure is imposed."""
    old = tables["rr_steer_stuck"]
    head = {k: v for k, v in old.header.items() if k not in ("content_hash", "failures", "failure_kinds")}
    f = tmp_path / "rr_steer_stuck.npz"
    f.write_bytes(table_bytes(head, old.arrays))
    undescribed = load_table(f)
    ctl = Controller({"nominal": tables["nominal"], "rr_steer_stuck": undescribed}, ControllerConfig(), mirror=False)
    assert "rr_steer_stuck" in ctl.unavailable and "offnominal tables describe" in ctl.unavailable["rr_steer_stuck"]
    _, d = _ticks(ctl, (FailureDeclaration("RR", "steer_stuck", -50 * DEG),), steer=(0.0, 0.0, -50 * DEG, 0.0))
    assert d.table == "nominal"
    assert any(x.startswith("table rr_steer_stuck unavailable since start-up") for x in d.flags)
    assert any(x.startswith("no table for the declared failures RR steer_stuck") for x in d.flags)
    with pytest.raises(Exception, match="no usable table"):
        Controller({"rr_steer_stuck": undescribed}, ControllerConfig())


def test_an_unknown_kind_is_flagged_counted_and_leaves_the_odometry(tables):
    ctl = Controller(tables, ControllerConfig())
    _, d = _ticks(ctl, (FailureDeclaration("FR", "gearbox_slipping", 0.5),))
    flag = [x for x in d.flags if x.startswith("no table for the declared failures")]
    assert flag and "FR gearbox_slipping: NOTHING imposed (no loaded table describes this failure kind)" in flag[0]
    c = dict(d.counters)
    assert c["unknown_failure_kind_preparations"] >= 3 and c["unmatched_failure_preparations"] >= 3
    assert ctl._odometry_wheels()[0] is False  # its wheel speed is not trusted for the travel speed


def test_a_value_outside_its_kinds_range_is_rejected_and_said(tables):
    ctl = Controller(tables, ControllerConfig())
    _, d = _ticks(ctl, (FailureDeclaration("RR", "rim_speed_cap", 25.0),))  # cm/s given as m/s
    assert any("rim_speed_cap cap 25 m/s outside [0, 2]" in x for x in d.flags), d.flags
    assert dict(d.counters)["rejected_failure_declaration"] >= 3
    _, d = _ticks(Controller(tables, ControllerConfig()), (FailureDeclaration("RR", "rim_speed_cap"),))
    assert any("rim_speed_cap needs its cap (m/s)" in x for x in d.flags), d.flags


def test_conflicting_descriptions_do_not_both_drive(tables, tmp_path):
    t = tables["rr_locked"]
    kinds = dict(t.header["failure_kinds"])
    kinds["locked"] = {**kinds["locked"], "rules": [{"on": "omega", "hi": {"const": 1.0}}]}  # another 'locked'
    head = {k: v for k, v in t.header.items() if k != "content_hash"}
    head["failure_kinds"] = kinds
    f = tmp_path / "rr_locked.npz"
    f.write_bytes(table_bytes(head, t.arrays))
    ctl = Controller({"nominal": tables["nominal"], "rr_locked": load_table(f)}, ControllerConfig(), mirror=False)
    assert "rr_locked" in ctl.unavailable and "differently from table nominal" in ctl.unavailable["rr_locked"]


def test_raised_is_imposed_through_the_models_contact(tables):
    """A raised wheel no table serves: its rules take the wheel out of contact in the exact
    residual and lock the pivot (before: 'NOTHING imposed')."""
    ctl = Controller(tables, ControllerConfig())
    _, d = _ticks(ctl, (FailureDeclaration("FR", "raised"),))
    prep = ctl._prep
    names = list(prep.allocator.layout.parameter_names)
    assert ctl._last_p[names.index("contact FR")] == 0.0 and ctl._last_p[names.index("pivot_locked")] == 1.0
    assert ctl._last_p[names.index("contact FL")] == 1.0


# ---------------------------------------------------------------- a kind the libraries never saw
@dataclass(frozen=True)
class SpeedFractionCap(FailureKind):
    """Rim speed limited to a fraction of the travel speed (a motor driver that scales with the
    commanded travel speed): ``omega r_s <= fraction V``. Defined here only."""

    fraction: float
    ROVER_KIND: ClassVar[str] = "rim_speed_fraction_test"
    ROVER_VALUE: ClassVar[Mapping[str, Any] | None] = {"name": "fraction", "unit": "1", "lo": 0.0, "hi": 3.0,
                                                        "required": True}
    RULES: ClassVar[tuple[Mapping[str, Any], ...]] = ({"on": "rim_speed", "hi": {"value_speed": 1.0}},)

    @classmethod
    def from_declared(cls, value: float) -> "SpeedFractionCap":
        return cls(float(value))

    def declared_value(self) -> float:
        return self.fraction

    def apply(self, b: WheelBounds) -> None:
        b.hi["omega"] = min(b.hi["omega"], self.fraction * b.speed / b.rim_radius)

    def check(self, s: Any) -> dict[str, tuple[float, float]]:
        return {"rim speed": (max(s.rim_speed - self.fraction * s.speed, 0.0), s.speed)}


FRACTION = 0.5


@pytest.fixture(scope="module")
def new_kind_index(tmp_path_factory):
    """A table of the new kind on the rear-right wheel, built by the optimizer on a tiny grid, in an
    index beside the shipped tables."""
    from offline.rover.scenario import WheelFailure
    from offline.rover.table_builder import BuildOptions, build_table, table_spec, write_index

    out = tmp_path_factory.mktemp("new_kind")
    spec = table_spec(TABLES / "scenarios" / "nominal.toml", grid="slope=0;cross_slope=0;speed=2,4",
                      build=BuildOptions(trust_steps=(0.0625, 0.125), trust_search=(0.0625, 0.25, 1.0)))
    sc = dataclasses.replace(spec.scenario, name="rr_fraction_test",
                             failures={"RR": WheelFailure(extra=(SpeedFractionCap(FRACTION),))})
    spec = dataclasses.replace(spec, name="rr_fraction_test", scenario=sc)
    path, summary = build_table(spec, out, progress=False)
    assert summary["statuses"].get("optimal", 0) == 2, summary
    return write_index(out, [path], base_index=TABLES / "index.json"), load_table(path)


def test_the_new_kind_is_described_by_its_own_class(new_kind_index):
    _, t = new_kind_index
    assert t.header["failures"] == [{"wheel": "RR", "kind": "rim_speed_fraction_test", "value": FRACTION,
                                     "text": "SpeedFractionCap"}]
    assert t.header["failure_kinds"]["rim_speed_fraction_test"]["rules"] == [{"on": "rim_speed",
                                                                                "hi": {"value_speed": 1.0}}]
    x = np.asarray(t.arrays["x"])  # the optimizer met the cap itself
    om = x[..., t.layout.var("omega", "RR")].reshape(-1)
    assert np.all(om * wheel_radius_of(t) <= FRACTION * np.asarray(t.axes["speed"]) + 1e-9), om


def _drive(index: Path, wheel: str, tmp_path: Path, distance: float = 0.5) -> tuple[dict, list, list]:
    from offline.rover.scenario import WheelFailure, load_scenario
    from offline.sim.experiments import run_drive
    from offline.sim.rtctl_bridge import rtctl_factory
    from offline.sim.simulator import RoverSimulator
    from offline.sim.truth import Truth

    sc = load_scenario(TABLES / "scenarios" / "nominal.toml")
    # the plant: that wheel's motor cannot run faster than the fraction of the travel speed
    plant = dataclasses.replace(sc, failures={wheel: WheelFailure(rim_speed_max=FRACTION * sc.speed)})
    sim = RoverSimulator(plant, Truth.nominal(sc.params, sc.rover), seed=1)
    sim.failures = (FailureDeclaration(wheel, "rim_speed_fraction_test", FRACTION),)  # fault management's words

    class Rec:
        def __init__(self) -> None:
            self.diag: list = []
            self.cmd: list = []

        def measurements(self, m: Any) -> None: ...

        def commands(self, c: Any) -> None:
            self.cmd.append(c)

        def diagnostics(self, t: float, d: Any) -> None:
            self.diag.append(d)

        def timing(self, *a: Any) -> None: ...

    rec = Rec()
    res = run_drive(sim, rtctl_factory(str(index))(sc), distance=distance, recorder=rec)
    return dict(res.metrics), rec.diag, rec.cmd


def test_a_kind_added_offline_in_one_class_drives_on_the_rover(new_kind_index, tmp_path):
    index, _ = new_kind_index
    m, diag, cmds = _drive(index, "RR", tmp_path)
    assert all(d.table == "rr_fraction_test" for d in diag[1:]), {d.table for d in diag}
    assert not any(f.startswith("no table for the declared failures") for d in diag for f in d.flags)
    i = 2  # RR
    assert all(c.rim_speed[i] <= FRACTION * 0.03 * 1.5 + 1e-12 for c in cmds)  # within the speed shift's range
    assert m["max_abs_heading_deg"] <= 3.0 and m["max_abs_cross_track_cm"] <= 3.0, m
    assert abs(m["speed_error_pct"]) <= 10.0, m


def test_the_new_kind_on_a_wheel_without_its_table_is_imposed_from_its_description(new_kind_index, tmp_path):
    index, _ = new_kind_index
    m, diag, cmds = _drive(index, "FL", tmp_path, distance=0.3)  # RL would be served by the table's mirror
    flags = [f for d in diag for f in d.flags if f.startswith("no table for the declared failures")]
    assert flags and "FL rim_speed_fraction_test: rim_speed <= v V" in flags[-1], flags[-1:]
    assert all(d.table == "nominal" for d in diag)
    speed_factor = [d.speed_factor for d in diag]
    assert all(c.rim_speed[1] <= FRACTION * 0.03 * f + 1e-12 for c, f in zip(cmds[1:], speed_factor[1:]))


def test_tables_describe_writes_what_a_build_writes(tables, tmp_path):
    """``offnominal tables describe`` on a table stripped of its description gives back the same
    description (the scenario's own kind objects write it), arrays untouched, input not overwritten."""
    from offline.cli import main

    t = tables["rr_rim_speed_cap"]
    head = {k: v for k, v in t.header.items() if k not in ("content_hash", "failures", "failure_kinds")}
    head["family"] = {k: v for k, v in head["family"].items() if k != "declares"}
    src = tmp_path / "in" / "rr_rim_speed_cap.npz"
    src.parent.mkdir()
    src.write_bytes(table_bytes(head, t.arrays))
    before = src.read_bytes()
    assert main(["tables", "describe", str(src), "--out", str(tmp_path / "out")]) == 0
    new = load_table(tmp_path / "out" / "rr_rim_speed_cap.npz")
    assert src.read_bytes() == before
    for k in ("failures", "failure_kinds", "family"):
        assert new.header[k] == t.header[k], k
    for k, v in t.arrays.items():
        np.testing.assert_array_equal(new.arrays[k], v)  # NaN where NaN
