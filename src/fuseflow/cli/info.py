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
    """Show cameras, frames, resolution, calibration state and missing views of a recording
    (or what a `fuseflow live --record` folder holds)."""
    from fuseflow.io.summary import check_recording_files, recording_summary

    if (rec / "live.json").is_file() and not (rec / "rig.json").exists():
        _live_record(rec, as_json)
        return

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


def live_record_summary(path: Path) -> dict:
    """What a ``fuseflow live --record`` folder holds: source, cameras, frames logged, clouds on
    disk, points and FUSE time per frame, views missing per camera."""
    import numpy as np

    try:
        doc = json.loads((path / "live.json").read_text())
        lines = [json.loads(x) for x in (path / "frames.jsonl").read_text().splitlines() if x.strip()]
    except (OSError, ValueError) as exc:
        fail(f"{path}: not a readable live recording ({exc})")
    points = np.array([x.get("points", 0) for x in lines], dtype=np.float64)
    fuse = np.array([x.get("fuse_ms", 0.0) for x in lines], dtype=np.float64)
    missing: dict[str, int] = {}
    for x in lines:
        for c in x.get("missing", []):
            missing[c] = missing.get(c, 0) + 1
    clouds = sorted(p.name for p in (path / "clouds").glob("*.ply")) if (path / "clouds").is_dir() else []
    logged = {f"{x['number']:06d}.ply" for x in lines if "number" in x}
    return {
        "path": str(path), "layout": "fuseflow live recording", "source": doc.get("source", ""),
        "cameras": doc.get("cameras", []), "frames": len(lines), "clouds": len(clouds),
        "clouds_not_logged": sorted(set(clouds) - logged), "logged_without_cloud": sorted(logged - set(clouds)),
        "points": None if not len(points) else {"mean": round(float(points.mean()), 1), "min": int(points.min()),
                                                 "max": int(points.max())},
        "fuse_ms_median": round(float(np.median(fuse)), 1) if len(fuse) else None,
        "missing_views": missing, "calibration": (path / "calib.json").is_file(),
    }  # fmt: skip


def _live_record(path: Path, as_json: bool) -> None:
    s = live_record_summary(path)
    if as_json:
        typer.echo(json.dumps(s, indent=2))
        return
    say(f"{s['path']} (fuseflow live recording of {escape(s['source'] or 'an unnamed source')}): "
        f"{_count(s['frames'], 'frame')}, {_count(len(s['cameras']), 'camera')} ({escape(', '.join(s['cameras']))}), "
        f"{_count(s['clouds'], 'cloud')} on disk" + (", calib.json" if s["calibration"] else ""))  # fmt: skip
    if s["points"]:
        p = s["points"]
        say(f"points per frame: mean {p['mean']:.0f} (min {p['min']}, max {p['max']}); "
            f"FUSE {s['fuse_ms_median']:.0f} ms median")  # fmt: skip
    for c, n in s["missing_views"].items():
        say(f"camera {escape(c)}: missing in {n} of {s['frames']} frames")
    for name in s["clouds_not_logged"]:
        error(f"clouds/{name} is not in frames.jsonl")
    for name in s["logged_without_cloud"]:
        error(f"frames.jsonl names clouds/{name}, which is not on disk")


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
  fuseflow info /tmp/live-clouds      # a fuseflow live --record folder
"""
