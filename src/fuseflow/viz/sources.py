"""What ``fuseflow view`` shows: the clouds of a run directory (or a calibrated recording fused
on the fly), the rig to draw as frustums, and the world's up direction."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fuseflow.errors import FuseFlowError, RecordingError
from fuseflow.types import FusedCloud, Rig

__all__ = ["ViewSource", "view_source", "world_up", "render_pngs", "send_to_rerun"]


@dataclass(frozen=True)
class ViewSource:
    """A rig to draw (None when unknown) and (frame number, cloud loader) pairs in frame order."""

    rig: Rig | None
    items: list[tuple[int, Callable[[], FusedCloud]]]
    volume: object | None = None
    """The capture volume a run stored in its calib.json (``geometry.volume.CaptureVolume``), or None."""
    weights: bool = True
    """Whether the clouds store FUSE's weight (False for Draco files: ``read_cloud`` gives 1.0)."""
    z_up: bool = False
    """Whether the clouds are in a z-up frame (a run's ``--world floor``)."""


def _run_world(path: Path) -> np.ndarray:
    """Output-from-calibration-world of a run directory's clouds (calib.json's ``world``; the
    identity without one)."""
    from fuseflow.io import read_calibration

    try:
        doc = read_calibration(path / "calib.json").report.get("world")
    except (FuseFlowError, OSError):
        return np.eye(4)
    return np.asarray(doc["T_out_world"], np.float64) if doc else np.eye(4)


def _run_rig(path: Path) -> Rig | None:
    """The calibrated rig of a run directory, placed in its clouds' frame, or None when its
    recording is gone or unreadable."""
    from fuseflow.io import open_recording, read_calibration
    from fuseflow.types import Calibration

    summary = path / "summary.json"
    if not ((path / "calib.json").exists() and summary.exists()):
        return None
    try:
        rec = open_recording(json.loads(summary.read_text())["recording"])
        cal = read_calibration(path / "calib.json")
        back = np.linalg.inv(_run_world(path))
        return Calibration({c: T @ back for c, T in cal.T_cam_world.items()}, cal.report).apply(rec.rig)
    except (FuseFlowError, OSError, KeyError, ValueError):  # the recording moved: no frustums
        return None


def _run_volume(path: Path):
    """The capture volume in a run directory's calib.json, in its clouds' frame, or None."""
    from fuseflow.geometry.volume import CaptureVolume
    from fuseflow.io import read_calibration

    try:
        doc = read_calibration(path / "calib.json").report.get("capture_volume")
    except (FuseFlowError, OSError):
        return None
    if not doc:
        return None
    v = CaptureVolume.from_json(doc)
    T = v.T_box_world @ np.linalg.inv(_run_world(path))
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return CaptureVolume(v.lo, v.hi, T, v.kind, v.radius, v.axis)


def view_source(path: str | Path) -> ViewSource:
    """The clouds of a run directory (``path/clouds/*.ply``), or of a calibrated recording fused
    frame by frame; RecordingError when there is nothing to show."""
    from fuseflow.io import open_recording

    path = Path(path)
    if (path / "clouds").is_dir():
        from fuseflow.io.exchange import read_cloud

        by_frame: dict[int, Path] = {}
        for ext in ("drc", "glb", "ply"):  # one file a frame: PLY (every field) over GLB over Draco
            for p in (path / "clouds").glob(f"*.{ext}"):
                if p.stem.isdigit():
                    by_frame[int(p.stem)] = p
        if not by_frame:
            raise RecordingError(f"{path / 'clouds'} holds no .ply, .drc or .glb files")
        items = [(n, (lambda p=p: read_cloud(p))) for n, p in sorted(by_frame.items())]
        weights = all(p.suffix != ".drc" for p in by_frame.values())
        return ViewSource(_run_rig(path), items, _run_volume(path), weights, _floor_world(path))
    rec = open_recording(path)
    if not rec.rig.is_calibrated:
        raise RecordingError(
            f"{path}: rig.json has no extrinsics; view a run directory (fuseflow run) or calibrate first"
        )
    from fuseflow.fuse import fuse

    return ViewSource(rec.rig, [(rec.frame_numbers[t], (lambda t=t: fuse(rec[t], rec.rig))) for t in range(len(rec))])


def _floor_world(path: Path) -> bool:
    """Whether a run directory's clouds are in the floor frame (calib.json's world)."""
    from fuseflow.io import read_calibration

    try:
        doc = read_calibration(path / "calib.json").report.get("world")
    except (FuseFlowError, OSError):
        return False
    return bool(doc) and doc.get("name") == "floor"


def world_up(rig: Rig | None) -> tuple[float, float, float]:
    """The world's up direction: the mean of the cameras' up axes (-y in OpenCV axes), since rig
    cameras are mounted roughly upright; (0, -1, 0) (the first camera's frame) without a rig."""
    if rig is None or not rig.is_calibrated:
        return (0.0, -1.0, 0.0)
    up = np.mean([-c.T_cam_world[1, :3] for c in rig], axis=0)  # row 1 of R = camera y in world
    n = float(np.linalg.norm(up))
    return tuple((up / n).tolist()) if n > 1e-6 else (0.0, -1.0, 0.0)


def render_pngs(
    source: ViewSource, out_dir: str | Path, color_by: str = "rgb", whole: bool = False, on_frame=None
) -> int:
    """Render each frame of ``source`` to OUT/<frame:06d>.png (headless) from one view
    (``viz.render.view_camera``) framed on the first non-empty cloud: the capture volume (the
    run's stored one, else the rig's) unless ``whole``; cameras, axes, frame label, colour bar
    for weights. ``on_frame(done, total)`` is called after each PNG (a progress bar). Returns the
    number of PNGs."""
    from fuseflow.viz.render import save_cloud_png, view_camera

    volume = None if whole else _volume(source)
    view = None
    for done, (number, load) in enumerate(source.items, start=1):
        cloud = load()
        if view is None and len(cloud):
            view = view_camera(cloud.xyz.numpy(), source.rig, volume)[:2]
        K, T = view if view is not None else (None, None)
        label = f"frame {number}  {len(cloud):,} points  ({color_by})"
        save_cloud_png(Path(out_dir) / f"{number:06d}.png", cloud, color_by, K, T, rig=source.rig, volume=volume,
                       label=label)  # fmt: skip
        if on_frame:
            on_frame(done, len(source.items))
    return len(source.items)


def _volume(source: ViewSource):
    """The source's stored capture volume, else the one of its calibrated rig, else None."""
    if source.volume is not None:
        return source.volume
    if source.rig is None or not source.rig.is_calibrated:
        return None
    from fuseflow.geometry.volume import capture_volume

    return capture_volume(source.rig)


def send_to_rerun(source: ViewSource, rrd: str | Path | None = None, full: bool = False) -> int:
    """Log the rig (frustums) and each cloud on rerun's frame timeline: to the viewer, or to the
    file ``rrd``; each cloud subsampled to ``viz.rerun_log.RERUN_POINTS`` unless ``full``;
    returns the number of frames."""
    from fuseflow.viz.rerun_log import RERUN_POINTS, RerunLogger

    logger = RerunLogger(save_to=rrd, spawn=rrd is None, z_up=source.z_up)
    if source.rig is not None:
        logger.log_rig(source.rig)
    for number, load in source.items:
        logger.log_cloud(number, load(), max_points=None if full else RERUN_POINTS)
    logger.close()
    return len(source.items)
