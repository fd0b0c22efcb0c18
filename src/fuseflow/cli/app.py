"""The typer application. Command modules register themselves on ``app``; this is the only
layer that prints or exits (library code raises FuseFlowError instead)."""

from __future__ import annotations

import typer
from rich.console import Console
from rich.markup import escape

app = typer.Typer(
    name="fuseflow",
    help="FuseFlow: target-free calibration (GMAC) and stateless fusion (FUSE) for multi-camera RGB-D rigs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

console = Console()
err_console = Console(stderr=True)


def fail(message: str, code: int = 2) -> None:
    """Print a one-line error and exit (CLI only). The message is printed verbatim (escaped:
    rich would read "[cam00-cam04, ...]" as a markup tag and drop it)."""
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def warn(message: str) -> None:
    """Print a warning line, verbatim (escaped like ``fail``)."""
    console.print(f"[yellow]warning:[/] {escape(message)}", highlight=False)


def parse_range(spec: str | None, n: int) -> range:
    """'A:B' (python-style, either side optional) -> range within [0, n)."""
    if spec is None:
        return range(n)
    try:
        a, _, b = spec.partition(":")
        start = int(a) if a else 0
        stop = int(b) if b else n
    except ValueError:
        fail(f"--frames expects A:B (e.g. 0:100), got {spec!r}")
    return range(n)[start:stop]


def parse_int_list(spec: str, option: str) -> list[int]:
    try:
        return [int(x) for x in spec.replace(" ", "").split(",") if x]
    except ValueError:
        fail(f"{option} expects comma-separated integers, got {spec!r}")
        raise  # unreachable


def progress(description: str):
    """A transient rich progress bar (description, bar, done/total, elapsed, eta) on the CLI console."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        "[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        "eta", TimeRemainingColumn(), console=console, transient=True,
    )  # fmt: skip
