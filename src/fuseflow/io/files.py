"""File reading and writing shared by every format module: one error convention, one atomic write.

Reads raise ``RecordingError`` naming the file when it is missing or unreadable, and
``FormatError`` when its content does not parse; writes go to ``<name>.tmp`` beside the target
and are renamed over it, so a crash never leaves half a file under the real name; a failed
write (full disk, no permission) removes the temporary file and raises ``OutputError``.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path
from typing import Any

from fuseflow.errors import FormatError, OutputError, RecordingError

__all__ = ["read_bytes", "load_json", "write_bytes_atomic", "write_json_atomic", "write_error"]


def read_bytes(path: str | Path) -> bytes:
    """The file's content; RecordingError naming the file when it is missing or unreadable."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise RecordingError(f"{path}: file not found") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror or exc})") from None


def load_json(path: str | Path) -> Any:
    """A JSON document: RecordingError when the file cannot be read, FormatError (with line and
    column) when it is not UTF-8 JSON."""
    data = read_bytes(path)
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise FormatError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise FormatError(f"{path}: JSON nested too deeply to be a FuseFlow file") from None


def write_bytes_atomic(path: str | Path, *chunks: bytes) -> Path:
    """Write ``chunks`` one after the other to ``path`` (parent folders created) through a
    temporary file and a rename. Returns the path."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            for chunk in chunks:
                f.write(chunk)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise write_error(path, exc) from None
    return path


def write_error(path: str | Path, exc: OSError) -> OutputError:
    """The one-line OutputError for a failed write of ``path``: a full disk or quota says so (with
    the space left), a read-only or forbidden place says that."""
    reason = {
        errno.ENOSPC: "no space left on the device",
        errno.EDQUOT: "disk quota exceeded",
        errno.EROFS: "read-only filesystem",
        errno.EACCES: "no permission",
        errno.EPERM: "no permission",
    }.get(exc.errno, exc.strerror or str(exc))
    free = ""
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        try:
            free = f" ({shutil.disk_usage(Path(path).parent).free / 1e6:.0f} MB free)"
        except OSError:
            pass
        return OutputError(f"cannot write {path}: {reason}{free}; free some space or choose another --out")
    return OutputError(f"cannot write {path}: {reason}")


def write_json_atomic(path: str | Path, doc: Any) -> None:
    """Write ``doc`` as indented JSON (``write_bytes_atomic``), so a crash never leaves half a file."""
    write_bytes_atomic(path, (json.dumps(doc, indent=2) + "\n").encode("utf-8"))
