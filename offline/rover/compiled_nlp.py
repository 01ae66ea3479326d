"""The steady-state NLP's IPOPT functions compiled to C, built once per NLP structure and cached on disk.

One IPOPT iteration on the mini rover's NLP is dominated by the exact Hessian of the Lagrangian:
a casadi SX function of about 714k instructions (README's worked example), 2.5 ms per call in
casadi's virtual machine (``tests/bench/results_worked_example_i22.md``). :func:`compiled_functions`
generates C for every function IPOPT evaluates (``nlp_f``, ``nlp_g``, ``nlp_grad_f``,
``nlp_jac_g`` and ``nlp_hess_l``; the problem's solvers do not ask casadi for the parameters'
multipliers, ``calc_lam_p = False``, so ``nlp_grad`` is never evaluated) with casadi's code
generator, cuts it into functions the C compiler can optimise (:func:`split_sources`), compiles
it with the system C compiler and loads it with ``casadi.external``; :class:`~offline.rover.primitives.SteadyStateProblem` hands the loaded
functions to ``casadi.nlpsol`` through its ``cache`` option, so IPOPT evaluates compiled code and
the problem (variables, rows, bounds, start points) is unchanged.

* Once per NLP structure: the grid's parameters (speed, slope, offsets, contacts) are casadi
  parameters and a scenario's failures are bounds, so one library serves every point of a table
  and every table of the same parameter set, rover and world terms.
* Cached on disk, keyed by the sha256 of the generated C, the compiler and its flags: in
  ``$OFFNOMINAL_CACHE`` if set, else ``$XDG_CACHE_HOME/offnominal`` (default
  ``~/.cache/offnominal``), never inside the repository.
* Atomic: the library is compiled into a temporary file in the cache folder and renamed into
  place; parallel workers (``--jobs``, Dask) of one machine take a file lock, so the first
  compiles and the others wait and load its result instead of compiling it again.
* Modes (:data:`COMPILE_MODES`): ``"off"`` (casadi's virtual machine, as before), ``"on"``
  (compiled; no compiler or a failed compilation is an error), ``"auto"`` (compiled when a C
  compiler is found, else the virtual machine with one line on stderr saying so), ``"cached"``
  (the compiled library if the cache holds it, else the virtual machine without compiling: for a
  table too small to pay for a compilation, :data:`~offline.rover.table_builder.COMPILE_MIN_POINTS`;
  the graph is the per-wheel one either way, so the table's bytes do not depend on the cache).

The results are the same physics: the C does the same floating-point operations in the same
order as the virtual machine (no ``-ffast-math``). Measured on README's worked example
(``tests/bench/results_worked_example_compiled.md``): a byte-identical table; the Hessian 1.6x
faster (1.54 against 2.50 ms: 714k straight-line operations stay memory-bound compiled), the
build 0.945 of the virtual machine's CPU; the compilation 354 s of compiler CPU, once.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Iterator

__all__ = ["COMPILE_MODES", "NLP_COMPILE_FLAGS", "NLP_FUNCTIONS", "CompileError", "cache_dir", "find_compiler",
           "compiled_functions", "split_sources"]

COMPILE_MODES = ("auto", "on", "off", "cached")
"""Values of ``build.compile`` / :attr:`~offline.rover.primitives.SolverOptions.compile` (module doc)."""

NLP_FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")
"""casadi's names of the functions its IPOPT interface evaluates in a solve (those the solver has
are compiled; ``nlp_grad``, for the parameters' multipliers, only with ``calc_lam_p``, stays
interpreted)."""

NLP_COMPILE_FLAGS: tuple[str, ...] = ("-O1",)
"""C compiler flags of the NLP library (``OFFNOMINAL_NLP_CFLAGS``, space separated, overrides them;
the flags are part of the cache key). Measured on README's worked example (26 MB of generated C):
``tests/bench/results_worked_example_compiled.md``."""

SPLIT_STATEMENTS = 4000
"""Statements per C function in :func:`split_sources` (see there)."""

_SOURCE_NAME = "nlp_fns"  # the generated file, symbol prefix and library name
_said_no_compiler = False


class CompileError(RuntimeError):
    """``compile = "on"`` without a C compiler, or the compilation failed (the compiler's output
    in the message)."""


def cache_dir() -> Path:
    """Folder of the compiled libraries: ``$OFFNOMINAL_CACHE``, else ``$XDG_CACHE_HOME/offnominal``,
    else ``~/.cache/offnominal``."""
    env = os.environ.get("OFFNOMINAL_CACHE")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "offnominal"


def find_compiler() -> str | None:
    """Path of the C compiler: ``$CC`` if set (and found), else ``gcc``, else ``cc``; None if none."""
    env = os.environ.get("CC")
    if env:
        return shutil.which(env)
    return shutil.which("gcc") or shutil.which("cc")


def _flags() -> tuple[str, ...]:
    env = os.environ.get("OFFNOMINAL_NLP_CFLAGS")
    return tuple(env.split()) if env else NLP_COMPILE_FLAGS


def _say(msg: str) -> None:
    print(f"offnominal: {msg}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive advisory lock on ``path`` (POSIX ``flock``; no lock where it does not exist:
    the atomic rename alone then keeps parallel compilations from corrupting the library)."""
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    with open(path, "a+b") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def compiled_functions(solver: Any, mode: str, label: str = "NLP") -> dict[str, Any] | None:
    """The IPOPT functions of ``solver`` (a ``casadi.nlpsol`` built on the interpreted graph)
    as compiled C, ready for ``nlpsol``'s ``cache`` option; None for the virtual machine.

    Parameters
    ----------
    solver : casadi.Function
        The interpreted solver; its functions (:data:`NLP_FUNCTIONS`) are generated as C.
    mode : str
        ``"auto"``, ``"on"``, ``"off"`` or ``"cached"`` (:data:`COMPILE_MODES`; ``"cached"``:
        None unless the cache already holds the library, nothing is compiled).
    label : str
        What the log lines call the NLP.

    Raises
    ------
    CompileError
        ``mode = "on"`` and no C compiler, an unwritable cache folder or a failed compilation.
    ValueError
        Unknown ``mode``.
    """
    global _said_no_compiler
    if mode not in COMPILE_MODES:
        raise ValueError(f"compile = {mode!r}: expected one of {COMPILE_MODES}")
    if mode == "off":
        return None
    cc = find_compiler()
    if cc is None:
        if mode == "on":
            raise CompileError("compile = 'on' but no C compiler was found (set CC, or install gcc); "
                               "compile = 'off' runs casadi's virtual machine")
        if not _said_no_compiler and mode != "cached":
            _said_no_compiler = True
            _say("no C compiler found (gcc, cc or $CC): the NLP runs in casadi's virtual machine (slower); "
                 "install gcc for compiled NLP functions, or set build.compile = 'off' to silence this")
        return None
    try:
        return _load_or_build(solver, cc, label, build=mode != "cached")
    except (OSError, subprocess.CalledProcessError) as exc:
        out = getattr(exc, "stderr", b"") or b""
        msg = f"could not compile the {label} functions in {cache_dir()} ({exc}) {out.decode(errors='replace')[-2000:]}"
        if mode == "on":
            raise CompileError(msg) from None
        _say(msg + ": the NLP runs in casadi's virtual machine (slower)")
        return None


