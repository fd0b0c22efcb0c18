"""The placement engine: GMAC from checked inputs to the judged calibration, the stages in order.

``place_and_judge`` is the one path every backbone takes:

1. the sampled depth of every camera (``correspondences.prepare_cameras``, once), then
   ``place_with_backbone`` for the backbone (``auto``: each source of
   ``auto.AUTO_SOURCES`` until ``auto.settled``): backbone (:mod:`backbones`) -> metric scale,
   or for a metric backbone its check (``scale_stage.placement_scale``, eq. 5-13) ->
   T_i = [R_i | s* t_i] (eq. 14) -> optional rigid refinement (:mod:`refine`) -> world anchor
   (``posegraph.anchor_world``) -> depth agreement. Then ``auto.merge_sources`` merges the
   sources, or the one backbone's placement goes through ``verdicts.drop_unconfirmed``.
2. the depth-aware joint refinement of all placed cameras (:mod:`joint_refine`, when on);
3. the report (``report.finish_report``);
4. in a repeating room, every camera's turn from the subject (:mod:`turns`);
5. the verdicts (:mod:`verdicts`): pair agreements, each camera's verdict, the scale check's
   warning dropped when the verdicts answer it.

The ``CalibConfig`` is read here once (``stage_settings``): each stage gets its own settings, the
scale stage a :class:`~fuseflow.calib.config.ScaleSettings`, the refinement a
:class:`~fuseflow.calib.config.RefineSettings`, the source merging, the report and the verdicts the
depth-agreement threshold; only the backbones take the config itself (their own settings are in it).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fuseflow.calib import progress
from fuseflow.calib.auto import AUTO_SOURCES, merge_sources, settled
from fuseflow.calib.backbones import MULTI_FRAME_BACKBONES, BackboneResult, get_backbone
from fuseflow.calib.blas import one_blas_thread
from fuseflow.calib.config import CalibConfig, RefineSettings, ScaleSettings, refine_settings, scale_settings
from fuseflow.calib.correspondences import CameraData, prepare_cameras
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.posegraph import anchor_world
from fuseflow.calib.report import finish_report
from fuseflow.calib.scale_stage import METRIC_SCALE_TOLERANCE, ScaleResult, placement_scale
from fuseflow.calib.turns import camera_turns, settle_turns
from fuseflow.calib.verdicts import (
    TURN_MIN_MARGIN,
    camera_verdicts,
    drop_answered_scale_warning,
    drop_unconfirmed,
    pair_agreements,
)
from fuseflow.errors import ValidationError
from fuseflow.geometry import depth_agreement
from fuseflow.types import Calibration, Frame, Rig

__all__ = [
    "as_frames",
    "Placement",
    "place_and_judge",
    "place_with_backbone",
    "anchor_world",
    "run_backbone",
    "StageSettings",
    "stage_settings",
    "METRIC_SCALE_TOLERANCE",
]


def as_frames(frames: Frame | Sequence[Frame]) -> list[Frame]:
    """``frames`` as a non-empty list: one Frame, or several Frames of a static rig with the same
    cameras in the same order and resolution (ValidationError otherwise)."""
    seq = [frames] if isinstance(frames, Frame) else list(frames) if isinstance(frames, Sequence) else None
    if not seq:
        raise ValidationError(
            f"calibrate: frame must be a fuseflow.Frame or a non-empty sequence of Frames, got {type(frames).__name__}"
        )
    for f in seq:
        if not isinstance(f, Frame):
            raise ValidationError(f"calibrate: frame must be a fuseflow.Frame, got {type(f).__name__}")
        if f.camera_ids != seq[0].camera_ids or f.resolution != seq[0].resolution:
            raise ValidationError(
                f"calibrate: frame {f.index} has cameras {f.camera_ids} at {f.resolution}, the first frame "
                f"{seq[0].camera_ids} at {seq[0].resolution}: the frames must come from one static rig"
            )
    return seq


@dataclass(frozen=True)
class StageSettings:
    """Each stage's settings, read from the ``CalibConfig`` once (``stage_settings``).

    Attributes:
        scale: the scale stage's. refine: the ICP / pose-graph refinement's (None: off).
        joint_refine: whether the depth-aware joint refinement runs. min_agreement: the depth
        agreement below which a camera is unplaced or not "good" (0 = not checked). report: the
        config's fields as calib.json's ``report.config``.
    """

    scale: ScaleSettings
    refine: RefineSettings | None
    joint_refine: bool
    min_agreement: float
    report: dict[str, Any]


def stage_settings(config: CalibConfig) -> StageSettings:
    """The stages' settings of ``config``."""
    return StageSettings(
        scale=scale_settings(config),
        refine=refine_settings(config) if config.refine else None,
        joint_refine=config.joint_refine,
        min_agreement=config.min_depth_agreement,
        report=config.as_dict(),
    )


