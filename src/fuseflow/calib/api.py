"""``calibrate(frame, rig, config) -> Calibration``: GMAC end to end (paper III-B, docs/design.md 3).

``calibrate`` checks the inputs and hands them to the placement engine,
:func:`fuseflow.calib.placement.place_and_judge`: backbone (scale-ambiguous poses, eq. 3,
:mod:`backbones`) -> metric scale (RC correspondences, the scale fixed point and cycle pruning,
eq. 5-13, :mod:`scale_stage`) -> place the cameras T_i = [R_i | s* t_i] (eq. 14) -> optional
rigid refinement (:mod:`refine`) -> depth-agreement check -> depth-aware joint refinement of all
cameras (:mod:`joint_refine`, beyond the paper) -> the report (:class:`CalibReport`) -> the
room's turns (:mod:`turns`) -> every camera's verdict (:mod:`verdicts`). A recording goes through
:mod:`pooling` first, which runs that path on one frame and, when needed, on pooled frames.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fuseflow.calib import progress as progress_events
from fuseflow.calib.backbones import BackboneResult
from fuseflow.calib.config import CalibConfig
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.placement import (
    METRIC_SCALE_TOLERANCE,
    Placement,
    anchor_world,
    as_frames,
    place_and_judge,
    place_with_backbone,
)
from fuseflow.calib.pooling import RecordingLike, first_complete, pooled_calibration, warn_verdicts
from fuseflow.calib.scale_stage import ScaleResult, metric_scale
from fuseflow.errors import ValidationError
from fuseflow.types import Calibration, Frame, Rig

# ScaleResult and metric_scale live in scale_stage; re-exported here, where they used to be.
__all__ = [
    "calibrate",
    "metric_scale",
    "ScaleResult",
    "check_inputs",
    "as_frames",
    "place_with_backbone",
    "Placement",
    "MIN_VALID_DEPTH",
    "METRIC_SCALE_TOLERANCE",
    "anchor_world",
]

#: A camera needs at least this share of pixels with in-range depth.
MIN_VALID_DEPTH = 0.01


def check_inputs(frame: Frame, rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate and return (depth (N, H, W) float32, K (N, 3, 3), depth_range (N, 2)) in frame order.

    Raises:
        ValidationError: not a Frame / Rig, fewer than two cameras, cameras not in the rig,
            mismatched resolution.
        CalibrationError: fewer than two views present (dropped views, ``frame.present``).
    """
    if not isinstance(frame, Frame):
        raise ValidationError(f"calibrate: frame must be a fuseflow.Frame, got {type(frame).__name__}")
    if not isinstance(rig, Rig):
        raise ValidationError(f"calibrate: rig must be a fuseflow.Rig, got {type(rig).__name__}")
    if frame.num_views < 2 or len(rig) < 2:
        raise ValidationError(
            f"GMAC needs at least two cameras (the scale comes from their overlap), got {frame.num_views}"
        )
    unknown = [c for c in frame.camera_ids if c not in rig.ids]
    if unknown:
        raise ValidationError(f"frame cameras {unknown} are not in the rig {list(rig.ids)}")
    cams = [rig[c] for c in frame.camera_ids]
    W, H = frame.resolution
    bad = [c.id for c in cams if (c.width, c.height) != (W, H)]
    if bad:
        raise ValidationError(f"cameras {bad} have a resolution other than the frame's {W}x{H}")
    missing = list(frame.missing)
    if frame.num_views - len(missing) < 2:
        # before any image check: a dropped view is all zeros and would read as "textureless"
        raise CalibrationError(
            f"frame {frame.index}: the views of cameras {missing} are missing (dropped, present=False); "
            f"GMAC needs at least two present views, {frame.num_views - len(missing)} present: "
            "calibrate on another frame (--frame / --frames)"
        )
    depth = frame.depth.detach().cpu().numpy().astype(np.float32)
    K = np.stack([c.K for c in cams])
    rng = np.array([c.depth_range for c in cams])
    return depth, K, rng


