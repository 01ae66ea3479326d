"""Safe output files: written whole or not at all, never over an input.

Every command that writes uses these: a file is written to a temporary name in the same
folder and renamed into place (``os.replace`` is atomic on POSIX), so an interrupt leaves
either the old file or the complete new one, never a truncated one. Output paths are
checked before the work starts (:func:`check_output_path`), and an output that would
replace one of the run's inputs is refused.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

__all__ = ["OutputError", "atomic_path", "write_bytes", "write_text", "check_output_path", "check_output_dir"]


class OutputError(ValueError):
    """An output path that cannot or must not be written (the message says why and what to do)."""


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    For writers that want a file name (matplotlib ``savefig``, ``np.savez``): write to the
    yielded path; if the block raises (or is interrupted), the temporary file is removed and
    ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part" + path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode("utf-8"))


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_output_path(path: str | Path, inputs: Iterable[str | Path | None] = ()) -> Path:
    """Check, before any work, that ``path`` can be written and is not one of ``inputs``.

    Raises
    ------
    OutputError
        If ``path`` is an input of the run, an existing folder, or its folder cannot be
        created or written. Nothing is created by the check.
    """
    path = Path(path)
    for inp in inputs:
        if inp is not None and _same(path, Path(inp)):
            raise OutputError(f"{path}: this is an input of the run; refusing to overwrite it (choose another --out)")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; give a file name (choose another --out)")
    _check_writable_dir(path.parent)
    return path


def check_output_dir(folder: str | Path, inputs: Iterable[str | Path | None] = (), names: Iterable[str] = ()) -> Path:
    """Check, before any work, that ``folder`` can hold the outputs ``names`` without replacing an input.

    Raises
    ------
    OutputError
        If ``folder`` is an existing file, cannot be created or written, or one of the files
        the run will write there (``names``) is an input.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder (choose another --out)")
    ins = [Path(i) for i in inputs if i is not None]
    for n in names:
        for inp in ins:
            if _same(folder / n, inp):
                raise OutputError(f"{folder / n}: would overwrite the input {inp}; choose another --out")
    _check_writable_dir(folder)
    return folder


def _check_writable_dir(folder: Path) -> None:
    """``folder`` exists and is writable, or can be created (its nearest existing ancestor is a
    writable folder). Nothing is created: a run refused later leaves no trace."""
    probe = folder.absolute()
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{folder}: cannot create the output folder: {probe} is a file; choose another --out")
    if not os.access(probe, os.W_OK | os.X_OK):
        what = "not writable" if probe == folder.absolute() else f"cannot be created ({probe} is not writable)"
        raise OutputError(f"{folder}: {what}; choose another --out")
