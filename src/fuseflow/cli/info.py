"""`fuseflow info REC`: what a recording holds."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.table import Table

from fuseflow.cli.app import console


def recording_summary(path: Path) -> dict:
    from fuseflow.io.datasets import SequenceRecording, open_recording

    rec = open_recording(path)
    rig = rec.rig
    missing = rec.missing_views()
    summary = {
        "path": str(path),
        "layout": getattr(rec, "layout", "fuseflow"),
        "frames": len(rec),
        "cameras": len(rig),
        "resolution": list(rig.resolution),
        "calibrated": rig.is_calibrated,
        "camera_list": [
            {
                "id": c.id,
                "width": c.width,
                "height": c.height,
                "fx": c.K[0, 0],
                "fy": c.K[1, 1],
                "cx": c.K[0, 2],
                "cy": c.K[1, 2],
                "depth_scale": c.depth_scale,
                "depth_range": list(c.depth_range),
                "calibrated": c.is_calibrated,
                "missing_views": len(missing.get(c.id, [])),
            }
            for c in rig.cameras
        ],
        "missing_views": missing,
    }
    if isinstance(rec, SequenceRecording):
        summary["poses"] = rec.has_poses
    return summary


def command(
    rec: Path = typer.Argument(..., help="Recording directory (FuseFlow, Open3D/Redwood/ICL or TUM layout)."),
    as_json: bool = typer.Option(False, "--json", help="Print machine-readable JSON instead of a table."),
) -> None:
    """Show cameras, frames, resolution, calibration state and missing views of a recording."""
    s = recording_summary(rec)
    if as_json:
        typer.echo(json.dumps(s, indent=2))
        return
    w, h = s["resolution"]
    console.print(
        f"[bold]{s['path']}[/] ({s['layout']}): {s['frames']} frames, {s['cameras']} cameras, {w}x{h}, "
        + ("calibrated" if s["calibrated"] else "[yellow]not calibrated[/]")
    )
    t = Table("camera", "size", "fx, fy", "cx, cy", "depth/m", "range m", "calib", "missing", box=None)
    for c in s["camera_list"]:
        t.add_row(
            c["id"],
            f"{c['width']}x{c['height']}",
            f"{c['fx']:.1f}, {c['fy']:.1f}",
            f"{c['cx']:.1f}, {c['cy']:.1f}",
            f"{c['depth_scale']:g}",
            f"{c['depth_range'][0]:g}-{c['depth_range'][1]:g}",
            "yes" if c["calibrated"] else "no",
            str(c["missing_views"]),
        )
    console.print(t)
    if "poses" in s:
        console.print("single moving camera; trajectory poses: " + ("yes" if s["poses"] else "no"))
