"""FuseFlow's command line. ``fuseflow --help`` lists the commands.

Every command is registered here, in ``COMMANDS`` (name -> the module whose ``command``
function implements it) and ``GROUPS`` (sub-apps), and nowhere else: a module that is not
listed is not a command. Each command parses its options, makes one library call and prints.
"""

from __future__ import annotations

from fuseflow.cli import bench, calibrate, convert, demo, fuse, info, run, simulate, view
from fuseflow.cli.app import app, error, guarded
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
}
"""Command name -> module defining ``command(...)`` (typer parameters)."""

GROUPS = {"bench": bench.bench_app}
"""Command groups (typer sub-apps)."""

for _name, _module in COMMANDS.items():
    app.command(_name)(guarded(_module.command))
for _name, _group in GROUPS.items():
    app.add_typer(_group, name=_name)


def main() -> None:
    """Entry point: run the app, turning FuseFlowError into a one-line message and exit code 2."""
    try:
        app()
    except FuseFlowError as exc:
        error(str(exc))
        raise SystemExit(2) from None


__all__ = ["COMMANDS", "GROUPS", "app", "main"]
