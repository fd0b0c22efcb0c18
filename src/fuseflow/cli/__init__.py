"""FuseFlow's command line. ``fuseflow --help`` lists the commands.

Every command is registered here, in ``COMMANDS`` (name -> the module whose ``command``
function implements it) and ``GROUPS`` (sub-apps), and nowhere else: a module that is not
listed is not a command. Each command parses its options, makes one library call and prints.
``parse_settings`` / ``fuse_config`` read the ``NAME=VALUE`` form of a FUSE setting (--set).
"""

from __future__ import annotations

import contextlib
import errno
import os
import sys
import tempfile
from pathlib import Path

import typer

from fuseflow.cli import bench, calibrate, convert, demo, fuse, info, live, node, run, simulate, view
from fuseflow.cli.app import app, error, guarded
from fuseflow.cli.settings import fuse_config, parse_settings
from fuseflow.errors import FuseFlowError

COMMANDS = {
    "demo": demo,
    "simulate": simulate,
    "info": info,
    "convert": convert,
    "calibrate": calibrate,
    "fuse": fuse,
    "run": run,
    "view": view,
    "live": live,
    "node": node,
}
"""Command name -> module defining ``command(...)`` (typer parameters)."""

GROUPS = {"bench": bench.bench_app}
"""Command groups (typer sub-apps)."""

for _name, _module in COMMANDS.items():
    app.command(_name, epilog=getattr(_module, "EXAMPLES", None))(guarded(_module.command))
for _name, _group in GROUPS.items():
    app.add_typer(_group, name=_name)


NATIVE_LOG = Path(tempfile.gettempdir()) / "fuseflow-native.log"
"""Where messages that native libraries (libpng, COLMAP/glog, Open3D) print on stderr go, unless
``--verbose`` or FUSEFLOW_VERBOSE=1: they would otherwise precede FuseFlow's own one-line error."""


@app.callback()
def _options(
    verbose: bool = typer.Option(
        False, "--verbose", help=f"Show native libraries' stderr messages (otherwise kept in {NATIVE_LOG})."
    ),
) -> None:
    """FuseFlow: target-free calibration (GMAC) and stateless fusion (FUSE) for multi-camera RGB-D rigs."""


@contextlib.contextmanager
def _native_stderr_to_log(enabled: bool):
    """Point file descriptor 2 (where C/C++ libraries write) at NATIVE_LOG while Python's
    sys.stderr (FuseFlow's own errors and warnings) keeps the terminal."""
    if not enabled:
        yield
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except OSError:
        saved = None
    log = _open_native_log() if saved is not None else None
    if log is None:  # no writable log (outside the except: its error must not chain into others)
        if saved is not None:
            os.close(saved)
        yield
        return
    python_stderr = sys.stderr
    sys.stderr = os.fdopen(os.dup(saved), "w", buffering=1)
    os.dup2(log, 2)
    os.close(log)
    try:
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
        sys.stderr.close()
        sys.stderr = python_stderr


def _open_native_log() -> int | None:
    """A descriptor of NATIVE_LOG, or of a per-user one beside it when that one belongs to another
    user; None when neither can be written."""
    for path in (NATIVE_LOG, NATIVE_LOG.with_name(f"fuseflow-native-{os.getuid()}.log")):
        try:
            return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError:
            continue
    return None


def _flush_stdout() -> None:
    """Flush stdout at exit; when it cannot be written (``> /dev/full``, a closed pipe) point it at
    /dev/null, so that Python's own flush at exit does not print a second error."""
    try:
        sys.stdout.flush()
    except OSError:
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def main() -> None:
    """Entry point: run the app, turning FuseFlowError into a one-line message and exit code 2."""
    verbose = "--verbose" in sys.argv[1:] or os.environ.get("FUSEFLOW_VERBOSE", "") not in ("", "0")
    with _native_stderr_to_log(not verbose):
        try:
            app()
        except FuseFlowError as exc:
            error(str(exc))
            raise SystemExit(2) from None
        except OSError as exc:  # --help or a usage message to a full device (commands: guarded)
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EPIPE):
                raise
            error(f"cannot write standard output: {os.strerror(exc.errno).lower()}")
            raise SystemExit(2) from None
        finally:
            _flush_stdout()


__all__ = ["COMMANDS", "GROUPS", "app", "fuse_config", "main", "parse_settings"]
