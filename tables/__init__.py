"""The shipped lookup tables, installed as the data package ``offnominal_tables``.

The repository's ``tables/`` folder (``*.npz`` tables, ``index.json``, the scenario files they
were built from) is installed under this import name so that a plain ``pip install .`` carries
them: :func:`index_path` is where ``offnominal drive`` and ``offnominal replay`` look by default.
Read them with :func:`rtctl.table.load_index` / :func:`rtctl.table.load_table` (numpy only).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["folder", "index_path"]


def folder() -> Path:
    """The folder holding the shipped tables and their ``index.json``."""
    return Path(str(resources.files(__name__)))


def index_path() -> Path:
    """The shipped table index (``index.json``)."""
    return folder() / "index.json"
