"""The typer application and the console helpers every command prints through.

The CLI is the only layer that prints or exits (library code raises FuseFlowError instead).
Commands are registered in one list, ``fuseflow.cli.COMMANDS``. Text is printed verbatim:
``say``, ``warn`` and ``fail`` escape rich markup, so "[cam00-cam04, ...]" or "fuseflow[ray]"
are never taken for markup tags and dropped; help text is plain (``rich_markup_mode=None``).
"""

from __future__ import annotations

import errno
import functools
import os
from collections.abc import Callable

import typer
from rich.console import Console
from rich.markup import escape

from fuseflow.errors import FuseFlowError

app = typer.Typer(
    name="fuseflow",
    help="FuseFlow: target-free calibration (GMAC) and stateless fusion (FUSE) for multi-camera RGB-D rigs.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

console = Console(emoji=False)  # ":abc:" in echoed input ("cuda:abc:") is text, never an emoji
err_console = Console(stderr=True, emoji=False)  # writes to sys.stderr at print time (see cli.main)


def say(message: str) -> None:
    """Print a line verbatim (rich markup escaped)."""
    console.print(escape(message), highlight=False)


def print_table(title: str, rows: list[tuple[str, str]]) -> None:
    """A two-column table (name, value), every cell verbatim."""
    from rich.table import Table

    t = Table(title=escape(title), show_header=False)
    for name, value in rows:
        t.add_row(escape(name), escape(str(value)))
    console.print(t)


def error(message: str) -> None:
    """Print "error: message" to stderr, verbatim."""
    err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)


def fail(message: str, code: int = 2) -> None:
    """Print a one-line error and exit (CLI only). The message is printed verbatim (escaped:
    rich would read "[cam00-cam04, ...]" as a markup tag and drop it)."""
    error(message)
    raise typer.Exit(code)


def warn(message: str, stderr: bool = False) -> None:
    """Print a warning line, verbatim (escaped like ``fail``); on stderr when asked."""
    (err_console if stderr else console).print(f"[yellow]warning:[/] {escape(message)}", highlight=False)


FRAMES_OPTION_HELP = "A:B[:step]: frame positions, a Python slice (A, B optional or negative; default all)."
"""The help of every ``--frames`` that selects frames (the grammar of ``io.convert.FRAMES_HELP``)."""


def frame_count(num_frames: int, old_frames: int | None) -> int:
    """A command's frame count: ``--num-frames``, or the deprecated count spelling ``--frames N``
    (still accepted, with a warning: ``--frames`` selects frames, A:B[:step], elsewhere)."""
    if old_frames is None:
        return num_frames
    warn(f"--frames {old_frames} as a count is deprecated: use --num-frames {old_frames}")
    return old_frames


OLD_FRAMES_COUNT = typer.Option(None, "--frames", hidden=True, help="Deprecated spelling of --num-frames.")
"""The hidden ``--frames N`` of the commands that take a frame count (``frame_count``)."""


def parse_range(spec: str | None, n: int) -> range:
    """``--frames A:B[:step]`` -> the positions it selects in range(n) (``io.convert.parse_frame_range``,
    the one parser); a bad spec or an empty selection exits with a one-line error."""
    from fuseflow.io.convert import parse_frame_range

    try:
        positions = parse_frame_range(spec, n)
    except FuseFlowError as exc:
        fail(str(exc))
        raise  # unreachable: fail exits
    if len(positions) == 0:
        fail(f"--frames {spec!r} selects no frame: the recording has {n} frames (positions 0:{n})")
    return positions


def parse_int_list(spec: str, option: str) -> list[int]:
    try:
        return [int(x) for x in spec.replace(" ", "").split(",") if x]
    except ValueError:
        fail(f"{option} expects comma-separated integers, got {spec!r}")
        raise  # unreachable


def guarded(command: Callable[..., None]) -> Callable[..., None]:
    """``command`` with FuseFlowError (bad recording, calib.json, rig, ...) turned into a one-line
    error and exit code 2, and Ctrl-C into a line saying how to resume and exit code 130, however
    the app is invoked (console script or typer's CliRunner)."""

    @functools.wraps(command)
    def wrapper(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except FuseFlowError as exc:
            fail(str(exc))
        except OSError as exc:  # a full disk or stdout on a full device, wherever it was written
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EPIPE):
                raise
            where = exc.filename or "standard output or an output file"
            fail(f"cannot write {where}: {os.strerror(exc.errno).lower()}; free some space or write elsewhere")
        except (KeyboardInterrupt, SystemError) as exc:
            if isinstance(exc, SystemError) and not _interrupted(exc):
                raise
            fail(
                "interrupted; every output written so far is complete: run the same command again "
                "to resume (run and fuse skip the frames already written)",
                code=130,
            )

    return wrapper


