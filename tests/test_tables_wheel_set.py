"""Tables for a rover file (issue 23): the header's wheel set and NLP layout, no machine path in
the header, the three verify checks on a six-wheel table, and the controller's rule on wheel sets
(one per controller; a rover file's rocker-bogie driven, tests/test_rtctl_any_rover.py).

The six-wheel table is a committed fixture, ``tests/data/tables/rovers/mer_rf_locked_backward.npz``
(MER-class rover, right-front wheel locked, driving backward; 3 slopes x 2 speeds), built by the
command in ``tests/data/tables/rovers/README.md``; building it in the suite would take about a minute.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

from offline.rover.scenario import load_scenario
from offline.rover.table_builder import encode, table_spec, wheel_set_header
from rtctl.config import ControllerConfig
from rtctl.controller import Controller, ControllerError
from rtctl.layout import NlpLayout
from rtctl.messages import Measurements
from rtctl.physics.rover_file import SHIPPED_ROVERS, shipped_rover
from rtctl.table import load_table
from rtctl.wheel_set import unsupported_reason, wheel_set_of

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
SIX = DATA / "tables" / "rovers" / "mer_rf_locked_backward.npz"
MINI = DATA / "rtctl_nominal_small.npz"
ROVER_SCENARIOS = ROOT / "offline" / "scenarios" / "rovers"
REBUILD = "rebuild the fixture with the command in tests/data/tables/rovers/README.md"


@pytest.fixture(scope="module")
def six():
    return load_table(SIX)


def _strings(obj):
    if isinstance(obj, str):
        yield obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield str(k)
            yield from _strings(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _strings(v)


_ABSOLUTE = re.compile(r"(?:^|[\s'\"(=])(?:/[^\s/'\"]+){2,}|[A-Za-z]:\\")


def _absolute_paths(header):
    return sorted({s for s in _strings(header) if _ABSOLUTE.search(s) or str(ROOT) in s})


def test_six_wheel_header_carries_the_wheel_set_and_layout(six):
    """rtctl can take the wheel names and count from the header: the wheel set (names, count,
    steerable, driven, the rover file by name and hash) agrees with the rover file and with the
    NLP layout the arrays are stored in."""
    rover = shipped_rover("mer_class_rocker_bogie")
    ws = six.header["wheel_set"]
    assert ws["wheels"] == list(rover.wheel_names) == ["RF", "LF", "RM", "LM", "RR", "LR"]
    assert ws["count"] == 6 and ws["suspension"] == "rocker_bogie" and ws["drive_direction"] == "backward"
    assert ws["steerable"] == [w.steerable for w in rover.wheels] == [True, True, False, False, True, True]
    assert ws["driven"] == [True] * 6 and ws["rover"] == "mer_class"
    sha = hashlib.sha256((SHIPPED_ROVERS / "mer_class_rocker_bogie.toml").read_bytes()).hexdigest()
    assert ws["rover_file"] == {"name": "mer_class_rocker_bogie.toml", "sha256": sha}, REBUILD
    lay = six.layout
    assert list(lay.wheels) == ws["wheels"] and lay.nx == 6 * 5
    assert six.arrays["wrench"].shape[-2:] == (6, 6) and six.arrays["x"].shape[-1] == lay.nx
    assert [n for n in lay.constraint_names if n.startswith("balance")] == [
        f"balance {r}" for r in ("Fx", "Fy", "Fz", "Mx", "My", "My_differential", "My_bogie_right", "My_bogie_left", "Mz")]
    assert six.header["failures"] and {f["wheel"] for f in six.header["failures"]} == {"RF"}
    assert "W/6 r_s" in six.header["objective"]


def test_six_wheel_header_names_no_machine_path(six):
    assert _absolute_paths(six.header) == []
    assert six.header["sources"]["rover_file"]["name"] == "mer_class_rocker_bogie.toml"
    assert six.header["scenario"]["rover_file"]["path"] == "mer_class_rocker_bogie.toml"


def test_rover_file_spec_records_the_file_by_name_and_hash():
    """The builder's spec (no solve): the rover file and its wheel parameter file by name and
    sha256, and the scenario with the machine path replaced by the file name."""
    spec = table_spec(ROVER_SCENARIOS / "mer_rf_locked_backward.toml", "slope=0;cross_slope=0;speed=2")
    rf = SHIPPED_ROVERS / "mer_class_rocker_bogie.toml"
    assert spec.sources["rover_file"] == {"name": rf.name, "sha256": hashlib.sha256(rf.read_bytes()).hexdigest()}
    wheel = SHIPPED_ROVERS / "mer_class_wheel.toml"
    assert spec.sources["params_file"] == {"name": wheel.name, "sha256": hashlib.sha256(wheel.read_bytes()).hexdigest()}
    assert spec.scenario.rover_file.path == rf.name
    assert _absolute_paths(encode(spec.scenario)) == [] and _absolute_paths(spec.sources) == []


def test_family_axis_on_a_rover_files_wheel():
    """A stuck right-front (``RF``) steering wheel gives the table its family axis; the builder
    used to look for the mini rover's names only and built a single-angle table."""
    spec = table_spec(ROVER_SCENARIOS / "mer_rf_steer_stuck_7.toml")
    assert spec.family == {"axis": "steer_stuck", "wheel": "RF", "kind": "stuck steering angle"}
    assert "steer_stuck" in spec.grid.names