def _load_or_build(solver: Any, cc: str, label: str, build: bool = True) -> dict[str, Any] | None:
    import casadi as ca

    names = [n for n in NLP_FUNCTIONS if n in solver.get_function()]
    flags = _flags()
    root = cache_dir()
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix=".gen-") as tmp:
        cg = ca.CodeGenerator(f"{_SOURCE_NAME}.c", {"with_header": False})
        for n in names:
            cg.add(solver.get_function(n))
        # the generator writes under the prefix given (a folder ends in a separator); changing the
        # process's working folder instead raced with worker processes started meanwhile
        src = Path(cg.generate(str(tmp) + os.sep))
        text = src.read_bytes()
        digest = hashlib.sha256(text + "\0".join((Path(cc).name, *flags, *names, f"split {SPLIT_STATEMENTS}")).encode()
                                ).hexdigest()[:20]
        so = root / f"{_SOURCE_NAME}_{digest}.so"
        if not so.exists() and not build:
            return None  # "cached": no compilation for this NLP; the virtual machine runs its graph
        if not so.exists():
            with _locked(root / f".{so.name}.lock"):
                if not so.exists():  # another process may have built it while this one waited
                    _build(src, so, cc, flags, label, len(text))
    return {n: ca.external(n, str(so)) for n in names}


_FUNCTION = re.compile(r"^static int (casadi_f\d+)\(const casadi_real\*\* arg, casadi_real\*\* res, "
                       r"casadi_int\* iw, casadi_real\* w, int mem\) \{$")
_VARIABLE = re.compile(r"\ba(\d+)\b")
_HELPER = re.compile(r"^(casadi_real|casadi_int|void|int) (casadi_\w+)\(")
"""A helper function of the preamble (``casadi_sq``; with an MX graph also ``casadi_copy``, ``casadi_fill``, ...)."""


