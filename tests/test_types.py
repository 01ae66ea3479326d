"""The code type-checks: ``mypy`` over ``rtctl/`` and ``offline/`` (settings in ``pyproject.toml [tool.mypy]``).

rtctl runs on the rover, where a wrong type is a field failure rather than a failed
ground run; mypy found a mis-annotated return there once (commands built as variable-length
tuples where ``Commands`` wants one value per wheel). Every module of both is checked: the
offline modules exempted in earlier stops were cleaned and the exempt list is gone.
"""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_rtctl_type_checks(tmp_path):
    api = pytest.importorskip("mypy.api", reason="mypy is in the [test] extra; install it to run this check")
    out, err, status = api.run(["--config-file", str(ROOT / "pyproject.toml"), "--cache-dir", str(tmp_path / "cache"),
                                str(ROOT / "rtctl")])
    assert status == 0, f"mypy found type errors in rtctl/:\n{out}{err}"


def test_offline_type_checks(tmp_path):
    api = pytest.importorskip("mypy.api", reason="mypy is in the [test] extra; install it to run this check")
    out, err, status = api.run(["--config-file", str(ROOT / "pyproject.toml"), "--cache-dir", str(tmp_path / "cache"),
                                str(ROOT / "offline")])
    assert status == 0, f"mypy found type errors in offline/:\n{out}{err}"