def test_mini_rover_wheel_set_and_spec_unchanged():
    """The mini rover (no rover file): the wheel set is the Table 7.2 rocker's, and the spec
    records no rover file and keeps the scenario as loaded."""
    path = ROOT / "tables" / "scenarios" / "nominal.toml"
    sc = load_scenario(path)
    spec = table_spec(path)
    assert "rover_file" not in spec.sources and spec.scenario.rover == sc.rover and spec.scenario.rover_file is None
    assert wheel_set_header(sc, spec.sources) == {
        "wheels": ["FR", "FL", "RR", "RL"], "count": 4, "steerable": [True] * 4, "driven": [True] * 4,
        "steer_range_rad": None, "suspension": "rocker", "drive_direction": "forward", "rover": sc.rover.name,
        "rover_file": None}


def test_verify_passes_on_the_six_wheel_table():
    """``offnominal tables verify``'s four checks (Jacobians, linearisation at the stored trust
    radius, a primitive at the sampled cell centres, the online step from there) on the six-wheel
    table."""
    from offline.rover.table_verify import verify_table

    rep = verify_table(SIX, points=2, ladder=False)
    assert rep.verdicts == {"jacobians": True, "linearisation": True, "interpolation": True, "online step": True}, \
        rep.text()
    assert rep.passed


def _meas(k: int) -> Measurements:
    return Measurements(0.2 * k, k, (0.2,) * 4, (0.0,) * 4, 0.0)


def test_controller_refuses_tables_of_two_wheel_sets_and_drives_the_six_wheel_one(six):
    """A six-wheel table beside a four-wheel one: a start-up error naming the tables of each
    wheel set (the controller's measurements and commands carry one wheel set; before issue 23's
    rtctl slice the six-wheel table was refused and the four-wheel one drove). Alone, the
    six-wheel table drives: six commands per tick (tests/test_rtctl_any_rover.py checks them)."""
    with pytest.raises(ControllerError, match=r"the tables are for different wheel sets: mer_rf_locked_backward: 6 "
                                              r"wheels RF, LF, RM, LM, RR, LR of rover mer_class .*; nominal: 4 wheels "
                                              r"FR, FL, RR, RL"):
        Controller({"nominal": load_table(MINI), "mer_rf_locked_backward": six}, ControllerConfig())
    c = Controller({"mer": six}, ControllerConfig())
    assert set(c.tables) >= {"mer"} and not c.unavailable and c.wheels == ("RF", "LF", "RM", "LM", "RR", "LR")
    cmd, d = c.step(Measurements(0.0, 0, (-0.2,) * 6, (0.0,) * 6, 0.0))
    assert np.all(np.isfinite(cmd.rim_speed)) and len(cmd.rim_speed) == 6


def _layout(wheels=("FR", "FL", "RR", "RL"), rows=None):
    kw = {"balance_rows": rows} if rows else {}
    return NlpLayout.build({"omega": 1.0, "beta": 0.3, "W": 10.0, "h": 0.01, "h0": 0.01},
                           {"force": 10.0, "moment": 1.0, "load": 10.0, "torque": 1.0, "height": 0.01},
                           wheels=wheels, **kw)


def test_wheel_set_rule_on_four_wheel_rover_files_and_older_headers():
    """Four wheels named FR, FL, RR, RL are not enough: a rover file's four-wheel rover (the rigid
    skid-steer) whose header lacks the rover record the residual is rebuilt from is refused, and a
    table written before the header carried the wheel set is judged from its scenario record."""
    lay = _layout()
    assert unsupported_reason({}, lay) is None
    assert unsupported_reason({"wheel_set": {"rover_file": None, "suspension": "rocker"}}, lay) is None
    skid = {"wheel_set": {"wheels": list(lay.wheels), "count": 4, "suspension": "rigid", "rover": "skid_steer_4w",
                          "rover_file": {"name": "skid_steer_4w.toml", "sha256": "0" * 64}}}
    assert unsupported_reason(skid, lay).startswith(
        "this table is for the 4 wheels FR, FL, RR, RL of rover skid_steer_4w (rover file skid_steer_4w.toml, "
        "suspension rigid), but its header has no rover record (scenario.rover_file)")
    older = {"rover": {"name": "mer_class"}, "scenario": {"rover_file": {
        "name": "mer_class", "suspension": "rocker_bogie", "path": "/somewhere/else/mer_class_rocker_bogie.toml"}}}
    lay6 = _layout(("RF", "LF", "RM", "LM", "RR", "LR"))
    ws = wheel_set_of(older, lay6)
    assert (ws.count, ws.rover_file, ws.steerable) == (6, "mer_class_rocker_bogie.toml", None)
    assert "6 wheels RF, LF, RM, LM, RR, LR of rover mer_class" in unsupported_reason(older, lay6)
    # the mini rover's names but other balance rows (a layout this rtctl's residual does not have)
    assert unsupported_reason({}, _layout(rows=("Fx", "Fy", "Fz", "Mx", "My", "Mz"))) is not None
    assert json.dumps(ws.text())


def test_tables_info_prints_the_wheel_set(capsys):
    from offline.cli import main

    assert main(["tables", "info", str(SIX)]) == 0
    out = capsys.readouterr().out
    assert ("wheel set: 6 wheels RF, LF, RM, LM, RR, LR of rover mer_class (rover file mer_class_rocker_bogie.toml, "
            "suspension rocker_bogie, driving backward); RM not steerable, LM not steerable") in out
    assert re.search(r"suspension rocker_bogie, driving backward\); RM not steerable, LM not steerable; rover file sha256 "
                     r"[0-9a-f]{12}; rtctl drives it\n", out)
    assert main(["tables", "info", str(MINI)]) == 0
    assert "wheel set: 4 wheels FR, FL, RR, RL of rover mini_rover (no rover file, suspension rocker); rtctl drives it" in \
        capsys.readouterr().out
