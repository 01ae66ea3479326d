"""Controller configuration (TOML, errors naming the key) and the 5 Hz runner's bookkeeping."""

from __future__ import annotations

import math

import pytest

from rtctl.config import DEFAULT_TOML, ConfigError, ControllerConfig
from rtctl.runner import Runner


def test_default_toml_equals_dataclass_defaults(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text(DEFAULT_TOML)
    cfg = ControllerConfig.from_toml(p)
    ref = ControllerConfig()
    for sec in ("actuators", "noise", "estimator", "outer_loop", "qp"):
        assert repr(getattr(cfg, sec)) == repr(getattr(ref, sec)), sec  # repr: nan == nan
    assert math.isnan(cfg.drive.wheel_radius) and cfg.drive.speed == ref.drive.speed
    assert cfg.period == 0.2 and cfg.tables_index == ""
    p.write_text(DEFAULT_TOML.replace('index = ""', 'index = "tables/index.json"'))
    assert ControllerConfig.from_toml(p).tables_index == str(tmp_path / "tables" / "index.json")


def test_degrees_converted_once(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("[actuators]\nmax_steer_deg = 45.0\n[drive]\npath_heading_deg = 90\n")
    cfg = ControllerConfig.from_toml(p)
    assert cfg.actuators.max_steer == pytest.approx(math.pi / 4) and cfg.drive.path_heading == pytest.approx(math.pi / 2)


@pytest.mark.parametrize("text, match", [
    ("[actuators]\nmax_steer_deg = -5.0\n", r"c.toml: \[actuators\] max_steer_deg = -5.0: must be finite and > 0"),
    ("[actuators]\nmax_steer = 1.0\n", r"\[actuators\] unknown key 'max_steer'"),
    ("[motors]\nx = 1\n", r"unknown section \[motors\]"),
    ("[qp]\nmax_iter = 5\n", r"\[qp\] max_iter = 5: must be an integer >= 10"),
    ("[noise]\ngyro = \"fast\"\n", r"\[noise\] gyro = 'fast': expected a number"),
    ("[timing]\nperiod = 0.5\nmax_gap = 0.1\n", r"max_gap = 0.1 is shorter than period"),
    ("[drive]\nspeed = 1.0\n", r"\[drive\] speed = 1.0 m/s exceeds \[actuators\] max_rim_speed"),
    ("[tables]\nindex = 3\n", r"\[tables\] index must be a path string"),
    ("[outer_loop]\nheading_gain = -1.0\n", r"heading_gain = -1.0: must be >= 0, or nan"),
    ("not toml ===", r"not valid TOML"),
])
def test_errors_name_file_section_and_key(tmp_path, text, match):
    p = tmp_path / "c.toml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match):
        ControllerConfig.from_toml(p)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        ControllerConfig.from_toml(tmp_path / "nope.toml")


class _FakeController:
    def __init__(self):
        self.calls = []

    def feedback(self, m):
        self.calls.append(("feedback", m))
        return ("cmd", m), ("diag", m)

    def prepare(self):
        self.calls.append(("prepare", None))


def test_runner_counts_overruns_and_late_commands():
    durations = iter([0.01, 0.25, 0.19, 0.01])
    now = [0.0]

    def clock():
        return now[0]

    class Timed(_FakeController):
        def feedback(self, m):
            now[0] += next(durations)
            return super().feedback(m)

        def prepare(self):
            now[0] += 0.02
            super().prepare()

    ctl = Timed()
    slept = []

    def sleep(s):
        slept.append(s)
        now[0] += s

    r = Runner(ctl, period=0.2, clock=clock, sleep=sleep)
    out = []
    stats = r.run(range(4), sink=lambda c, d: out.append(c), realtime=True)
    # tick 2: feedback 0.25 s (late command, overrun); tick 3: 0.19 + 0.02 > 0.2 (overrun only)
    assert stats.late_commands == 1 and stats.overruns == 2
    assert [c[1] for c in out] == [0, 1, 2, 3]
    assert [k for k, _ in ctl.calls] == ["feedback", "prepare"] * 4
    s = stats.summary()
    assert s["ticks"] == 4 and s["feedback_max"] == pytest.approx(0.25)
    assert slept and all(x > 0 for x in slept)  # paced on the 5 Hz grid after the fast ticks


def test_runner_rejects_bad_period():
    with pytest.raises(ValueError, match="period"):
        Runner(_FakeController(), period=0.0)
