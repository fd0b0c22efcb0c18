"""FuseFlow's command line. ``fuseflow --help`` lists the commands; each module adds one."""

from __future__ import annotations

from fuseflow.cli import calibrate as _calibrate  # noqa: F401  (registers `fuseflow calibrate`)
from fuseflow.cli import convert, info  # noqa: F401  (registers the commands)
from fuseflow.cli import fuse as _fuse  # noqa: F401  (registers `fuseflow fuse`)
from fuseflow.cli import run as _run  # noqa: F401  (registers `fuseflow run`, `demo`, `view`)
from fuseflow.cli import simulate as _simulate  # noqa: F401  (registers `fuseflow simulate`)
from fuseflow.cli.app import app, err_console
from fuseflow.cli.bench import bench_app
from fuseflow.cli.demo import demo
from fuseflow.errors import FuseFlowError

# Explicit registration (issue 18; after the side-effect imports above, so `demo` replaces cli/run.py's).
app.command("demo")(demo)
app.add_typer(bench_app, name="bench")


def main() -> None:
    """Entry point: run the app, turning FuseFlowError into a one-line message and exit code 2."""
    try:
        app()
    except FuseFlowError as exc:
        err_console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        raise SystemExit(2) from None


__all__ = ["app", "main"]
