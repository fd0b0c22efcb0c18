"""``fuse_recording(rec, out_dir)``: FUSE every frame of a recording with known extrinsics, one
PLY per frame (no calibration, no health monitor): what ``fuseflow fuse`` runs.

Writes ``OUT/clouds/<frame:06d>.ply`` (the layout ``run`` uses, so ``fuseflow view OUT`` shows
it), ``OUT/calib.json`` (the extrinsics used) and ``OUT/summary.json``.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fuseflow.errors import FuseFlowError, ValidationError
from fuseflow.io.calibration import write_calibration
from fuseflow.io.datasets import open_recording
from fuseflow.io.exchange import read_cloud
from fuseflow.io.paths import prepare_output_dir
from fuseflow.io.ply import ply_point_count
from fuseflow.io.recording import Recording, write_json_atomic
from fuseflow.pipeline.checks import validate_inputs
from fuseflow.pipeline.config import OutputOptions
from fuseflow.pipeline.exports import (
    FrameWriter,
    frame_file,
    recording_centres,
    resolve_outputs,
    with_volume,
    write_sequence,
)
from fuseflow.pipeline.extrinsics import placed_rig, reindex_cameras
from fuseflow.pipeline.frames import select_views
from fuseflow.pipeline.outputs import (
    OutputManifest,
    calibration_digest,
    fuseflow_version,
    open_output,
    recording_fingerprint,
    settings_digest,
    settings_doc,
)
from fuseflow.types import Calibration, Rig

if TYPE_CHECKING:
    from fuseflow.fuse import FuseConfig

__all__ = ["fuse_recording", "FuseRunSummary", "rig_for_fusion"]


@dataclass
class FuseRunSummary:
    """The result of ``fuse_recording`` (also written as summary.json)."""

    recording: str
    frames: int
    cameras: int
    preset: str
    backend: str
    device: str
    points_per_frame: dict[str, float]
    fuse_ms_per_frame: dict[str, float]
    """Median and mean FUSE time (the first frame of a fresh process includes numba's compilation
    or CUDA start-up: the median leaves it out)."""
    wall_s: float
    warnings: dict[str, int] = field(default_factory=dict)
    """Each kind of degraded input FUSE reported (cameras, then "at frames" and their numbers), with
    the number of frames it happened in."""
    left_out: list[str] = field(default_factory=list)
    """Cameras of the recording the calibration does not place (not fused)."""
    input_warnings: list[str] = field(default_factory=list)
    """What ``pipeline.checks.validate_inputs`` found on the first frame (cameras outside their
    depth_range, cameras that cannot share a point, two cameras exchanged)."""
    frames_resumed: int = 0
    """Frames whose cloud an earlier call with the same manifest had written (not fused again)."""
    pixel_strides: list[int] = field(default_factory=list)
    """The pixel grids the frames fused in this call took their candidates on
    (FuseReport.pixel_stride: FuseConfig.pixel_stride, or a coarser one a point budget picked)."""
    grid_choices: list[str] = field(default_factory=list)
    """With the ``auto`` preset, each distinct choice of grid it made, with the number of frames
    that took it and the first one's account (FuseReport.grid), e.g. "auto: stride 2, s0 1 in 30
    frames (first: 8 views, 2.41 M valid depth pixels; more than 0.80 M: ...)"."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def rig_for_fusion(rec: Recording, calibration: Calibration | None) -> Rig:
    """The rig to fuse ``rec`` with: ``calibration``'s extrinsics (cameras it does not place are
    left out), or rig.json's; FuseFlowError naming the cameras without extrinsics."""
    rig = rec.rig
    if calibration is not None:
        return placed_rig(rig, calibration)
    if not any(c.is_calibrated for c in rig):
        raise FuseFlowError(f"{rec.path}: rig.json has no extrinsics: run fuseflow calibrate first or pass --calib")
    if not rig.is_calibrated:
        missing = [c.id for c in rig if not c.is_calibrated]
        raise FuseFlowError(
            f"{rec.path}: rig.json has no extrinsics for cameras {missing}; run fuseflow calibrate first or pass --calib"
        )
    return rig


