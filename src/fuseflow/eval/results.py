"""One JSON schema for benchmark results, written by ``fuseflow bench ... --json`` and by every
program of the source tree's ``benchmarks/`` (through ``benchmarks/common.py``)::

    {"schema": 1, "benchmark": "fuse_speed", "version": "0.2.1",
     "machine": {"cpu": ..., "cores": ..., "platform": ..., "python": ..., "libraries": {...}},
     "command": "fuseflow bench fuse --cameras 8 --json OUT", "meta": {...}, "rows": [{...}, ...]}

``version`` is fuseflow's, ``command`` the command line that reproduces the file, ``meta`` what
the benchmark wants to record beside its rows (options, derived ratios), ``rows`` one object per
measurement. :func:`read_result` checks the envelope and raises
:class:`~fuseflow.errors.ValidationError` on a file that is not one.
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any

from fuseflow.errors import ValidationError

__all__ = ["SCHEMA", "machine", "result_record", "write_result", "read_result"]

SCHEMA = 1
"""Version of the envelope below (bumped when a key changes meaning)."""

_LIBRARIES = ("torch", "numpy", "numba", "open3d", "scipy", "pycolmap", "opencv-python-headless", "opencv-python")


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> dict[str, Any]:
    """CPU, usable cores, OS, Python and the versions of the libraries the numbers depend on."""
    import importlib.metadata as md

    libs = {}
    for name in _LIBRARIES:
        try:
            libs[name] = md.version(name)
        except md.PackageNotFoundError:
            continue
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {
        "cpu": _cpu_name(),
        "cores": cores,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "libraries": libs,
    }


def result_record(benchmark: str, command: str, rows: list[Any], meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """The envelope of one benchmark run (module docstring)."""
    from fuseflow import __version__

    return {
        "schema": SCHEMA,
        "benchmark": benchmark,
        "version": __version__,
        "machine": machine(),
        "command": command,
        "meta": dict(meta or {}),
        "rows": list(rows),
    }


def write_result(
    path: str | Path, benchmark: str, command: str, rows: list[Any], meta: dict[str, Any] | None = None
) -> Path:
    """Write :func:`result_record` to ``path`` (parents created); returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result_record(benchmark, command, rows, meta), indent=1) + "\n")
    return path


def read_result(path: str | Path) -> dict[str, Any]:
    """A results file, checked: JSON with the envelope's keys and a known schema."""
    try:
        doc = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ValidationError(f"{path}: not a readable JSON results file ({exc})") from exc
    missing = [k for k in ("schema", "benchmark", "version", "machine", "command", "rows") if k not in doc]
    if not isinstance(doc, dict) or missing:
        raise ValidationError(f"{path}: not a benchmark results file (missing {missing})")
    if doc["schema"] != SCHEMA:
        raise ValidationError(f"{path}: results schema {doc['schema']}, this fuseflow reads {SCHEMA}")
    return doc