@dataclass(kw_only=True)
class Placement:
    """One backbone's cameras placed in metres (the steps of ``calibrate`` up to the report).

    Attributes:
        bb: the backbone's result. sr: the scale stage (for a metric backbone: the check, s = 1).
        T: camera id -> (4, 4) float64 camera-from-world, metres, world = ``anchor``.
        connected: sorted frame indices of the placed cameras. anchor: the world camera's id.
        agreement: camera id -> depth agreement under ``T`` (``geometry.depth_agreement``).
        scale_check: GMAC's s* on a metric backbone's poses (None for scale-free ones).
        refinement: the refinement's diagnostics or None. warnings: extra warnings.
        timings: seconds per stage. placed_by: camera id -> the source that placed it (None:
        ``bb.name`` for all). unplaced_reasons: camera id -> why it is not placed (``auto``).
        joint_refinement: the depth-aware joint refinement's summary (None when off).
    """

    bb: BackboneResult
    sr: ScaleResult
    T: dict[str, np.ndarray]
    connected: list[int]
    anchor: str | None
    agreement: dict[str, float | None]
    scale_check: float | None
    refinement: dict[str, Any] | None
    warnings: list[str]
    timings: dict[str, float]
    placed_by: dict[str, str] | None = None
    unplaced_reasons: dict[str, str] | None = None
    joint_refinement: dict[str, Any] | None = None


def place_and_judge(
    frames: list[Frame],
    rig: Rig,
    depth: np.ndarray,
    K: np.ndarray,
    drange: np.ndarray,
    config: CalibConfig,
    backbone_result: BackboneResult | None = None,
) -> Calibration:
    """GMAC on checked ``frames`` (the first frame's ``depth`` (N, H, W) float32 m, ``K``
    (N, 3, 3), ``drange`` (N, 2) m): the stages in order (module docstring). The cameras are
    placed by ``config.backbone`` (or ``backbone_result``), that placement going through
    ``verdicts.drop_unconfirmed`` (a camera its neighbours' depth does not confirm is left
    unplaced, with the reason), or, for ``auto``, by the sources of ``auto.AUTO_SOURCES`` until
    one settles, merged (``auto.merge_sources``, the same rule). Returns the calibration with
    its report and every camera's verdict."""
    t_start = time.perf_counter()
    ids = frames[0].camera_ids
    st = stage_settings(config)
    limit = st.min_agreement
    with one_blas_thread():  # thin (M, 3) / (M, 6) products: BLAS threads only cost (calib.blas)
        cams = prepare_cameras(depth, K, drange, config.samples_per_camera, config.seed)
        is_auto = config.backbone == "auto" and backbone_result is None
        runs: dict[str, Placement] = {}
        failures: dict[str, str] = {}
        for name in AUTO_SOURCES if is_auto else (config.backbone,):
            try:
                runs[name] = place_with_backbone(name, frames, rig, depth, K, drange, cams, config, backbone_result, st)
            except CalibrationError as e:
                if not is_auto:
                    raise
                failures[name] = str(e)
            if is_auto and settled(runs, ids, limit):
                break
        if is_auto:
            pl = merge_sources(runs, failures, frames[0], rig, limit, t_start)
        else:
            pl = runs[config.backbone]
            if any(a is not None and a < limit for a in pl.agreement.values()):
                T, pl.agreement, pl.unplaced_reasons = drop_unconfirmed(
                    pl.T, frames[0], rig, limit, {pl.bb.name: pl.agreement}, merged=False, agreement=pl.agreement
                )
                pl.T, pl.anchor = anchor_world(T, rig.ids)
        if st.joint_refine and len(pl.T) >= 2:
            from fuseflow.calib.joint_refine import joint_refine

            t = time.perf_counter()
            progress.report("joint refinement")
            res = joint_refine(pl.T, frames, rig, anchor=pl.anchor, tracks=pl.bb.tracks)
            pl.joint_refinement = res.as_dict()
            if res.accepted:
                pl.T = res.T_cam_world
                if limit > 0:
                    pl.agreement = depth_agreement(frames[0], rig, pl.T)
            pl.timings["joint_refine"] = time.perf_counter() - t
        progress.report("report")
        t = time.perf_counter()
        report = finish_report(pl, ids, st.report, st.scale.closed_form, limit)
        room, turns = camera_turns(frames, rig, pl.T, report)  # a repeating room: the subject decides turns
        if room is not None:
            pl.T, turns = settle_turns(pl.T, room, turns, TURN_MIN_MARGIN)  # about the room's axis
            if any(t.moved for t in turns.values()):
                pl.agreement = depth_agreement(frames[0], rig, pl.T) if limit > 0 else {}
                report = finish_report(pl, ids, st.report, st.scale.closed_form, limit)
            report.room = room.to_json()
        report.camera_verdicts = camera_verdicts(report, pl.T, ids, turns, room, limit)
        report.pair_agreement = pair_agreements(frames[0], rig, pl.T)
        drop_answered_scale_warning(report)
        pl.timings["report"] = time.perf_counter() - t
    pl.timings["total"] = time.perf_counter() - t_start
    return Calibration(pl.T, report)


