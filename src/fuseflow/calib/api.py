"""``calibrate(frame, rig, config) -> Calibration``: GMAC end to end (paper III-B, DESIGN.md 3).

``calibrate`` is the method's outline, one named step each: check the inputs -> backbone
(scale-ambiguous poses, eq. 3, :mod:`backbones`) -> metric scale (RC correspondences, the scale
fixed point and cycle pruning, eq. 5-13, :mod:`scale_stage`) -> place the cameras
T_i = [R_i | s* t_i] (eq. 14) -> optional rigid refinement (:mod:`refine`) -> depth-agreement
check (:func:`fuseflow.geometry.depth_agreement`) -> the report (:class:`CalibReport`).
"""

from __future__ import annotations

import re
import time
from dataclasses import asdict
from typing import Any

import numpy as np

from fuseflow.calib.backbones import BackboneResult, get_backbone
from fuseflow.calib.config import CalibConfig
from fuseflow.calib.correspondences import prepare_cameras
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.report import CalibReport
from fuseflow.calib.scale_stage import ScaleResult, metric_scale
from fuseflow.errors import ValidationError
from fuseflow.geometry import depth_agreement
from fuseflow.types import Calibration, Frame, Rig, invert_rigid

# ScaleResult and metric_scale live in scale_stage; re-exported here, where they used to be.
__all__ = ["calibrate", "metric_scale", "ScaleResult", "check_inputs", "MIN_VALID_DEPTH"]

#: A camera needs at least this share of pixels with in-range depth.
MIN_VALID_DEPTH = 0.01


def check_inputs(frame: Frame, rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate and return (depth (N, H, W) float32, K (N, 3, 3), depth_range (N, 2)) in frame order."""
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
    depth = frame.depth.detach().cpu().numpy().astype(np.float32)
    K = np.stack([c.K for c in cams])
    rng = np.array([c.depth_range for c in cams])
    return depth, K, rng


def calibrate(
    frame: Frame,
    rig: Rig,
    config: CalibConfig | None = None,
    backbone_result: BackboneResult | None = None,
) -> Calibration:
    """Metric extrinsics of every camera from one multi-view RGB-D frame, with no target.

    Args:
        frame: the N views of one instant (depth (N, H, W) float32 metres, colour uint8).
        rig: the cameras (intrinsics, depth ranges; extrinsics ignored).
        config: :class:`CalibConfig` (default preset: colmap backbone, point-to-plane, CC, no refinement).
        backbone_result: skip the backbone and use these poses (e.g. to rerun GMAC variants on
            one backbone run).

    Returns:
        :class:`fuseflow.Calibration`: camera-from-world 4x4 in metres for every placed camera
        (world = the backbone's frame with metric scale); its ``report`` is a :class:`CalibReport`
        (s*, per-edge scales, correspondence counts, cycle residuals, pruned edges, unconnected
        cameras, warnings, timings).

    Raises:
        ValidationError: fewer than two cameras, cameras not in the rig, mismatched resolution.
        CalibrationError: a camera without depth, textureless images, no overlapping pair.
    """
    config = config or CalibConfig()
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    depth, K, drange = check_inputs(frame, rig)
    check_depth_coverage(frame, depth, drange)
    t = time.perf_counter()
    bb = run_backbone(frame, rig, config, backbone_result)
    timings["backbone"] = time.perf_counter() - t
    t = time.perf_counter()
    cams = prepare_cameras(depth, K, drange, config.samples_per_camera, config.seed)
    sr = metric_scale(bb, cams, config)
    timings["scale"] = time.perf_counter() - t
    T, connected = place_cameras(bb, sr, frame.camera_ids)
    refinement = None
    if config.refine:
        t = time.perf_counter()
        refinement = _refine(T, connected, frame, depth, K, drange, sr, bb, config)
        timings["refine"] = time.perf_counter() - t
    T, anchor = anchor_world(T, rig.ids)
    agreement = depth_agreement(frame, rig, T) if config.min_depth_agreement > 0 and T else {}
    timings["total"] = time.perf_counter() - t_start
    report = build_report(frame.camera_ids, bb, sr, config, connected, agreement, refinement, timings)
    report.world_anchor = anchor
    return Calibration(T, report)


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


def run_backbone(
    frame: Frame, rig: Rig, config: CalibConfig, backbone_result: BackboneResult | None = None
) -> BackboneResult:
    """The backbone's poses for the frame (``backbone_result`` when given, else ``config.backbone``
    run on it), checked: one pose per camera and at least two cameras registered."""
    ids = frame.camera_ids
    bb = backbone_result if backbone_result is not None else get_backbone(config.backbone)(frame, rig, config)
    if bb.T_cam_world.shape[0] != len(ids):
        raise CalibrationError(f"backbone returned {bb.T_cam_world.shape[0]} poses for {len(ids)} cameras")
    if bb.registered.sum() < 2:
        raise CalibrationError(
            f"the backbone placed fewer than two cameras ({[ids[k] for k in np.flatnonzero(bb.registered)]})"
        )
    return bb


def place_cameras(bb: BackboneResult, sr: ScaleResult, ids: tuple[str, ...]) -> tuple[dict[str, np.ndarray], list[int]]:
    """Eq. (14): T_i = [R_i | s* t_i] for every camera on a kept edge.

    Returns (camera id -> (4, 4) float64 camera-from-world in metres, sorted indices of the
    placed cameras).
    """
    connected = sorted({n for e in sr.kept for n in e})
    T = {}
    for k in connected:
        Tk = bb.T_cam_world[k].copy()
        Tk[:3, 3] *= sr.s
        T[ids[k]] = Tk
    return T, connected


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
        config=asdict(config),
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
