"""FuseFlow's command line. ``fuseflow --help`` lists the commands; each module adds one."""

from __future__ import annotations

from fuseflow.cli import bench_calib as _bench_calib  # noqa: F401  (registers `fuseflow bench calib`)
from fuseflow.cli import bench_paper as _bench_paper  # noqa: F401  (registers `fuseflow bench` and `bench paper`)
from fuseflow.cli import calibrate as _calibrate  # noqa: F401  (registers `fuseflow calibrate`)
from fuseflow.cli import convert, info, simulate
from fuseflow.cli import fuse as _fuse  # noqa: F401  (registers `fuseflow fuse`)
from fuseflow.cli import run as _run  # noqa: F401  (registers `fuseflow run`, `demo`, `view`)
from fuseflow.cli.app import app, err_console
from fuseflow.errors import FuseFlowError

# plain `command` functions (the one-list registration of the restructured CLI)
app.command("simulate")(simulate.command)
app.command("info")(info.command)
app.command("convert")(convert.command)


def main() -> None:
    """Entry point: run the app, turning FuseFlowError into a one-line message and exit code 2."""
    try:
        app()
    except FuseFlowError as exc:
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        raise SystemExit(2) from None


__all__ = ["app", "main"]