def _manifest(rec: Recording, rig: Rig, cfg: FuseConfig, outputs: OutputOptions) -> OutputManifest:
    """The manifest of a ``fuse``: its FuseConfig recorded and digested as ``run`` does (and the
    output options where they are not the defaults)."""
    settings = settings_doc(fuse=cfg)
    if outputs != OutputOptions():
        settings["outputs"] = asdict(outputs)
    return OutputManifest(
        command="fuse",
        recording=str(Path(rec.path).resolve()),
        recording_fingerprint=recording_fingerprint(rec),
        calibration=f"given:{calibration_digest({c.id: c.T_cam_world for c in rig})}",
        config=settings_digest(settings),
        fuseflow_version=fuseflow_version(),
        settings=settings,
    )


def _warning_kinds(report) -> list[str]:
    """One key per kind of degraded input in a FuseReport (frame numbers left out, so that the
    same problem in many frames counts once per frame)."""
    kinds = []
    if report.missing:
        kinds.append(f"views missing: {list(report.missing)} (fused without them)")
    if report.empty:
        kinds.append(f"views with no valid depth: {list(report.empty)}")
    if report.isolated and report.views > 1:
        kinds.append(f"cameras with no overlapping neighbour: {list(report.isolated)} (omega_geo = c, eq. 21)")
    if report.out_of_range:
        kinds.append("points beyond the spatial hash's range were dropped")
    if report.points == 0:
        kinds.append("the fused cloud is empty")
    return kinds


def _frame_list(numbers: list[int], shown: int = 10) -> str:
    """'0, 3, 7' (the first ``shown`` frame numbers, then how many more)."""
    head = ", ".join(str(n) for n in numbers[:shown])
    return head if len(numbers) <= shown else f"{head} and {len(numbers) - shown} more"


@dataclass
class _Fused:
    """What the frame loop of ``fuse_recording`` collected."""

    counts: list[int] = field(default_factory=list)
    fuse_ms: list[float] = field(default_factory=list)
    warnings: dict[str, list[int]] = field(default_factory=dict)
    backend: str = ""
    resumed: int = 0
    strides: set[int] = field(default_factory=set)
    grids: dict[str, list] = field(default_factory=dict)  # choice -> [first account, frames]

    def add_grid(self, grid: str) -> None:
        """Count FuseReport.grid by its choice ("auto: stride 2, s0 1"): frames differ only in the
        numbers of the account (valid pixels, spacing)."""
        choice = grid.split(" (", 1)[0]
        self.grids.setdefault(choice, [grid, 0])[1] += 1

    def grid_lines(self) -> list[str]:
        """One line per distinct choice: how many frames took it and the first frame's account."""
        return [
            grid if n == 1 else f"{grid.split(' (', 1)[0]} in {n} frames (first: {grid.split(' (', 1)[1]}"
            for grid, n in self.grids.values()
        ]


def _fuse_positions(rec: Recording, positions: list[int], cfg, device: str, on_frame, writer: FrameWriter) -> _Fused:
    """FUSE each position into OUT/clouds (keeping clouds an earlier matching call wrote)."""
    from fuseflow.fuse import fuse_with_report

    rig = writer.rig
    sel = [rec.rig.index(c) for c in rig.ids]
    done = _Fused()
    for k, t in enumerate(positions, start=1):
        number = rec.frame_numbers[t]
        path = frame_file(writer.out, number, writer.options.formats[0])
        if writer.done(number):  # written by an earlier call with the same manifest
            n = ply_point_count(path) if path.suffix == ".ply" else len(read_cloud(path))
            done.counts.append(n)
            writer.resumed(number, None, n)
            done.resumed += 1
        else:
            frame = select_views(rec.frame(t, numpy=device == "cpu"), sel, device)
            res = fuse_with_report(frame, rig, cfg)
            cloud = writer.crop(res.cloud.numpy())
            if len(sel) != len(rec.rig):
                cloud = reindex_cameras(cloud, sel)  # camera = index in the recording's rig
            writer.write(number, cloud, lambda frame=frame: frame, frame.timestamp)
            done.counts.append(len(cloud))
            done.fuse_ms.append(res.report.ms)
            done.backend = res.report.backend
            done.strides.add(res.report.pixel_stride)
            if res.report.grid:
                done.add_grid(res.report.grid)
            for kind in _warning_kinds(res.report):
                done.warnings.setdefault(kind, []).append(rec.frame_numbers[t])
        if on_frame:
            on_frame(k, len(positions))
    return done


