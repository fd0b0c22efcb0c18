"""Placing the cameras from one backbone (GMAC's steps between the inputs and the report):
backbone -> metric scale (or, for a metric backbone, its check) -> T_i = [R_i | s* t_i]
(eq. 14) -> optional refinement -> world anchor -> depth agreement; and the report. Used by
``api.calibrate`` for one backbone and by ``auto.auto_place`` for several."""

from __future__ import annotations

import re
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from fuseflow.calib import progress
from fuseflow.calib.backbones import MULTI_FRAME_BACKBONES, BackboneResult, get_backbone
from fuseflow.calib.config import CalibConfig
from fuseflow.calib.correspondences import CameraData, prepare_cameras
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.report import CalibReport
from fuseflow.calib.scale_stage import ScaleResult, metric_scale
from fuseflow.calib.verdicts import drop_unconfirmed
from fuseflow.errors import ValidationError
from fuseflow.geometry import depth_agreement
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = [
    "as_frames",
    "Placement",
    "place_with_backbone",
    "finish_report",
    "keep_confirmed",
    "anchor_world",
    "run_backbone",
    "place_cameras",
    "build_report",
    "metric_scale_check",
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


#: A metric backbone's poses are trusted at s* = 1; GMAC's own s* further than this from 1 warns.
#: On correct poses of simulated rings it reads 0.90-0.99 (docs/gmac-rgbd.md), so a tighter bound
#: warns on correct calibrations; wrong depth units (mm vs 0.1 mm, 1/8 mm) move it by 2-10x.
METRIC_SCALE_TOLERANCE = 0.15

SCALE_CHECK_WARNING = "GMAC's closed-form scale on the metric backbone's poses is"
"""How the scale check's warning (``metric_scale_check``) starts."""


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


def place_with_backbone(
    name: str,
    frames: list[Frame],
    rig: Rig,
    depth: np.ndarray,
    K: np.ndarray,
    drange: np.ndarray,
    config: CalibConfig,
    backbone_result: BackboneResult | None = None,
) -> Placement:
    """Backbone ``name`` (or ``backbone_result``) -> scale (or its check) -> placement ->
    optional refinement -> world anchor -> depth agreement, on ``frames`` (checked; the first
    frame's ``depth`` (N, H, W) float32 m, ``K`` (N, 3, 3), ``drange`` (N, 2) m)."""
    timings: dict[str, float] = {}
    frame = frames[0]
    t = time.perf_counter()
    progress.report(f"{name}: backbone")
    bb = run_backbone(frames, rig, config, backbone_result, name)
    timings["backbone"] = time.perf_counter() - t
    t = time.perf_counter()
    progress.report(f"{name}: scale")
    cams = prepare_cameras(depth, K, drange, config.samples_per_camera, config.seed)
    warnings: list[str] = []
    scale_check = None
    if bb.metric:
        sr, scale_check, warnings = metric_scale_check(bb, cams, config)
        connected = [int(k) for k in np.flatnonzero(bb.registered)]
    else:
        sr = metric_scale(bb, cams, config)
        connected = sorted({n for e in sr.kept for n in e})
    timings["scale"] = time.perf_counter() - t
    T = place_cameras(bb, sr.s, connected, frame.camera_ids)
    refinement = None
    if config.refine:
        t = time.perf_counter()
        progress.report(f"{name}: refinement")
        refinement = _refine(T, connected, frame, depth, K, drange, sr, bb, config)
        timings["refine"] = time.perf_counter() - t
    T, anchor = anchor_world(T, rig.ids)
    agreement = depth_agreement(frame, rig, T) if config.min_depth_agreement > 0 and T else {}
    return Placement(
        bb=bb, sr=sr, T=T, connected=connected, anchor=anchor, agreement=agreement, scale_check=scale_check,
        refinement=refinement, warnings=warnings, timings=timings,
    )  # fmt: skip


def keep_confirmed(pl: Placement, frame: Frame, rig: Rig, min_agreement: float) -> None:
    """One backbone's placement through the rule ``auto`` applies to its merged sources
    (:func:`fuseflow.calib.verdicts.drop_unconfirmed`): a camera its neighbours' depth does not
    confirm is left unplaced with the reason, whichever backbone placed it. Updates ``pl`` in
    place (extrinsics, world anchor, agreement, ``unplaced_reasons``); unchanged when every
    camera is confirmed."""
    if not any(a is not None and a < min_agreement for a in pl.agreement.values()):
        return
    T, pl.agreement, pl.unplaced_reasons = drop_unconfirmed(
        pl.T, frame, rig, min_agreement, {pl.bb.name: pl.agreement}, merged=False, agreement=pl.agreement
    )
    pl.T, pl.anchor = anchor_world(T, rig.ids)


def metric_scale_check(
    bb: BackboneResult, cams: list[CameraData], config: CalibConfig
) -> tuple[ScaleResult, float | None, list[str]]:
    """GMAC's scale stage run on a metric backbone's poses as a check: returns (its result with
    s = 1, the s* it found or None when it could not run, warnings). s* far from 1 means the
    backbone's metric poses and the sensor depth disagree (wrong pose, depth scale, intrinsics)."""
    try:
        sr = metric_scale(bb, cams, config)
    except CalibrationError as e:
        empty = ScaleResult(
            s=1.0, s_initial=1.0, s_coarse=1.0, s_naive=None, edge_scales={}, edge_counts={}, edges=(), kept=(),
            pruned=(), cycle_mode="off", cycle_residuals={}, cycle_residuals_before={}, cycle_residuals_mm={},
            std_error=0.0, iterations=0, converged=True, peak_spread=0.0, warnings=(),
        )  # fmt: skip
        return empty, None, [f"the scale check on the metric backbone's poses could not run: {e}"]
    check = sr.s
    warnings = []
    if abs(check - 1.0) > METRIC_SCALE_TOLERANCE:
        warnings.append(
            f"{SCALE_CHECK_WARNING} {check:.4f}, more than "
            f"{METRIC_SCALE_TOLERANCE:.0%} from 1 (correct poses read 0.90-0.99): check the depth units "
            "(rig.json depth_scale) and the intrinsics; the poses are used at scale 1"
        )
    return replace(sr, s=1.0, s_initial=1.0), check, warnings


def drop_answered_scale_warning(report: CalibReport) -> None:
    """Drop the scale check's warning when every camera's verdict is "good": the verdicts'
    depth-agreement and cycle evidence then shows the poses fit the sensor depth, and the check's
    own bias is the likelier cause (far-range rings with 120 deg between cameras read 0.76 on
    poses 0.1 deg / 12 mm from the truth). ``report.scale_check`` keeps the value."""
    verdicts = report.camera_verdicts or {}
    if verdicts and all(v.get("verdict") == "good" for v in verdicts.values()):
        report.warnings = [w for w in report.warnings if not w.startswith(SCALE_CHECK_WARNING)]


def finish_report(pl: Placement, ids: tuple[str, ...], config: CalibConfig) -> CalibReport:
    """The report of a placement, cameras named by id."""
    report = build_report(ids, pl.bb, pl.sr, config, pl.connected, pl.agreement, pl.refinement, pl.timings)
    report.world_anchor = pl.anchor
    report.scale_check = pl.scale_check
    report.warnings = pl.warnings + report.warnings
    report.placed_by = pl.placed_by if pl.placed_by is not None else dict.fromkeys(pl.T, pl.bb.name)
    report.unplaced_reasons = pl.unplaced_reasons or {}
    report.joint_refinement = pl.joint_refinement
    return report


def refine_jointly(pl: Placement, frames: list[Frame], rig: Rig, min_agreement: float) -> None:
    """The depth-aware joint refinement of every placed camera (:mod:`fuseflow.calib.joint_refine`)
    on ``frames``, with the backbone's keypoint tracks; updates ``pl`` in place (poses and depth
    agreement, measured when ``min_agreement`` > 0, when the refinement is kept; its summary and
    timing always)."""
    from fuseflow.calib.joint_refine import joint_refine

    t = time.perf_counter()
    progress.report("joint refinement")
    res = joint_refine(pl.T, frames, rig, anchor=pl.anchor, tracks=pl.bb.tracks)
    pl.joint_refinement = res.as_dict()
    if res.accepted:
        pl.T = res.T_cam_world
        if min_agreement > 0:
            pl.agreement = depth_agreement(frames[0], rig, pl.T)
    pl.timings["joint_refine"] = time.perf_counter() - t


def anchor_world(
    T_cam_world: dict[str, np.ndarray], order: tuple[str, ...]
) -> tuple[dict[str, np.ndarray], str | None]:
    """Re-express the extrinsics in the frame of the first placed camera in ``order`` (rig order),
    whose extrinsic becomes the identity: the backbone's own world frame depends on which image
    it happened to start from, so two calibrations of one rig would otherwise differ by a rigid
    motion. Returns (camera id -> camera-from-world, the anchor's id or None when none is placed)."""
    anchor = next((c for c in order if c in T_cam_world), None)
    if anchor is None:
        return T_cam_world, None
    world_from_anchor = invert_rigid(T_cam_world[anchor])
    out = {c: T @ world_from_anchor for c, T in T_cam_world.items()}
    out[anchor] = np.eye(4)
    return out, anchor


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


def place_cameras(bb: BackboneResult, s: float, connected: list[int], ids: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Eq. (14): T_i = [R_i | s t_i] for the ``connected`` cameras (frame indices): for a
    scale-free backbone those on a kept edge, for a metric one (s = 1) every registered camera.

    Returns camera id -> (4, 4) float64 camera-from-world in metres.
    """
    T = {}
    for k in connected:
        Tk = bb.T_cam_world[k].copy()
        Tk[:3, 3] *= s
        T[ids[k]] = Tk
    return T


def _refine(
    T: dict[str, np.ndarray],
    connected: list[int],
    frame: Frame,
    depth: np.ndarray,
    K: np.ndarray,
    drange: np.ndarray,
    sr: ScaleResult,
    bb: BackboneResult,
    config: CalibConfig,
) -> dict[str, Any]:
    """Rigid refinement of the placed cameras; updates ``T`` in place, returns the diagnostics."""
    from fuseflow.calib.refine import refine_poses

    ids = frame.camera_ids
    rr = refine_poses(
        {k: T[ids[k]] for k in connected},
        depth,
        K,
        drange,
        list(sr.kept),
        config,
        color=frame.color.detach().cpu().numpy(),
        counts=sr.edge_counts,
        matches=bb.matches,
    )
    for k, Tk in rr.T_cam_world.items():
        T[ids[k]] = Tk
    out = asdict(rr)
    out.pop("T_cam_world")
    return out


def build_report(
    ids: tuple[str, ...],
    bb: BackboneResult,
    sr: ScaleResult,
    config: CalibConfig,
    connected: list[int],
    agreement: dict[str, float | None],
    refinement: dict[str, Any] | None,
    timings: dict[str, float],
) -> CalibReport:
    """The report of one run, cameras and edges named by id (camera index k -> ``ids[k]``)."""
    suspect = [c for c, a in agreement.items() if a is not None and a < config.min_depth_agreement]
    unconnected = [ids[k] for k in range(len(ids)) if k not in connected]
    unregistered = [ids[k] for k in np.flatnonzero(~bb.registered)]
    name = lambda e: f"{ids[e[0]]}-{ids[e[1]]}"  # noqa: E731
    return CalibReport(
        method="GMAC",
        backbone=bb.name,
        backbone_info=bb.info,
        config=config.as_dict(),
        scale=sr.s,
        scale_before_pruning=sr.s_initial,
        scale_coarse=sr.s_coarse,
        scale_naive_median_depth_ratio=sr.s_naive,
        scale_std_error=sr.std_error,
        closed_form=config.closed_form,
        fixed_point={"iterations": sr.iterations, "converged": sr.converged},
        coarse_peak_spread=sr.peak_spread,
        edge_scales={name(e): v for e, v in sr.edge_scales.items()},
        correspondence_counts={name(e): v for e, v in sr.edge_counts.items()},
        edges=[name(e) for e in sr.edges],
        kept_edges=[name(e) for e in sr.kept],
        scale_edges=[name(e) for e in sr.scale_edges],
        pruned_edges=[name(e) for e in sr.pruned],
        cycle_mode=sr.cycle_mode,
        cycle_residuals_relative=_rename(sr.cycle_residuals, ids),
        cycle_residuals_relative_before_pruning=_rename(sr.cycle_residuals_before, ids),
        cycle_residuals_mm=_rename(sr.cycle_residuals_mm, ids),
        unconnected_cameras=unconnected,
        unregistered_cameras=unregistered,
        depth_agreement=agreement,
        suspect_cameras=suspect,
        warnings=[_edge_names(w, ids) for w in sr.warnings]
        + _placement_warnings(unconnected, unregistered)
        + _agreement_warnings(suspect, agreement, config.min_depth_agreement),
        ill_conditioned=any("ill-conditioned" in w for w in sr.warnings),
        refinement=refinement,
        timings_s=timings,
    )


def _agreement_warnings(suspect: list[str], agreement: dict[str, float | None], limit: float) -> list[str]:
    if not suspect:
        return []
    vals = ", ".join(f"{c} {agreement[c]:.2f}" for c in suspect)
    return [
        f"cameras {suspect} disagree with their neighbours' depth under these extrinsics ({vals}; below "
        f"{limit:.2f}): the backbone's poses are probably wrong (wrong matches between similar views); "
        "check the images for overlap and texture, or calibrate on another frame (--frame)"
    ]


def _edge_names(text: str, ids) -> str:
    """The scale stage's warnings name edges by index, "(0, 4)"; users know camera ids."""
    return re.sub(r"\((\d+), (\d+)\)", lambda m: f"{ids[int(m[1])]}-{ids[int(m[2])]}", text)


def _placement_warnings(unconnected: list[str], unregistered: list[str]) -> list[str]:
    out = []
    if unregistered:
        out.append(f"the backbone could not register cameras {unregistered}; they are not placed")
    rest = [c for c in unconnected if c not in unregistered]
    if rest:
        out.append(f"cameras {rest} share no usable depth overlap with the others and are not placed")
    return out


def _rename(d: dict[str, float], ids) -> dict[str, float]:
    return {"-".join(ids[int(x)] for x in k.split("-")): v for k, v in d.items()}
