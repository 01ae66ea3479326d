"""Tests of offline.physics.params: presets and their provenance, SI validation in the constructors,
TOML round trips (unit conversion in and out) and the error messages of load_toml."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import pytest

import offline.physics.params as P
from offline.physics.params import (
    ROVER_MINI_T72,
    SOIL_DISSERTATION_T53_GROUSERED,
    TUNING_T54_GROUSERED,
    TUNING_T72_LINEAR,
    WHEEL_GROUSERED_PUBLISHED_CODE,
    ContactTuning,
    ParameterError,
    ParameterSet,
    Rover,
    Soil,
    Wheel,
    load_toml,
    save_toml,
)

# TOML stores angles in degrees and k, rho, c in kN / kPa; the round trip divides and then
# multiplies by the same factor, so it is exact up to a few ulp.
RTOL_ROUND_TRIP = 1e-12

SECTION_OF = {Soil: "soil", Wheel: "wheel", ContactTuning: "tuning", Rover: "rover"}


def _presets() -> list[tuple[str, object]]:
    """Every preset in ``offline.physics.params.__all__``; per-angle tables expanded entry by entry."""
    out = []
    for name in P.__all__:
        obj = getattr(P, name)
        if isinstance(obj, dict):
            out += [(f"{name}[{b:g}]", t) for b, t in obj.items()]
        elif type(obj) in SECTION_OF:
            out.append((name, obj))
    return out


PRESETS = _presets()
PRESET_IDS = [n for n, _ in PRESETS]


def assert_same(a: object, b: object) -> None:
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, str):
            assert x == y, f.name
        else:
            assert math.isclose(x, y, rel_tol=RTOL_ROUND_TRIP, abs_tol=0.0), (f.name, x, y)


# --------------------------------------------------------------------------- presets
def test_presets_cover_every_kind():
    kinds = {type(o) for _, o in PRESETS}
    assert kinds == {Soil, Wheel, ContactTuning, Rover}
    assert len(PRESETS) >= 4 + 5 + 5 + 1  # soils/wheels, two 5-angle tables, T7.2, rover


@pytest.mark.parametrize("name,obj", PRESETS, ids=PRESET_IDS)
def test_every_preset_names_its_source(name, obj):
    assert obj.source.strip(), f"{name} has no source"
    assert obj.name.strip()
    # presets are named after their source: a T5x/T4x/T7x preset cites that table
    for tag, table in (("T53", "Table 5.3"), ("T42", "Table 4.2"), ("T52", "Table 5.2"), ("T54", "Table 5.4"),
                       ("T72", "Table 7.2")):
        if tag in name:
            assert table in obj.source, (name, obj.source)


def test_table_5_3_soil_in_si():
    """Table 5.3: k = 8000 kN/m^(n+2), rho = 13.03 kN/m^3, c = 1 kPa, phi = 29 deg, K = 21 mm."""
    s = SOIL_DISSERTATION_T53_GROUSERED
    assert s.k == 8.0e6
    assert s.unit_weight == pytest.approx(13030.0, rel=1e-15)
    assert s.cohesion == 1000.0
    assert s.friction_angle == pytest.approx(math.radians(29.0), rel=1e-15)
    assert s.shear_modulus == 0.021
    assert (s.n0, s.n1, s.n2) == (1.46, 0.01, 0.74)


def test_table_7_2_lines_evaluate_eqs_7_8_and_7_9():
    """a0 = 0.24 + beta / 129.1 deg, a1 = 0.69 - beta / 133.5 deg (|beta|, radians in)."""
    for beta_deg in (0.0, 15.0, 30.0, 60.0, 90.0):
        a0, a1, b0, b1 = TUNING_T72_LINEAR.at(math.radians(beta_deg))
        assert a0 == pytest.approx(0.24 + beta_deg / 129.1, rel=1e-13)
        assert a1 == pytest.approx(0.69 - beta_deg / 133.5, rel=1e-13)
        assert (b0, b1) == (TUNING_T72_LINEAR.b0, TUNING_T72_LINEAR.b1)


def test_table_5_4_grousered_obeys_its_own_constraints():
    """Section 5.3.2: a0 + a1 <= 1 and b0 + b1 >= -1 for every tuned slip angle."""
    for b, t in TUNING_T54_GROUSERED.items():
        assert t.a0 + t.a1 <= 1.0 + 1e-12, b
        assert t.b0 + t.b1 >= -1.0 - 1e-12, b


# ----------------------------------------------------------------- constructor checks
@pytest.mark.parametrize(
    "make,match",
    [
        (lambda: dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, k=500.0), r"Soil\.k .*did you pass kN"),
        (lambda: dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, friction_angle=29.0),
         r"Soil\.friction_angle .*did you pass degrees"),
        (lambda: dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, repose_angle=-0.1), r"Soil\.repose_angle"),
        (lambda: dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, n0=0.0), r"Soil\.n0 must be > 0"),
        (lambda: dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, cohesion=math.nan), r"Soil\.cohesion must be finite"),
        (lambda: dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, shear_modulus=True), r"Soil\.shear_modulus must be a number"),
        (lambda: dataclasses.replace(WHEEL_GROUSERED_PUBLISHED_CODE, radius=58.0, width=50.0, grouser_height=5.0),
         r"metres .*millimetres"),
        (lambda: dataclasses.replace(WHEEL_GROUSERED_PUBLISHED_CODE, grouser_area_ratio=1.5), r"Wheel\.grouser_area_ratio"),
        (lambda: dataclasses.replace(WHEEL_GROUSERED_PUBLISHED_CODE, grouser_height=0.1), r"Wheel\.grouser_height"),
        (lambda: ContactTuning(2.0, 0.1, -0.5, -0.2), r"ContactTuning\.a0 = 2\.0 outside"),
        (lambda: ContactTuning(0.2, 0.1, -0.5, -0.2, b1_per_rad=math.inf), r"ContactTuning\.b1_per_rad must be finite"),
        (lambda: dataclasses.replace(ROVER_MINI_T72, weight=0.0), r"Rover\.weight must be > 0"),
    ],
    ids=["k_in_kN", "phi_in_deg", "repose_negative", "n0_zero", "c_nan", "K_bool", "wheel_in_mm", "mu_gt_1",
         "grouser_gt_radius", "a0_range", "slope_inf", "rover_weight"],
)
def test_constructors_reject_bad_values_with_a_named_field(make, match):
    with pytest.raises(ParameterError, match=match):
        make()


def test_table_5_3_k_given_in_kN_is_refused():
    with pytest.raises(ParameterError, match=r"Soil\.k .*did you pass kN"):
        dataclasses.replace(SOIL_DISSERTATION_T53_GROUSERED, k=8000.0)


def test_parameter_error_is_a_value_error_and_presets_are_frozen():
    assert issubclass(ParameterError, ValueError)
    with pytest.raises(dataclasses.FrozenInstanceError):
        SOIL_DISSERTATION_T53_GROUSERED.k = 1.0  # type: ignore[misc]


# ---------------------------------------------------------------------------- TOML
@pytest.mark.parametrize("name,obj", PRESETS, ids=PRESET_IDS)
def test_toml_round_trip_of_every_preset(tmp_path, name, obj):
    section = SECTION_OF[type(obj)]
    path = save_toml(tmp_path / "p.toml", **{section: obj})
    back = load_toml(path)
    assert set(back) == {section}
    assert_same(obj, back[section])


def test_round_trip_keeps_nonzero_beta_slopes(tmp_path):
    """All four per-degree slopes survive the deg <-> rad conversion (T7.2 has only two)."""
    t = ContactTuning(0.3, 0.6, -0.5, -0.4, a0_per_rad=0.45, a1_per_rad=-0.43, b0_per_rad=0.08, b1_per_rad=-0.1,
                      name="all_slopes", source='quotes " and back\\slash\nand a newline, ünïcode')
    assert_same(t, load_toml(save_toml(tmp_path / "t.toml", tuning=t))["tuning"])


def test_toml_carries_the_printed_units(tmp_path):
    """Keys are in the dissertation's printed units: kN/m^(n+2), kN/m^3, kPa, degrees, per degree."""
    path = save_toml(tmp_path / "p.toml", soil=SOIL_DISSERTATION_T53_GROUSERED, tuning=TUNING_T72_LINEAR)
    raw = tomllib.loads(path.read_text())
    soil, tun = raw["soil"], raw["tuning"]
    assert soil["k_kN_per_m_n_plus_2"] == pytest.approx(8000.0, rel=RTOL_ROUND_TRIP)
    assert soil["unit_weight_kN_per_m3"] == pytest.approx(13.03, rel=RTOL_ROUND_TRIP)
    assert soil["cohesion_kPa"] == pytest.approx(1.0, rel=RTOL_ROUND_TRIP)
    assert soil["friction_angle_deg"] == pytest.approx(29.0, rel=RTOL_ROUND_TRIP)
    assert tun["a0_per_deg"] == pytest.approx(1.0 / 129.1, rel=RTOL_ROUND_TRIP)  # Table 7.2
    assert tun["a1_per_deg"] == pytest.approx(-1.0 / 133.5, rel=RTOL_ROUND_TRIP)


