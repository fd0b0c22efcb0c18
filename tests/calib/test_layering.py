"""calib's imports: nothing above it (fuse, pipeline, eval, cli), no private names across modules."""

from __future__ import annotations

import ast
from pathlib import Path

import fuseflow.calib

CALIB = Path(fuseflow.calib.__file__).parent
#: io is below calib too (docs/architecture.md); of it calib needs only numba's cache location
ALLOWED = ("fuseflow.calib", "fuseflow.types", "fuseflow.errors", "fuseflow.geometry", "fuseflow.io.numba_cache")


def _imports():
    for path in sorted(CALIB.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                yield path, node.module, [a.name for a in node.names]
            elif isinstance(node, ast.Import):
                for a in node.names:
                    yield path, a.name, []


def test_calib_imports_only_lower_layers():
    bad = [
        (p.name, mod)
        for p, mod, _ in _imports()
        if (mod == "fuseflow" or mod.startswith("fuseflow.")) and not mod.startswith(ALLOWED)
    ]
    assert bad == []


def test_no_private_names_imported_across_calib_modules():
    bad = [
        (p.name, mod, n)
        for p, mod, names in _imports()
        if mod.startswith("fuseflow.")
        for n in names
        if n.startswith("_")
    ]
    assert bad == []
