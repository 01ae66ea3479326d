"""Docstrings say what the code takes: for every public function, class and public method
(``__all__`` of every ``rtctl`` and ``offline`` module) whose numpy-style docstring has a
``Parameters`` section, the names listed there are exactly the names of its signature.

Parsed with numpydoc's own docstring reader (``numpydoc.docscrape``), so ``a, b : float``
documents both ``a`` and ``b`` and ``*args`` matches ``args``. A docstring without a
Parameters section is not checked here (``tests/test_imports.py`` checks that public names
have a docstring at all).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import warnings
from typing import Any

import pytest

docscrape = pytest.importorskip("numpydoc.docscrape", reason="numpydoc is in the [test] extra")


def _modules() -> list[str]:
    out = []
    for pkg in ("rtctl", "offline"):
        mod = importlib.import_module(pkg)
        out += [m.name for m in pkgutil.walk_packages(mod.__path__, pkg + ".")]
    return sorted(out)


def _public_callables(mod: Any) -> list[Any]:
    found = []
    for name in getattr(mod, "__all__", ()):
        obj = getattr(mod, name, None)
        if inspect.isfunction(obj) and obj.__module__ == mod.__name__:
            found.append(obj)
        elif inspect.isclass(obj) and obj.__module__ == mod.__name__:
            found.append(obj)
            found += [v for k, v in vars(obj).items() if inspect.isfunction(v) and not k.startswith("_")]
    return found


def documented_vs_signature(obj: Any) -> tuple[set[str], set[str]] | None:
    """``(documented, in the signature)`` parameter names, or None without a Parameters section."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numpydoc warns about sections it does not know
        doc = docscrape.ClassDoc(obj) if inspect.isclass(obj) else docscrape.FunctionDoc(obj)
    listed = [p.name for p in doc["Parameters"]]
    if not listed:
        return None
    documented = {n.strip().lstrip("*") for item in listed for n in item.split(",")}
    sig = {p for p in inspect.signature(obj).parameters if p not in ("self", "cls")}
    return documented, sig


@pytest.mark.parametrize("name", _modules())
def test_parameters_sections_match_signatures(name):
    mod = importlib.import_module(name)
    wrong = []
    for obj in _public_callables(mod):
        pair = documented_vs_signature(obj)
        if pair is None:
            continue
        documented, sig = pair
        if documented != sig:
            wrong.append(f"{obj.__qualname__}: not documented {sorted(sig - documented)}, "
                         f"documented but not taken {sorted(documented - sig)}")
    assert not wrong, f"{name}: Parameters sections that do not match the signature:\n" + "\n".join(wrong)


def test_check_can_fail():
    """A docstring that lists a parameter the function does not take, and misses one it does, is caught."""

    def f(a: int, b: int) -> int:
        """Add.

        Parameters
        ----------
        a, c : int
            Numbers.
        """
        return a + b

    documented, sig = documented_vs_signature(f)
    assert documented - sig == {"c"} and sig - documented == {"b"}