def fuse_recording(
    rec: Recording | str | Path,
    out_dir: str | Path,
    calibration: Calibration | None = None,
    frames: range | None = None,
    preset: str = "auto",
    device: str = "cpu",
    on_frame: Callable[[int, int], None] | None = None,
    calibration_source: str | None = None,
    force: bool = False,
    points: int | None = None,
    outputs: OutputOptions | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> FuseRunSummary:
    """FUSE the frames at positions ``frames`` (default all) of ``rec`` into OUT/clouds.

    Args:
        calibration: extrinsics to use; None = rig.json's (``rig_for_fusion``).
        preset: a FUSE preset name (``fuseflow.fuse.PRESETS``); "auto" picks the pixel grid
            from the rig per frame (FuseConfig.auto_grid).
        device: "cpu" (compiled numba path) or "cuda".
        on_frame: called with (done, total) after each frame, e.g. for a progress bar.
        calibration_source: where ``calibration`` came from (e.g. its file), for calib.json.
        points: a target point count per frame (``FuseConfig.target_points``); None = the
            preset's density.
        outputs: crop, cloud format and meshes (``OutputOptions``; default: every point, PLY,
            no mesh).
        overrides: FUSE settings over the preset, as ``FuseConfig.replace`` keyword arguments
            (``{"rps": {"k_max": 2}, "pixel_stride": 2}``; the CLI's --set).
        force: start over in a used ``out_dir`` whose manifest does not match (see
            ``pipeline.outputs.open_output``); with a matching manifest, frames already written
            are kept, not fused again.
    """
    from fuseflow.fuse.presets import preset_config

    cfg = preset_config(preset, points, overrides)
    rec = rec if isinstance(rec, Recording) else open_recording(rec)
    rig = rig_for_fusion(rec, calibration)
    positions = list(frames if frames is not None else range(len(rec)))
    if not positions:
        raise ValidationError(f"no frame selected: the recording has {len(rec)} frames (positions 0:{len(rec)})")
    outputs = outputs if outputs is not None else OutputOptions()
    sel = [rec.rig.index(c) for c in rig.ids]
    first = rec.frame(positions[0], numpy=True)  # numpy: only the agreement checks load torch
    world, volume = resolve_outputs(outputs, rig, calibration, select_views(first, sel, "cpu"))
    checked = validate_inputs(first, rig, cfg, volume)  # before anything is written
    out = prepare_output_dir(out_dir)
    open_output(out, _manifest(rec, rig, cfg, outputs), force)
    source = calibration_source or ("rig.json" if calibration is None else "given")
    used = with_volume(Calibration({c.id: c.T_cam_world for c in rig}, {"source": source}), volume, world)
    write_calibration(out / "calib.json", used, rig=rec.rig)
    t0 = time.perf_counter()
    writer = FrameWriter(out, outputs, rig, volume, recording_centres(rec.rig, rig), world=world)
    done = _fuse_positions(rec, positions, cfg, device, on_frame, writer)
    write_sequence(out, writer)
    summary = FuseRunSummary(
        recording=str(Path(rec.path).resolve()),
        frames=len(positions),
        cameras=len(rig),
        preset=preset,
        backend=done.backend,
        device=device,
        points_per_frame={"mean": statistics.fmean(done.counts), "min": min(done.counts), "max": max(done.counts)},
        fuse_ms_per_frame={
            "median": statistics.median(done.fuse_ms) if done.fuse_ms else 0.0,
            "mean": statistics.fmean(done.fuse_ms) if done.fuse_ms else 0.0,
        },
        wall_s=time.perf_counter() - t0,
        warnings={f"{kind} at frames {_frame_list(nums)}": len(nums) for kind, nums in done.warnings.items()},
        left_out=[c for c in rec.rig.ids if c not in rig.ids],
        input_warnings=checked,
        frames_resumed=done.resumed,
        pixel_strides=sorted(done.strides),
        grid_choices=done.grid_lines(),
    )
    write_json_atomic(out / "summary.json", summary.to_json())
    return summary
