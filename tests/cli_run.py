"""Run the ``offnominal`` command line in-process and capture its output (shared by the CLI tests)."""

from __future__ import annotations

import contextlib
import io

from offline.cli import main

__all__ = ["run"]


def run(argv: list[str]) -> tuple[int, str, str]:
    """``(exit status, stdout, stderr)`` of ``offnominal *argv``."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()
