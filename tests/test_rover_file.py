"""Rover files: the shipped examples load, and every malformed file is refused with a message
naming the file, the section and the key, and what was expected."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from offline.physics.params import ROVER_MINI_T72, load_toml
from rtctl.physics.rover_file import SHIPPED_ROVERS, RoverFileError, load_rover_file, shipped_rover

MINI = (SHIPPED_ROVERS / "mini_rover_t72.toml").read_text()
SKID = (SHIPPED_ROVERS / "skid_steer_4w.toml").read_text()
MER = (SHIPPED_ROVERS / "mer_class_rocker_bogie.toml").read_text()


def _write(tmp_path: Path, text: str, name: str = "bad_rover.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _refused(tmp_path: Path, text: str, section: str, key: str | None, what: str) -> str:
    """Load ``text``; the error must name the file, ``[section]``, ``key`` and match ``what``."""
    p = _write(tmp_path, text)
    with pytest.raises(RoverFileError) as exc:
        load_rover_file(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}: "), msg
    assert f"[{section}]" in msg, msg
    if key is not None:
        assert key in msg, msg
    assert re.search(what, msg), msg
    return msg


def _replace(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text, old
    return text.replace(old, new, count)


def test_mini_rover_file_is_table_7_2():
    r = shipped_rover("mini_rover_t72")
    assert r.wheel_names == ("FR", "FL", "RR", "RL")
    assert r.suspension == "rocker" and r.body_fixed_to == "rocker_right"
    fr, rr, fl = r.wheel("FR"), r.wheel("RR"), r.wheel("FL")
    assert fr.position[0] - rr.position[0] == pytest.approx(ROVER_MINI_T72.rocker_length, abs=1e-15)
    assert r.link("rocker_right").pivot[2] - fr.position[2] == pytest.approx(ROVER_MINI_T72.pivot_height, abs=1e-15)
    assert fl.position[1] - fr.position[1] == pytest.approx(ROVER_MINI_T72.track_width, abs=1e-15)
    assert r.weight == ROVER_MINI_T72.weight
    assert r.travel_speed == ROVER_MINI_T72.travel_speed
    assert fr.steer_min == pytest.approx(-math.pi / 2) and fr.steer_max == pytest.approx(math.pi / 2)


def test_shipped_examples_load_with_their_kinds():
    mer = shipped_rover("mer_class_rocker_bogie")
    assert mer.suspension == "rocker_bogie" and len(mer.wheels) == 6
    assert mer.weight == pytest.approx(174.0 * 3.71)
    assert [w.steerable for w in mer.wheels] == [True, True, False, False, True, True]
    skid = shipped_rover("skid_steer_4w")
    assert skid.suspension == "rigid" and not skid.links
    assert not any(w.steerable for w in skid.wheels) and skid.actuators.steer_rate_max is None
    # the MER-class wheel parameter file the rover file names is a valid parameter file
    ps = load_toml(SHIPPED_ROVERS / mer.wheel("RF").params)["parameter_set"]
    assert ps.wheel.radius == 0.13
    with pytest.raises(RoverFileError, match="no shipped rover 'nope'"):
        shipped_rover("nope")


def test_shipped_files_name_no_machine_paths():
    for p in SHIPPED_ROVERS.glob("*.toml"):
        text = p.read_text()
        assert "/work/" not in text and "/home/" not in text and "/tmp/" not in text, p


def test_missing_key(tmp_path):
    _refused(tmp_path, _replace(MINI, "weight_N = 34.3\n", ""), "rover", "weight_N", "missing key")
    _refused(tmp_path, _replace(MINI, 'params = "dissertation-ch7"\n', ""), "wheels.FR", "params", "missing key")
    _refused(tmp_path, _replace(MINI, "[actuators]\n", "[actuator_limits]\n"), "actuator_limits", None, "unknown section")


def test_wrong_unit_is_an_unknown_key_with_the_expected_unit(tmp_path):
    msg = _refused(tmp_path, _replace(MINI, "weight_N = 34.3", "weight_kg = 3.5"), "rover", "weight_kg",
                   r"unknown key \(wrong unit\? expected \['weight_N'\]\)")
    assert "known keys" in msg
    _refused(tmp_path, _replace(MINI, "position_m = [0.16, -0.1655, -0.112]", "position_mm = [160, -165.5, -112]"),
             "wheels.FR", "position_mm", r"expected \['position_m'\]")
    _refused(tmp_path, _replace(MINI, "steer_min_deg = -90.0", "steer_min_rad = -1.5"), "wheels.FR", "steer_min_rad",
             r"expected \['steer_min_deg'\]")


def test_wrong_type(tmp_path):
    _refused(tmp_path, _replace(MINI, "weight_N = 34.3", 'weight_N = "34.3"'), "rover", "weight_N", "expected a finite number")
    _refused(tmp_path, _replace(MINI, "weight_N = 34.3", "weight_N = true"), "rover", "weight_N", "expected a finite number")
    _refused(tmp_path, _replace(MINI, "position_m = [0.16, -0.1655, -0.112]", "position_m = [0.16, -0.1655]"),
             "wheels.FR", "position_m", r"three numbers \[x, y, z\] in metres")
    _refused(tmp_path, _replace(MINI, "position_m = [0.16, -0.1655, -0.112]", 'position_m = [0.16, "a", -0.112]'),
             "wheels.FR", "position_m[1]", "finite number")
    _refused(tmp_path, _replace(MINI, "driven = true", "driven = 1"), "wheels.FR", "driven", "true or false")
    _refused(tmp_path, _replace(MINI, 'kind = "rocker"', "kind = 3"), "suspension", "kind", "non-empty string")


def test_nan_and_infinity(tmp_path):
    _refused(tmp_path, _replace(MINI, "weight_N = 34.3", "weight_N = nan"), "rover", "weight_N", "finite")
    _refused(tmp_path, _replace(MINI, "drive_torque_max_N_m = 4.1", "drive_torque_max_N_m = inf"), "actuators",
             "drive_torque_max_N_m", "finite")
    _refused(tmp_path, _replace(MINI, "pivot_m = [0.0, -0.1655, 0.0]", "pivot_m = [0.0, -0.1655, nan]"),
             "links.rocker_right", "pivot_m[2]", "finite")


def test_out_of_range(tmp_path):
    _refused(tmp_path, _replace(MINI, "weight_N = 34.3", "weight_N = -34.3"), "rover", "weight_N", r"out of range: expected > 0")
    _refused(tmp_path, _replace(MINI, "steer_min_deg = -90.0", "steer_min_deg = -200.0"), "wheels.FR", "steer_min_deg",
             r"out of range: expected >= -180")
    _refused(tmp_path, _replace(MINI, "steer_max_deg = 90.0", "steer_max_deg = -95.0"), "wheels.FR", "steer_max_deg",
             "must exceed steer_min_deg")
    _refused(tmp_path, _replace(MINI, "drive_speed_max_rad_s = 4.817", "drive_speed_max_rad_s = 0.0"), "actuators",
             "drive_speed_max_rad_s", "expected > 0")
    _refused(tmp_path, _replace(SKID, "gravity_m_s2 = 9.81", "gravity_m_s2 = 98.1"), "rover", "gravity_m_s2",
             "expected <= 30")


def test_unknown_key_and_contradictions(tmp_path):
    _refused(tmp_path, _replace(MINI, "driven = true", "driven = true\ncolour = \"red\""), "wheels.FR", "colour",
             "unknown key; known keys")
    _refused(tmp_path, _replace(MINI, "weight_N = 34.3", "weight_N = 34.3\nmass_kg = 3.5"), "rover", "mass_kg",
             "either weight_N, or mass_kg with gravity_m_s2")
    _refused(tmp_path, _replace(SKID, "gravity_m_s2 = 9.81\n", ""), "rover", "gravity_m_s2", "missing key")
    _refused(tmp_path, _replace(SKID, "steerable = false", "steerable = false\nsteer_min_deg = -10.0"), "wheels.FR",
             "steer_min_deg", "steerable = false")
    _refused(tmp_path, _replace(MINI, "steer_rate_max_deg_s = 582.0\n", ""), "actuators", "steer_rate_max_deg_s",
             "missing key")
    _refused(tmp_path, _replace(SKID, "drive_torque_max_N_m = 4.1", "drive_torque_max_N_m = 4.1\nsteer_rate_max_deg_s = 5.0"),
             "actuators", "steer_rate_max_deg_s", "no wheel is steerable")
    _refused(tmp_path, _replace(MINI, 'params = "dissertation-ch7"', 'params = "/home/me/wheel.toml"'), "wheels.FR",
             "params", "relative to the rover file")


def test_suspension_tree_must_fit_the_kind(tmp_path):
    _refused(tmp_path, _replace(MINI, 'kind = "rocker"', 'kind = "tracked"'), "suspension", "kind",
             r"expected one of \['rocker', 'rocker_bogie', 'rigid'\]")
    _refused(tmp_path, _replace(MINI, 'body_fixed_to = "rocker_right"', 'body_fixed_to = "bogie"'), "suspension",
             "body_fixed_to", "expected one of the rockers")
    _refused(tmp_path, _replace(MER, 'kind = "rocker_bogie"', 'kind = "rocker_bogie"\nbody_fixed_to = "rocker_right"'),
             "suspension", "body_fixed_to", "only for kind = 'rocker'")
    # a rocker wheel moved to the other rocker: three supports on one link
    _refused(tmp_path, _replace(MINI, 'link = "rocker_left"', 'link = "rocker_right"'), "links.rocker_right", None,
             "exactly two supports")
    _refused(tmp_path, _replace(MINI, "position_m = [-0.16, -0.1655, -0.112]", "position_m = [0.16, -0.1655, -0.3]"),
             "links.rocker_right", None, "apart along x")
    _refused(tmp_path, _replace(MINI, 'link = "rocker_left"', 'link = "rocker_middle"'), "wheels.FL", "link",
             "expected 'body' or one of the links")
    _refused(tmp_path, _replace(MINI, "pivot_m = [0.0, 0.1655, 0.0]", "pivot_m = [0.01, 0.1655, 0.0]"),
             "links.rocker_left", "pivot_m", "one lateral axis")
    _refused(tmp_path, _replace(MER, 'parent = "rocker_right"', 'parent = "bogie_left"'), "links.rocker_right", None,
             r"exactly two supports .* it has 1")
    _refused(tmp_path, _replace(MER, 'parent = "body"', 'parent = "bogie_right"'), "links.rocker_right", "parent",
             "cycle")
    _refused(tmp_path, _replace(SKID, "position_m = [-0.18, 0.20, -0.05]", "position_m = [-0.18, 0.20, -0.06]"),
             "wheels.RL", "position_m", "one body height")
    collinear = SKID.replace("0.20, -0.05]", "0.0, -0.05]").replace("-0.20, -0.05]", "0.0, -0.05]")
    _refused(tmp_path, collinear, "wheels", None, "on one line")
    _refused(tmp_path, _replace(MINI, "[suspension]", "[suspension]\n", 1).replace('kind = "rocker"', 'kind = "rigid"')
             .replace('body_fixed_to = "rocker_right"\n', ""), "links", None, "has no passive links")


def test_unreadable_files(tmp_path):
    with pytest.raises(RoverFileError, match="no such rover file"):
        load_rover_file(tmp_path / "missing.toml")
    with pytest.raises(RoverFileError, match=r"not valid TOML"):
        load_rover_file(_write(tmp_path, "[rover\nname = 1"))
