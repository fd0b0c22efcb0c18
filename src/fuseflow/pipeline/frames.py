"""Per-frame work of the pipeline: fuse one frame and measure its health (``process_frame``),
pick the frame to calibrate on (``first_good_frame``), and ``stream`` clouds from a source.

Stateless: the same inputs give the same outputs, in any process (see pipeline/ray.py)."""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from fuseflow.errors import FuseFlowError
from fuseflow.io.datasets import open_recording
from fuseflow.io.recording import Recording
from fuseflow.pipeline.checks import validate_inputs
from fuseflow.pipeline.config import PipelineConfig
from fuseflow.pipeline.extrinsics import placed_rig, reindex_cameras, resolve_rig
from fuseflow.pipeline.health import frame_health
from fuseflow.pipeline.records import FrameRecord
from fuseflow.types import Calibration, Frame, FusedCloud, Rig

__all__ = ["process_frame", "first_good_frame", "stream", "select_views", "fuse_notes"]


def select_views(frame: Frame, sel: list[int], device: str) -> Frame:
    """The views ``sel`` (positions in the frame) of ``frame``, on ``device`` (a numpy frame
    stays numpy on the CPU)."""
    if len(sel) != frame.num_views:
        frame = frame.subset(sel)
    return frame if frame.is_numpy and device == "cpu" else frame.to(device)


def process_frame(frame: Frame, sel: list[int], rig: Rig, config: PipelineConfig) -> tuple[FusedCloud, FrameRecord]:
    """Fuse one frame and measure its cameras' agreement: the per-frame work of ``run``.

    ``sel`` picks the frame's views that ``rig`` has (cameras GMAC could not place are left
    out); the cloud's ``camera`` indexes the frame's full camera list.
    """
    from fuseflow.fuse import fuse_with_report

    full = frame.num_views
    frame = select_views(frame, sel, config.device)
    t0 = time.perf_counter()
    result = fuse_with_report(frame, rig, config.fuse_config())
    cloud = result.cloud
    if not frame.is_numpy and frame.device.type == "cuda":
        import torch

        torch.cuda.synchronize()
    ms = (time.perf_counter() - t0) * 1000.0
    if len(sel) != full:
        cloud = reindex_cameras(cloud, sel)
    pairs, agreement = frame_health(frame, rig, config.health_samples, config.health_tau)
    empty = _empty_views(frame)
    record = FrameRecord(
        index=frame.index,
        points=len(cloud),
        fuse_ms=round(ms, 3),
        missing=list(frame.missing),
        empty=empty,
        agreement=agreement,
        pairs=pairs,
        timestamp=frame.timestamp,
        notes=fuse_notes(result.report, empty),
    )
    return cloud, record


def fuse_notes(report, empty: list[str]) -> list[str]:
    """FUSE's warnings about one frame that ``run``'s own records do not already carry (missing
    views and all-zero depth are in ``FrameRecord.missing`` / ``empty``), without frame numbers
    or counts, so that the summary can group frames by kind."""
    notes = []
    out_of_depth_range = [c for c in report.empty if c not in empty]
    if out_of_depth_range:
        notes.append(f"cameras with no depth inside their depth_range: {out_of_depth_range}")
    if report.isolated and report.views > 1:
        notes.append(f"cameras with no overlapping neighbour: {list(report.isolated)} (omega_geo = c, eq. 21)")
    if report.out_of_range:
        notes.append("points beyond the spatial hash's range were dropped (extrinsics in millimetres?)")
    if report.points == 0:
        notes.append("the fused cloud is empty")
    return notes


def _empty_views(frame) -> list[str]:
    """Ids of present views with no depth measurement at all (an all-zero depth image)."""
    has_depth = (frame.depth > 0).flatten(1).any(1).tolist()
    return [c for c, p, d in zip(frame.camera_ids, frame.present.tolist(), has_depth) if p and not d]


def first_good_frame(rec: Recording, min_valid: float = 0.2, limit: int = 30) -> int:
    """Index of the first frame (among the first ``limit``) with every camera present and at least
    ``min_valid`` of each camera's pixels with depth; FuseFlowError when none is."""
    for t in range(min(len(rec), limit)):
        f = rec[t]
        valid = (f.depth > 0).flatten(1).float().mean(1)
        if bool(f.present.all()) and bool((valid >= min_valid).all()):
            return t
    raise FuseFlowError(
        f"no frame among the first {min(len(rec), limit)} has every camera present with >= "
        f"{min_valid:.0%} valid depth; pass --calib with known extrinsics or --calib-frame"
    )


def stream(
    source: Recording | str | Path | Any,
    calibration: Calibration | Rig | None = None,
    config: PipelineConfig = PipelineConfig(),
) -> Iterator[FusedCloud]:
    """Yield one FusedCloud per frame of ``source``, fused with FUSE as ``fuseflow run`` does.

    Args:
        source: a Recording, a recording path, or any object with ``.rig`` that iterates
            Frames (a live source such as RealSenseSource).
        calibration: extrinsics to use (a Calibration, or a calibrated Rig); None = the
            source rig's own extrinsics. Cameras a Calibration does not place (GMAC reports
            them unconnected) are left out of fusion, with a warning naming them.
        config: PipelineConfig; its ``fuse`` None is the ``auto`` preset (the CLI's default)
            and its ``device`` where FUSE runs.

    The first frame goes through ``pipeline.checks.validate_inputs`` (ValidationError when
    every cloud would be empty; its other findings, and FUSE's per-frame ones, are warnings:
    ``warnings.warn``). Clouds hold numpy arrays unless ``config.device`` is a GPU.
    """
    from fuseflow.fuse import fuse_with_report

    if isinstance(source, (str, Path)):
        source = open_recording(source)
    if isinstance(calibration, Calibration):
        rig = placed_rig(source.rig, calibration)
    else:
        rig = resolve_rig(source.rig, calibration)
    left_out = [c for c in source.rig.ids if c not in rig.ids]
    if left_out:
        warnings.warn(
            f"the calibration does not place cameras {left_out}: fusing {len(rig)} of {len(source.rig)} cameras",
            stacklevel=2,
        )
    cfg = config.fuse_config()
    for k, frame in enumerate(source):
        sel = [frame.camera_ids.index(c) for c in rig.ids if c in frame.camera_ids]
        if k == 0:
            for line in validate_inputs(frame, rig.subset([rig.index(frame.camera_ids[i]) for i in sel]), cfg):
                warnings.warn(line, stacklevel=2)
        same = tuple(frame.camera_ids) == rig.ids
        result = fuse_with_report(select_views(frame, sel, config.device), rig, cfg)
        for line in result.report.warnings:
            warnings.warn(line, stacklevel=2)
        cloud = result.cloud if same else reindex_cameras(result.cloud, sel)
        yield cloud if cloud.is_numpy or cloud.device.type != "cpu" else cloud.numpy()