def place_with_backbone(
    name: str,
    frames: list[Frame],
    rig: Rig,
    depth: np.ndarray,
    K: np.ndarray,
    drange: np.ndarray,
    cams: list[CameraData],
    config: CalibConfig,
    backbone_result: BackboneResult | None = None,
    stages: StageSettings | None = None,
) -> Placement:
    """Backbone ``name`` (or ``backbone_result``) -> scale (or its check) -> placement ->
    optional refinement -> world anchor -> depth agreement, on ``frames`` (checked; the first
    frame's ``depth`` (N, H, W) float32 m, ``K`` (N, 3, 3), ``drange`` (N, 2) m; ``cams``: their
    ``correspondences.prepare_cameras``). ``config`` goes to the backbone; the other stages read
    ``stages`` (default: ``stage_settings(config)``)."""
    st = stages or stage_settings(config)
    timings: dict[str, float] = {}
    frame, ids = frames[0], frames[0].camera_ids
    t = time.perf_counter()
    progress.report(f"{name}: backbone")
    bb = run_backbone(frames, rig, config, backbone_result, name)
    timings["backbone"] = time.perf_counter() - t
    t = time.perf_counter()
    progress.report(f"{name}: scale")
    sr, scale_check, warnings = placement_scale(bb, cams, st.scale)
    connected = (
        [int(k) for k in np.flatnonzero(bb.registered)] if bb.metric else sorted({n for e in sr.kept for n in e})
    )
    timings["scale"] = time.perf_counter() - t
    T = {}  # eq. (14): T_i = [R_i | s t_i] (metric backbones: s = 1, every registered camera)
    for k in connected:
        T[ids[k]] = bb.T_cam_world[k].copy()
        T[ids[k]][:3, 3] *= sr.s
    refinement = None
    if st.refine is not None:
        from fuseflow.calib.refine import refine_poses

        t = time.perf_counter()
        progress.report(f"{name}: refinement")
        color = frame.color.detach().cpu().numpy()
        rr = refine_poses(
            {k: T[ids[k]] for k in connected}, depth, K, drange, list(sr.kept), st.refine, color=color,
            counts=sr.edge_counts, matches=bb.matches,
        )  # fmt: skip
        T.update({ids[k]: Tk for k, Tk in rr.T_cam_world.items()})
        refinement = asdict(rr)
        refinement.pop("T_cam_world")
        timings["refine"] = time.perf_counter() - t
    T, anchor = anchor_world(T, rig.ids)
    agreement = depth_agreement(frame, rig, T) if st.min_agreement > 0 and T else {}
    return Placement(
        bb=bb, sr=sr, T=T, connected=connected, anchor=anchor, agreement=agreement, scale_check=scale_check,
        refinement=refinement, warnings=warnings, timings=timings,
    )  # fmt: skip


def run_backbone(
    frames: Frame | list[Frame],
    rig: Rig,
    config: CalibConfig,
    backbone_result: BackboneResult | None = None,
    name: str | None = None,
) -> BackboneResult:
    """The backbone's poses (``backbone_result`` when given, else backbone ``name``, default
    ``config.backbone``, run on the frames: all of them for ``MULTI_FRAME_BACKBONES``, else the
    first), checked: one pose per camera and at least two cameras registered."""
    frames = as_frames(frames)
    ids = frames[0].camera_ids
    name = name or config.backbone
    if backbone_result is not None:
        bb = backbone_result
    elif name in MULTI_FRAME_BACKBONES:
        sub = Rig(tuple(rig[c] for c in ids))  # the frames' cameras, in their order
        bb = get_backbone(name)(frames, sub, config)
    else:
        bb = get_backbone(name)(frames[0], rig, config)
    if bb.T_cam_world.shape[0] != len(ids):
        raise CalibrationError(f"backbone returned {bb.T_cam_world.shape[0]} poses for {len(ids)} cameras")
    if bb.registered.sum() < 2:
        raise CalibrationError(
            f"the backbone placed fewer than two cameras ({[ids[k] for k in np.flatnonzero(bb.registered)]})"
        )
    return bb
