"""Truth files of any wheel set (issue 23): per-wheel sections by a rover file's wheel names, and
their disturbance hooks simulated on that rover's plant.

``load_truth`` takes the mini rover (wheels FR, FL, RR, RL) or a rover file (a scenario's
``rover_file``): a ``[wheels.<name>]`` section names one of that rover's wheels, the truth has one
radius and steering offset per wheel in its order, and the defaults are the rover-file simulator's.
Errors name the file, the section and the key. The discrepancy tool's accepted truth of a six-wheel
diagnosis (``write_truth_toml`` with the rover's wheels) reads back. The hook sections of a truth
(``[hub_contact]``, ``[tether_anchor]``, ``[[empirical_force]]``) become a disturbance
hook on the rover's wheels (:func:`offline.discrepancy.drive.wheel_set.truth_disturbance`).

About 2 CPU-s (one 1 s six-wheel drive).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from offline.rover.scenario import load_scenario
from offline.sim.simulator import RoverSimulator, rover_file_truth, suspension_plant_for
from offline.sim.truth import TruthError, load_truth

ROOT = Path(__file__).resolve().parents[1]
MER = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_rf_unpowered.toml").with_(speed=0.03)
MINI = load_scenario(ROOT / "offline" / "scenarios" / "nominal.toml")


def _write(tmp_path: Path, text: str, name: str = "world.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_rover_file_truth_names_its_own_wheels(tmp_path):
    """``[wheels.LM]`` and ``[wheels.RF]`` on the MER-class rover: six radii and offsets in the file's
    order, the others the parameter set's; the defaults (mass, yaw and spin inertia) are the
    simulator's own world of the rover file, so a truth file with only the worn wheel differs from
    ``rover_file_truth`` in that wheel alone."""
    p = _write(tmp_path, "[truth]\n\n[wheels.LM]\nradius_mm = 123.5\n\n[wheels.RF]\nsteer_offset_deg = 1.5\n")
    t = load_truth(p, MER.rover_file, MER.params)
    base = rover_file_truth(MER, suspension_plant_for(MER.params, MER.rover_file, MER.exit_angle))
    i = MER.wheels.index("LM")
    assert len(t.wheel_radius) == len(t.steer_offset) == 6
    assert t.wheel_radius[i] == pytest.approx(0.1235, rel=1e-15)
    assert t.steer_offset == (math.radians(1.5), 0.0, 0.0, 0.0, 0.0, 0.0)
    assert replace(t, wheel_radius=base.wheel_radius, steer_offset=base.steer_offset, source=base.source) == base
    assert t.describe()["wheel_radius_mm"][i] == pytest.approx(123.5)
    sim = RoverSimulator(MER, t, seed=1)  # the simulator takes it: six radii for six wheels
    assert sim.rs_true[i] == pytest.approx(0.1235 + MER.params.wheel.grouser_height)


@pytest.mark.parametrize("rover, text, match", [
    ("mer", "[wheels.FR]\nradius_mm = 120.0\n", r"world.toml: \[wheels.FR\] unknown wheel; use one of \['RF', 'LF', 'RM', 'LM', 'RR', 'LR'\]"),
    ("mini", "[wheels.LM]\nradius_mm = 50.0\n", r"world.toml: \[wheels.LM\] unknown wheel; use one of \['FR', 'FL', 'RR', 'RL'\]"),
    ("mer", "[wheels.LM]\nradius_cm = 12.0\n", r"world.toml: \[wheels.LM\] unknown key\(s\) \['radius_cm'\]"),
    ("mer", "[wheels.LM]\nradius_mm = 5000.0\n", r"world.toml: \[wheels.LM\] radius_mm = 5000.0 outside \[10.0, 2000.0\]"),
    ("mer", "[wheel.LM]\nradius_mm = 120.0\n", r"world.toml: unknown section\(s\) \['wheel'\]; expected \[truth\], \[wheels.<RF\|LF\|RM\|LM\|RR\|LR>\]"),
    ("mer", '[[empirical_force]]\ndirection = "drag.FR"\nmagnitude_si = 1.0\n',
     r"world.toml: \[empirical_force #1\] direction = 'drag.FR'; expected one of \['drag.body', 'drag.RF', 'drag.LF', "
     r"'drag.RM', 'drag.LM'"),
])
def test_bad_wheel_sections_name_the_file_section_and_key(tmp_path, rover, text, match):
    """Unknown wheels (the other rover's names), keys, ranges and sections, and a per-wheel empirical
    term naming the other rover's wheel: a TruthError naming the file, the section and the key."""
    p = _write(tmp_path, text)
    with pytest.raises(TruthError, match=match):
        load_truth(p, MER.rover_file if rover == "mer" else MINI.rover)


def test_the_accepted_truth_of_a_six_wheel_diagnosis_reads_back(tmp_path):
    """``write_truth_toml`` with the rover's wheels writes ``[wheels.LM]``; ``load_truth`` with the
    rover file reads the same radius back (it could not before: 'unknown wheel')."""
    from offline.discrepancy.drive.candidates import write_truth_toml

    base = rover_file_truth(MER, suspension_plant_for(MER.params, MER.rover_file, MER.exit_angle))
    i = MER.wheels.index("LM")
    worn = replace(base, wheel_radius=tuple(r * 0.95 if j == i else r for j, r in enumerate(base.wheel_radius)))
    wheel_file = str(ROOT / "rtctl" / "physics" / "rovers" / "mer_class_wheel.toml")  # the rover file's wheel and soil
    p = write_truth_toml(tmp_path / "accepted_truth.toml", wheel_file, worn, base, {}, None, {}, wheels=MER.wheels)
    assert "[wheels.LM]" in p.read_text()
    back = load_truth(p, MER.rover_file, MER.params)
    assert back.wheel_radius == pytest.approx(worn.wheel_radius, rel=1e-6)
    assert back.params == MER.params


def test_hook_sections_of_a_truth_drive_the_six_wheel_plant(tmp_path):
    """``[hub_contact]`` and ``[tether_anchor]`` on the MER-class rover: the hook gives a drag and a hub
    torque at each of the six wheels (against the travel) and the anchored pull on the body; the
    simulator runs under it, slower than in the believed world; a body drag term works too."""
    from offline.discrepancy.drive.wheel_set import WheelSetHooks, truth_disturbance
    from rtctl.messages import Commands

    p = _write(tmp_path, "[truth]\n\n[hub_contact]\nclearance_mm = 5.0\nface_width_mm = 150.0\narm_mm = 60.0\n\n"
                         "[tether_anchor]\ntension_N = 20.0\n\n"
                         '[[empirical_force]]\ndirection = "drag.body"\nmagnitude_si = 5.0\n')
    t = load_truth(p, MER.rover_file, MER.params)
    hook = truth_disturbance(t, MER)
    assert isinstance(hook, WheelSetHooks) and hook.wheels == 6
    go = Commands(0.0, 0, (0.03,) * 6, (0.0,) * 6)
    speeds = {}
    for name, truth, h in (("believed", None, None), ("hooks", t, hook)):
        sim = RoverSimulator(MER, truth, seed=1, disturbance=h)
        sim.start(go)
        sim.advance(1.0)
        speeds[name] = sim.truth_state()
    f = speeds["hooks"].disturbance
    assert len(f.wheel_force) == len(f.wheel_torque) == 6
    assert all(fx < 0.0 for fx, _ in f.wheel_force) and all(tq > 0.0 for tq in f.wheel_torque[1:])  # against the travel
    assert f.body_force[0] == pytest.approx(-25.0, rel=1e-3)  # tether 20 N behind, body drag 5 N
    assert speeds["hooks"].u < speeds["believed"].u
    assert np.all(np.isfinite(speeds["hooks"].sinkage))