def test_full_file_gives_parameter_set_rover_and_meta(tmp_path):
    meta = {"notes": "written by a test", "rms": 3.25, "evaluations": 15, "converged": True}
    path = save_toml(tmp_path / "all.toml", meta=meta, soil=SOIL_DISSERTATION_T53_GROUSERED,
                     wheel=WHEEL_GROUSERED_PUBLISHED_CODE, tuning=TUNING_T54_GROUSERED[30.0], rover=ROVER_MINI_T72)
    out = load_toml(path)
    assert out["meta"] == meta
    ps = out["parameter_set"]
    assert isinstance(ps, ParameterSet)
    assert ps.notes == "written by a test"
    assert_same(ps.soil, SOIL_DISSERTATION_T53_GROUSERED)
    assert_same(ps.wheel, WHEEL_GROUSERED_PUBLISHED_CODE)
    assert_same(ps.tuning, TUNING_T54_GROUSERED[30.0])
    assert_same(out["rover"], ROVER_MINI_T72)


def test_partial_file_has_no_parameter_set(tmp_path):
    out = load_toml(save_toml(tmp_path / "sw.toml", soil=SOIL_DISSERTATION_T53_GROUSERED, wheel=WHEEL_GROUSERED_PUBLISHED_CODE))
    assert "parameter_set" not in out


