"""`fuseflow view PATH`: fused clouds in the rerun viewer, a .rrd file, or PNGs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import typer

from fuseflow.cli.app import FRAMES_OPTION_HELP, fail, parse_range, say


def command(
    path: Path = typer.Argument(..., help="A run directory (with clouds/) or a calibrated recording."),
    save_png: Path = typer.Option(None, "--save-png", help="Headless: render each frame to DIR/<frame>.png."),
    color_by: str = typer.Option("rgb", "--color-by", help="rgb or weight (PNG only; rerun shows both)."),
    rrd: Path = typer.Option(None, "--rrd", help="Write a rerun .rrd file instead of opening the viewer."),
    frames: str = typer.Option(None, "--frames", help=FRAMES_OPTION_HELP),
    whole: bool = typer.Option(
        False, "--whole", help="PNG: draw every point (default: the capture volume the cameras look at)."
    ),
) -> None:
    """Show fused clouds per frame (rerun: cameras as frustums, clouds on a timeline, weight as colour)."""
    from fuseflow.viz.sources import render_pngs, send_to_rerun, view_source

    if color_by not in ("rgb", "weight"):
        fail(f"--color-by must be rgb or weight, got {color_by!r}")
    source = view_source(path)
    source = replace(source, items=[source.items[i] for i in parse_range(frames, len(source.items))])
    if save_png is not None:
        n = render_pngs(source, save_png, color_by, whole)
        say(f"wrote {n} PNGs to {save_png}")
        return
    n = send_to_rerun(source, rrd)
    say(f"wrote {rrd}" if rrd is not None else f"sent {n} frames to the rerun viewer")
