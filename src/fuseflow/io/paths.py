"""Output locations, checked before any work starts: a command that would fail only after
minutes of calibration or fusion (or leave a half-written file behind) fails first, in one line
that says what is wrong with the path."""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

from fuseflow.errors import OutputError

__all__ = ["prepare_output_dir", "check_output_file"]


def _existing_ancestor(path: Path) -> Path:
    """The nearest ancestor of ``path`` (itself included) that exists; OutputError when one of
    them is a file (``path`` would lie under a file)."""
    p = path
    while not p.exists():
        if p.parent == p:
            break
        p = p.parent
    if p.exists() and not p.is_dir() and p != path:
        raise OutputError(f"{path}: cannot be created, {p} is a file, not a directory")
    return p


def _why(exc: OSError) -> str:
    if exc.errno == errno.EROFS:
        return "the filesystem is read-only"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return "no permission to write there"
    if exc.errno == errno.ENOSPC:
        return "no space left on the device"
    return exc.strerror or str(exc)


def _probe_writable(directory: Path, what: Path) -> None:
    """Create and delete a temporary file in ``directory``: the one reliable test (os.access
    does not see read-only mounts or ACLs)."""
    try:
        fd, name = tempfile.mkstemp(prefix=".fuseflow-probe-", dir=directory)
        os.close(fd)
        os.unlink(name)
    except OSError as exc:
        raise OutputError(f"{what}: cannot write in {directory}: {_why(exc)}") from None


def prepare_output_dir(path: str | Path) -> Path:
    """Create the output directory ``path`` (and its parents) and check that files can be
    written in it; OutputError naming the problem (a file in the way, a path under a file, no
    permission, a read-only filesystem). Returns the path."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{path}: exists and is a file, not a directory (choose a directory for --out)")
    _existing_ancestor(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{path}: cannot create the directory: {_why(exc)}") from None
    _probe_writable(path, path)
    return path


def check_output_file(path: str | Path) -> Path:
    """Check that the file ``path`` can be written (its directory exists or can be created and
    is writable; ``path`` is not a directory) without creating it; OutputError otherwise."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path}: is a directory; give a file name (e.g. {path / 'calib.json'})")
    parent = path.parent if str(path.parent) else Path(".")
    anc = _existing_ancestor(parent)
    if not anc.is_dir():
        raise OutputError(f"{path}: cannot be created, {anc} is a file, not a directory")
    _probe_writable(anc, path)
    return path