def test_beta_slopes_are_optional_in_toml(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text("[tuning]\na0 = 0.27\na1 = 0.67\nb0 = -0.66\nb1 = -0.18\n")
    t = load_toml(p)["tuning"]
    assert (t.a0_per_rad, t.a1_per_rad, t.b0_per_rad, t.b1_per_rad) == (0.0, 0.0, 0.0, 0.0)
    assert t.at(1.0) == (0.27, 0.67, -0.66, -0.18)


def test_integers_are_accepted_as_numbers(tmp_path):
    p = tmp_path / "r.toml"
    p.write_text("[rover]\nrocker_length_m = 1\npivot_height_m = 0.112\ntrack_width_m = 0.331\nweight_N = 34\n"
                 "travel_speed_m_s = 0.03\n")
    r = load_toml(p)["rover"]
    assert r.weight == 34.0 and isinstance(r.weight, float)


# ---------------------------------------------------------------------- TOML errors
def _soil_text(**override: str) -> str:
    keys = {
        "k_kN_per_m_n_plus_2": "8000.0", "n0": "1.46", "n1": "0.01", "n2": "0.74", "friction_angle_deg": "29.0",
        "unit_weight_kN_per_m3": "13.03", "cohesion_kPa": "1.0", "shear_modulus_m": "0.021", "repose_angle_deg": "29.0",
    }
    keys.update(override)
    return "[soil]\n" + "".join(f"{k} = {v}\n" for k, v in keys.items() if v is not None)


def _write(tmp_path: Path, text: str, name: str = "bad_soil.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_valid_helper_text_loads(tmp_path):
    s = load_toml(_write(tmp_path, _soil_text()))["soil"]
    assert s.k == pytest.approx(SOIL_DISSERTATION_T53_GROUSERED.k, rel=RTOL_ROUND_TRIP)


@pytest.mark.parametrize(
    "text,match",
    [
        (_soil_text(n3="1.0"), r"bad_soil\.toml: \[soil\] unknown key\(s\) \['n3'\]; known keys: .*'n2'"),
        (_soil_text(n0=None), r"bad_soil\.toml: \[soil\] missing key 'n0'"),
        (_soil_text(n0='"1.46"'), r"bad_soil\.toml: \[soil\] n0 must be a number, got '1\.46'"),
        (_soil_text(n0="true"), r"bad_soil\.toml: \[soil\] n0 must be a number, got True"),
        (_soil_text(n0="[1.46]"), r"bad_soil\.toml: \[soil\] n0 must be a number"),
        (_soil_text() + "[terrain]\nslope_deg = 10\n", r"bad_soil\.toml: unknown section \[terrain\]; expected one of"),
        ("soil = 3\n", r"bad_soil\.toml: \[soil\] must be a table"),
        (_soil_text(n0="1.46.2"), r"bad_soil\.toml: not valid TOML"),
        (_soil_text(friction_angle_deg="400"), r"bad_soil\.toml: \[soil\] .*friction_angle"),
        (_soil_text(k_kN_per_m_n_plus_2="0.008"), r"bad_soil\.toml: \[soil\] k_kN_per_m_n_plus_2 = 0\.008 .*did you pass kN"),
        (_soil_text(shear_modulus_m="nan"), r"bad_soil\.toml: \[soil\] .*shear_modulus must be finite"),
    ],
    ids=["unknown_key", "missing_key", "string_value", "bool_value", "array_value", "unknown_section", "not_a_table",
         "invalid_toml", "angle_out_of_range", "k_too_small", "nan"],
)
def test_load_toml_errors_name_file_section_and_key(tmp_path, text, match):
    with pytest.raises(ParameterError, match=match):
        load_toml(_write(tmp_path, text))


def test_missing_file_is_a_parameter_error(tmp_path):
    with pytest.raises(ParameterError, match=r"nowhere\.toml: no such parameter file"):
        load_toml(tmp_path / "nowhere.toml")


def test_range_error_from_toml_names_the_toml_key_and_value(tmp_path):
    with pytest.raises(ParameterError) as exc:
        load_toml(_write(tmp_path, _soil_text(friction_angle_deg="400")))
    msg = str(exc.value)
    assert "friction_angle_deg" in msg
    assert "400" in msg
    assert "math.radians" not in msg


@pytest.mark.parametrize("text", ["meta = 3\n", 'meta = "notes"\n'])
def test_meta_must_be_a_table(tmp_path, text):
    with pytest.raises(ParameterError, match=r"bad_soil\.toml: .*meta"):
        load_toml(_write(tmp_path, text))


def test_save_rejects_unknown_section(tmp_path):
    with pytest.raises(ParameterError, match="cannot save unknown section 'terrain'"):
        save_toml(tmp_path / "x.toml", terrain=SOIL_DISSERTATION_T53_GROUSERED)
    assert not (tmp_path / "x.toml").exists()


def test_round_trip_of_control_characters_in_strings(tmp_path):
    t = dataclasses.replace(TUNING_T72_LINEAR, source="line one\r\nline two\x01")
    assert_same(t, load_toml(save_toml(tmp_path / "t.toml", tuning=t))["tuning"])
