"""The rover install (issue 25): ``pip install .`` pulls only what rtctl needs, and rtctl runs
the controller on the shipped tables with nothing else importable.

The second test runs in a fresh interpreter in which an import hook refuses every top-level
package outside the rover set (numpy, scipy, osqp, filterpy, mcap, the standard library and
their own dependencies): casadi, matplotlib, tqdm, dask, qpsolvers and ``offline`` cannot be
imported there, as on a rover with only ``pip install .``. (A real lean environment, made with
``pip install .`` in a fresh venv, is measured in tests/bench/results_rtctl_rover_install.md.)"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROVER = {"numpy", "scipy", "osqp", "filterpy", "mcap"}
GROUND = {"casadi", "matplotlib", "tqdm", "dask", "qpsolvers"}


def _name(req: str) -> str:
    for sep in "[<>=!~ ;":
        req = req.split(sep)[0]
    return req.strip().lower()


def test_base_dependencies_are_the_rover_set():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert {_name(r) for r in meta["dependencies"]} == ROVER
    extras = meta["optional-dependencies"]
    assert {_name(r) for r in extras["ground"]} == GROUND
    assert GROUND <= {_name(r) for r in extras["test"]}  # the test extra runs the ground side too


BLOCKER = r"""
import sys, importlib.abc
BLOCKED = {"casadi", "matplotlib", "tqdm", "dask", "distributed", "qpsolvers", "offline", "clarabel", "pandas"}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"blocked on the rover: {name}", name=name)
        return None
sys.meta_path.insert(0, Block())
"""

RUN = r"""
import math
import rtctl, rtctl.controller, rtctl.recording, rtctl.replay, rtctl.runner, rtctl.hil
from rtctl.config import ControllerConfig
from rtctl.controller import Controller, load_tables
from rtctl.messages import FailureDeclaration, Measurements
from rtctl.recording import Recorder, provenance, read_recording
from rtctl.replay import replay
tables = load_tables(INDEX)
c = Controller(tables, ControllerConfig())
a = c.config.actuators
with Recorder(OUT, provenance=provenance(c)) as rec:
    for k in range(10):
        m = Measurements(0.2 * k, k, (0.6,) * 4, (0.0, 0.0, math.radians(-50.0), 0.0), 0.0,
                         failures=(FailureDeclaration("RR", "steer_stuck"),))
        cmd, d = c.step(m)
        assert cmd.is_valid(a.max_rim_speed, a.max_steer) and d.mode == "qp", d
        rec.measurements(m); rec.commands(cmd)
assert d.table == "rr_steer_stuck"
r = replay(read_recording(OUT), Controller(tables, ControllerConfig()))
assert r.identical, r.summary()
bad = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
print("ok", len(tables), bad)
"""


def test_rtctl_runs_on_the_shipped_tables_with_rover_packages_only(tmp_path):
    code = (BLOCKER + f"INDEX = {str(ROOT / 'tables' / 'index.json')!r}\nOUT = {str(tmp_path / 'r.mcap')!r}\n" + RUN)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    n = len(json.loads((ROOT / "tables" / "index.json").read_text())["tables"])  # every shipped table loads
    assert n >= 8 and out.stdout.strip() == f"ok {n} []"


def test_blocker_blocks():
    """The same hook makes a ground import fail (the test above is not vacuous)."""
    out = subprocess.run([sys.executable, "-c", BLOCKER + "import casadi"], capture_output=True, text=True)
    assert out.returncode == 1 and "blocked on the rover: casadi" in out.stderr


def test_ground_command_on_the_rover_install_says_what_to_install(tmp_path):
    """Blocking casadi, matplotlib and tqdm (not offline itself, which the rover install has)."""
    code = ("import sys, importlib.abc\n"
            "class Block(importlib.abc.MetaPathFinder):\n"
            "    def find_spec(self, name, path=None, target=None):\n"
            "        if name.split('.')[0] in {'casadi', 'matplotlib', 'tqdm'}:\n"
            "            raise ModuleNotFoundError(f'blocked: {name}', name=name)\n"
            "sys.meta_path.insert(0, Block())\n"
            "from offline.cli import main\n"
            "sys.exit(main(['drive', '--out', sys.argv[1], '--quiet', '--no-record', '--distance', '0.01']))\n")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "out")], capture_output=True, text=True,
                         cwd=tmp_path)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "needs the ground-side dependencies" in out.stderr and "[ground]" in out.stderr
