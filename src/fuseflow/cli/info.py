"""`fuseflow info REC`: what a recording holds. Parsing and printing only: the summary is
``fuseflow.io.summary.recording_summary``."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from fuseflow.cli.app import console, error, fail, say


def command(
    rec: Path = typer.Argument(..., help="Recording directory (FuseFlow, Open3D/Redwood/ICL or TUM layout)."),
    as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON instead of a table."),
    check: bool = typer.Option(
        False, "--check", help="Also decode every colour and depth file; exit 1 naming each corrupt one."
    ),
) -> None:
    """Show cameras, frames, resolution, calibration state and missing views of a recording."""
    from fuseflow.io.summary import check_recording_files, recording_summary

    s = recording_summary(rec)
    problems = check_recording_files(rec) if check else None
    if as_json:
        if problems is not None:
            s["check"] = {"ok": not problems, "problems": problems}
        typer.echo(json.dumps(s, indent=2))
    else:
        _print_summary(s)
    if problems:
        for p in problems:
            error(p)
        fail(f"{len(problems)} unreadable file{'s' if len(problems) > 1 else ''} in {rec}", code=1)
    elif problems is not None and not as_json:
        say("every colour and depth file decodes at the size rig.json gives")


def _count(n: int, noun: str) -> str:
    """'1 frame', '30 frames'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def _print_summary(s: dict) -> None:
    w, h = s["resolution"]
    say(
        f"{s['path']} ({s['layout']}): {_count(s['frames'], 'frame')}, {_count(s['cameras'], 'camera')}, {w}x{h}, "
        + ("calibrated" if s["calibrated"] else "not calibrated")
    )
    t = Table("camera", "size", "fx, fy", "cx, cy", "depth/m", "range m", "calib", "missing", box=None)
    t.columns[0].no_wrap, t.columns[0].overflow = True, "fold"  # ids (12-digit serials) are never cut to "..."
    for c in s["camera_list"]:
        t.add_row(
            escape(c["id"]),
            f"{c['width']}x{c['height']}",
            f"{c['fx']:.1f}, {c['fy']:.1f}",
            f"{c['cx']:.1f}, {c['cy']:.1f}",
            f"{c['depth_scale']:g}",
            f"{c['depth_range'][0]:g}-{c['depth_range'][1]:g}",
            "yes" if c["calibrated"] else "no",
            str(c["missing_views"]),
        )
    console.print(t)
    if "timing" in s:
        tm = s["timing"]
        sp = tm["spread_ms"]
        say(
            f"views paired by device timestamp within {tm['tolerance_ms']:.1f} ms; spread per frame: median "
            f"{sp['median']:.2f} ms, p95 {sp['p95']:.2f} ms, max {sp['max']:.2f} ms"
        )
        tt = Table(
            "camera", "fps", "stream frames", "gaps", "longest gap ms", "dropped views", "first view s", box=None
        )
        for cid, c in tm["cameras"].items():
            first = "-" if c["first_view_s"] is None else f"{c['first_view_s']:.4f}"
            tt.add_row(escape(cid), f"{c['fps']:.2f}", str(c["stream_frames"]), str(c["gaps"]), f"{c['longest_gap_ms']:.1f}",
                       str(c["dropped_views"]), first)  # fmt: skip
        console.print(tt)
    if "poses" in s:
        say("single moving camera; trajectory poses: " + ("yes" if s["poses"] else "no"))


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow info /tmp/studio
  fuseflow info /data/rig --check     # also decode every file
"""