def _interrupted(exc: BaseException) -> bool:
    """A SystemError that wraps Ctrl-C: numba's dispatcher reports a KeyboardInterrupt raised
    inside a compiled kernel as "returned a result with an exception set"."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


#: Help of `fuse` and `run`'s --preset auto (FuseConfig.auto_grid, fuse.presets.auto_config).
AUTO_HELP = (
    "FUSE preset: auto (default): per frame, every pixel when the frame has at most 0.8 M valid depth "
    "pixels, else every 2nd pixel where that still samples the surface within 1 cm (every pixel otherwise);"
)

#: Help of `fuse` and `run`'s --out.
OUT_HELP = (
    "Output directory: clouds/<frame>.ply (or --format's), calib.json, summary.json, manifest.json; "
    "run also frames.jsonl (a line per frame); --mesh adds meshes/<frame>.glb."
)

#: Help of `fuse` and `run`'s --points.
POINTS_HELP = "About N points per frame: s0 is searched per frame; a small budget also takes a coarser pixel grid."


#: Help of `fuse` and `run`'s --set.
SET_HELP = (
    "NAME=VALUE: one FUSE setting over the preset, as FuseConfig.describe() names it "
    "(rps.k_max=2, ash.s0=3, cvgc.multiview_mean=false, pixel_stride=2); repeat for more."
)


def check_fuse_options(preset: str, points: int | None, settings: list[str] | None = None) -> None:
    """`fuse` and `run`'s --preset (a name of fuseflow.fuse.PRESETS), --points (>= 1) and --set
    (``cli.settings.parse_settings``, checked against the preset)."""
    from fuseflow.cli.settings import fuse_config
    from fuseflow.errors import ValidationError
    from fuseflow.fuse import PRESETS

    if points is not None and points < 1:
        fail(f"--points must be a positive integer, got {points}")
    if preset not in PRESETS:
        fail(f"--preset: no FUSE preset {preset!r}; presets are {sorted(PRESETS)}")
    try:
        fuse_config(preset, points, settings or ())
    except ValidationError as e:
        fail(str(e))


def check_device(device: str) -> str:
    """``--device``: cpu, cuda or cuda:N, and CUDA only where torch sees a GPU."""
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        fail(f"--device must be cpu or cuda, got {device!r}")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            fail(f"--device {device}: torch sees no CUDA device on this machine (use --device cpu)")
    return device


def progress(description: str):
    """A transient rich progress bar (description, bar, done/total, elapsed, eta) on the CLI console."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn, TimeRemainingColumn

    return Progress(
        "[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
        "eta", TimeRemainingColumn(), console=console, transient=True,
    )  # fmt: skip


class StageProgress:
    """``callback(stage, done, total)`` for a library's progress (e.g. ``fuseflow.calib.calibrate(...,
    progress=)``): on a terminal a transient rich bar per stage; piped, plain lines (a stage's
    start, then about every 10 % of its steps and its end). Use as a context manager."""

    def __init__(self, prefix: str = ""):
        self.prefix = prefix
        self.live = None
        self.tasks: dict[str, int] = {}
        self.shown: dict[str, int] = {}

    def __enter__(self) -> StageProgress:
        if console.is_terminal:
            self.live = progress("")
            self.live.start()
        return self

    def __exit__(self, *exc) -> None:
        if self.live is not None:
            self.live.stop()

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.live is not None:
            if stage not in self.tasks:
                for t in self.live.tasks:  # a new stage ends the open-ended ones before it
                    if t.total is None:
                        self.live.update(t.id, total=1, completed=1)
                self.tasks[stage] = self.live.add_task(escape(self.prefix + stage), total=total or None)
            self.live.update(self.tasks[stage], completed=done, total=total or None)
            return
        if stage not in self.shown:
            self.shown[stage] = -1
            if total == 0 or done < total:
                say(f"{self.prefix}{stage}" + (f": 0/{total}" if total else ""))
        if total:
            tenth = done * 10 // total
            if tenth > self.shown[stage]:
                self.shown[stage] = tenth
                say(f"{self.prefix}{stage}: {done}/{total}")