def split_sources(text: str, chunk: int = SPLIT_STATEMENTS, units: int = 2) -> list[str]:
    """casadi's generated C cut for the C compiler: ``[main, part_1, ..., part_units]``.

    casadi writes an SX function as one C function of straight-line statements on local
    variables (``a00123=(a00042*a00007);``). The Lagrangian Hessian of the mini rover's NLP is one
    such function of 714k statements: ``gcc -O1`` on it grew past 21 GB of memory and was killed
    (2026-11-25, this machine), and ``-O0`` code is no faster than casadi's virtual machine. Here
    every function longer than ``chunk`` statements becomes a driver that calls parts of ``chunk``
    statements sharing the work variables through one array (``a00123`` becomes ``a[123]``): the
    same operations in the same order, each part small enough for the optimiser. The parts go
    to ``units`` further files (compiled in parallel), which repeat the generated file's
    preamble with its helper functions made ``static``.
    """
    lines = text.split("\n")
    try:
        end_pre = lines.index("/* Configuration this file was compiled with */")
    except ValueError:
        return [text]
    preamble = [_HELPER.sub(r"static \1 \2(", ln) for ln in lines[:end_pre]]
    main: list[str] = []
    parts: list[list[str]] = []
    i = 0
    while i < len(lines):
        m = _FUNCTION.match(lines[i])
        if not m:
            main.append(lines[i])
            i += 1
            continue
        j = i + 1
        while lines[j] != "}":
            j += 1
        body = lines[i + 1:j]
        stmts = [ln for ln in body if not ln.startswith("  casadi_real a") and ln != "  return 0;"]
        if len(stmts) <= chunk or body[-1] != "  return 0;":
            main.extend(lines[i:j + 1])
            i = j + 1
            continue
        name = m.group(1)
        nv = 1 + max((int(v) for ln in stmts for v in _VARIABLE.findall(ln)), default=0)
        names = []
        for k in range(0, len(stmts), chunk):
            names.append(f"{name}_part{k // chunk}")
            head = f"void {names[-1]}(const casadi_real** arg, casadi_real** res, casadi_real* __restrict a)"
            main.append(f"{head};")
            parts.append([f"__attribute__((visibility(\"hidden\"))) {head} {{",
                          *(_VARIABLE.sub(lambda v: f"a[{int(v.group(1))}]", ln) for ln in stmts[k:k + chunk]), "}", ""])
        main += [lines[i], f"  casadi_real a[{nv}];", *(f"  {n}(arg, res, a);" for n in names), "  return 0;", "}"]
        i = j + 1
    if not parts:
        return [text]
    units = max(1, min(units, len(parts)))
    files = ["\n".join(main)]
    for u in range(units):  # contiguous runs of parts, about equal in length
        mine = parts[u * len(parts) // units:(u + 1) * len(parts) // units]
        files.append("\n".join([*preamble, "", *(ln for part in mine for ln in part)]))
    return files


def _build(src: Path, so: Path, cc: str, flags: tuple[str, ...], label: str, size: int) -> None:
    t0, c0 = time.perf_counter(), _children_cpu()
    _say(f"compiling the {label} functions ({size / 1e6:.0f} MB of generated C, {Path(cc).name} {' '.join(flags)}) "
         f"into {so.parent}: once per NLP structure, cached for later runs ...")
    jobs = max(1, os.cpu_count() or 1)
    objects, procs = [], []
    for k, code in enumerate(split_sources(src.read_text(), SPLIT_STATEMENTS, jobs)):
        c = src.with_name(f"{src.stem}_{k}.c")
        c.write_text(code)
        objects.append(c.with_suffix(".o"))
        procs.append([cc, *flags, "-fPIC", "-c", str(c), "-o", str(objects[-1])])
    running: list[subprocess.Popen[bytes]] = []
    for cmd in procs:  # at most `jobs` compilers at a time
        while len(running) >= jobs:
            _wait(running.pop(0))
        running.append(subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE))
    for pr in running:
        _wait(pr)
    tmp_so = src.with_suffix(".so")
    subprocess.run([cc, "-shared", *map(str, objects), "-o", str(tmp_so), "-lm"], check=True, capture_output=True)
    os.replace(tmp_so, so)  # atomic: a reader sees no library or the whole library
    _say(f"compiled {so.name} in {time.perf_counter() - t0:.0f} s wall, {_children_cpu() - c0:.0f} s CPU")


def _wait(pr: "subprocess.Popen[bytes]") -> None:
    out, err = pr.communicate()
    if pr.returncode:
        raise subprocess.CalledProcessError(pr.returncode, pr.args, out, err)


def _children_cpu() -> float:
    t = os.times()
    return float(t.children_user + t.children_system)
