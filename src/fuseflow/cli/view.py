"""`fuseflow view PATH`: fused clouds in the rerun viewer, a .rrd file, or PNGs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer

from fuseflow.cli.app import FRAMES_OPTION_HELP, fail, parse_range, progress, say


def command(
    path: Path = typer.Argument(..., help="A run directory (with clouds/) or a calibrated recording."),
    save_png: Path = typer.Option(None, "--save-png", help="Headless: render each frame to DIR/<frame>.png."),
    color_by: str = typer.Option("rgb", "--color-by", help="rgb or weight (PNG only; rerun shows both)."),
    rrd: Path = typer.Option(None, "--rrd", help="Write a rerun .rrd file instead of opening the viewer."),
    frames: str = typer.Option(None, "--frames", help=FRAMES_OPTION_HELP),
    whole: bool = typer.Option(
        False, "--whole", help="PNG: draw every point (default: the capture volume the cameras look at)."
    ),
    rerun_full: bool = typer.Option(
        False, "--rerun-full", help="rerun: log every point (default: at most 100 000 a frame, an even subset)."
    ),
) -> None:
    """Show fused clouds per frame (rerun: cameras as frustums, clouds on a timeline, weight as colour)."""
    from fuseflow.io.paths import check_output_file, prepare_output_dir
    from fuseflow.viz.sources import render_pngs, send_to_rerun, view_source

    if color_by not in ("rgb", "weight"):
        fail(f"--color-by must be rgb or weight, got {color_by!r}")
    if save_png is None and rrd is None and not viewer_reachable():
        fail(
            "no display (DISPLAY and WAYLAND_DISPLAY are unset) and no rerun viewer listening on "
            f"127.0.0.1:{VIEWER_PORT}: write a file instead, --rrd run.rrd (open it with 'rerun run.rrd' where "
            "there is a display) or --save-png DIR"
        )
    source = view_source(path)
    if color_by == "weight" and not source.weights:
        fail(
            f"--color-by weight: the clouds in {path} are Draco (.drc) files, which do not store FUSE's weight; "
            "write ply or glb clouds as well (--format ply,drc) or use --color-by rgb"
        )
    n_all = len(source.items)
    source = replace(source, items=[source.items[i] for i in parse_range(frames, n_all)])
    if not source.items:
        fail(f"--frames {frames}: no frame of {path} in that range (it has {n_all} frames, positions 0 to {n_all - 1})")
    if save_png is not None:
        prepare_output_dir(save_png)
        with progress("rendering") as bar:
            task = bar.add_task(f"rendering {len(source.items)} PNGs", total=len(source.items))
            n = render_pngs(
                source, save_png, color_by, whole, on_frame=lambda done, total: bar.update(task, completed=done)
            )
        say(f"wrote {n} PNGs to {save_png}")
        return
    if rrd is not None:
        check_output_file(rrd)
    try:
        n = send_to_rerun(source, rrd, full=rerun_full)
    except RuntimeError as exc:  # rerun's gRPC connection to a viewer
        fail(
            f"the rerun viewer could not be reached ({str(exc).splitlines()[0][:120]}): use --rrd FILE or --save-png DIR"
        )
    say(f"wrote {rrd}" if rrd is not None else f"sent {n} frames to the rerun viewer")


VIEWER_PORT = 9876
"""Where a rerun viewer listens for logging connections (rerun's default gRPC port)."""


def viewer_reachable() -> bool:
    """True when a viewer window can open (a display, or not Linux) or one already listens on
    VIEWER_PORT (e.g. forwarded over SSH); checked in well under a second."""
    import os
    import socket
    import sys

    if not sys.platform.startswith("linux") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return True
    try:
        with socket.create_connection(("127.0.0.1", VIEWER_PORT), timeout=0.3):
            return True
    except OSError:
        return False


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow view /tmp/studio-run                         # the rerun viewer (needs a display)
  fuseflow view /tmp/studio-run --rrd /tmp/run.rrd      # headless: a rerun file
  fuseflow view /tmp/studio-run --save-png /tmp/png     # headless: a PNG per frame
"""
