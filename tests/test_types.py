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


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """One fresh mypy cache for both runs of this module: the offline run reuses what the rtctl run
    parsed (numpy's stubs, the standard library, rtctl itself; mypy re-checks any module whose
    source or options changed, so the cache cannot hide an error). Fresh per test session."""
    return tmp_path_factory.mktemp("mypy") / "cache"


def test_rtctl_type_checks(cache_dir):
    api = pytest.importorskip("mypy.api", reason="mypy is in the [test] extra; install it to run this check")
    out, err, status = api.run(["--config-file", str(ROOT / "pyproject.toml"), "--cache-dir", str(cache_dir),
                                str(ROOT / "rtctl")])
    assert status == 0, f"mypy found type errors in rtctl/:\n{out}{err}"


def test_offline_type_checks(cache_dir):
    api = pytest.importorskip("mypy.api", reason="mypy is in the [test] extra; install it to run this check")
    out, err, status = api.run(["--config-file", str(ROOT / "pyproject.toml"), "--cache-dir", str(cache_dir),
                                str(ROOT / "offline")])
    assert status == 0, f"mypy found type errors in offline/:\n{out}{err}"
