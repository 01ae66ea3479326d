"""The offline package's layers import downward only (``offline/__init__.py``).

Order, bottom to top: files, data, scenarios, physics, rover, fit, sim, discrepancy, cli. Every
``import`` and ``from ... import`` of every module under ``offline/`` (relative imports resolved,
imports inside functions included) is checked. Before the discrepancy tool became its own layer,
the drive diagnosis in ``offline.fit`` imported ``offline.sim``, a layer above it, and this test
failed.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["files", "data", "scenarios", "physics", "rover", "fit", "sim", "discrepancy", "cli"]


def _imports(path: Path, package: list[str]) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                out.append(".".join(base + ([node.module] if node.module else [])))
            else:
                out.append(node.module or "")
        elif isinstance(node, ast.Import):
            out.extend(a.name for a in node.names)
    return out


def test_offline_layers_import_downward_only():
    upward, unknown = [], set()
    for f in sorted((ROOT / "offline").rglob("*.py")):
        parts = f.relative_to(ROOT / "offline").with_suffix("").parts
        layer = parts[0]
        if layer == "__init__":
            continue
        if layer not in ORDER:
            unknown.add(layer)
            continue
        for m in _imports(f, ["offline", *parts[:-1]]):
            names = m.split(".")
            if names[0] != "offline" or len(names) < 2:
                continue
            if names[1] not in ORDER:
                unknown.add(names[1])
            elif ORDER.index(names[1]) > ORDER.index(layer):
                upward.append(f"{f.relative_to(ROOT)} imports {m}")
    assert not unknown, f"modules outside the layer list {ORDER}: {sorted(unknown)} (add them to offline/__init__.py and here)"
    assert not upward, "imports of a layer above:\n" + "\n".join(upward)