def calibrate(
    frame: Frame | Sequence[Frame] | RecordingLike,
    rig: Rig | None = None,
    config: CalibConfig | None = None,
    backbone_result: BackboneResult | None = None,
    progress: progress_events.ProgressCallback | None = None,
) -> Calibration:
    """Metric extrinsics of every camera from one (or several) multi-view RGB-D frames, no target.

    Args:
        frame: the N views of one instant (depth (N, H, W) float32 metres, colour uint8), or a
            sequence of such frames of a static rig (same cameras, same order). Multi-frame
            backbones (``MULTI_FRAME_BACKBONES``: rgbd) pool all of them; the others, the scale
            stage and the depth-agreement check use the first. Or a whole ``Recording``: GMAC
            then does what ``fuseflow calibrate REC`` does (:mod:`fuseflow.calib.pooling`): the
            first frame with every camera, and up to 10 frames spread over the recording pooled
            when that frame fails or leaves a camera not "good".
        rig: the cameras (intrinsics, depth ranges; extrinsics ignored); with a Recording,
            None takes the recording's rig.
        config: :class:`CalibConfig` (default preset: auto backbone, point-to-plane, CC, no refinement).
        backbone_result: skip the backbone and use these poses (e.g. to rerun GMAC variants on
            one backbone run).
        progress: ``callback(stage, done, total)`` called as the stages and camera pairs finish
            (:mod:`fuseflow.calib.progress`); the library itself prints nothing.

    Returns:
        :class:`fuseflow.Calibration`: camera-from-world 4x4 in metres for every placed camera
        (world = the first placed camera in rig order); its ``report`` is a :class:`CalibReport`
        (s*, per-edge scales, correspondence counts, cycle residuals, pruned edges, unconnected
        cameras, warnings, timings). With a metric backbone (``BackboneResult.metric``) the
        poses are used as they are (s* = 1) and GMAC's closed-form scale is reported as a check
        (``scale_check``, a warning when it is more than ``METRIC_SCALE_TOLERANCE`` from 1).
        ``report.camera_verdicts`` judges every camera (:mod:`fuseflow.calib.verdicts`).

    Raises:
        ValidationError: fewer than two cameras, cameras not in the rig, mismatched resolution,
            frames of different rigs.
        CalibrationError: fewer than two present views, a camera without depth, textureless
            images, no overlapping pair.

    Warns:
        CalibrationWarning: one per camera left unplaced or not "good", with its verdict's reason.
    """
    if isinstance(frame, (Frame, Sequence)) or not isinstance(frame, RecordingLike):
        if rig is None:
            raise ValidationError("calibrate: a rig is needed with frames (only a Recording carries its own)")
        cal, ids = _calibrate_reporting(frame, rig, config, progress, backbone_result), rig.ids
    else:
        if backbone_result is not None:
            raise ValidationError("calibrate: backbone_result applies to given frames, not to a recording")
        if rig is not None and rig.ids != frame.rig.ids:
            raise ValidationError(
                f"calibrate: rig cameras {list(rig.ids)} differ from the recording's {list(frame.rig.ids)}"
            )
        done = pooled_calibration(frame, [first_complete(frame)], config, True, _calibrate_reporting, progress)
        cal, ids = done.calibration, frame.rig.ids
    warn_verdicts(cal, ids)
    return cal


def _calibrate_reporting(
    frame, rig: Rig, config: CalibConfig | None, progress=None, backbone_result=None
) -> Calibration:
    """``calibrate`` on frames, its progress callback set, no warnings."""
    with progress_events.reporting(progress):
        return _calibrate(frame, rig, config or CalibConfig(), backbone_result)


def _calibrate(frame, rig: Rig, config: CalibConfig, backbone_result: BackboneResult | None) -> Calibration:
    """``calibrate`` on checked frames, its progress callback set: the placement engine."""
    frames = as_frames(frame)
    for f in frames:
        depth, K, drange = check_inputs(f, rig)
        check_depth_coverage(f, depth, drange)
    depth, K, drange = check_inputs(frames[0], rig)
    return place_and_judge(frames, rig, depth, K, drange, config, backbone_result)


def check_depth_coverage(frame: Frame, depth: np.ndarray, drange: np.ndarray) -> None:
    """Raise CalibrationError naming present cameras with in-range depth on fewer than
    MIN_VALID_DEPTH of their pixels (GMAC takes its metric scale from sensor depth).

    Args:
        depth: (N, H, W) float32 metres, frame order. drange: (N, 2) metres, frame order.
    """
    ids = frame.camera_ids
    present = frame.present.cpu().numpy()
    valid_share = [
        float(((depth[k] >= drange[k, 0]) & (depth[k] <= drange[k, 1]) & (depth[k] > 0)).mean())
        for k in range(len(ids))
    ]
    no_depth = [ids[k] for k in range(len(ids)) if present[k] and valid_share[k] < MIN_VALID_DEPTH]
    if no_depth:
        raise CalibrationError(
            f"cameras {no_depth} have depth on fewer than {MIN_VALID_DEPTH:.0%} of pixels within their "
            "depth_range: GMAC takes its metric scale from sensor depth"
        )
