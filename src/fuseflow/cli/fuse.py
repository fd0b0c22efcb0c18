"""`fuseflow fuse`: FUSE every frame of a recording with known extrinsics, one PLY per frame.

Writes ``OUT/clouds/<frame:06d>.ply`` (the layout ``fuseflow run`` uses, so ``fuseflow view OUT``
shows the result), ``OUT/calib.json`` (the extrinsics used) and ``OUT/summary.json``.
"""

from __future__ import annotations

import json
import statistics
import time
from pathlib import Path

import typer

from fuseflow.cli.app import app, console, fail, parse_range, warn
from fuseflow.errors import FuseFlowError

NO_EXTRINSICS = "no extrinsics: run fuseflow calibrate first or pass --calib"


def _check_device(device: str) -> str:
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        fail(f"--device must be cpu or cuda, got {device!r}")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            fail(f"--device {device}: torch sees no CUDA device on this machine (use --device cpu)")
    return device


def _rig_for(recording, calib: Path | None):
    """The rig to fuse with: --calib's extrinsics (cameras it does not place are left out), or
    rig.json's; exits with NO_EXTRINSICS when there are none."""
    from fuseflow.io import read_calibration
    from fuseflow.pipeline import placed_rig

    rig = recording.rig
    if calib is not None:
        return placed_rig(rig, read_calibration(calib))
    if not any(c.is_calibrated for c in rig):
        fail(f"{recording.path}: rig.json has {NO_EXTRINSICS}")
    if not rig.is_calibrated:
        missing = [c.id for c in rig if not c.is_calibrated]
        fail(
            f"{recording.path}: rig.json has no extrinsics for cameras {missing}; run fuseflow calibrate first or pass --calib"
        )
    return rig


@app.command("fuse")
def fuse_cmd(
    rec: Path = typer.Argument(..., help="Recording directory (fuseflow format, Open3D/ICL or TUM layout)."),
    out: Path = typer.Option(..., "--out", help="Output directory: clouds/<frame>.ply, calib.json, summary.json."),
    calib: Path = typer.Option(None, "--calib", help="Extrinsics to use (calib.json); default: rig.json's."),
    frames: str = typer.Option(None, "--frames", help="A:B, frame positions to fuse (default all)."),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda (cpu runs the compiled numba path)."),
    preset: str = typer.Option("default", "--preset", help="FUSE preset: default, paper, 'w/o CVGC', ..."),
) -> None:
    """FUSE every frame with known extrinsics (no calibration, no health monitor): one PLY per frame."""
    try:
        _fuse_recording(rec, out, calib, frames, _check_device(device), preset)
    except FuseFlowError as exc:  # bad recording / calib.json / rig: one line, no traceback
        fail(str(exc))


def _fuse_recording(rec: Path, out: Path, calib: Path | None, frames: str | None, device: str, preset: str) -> None:
    from fuseflow.cli.app import progress
    from fuseflow.fuse import PRESETS, fuse_with_report
    from fuseflow.io import open_recording, write_calibration
    from fuseflow.io.ply import write_ply
    from fuseflow.pipeline import cloud_path, reindex_cameras
    from fuseflow.types import Calibration

    if preset not in PRESETS:
        fail(f"--preset: no FUSE preset {preset!r}; presets are {sorted(PRESETS)}")
    cfg = PRESETS[preset]
    recording = open_recording(rec)
    rig = _rig_for(recording, calib)
    positions = parse_range(frames, len(recording))
    if len(positions) == 0:
        fail(
            f"--frames {frames!r} selects no frame: the recording has {len(recording)} frames (positions 0:{len(recording)})"
        )
    out.mkdir(parents=True, exist_ok=True)
    write_calibration(
        out / "calib.json",
        Calibration({c.id: c.T_cam_world for c in rig}, {"source": str(calib) if calib else "rig.json"}),
    )
    sel = [recording.rig.index(c) for c in rig.ids]
    points: list[int] = []
    fuse_ms: list[float] = []
    warnings: dict[str, int] = {}
    backend = ""
    t0 = time.perf_counter()
    with progress("fusing") as bar:
        task = bar.add_task(f"fusing {len(positions)} frames", total=len(positions))
        for done, t in enumerate(positions, start=1):
            frame = recording[t]
            if len(sel) != frame.num_views:
                frame = frame.subset(sel)
            res = fuse_with_report(frame.to(device), rig, cfg)
            cloud = res.cloud.to("cpu")
            if len(sel) != len(recording.rig):
                cloud = reindex_cameras(cloud, sel)  # camera = index in the recording's rig
            write_ply(cloud_path(out, frame.index), cloud)
            points.append(len(cloud))
            fuse_ms.append(res.report.ms)
            backend = res.report.backend
            for w in res.report.warnings:
                key = w.split(" in frame ")[0] if " in frame " in w else w
                warnings[key] = warnings.get(key, 0) + 1
            bar.update(task, completed=done)
    wall = time.perf_counter() - t0
    # the first frame includes numba's compilation (or CUDA start-up): report the median too
    summary = {
        "recording": str(Path(rec).resolve()),
        "frames": len(positions),
        "cameras": len(rig),
        "preset": preset,
        "backend": backend,
        "device": device,
        "points_per_frame": {"mean": statistics.fmean(points), "min": min(points), "max": max(points)},
        "fuse_ms_per_frame": {"median": statistics.median(fuse_ms), "mean": statistics.fmean(fuse_ms)},
        "wall_s": wall,
        "warnings": warnings,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    from rich.table import Table

    t = Table(title=f"FUSE: {out}", show_header=False)
    t.add_row("frames", f"{len(positions)} ({len(rig)} cameras, preset {preset})")
    ppf = summary["points_per_frame"]
    t.add_row("points per frame", f"{ppf['mean']:.0f} (min {ppf['min']}, max {ppf['max']})")
    ms = summary["fuse_ms_per_frame"]
    t.add_row(
        "fusion", f"{ms['median']:.1f} ms per frame median ({ms['mean']:.1f} mean) on {device} ({backend} backend)"
    )
    t.add_row("wall time", f"{wall:.1f} s with reading and writing ({len(positions) / wall:.2f} frames/s)")
    t.add_row("clouds", str(out / "clouds"))
    console.print(t)
    for w, n in warnings.items():
        warn(f"{w} ({n} frames)")
