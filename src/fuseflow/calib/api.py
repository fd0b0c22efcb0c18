"""``calibrate(frame, rig, config) -> Calibration``: GMAC end to end (paper III-B, DESIGN.md 3).

Stages (one module each): backbone (scale-ambiguous poses, eq. 3) -> RC correspondences and the
scale fixed point (eq. 5-12, :mod:`correspondences`, :mod:`scale`) -> per-edge scales and cycle
pruning (eq. 13, :mod:`cycles`) -> metric extrinsics T_i = [R_i | s* t_i] (eq. 14) -> optional
rigid refinement (:mod:`refine`).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from fuseflow.calib.backbones import BackboneResult, get_backbone
from fuseflow.calib.config import CalibConfig
from fuseflow.calib.correspondences import (
    CameraData,
    EdgeGeometry,
    coarse_scale_search,
    consistent_count,
    edge_geometry,
    edge_weight,
    fixed_point_scale,
    match_lookup,
    prepare_cameras,
)
from fuseflow.calib.cycles import prune_by_cycles
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.scale import naive_median_scale
from fuseflow.errors import ValidationError
from fuseflow.geometry import depth_agreement
from fuseflow.types import Calibration, Frame, Rig, invert_rigid

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


@dataclass(frozen=True)
class ScaleResult:
    """The scale stage's result (everything the report needs).

    Attributes:
        s: the global metric scale s*. s_initial: fixed point before pruning. s_coarse: coarse search.
        s_naive: the naive median depth-ratio scale (None when the backbone gives no depths).
        edge_scales: (i, j) -> per-edge scale. edge_counts: (i, j) -> correspondences.
        edges: candidate edges (i, j) with enough overlap. kept, pruned: after CC.
        cycle_mode: "cycles", "median", "single" or "off". cycle_residuals: "i-j-k" -> relative.
        std_error: relative standard error of s. iterations, converged: fixed point.
        peak_spread: relative width of the coarse-search peak. warnings: text.
    """

    s: float
    s_initial: float
    s_coarse: float
    s_naive: float | None
    edge_scales: dict[tuple[int, int], float]
    edge_counts: dict[tuple[int, int], int]
    edges: tuple[tuple[int, int], ...]
    kept: tuple[tuple[int, int], ...]
    pruned: tuple[tuple[int, int], ...]
    cycle_mode: str
    cycle_residuals: dict[str, float]
    cycle_residuals_before: dict[str, float]
    cycle_residuals_mm: dict[str, float]
    std_error: float
    iterations: int
    converged: bool
    peak_spread: float
    warnings: tuple[str, ...]
    scale_edges: tuple[tuple[int, int], ...] = ()
    """The kept edges whose correspondences gave s* (the match-only ones with
    ``global_from_matches``, else all kept edges)."""


def _directed(geoms_by_edge: dict[tuple[int, int], list[EdgeGeometry]], edges) -> list[EdgeGeometry]:
    return [g for e in edges for g in geoms_by_edge[e]]


def metric_scale(
    bb: BackboneResult,
    cams: list[CameraData],
    config: CalibConfig,
    corrupt: dict[tuple[int, int], float] | None = None,
) -> ScaleResult:
    """Scale stage of GMAC on backbone poses ``bb`` and per-camera RC data ``cams``.

    Args:
        corrupt: test/benchmark hook, edge (i, j) -> offset metres: that edge's points in camera j
            are shifted by offset along the baseline, Y' = Y + offset t / |t|, so the edge alone
            implies a baseline ``offset`` too long, as an edge with wrong matches would
            (robustness check of CC).
    """
    warnings: list[str] = []
    reg = np.flatnonzero(bb.registered)
    T0 = bb.T_cam_world
    # s0: scene depth over backbone baseline, the centre of the coarse search
    depths = np.concatenate([c.X[:, 2] for k, c in enumerate(cams) if k in set(reg) and len(c.X)])
    centers = np.stack([invert_rigid(T0[k])[:3, 3] for k in reg])
    base = np.median(np.linalg.norm(centers[:, None] - centers[None], axis=2)[np.triu_indices(len(reg), 1)])
    if not np.isfinite(base) or base <= 0:
        raise CalibrationError("the backbone placed all registered cameras at the same position")
    s0 = float(np.median(depths)) / float(base)
    pairs = [(int(a), int(b)) for ai, a in enumerate(reg) for b in reg[ai + 1 :]]

    def geoms_for(e):
        i, j = e
        w = (
            edge_weight(i, j, bb.overlap, bb.features, config.feature_weight)
            if not config.random_correspondences
            else 1.0
        )
        return [
            edge_geometry(T0, i, j, w, match_lookup(bb.matches, i, j)),
            edge_geometry(T0, j, i, w, match_lookup(bb.matches, j, i)),
        ]

    all_geoms = {e: geoms_for(e) for e in pairs}
    coarse = coarse_scale_search(_directed(all_geoms, pairs), cams, s0, config)
    s_c = coarse.s
    # edge gating by measured overlap at the coarse scale (eq. 8: overlap_ij gates edges)
    edges, overlap_meas = [], {}
    for e in pairs:
        i, j = e
        o = []
        for g in all_geoms[e]:
            n_i = max(len(cams[g.i].X), 1)
            o.append(consistent_count(g, cams[g.i], cams[g.j], s_c, config.depth_tau) / n_i)
        overlap_meas[e] = float(np.mean(o))
        if overlap_meas[e] >= config.min_overlap:
            edges.append(e)
    if bb.overlap is None and not config.random_correspondences:
        ov = np.eye(len(cams))
        for (i, j), v in overlap_meas.items():
            ov[i, j] = ov[j, i] = v
        bb_overlap = ov
        all_geoms = {
            e: [EdgeGeometry(g.i, g.j, g.R, g.t, g.weight * bb_overlap[g.i, g.j], g.matches) for g in all_geoms[e]]
            for e in pairs
        }
    if not edges:
        raise CalibrationError(
            f"no camera pair overlaps by at least {config.min_overlap:.0%} at the best scale "
            f"(measured: { {f'{i}-{j}': round(v, 3) for (i, j), v in overlap_meas.items()} })"
        )
    cams_used = cams
    geoms_for_edges = _corrupt_step(corrupt, cams_used)
    # Per-edge scales first (for CC), each edge's own fixed point from the robust coarse scale;
    # the global estimate only ever sees the edges CC keeps, so one wrong edge cannot drag it.
    # An edge whose own fixed point walks to a scale where its correspondences fail the depth
    # gate (what a wrong edge does) gets the one-step closed form at the coarse scale instead
    # (the paper's fixed-correspondence approximation), so it shows up in the cycle residuals
    # instead of vanishing.
    edge_scales, edge_counts = {}, {}
    match_only: set[tuple[int, int]] = set()
    final_cfg = replace(config, depth_tau=min(config.depth_tau_final, config.depth_tau))
    for e in edges:
        try:
            fe = fixed_point_scale(all_geoms[e], cams_used, s_c, config, step=geoms_for_edges)
            matched = _all_matches(fe.correspondences)
            if fe.s > 0 and (fe.estimate.count >= config.min_correspondences or matched):
                edge_scales[e], edge_counts[e] = fe.s, fe.estimate.count
                if matched:
                    match_only.add(e)
                continue
        except CalibrationError:
            pass
        try:
            est_e, _ = geoms_for_edges(all_geoms[e], cams_used, s_c, final_cfg)
        except CalibrationError:
            continue
        if est_e.count >= config.min_correspondences and est_e.s > 0:
            edge_scales[e], edge_counts[e] = est_e.s, est_e.count
    usable = [e for e in edges if e in edge_scales]
    dropped = [e for e in edges if e not in edge_scales]
    if dropped:
        warnings.append(f"edges {dropped} have fewer than {config.min_correspondences} correspondences")
    if not usable:
        raise CalibrationError(f"no edge has {config.min_correspondences} depth-consistent correspondences")
    if config.cycle_consistency:
        pts = {k: c.X[:: max(1, len(c.X) // 64)] for k, c in enumerate(cams)}
        cyc = prune_by_cycles(
            T0,
            {e: edge_scales[e] for e in usable},
            config.delta_cycle,
            config.max_pruned_fraction,
            pts,
            {e: float(edge_counts[e]) for e in usable},
        )
        kept, pruned, mode = cyc.kept, cyc.pruned, cyc.mode
        fmt = lambda d: {f"{a}-{b}-{c}": float(v) for (a, b, c), v in d.items()}  # noqa: E731
        res, res0, res_mm = fmt(cyc.residuals), fmt(cyc.residuals_before), fmt(cyc.residuals_mm)
        if mode == "median":
            warnings.append("the edge graph has no triangle: cycle check replaced by the median of per-edge scales")
    else:
        kept, pruned, mode, res, res0, res_mm = tuple(usable), (), "off", {}, {}, {}
    global_edges = list(kept)
    if config.use_matches and config.global_from_matches:
        kept_matches = [e for e in kept if e in match_only]
        if len(kept_matches) >= 2:
            global_edges = kept_matches
    fp = fixed_point_scale(_directed(all_geoms, global_edges), cams_used, s_c, config, step=geoms_for_edges)
    if not fp.converged:
        warnings.append(f"the scale fixed point did not converge in {fp.iterations} steps (history {fp.history[-3:]})")
    s_final, est, iters, conv = fp.s, fp.estimate, fp.iterations, fp.converged
    s_init = s_final
    if pruned:  # for the report: what the global estimate would have been without pruning
        s_init = fixed_point_scale(_directed(all_geoms, usable), cams_used, s_c, config, step=geoms_for_edges).s
    if coarse.peak_spread > config.ill_conditioned_spread and not (config.use_matches and bb.matches):
        warnings.append(
            f"ill-conditioned: scales within {coarse.peak_spread:.0%} of each other explain the depth equally "
            "well (baselines parallel to the dominant surfaces)"
        )
    if est.relative_std_error > 0.01:
        warnings.append(f"ill-conditioned: relative standard error of s* is {est.relative_std_error:.1%}")
    s_naive = None
    if bb.points:
        sd, bd = [], []
        for k, (uv, z) in bb.points.items():
            H, W = cams[k].shape
            ui = np.clip(np.round(uv[:, 0]).astype(int), 0, W - 1)
            vi = np.clip(np.round(uv[:, 1]).astype(int), 0, H - 1)
            sd.append(cams[k].depth[vi, ui])
            bd.append(z)
        try:
            s_naive = naive_median_scale(np.concatenate(sd), np.concatenate(bd))
        except CalibrationError:
            s_naive = None
    return ScaleResult(
        s=float(s_final),
        s_initial=float(s_init),
        s_coarse=float(s_c),
        s_naive=s_naive,
        edge_scales=edge_scales,
        edge_counts=edge_counts,
        edges=tuple(edges),
        kept=tuple(kept),
        pruned=tuple(pruned),
        cycle_mode=mode,
        cycle_residuals=res,
        cycle_residuals_before=res0,
        cycle_residuals_mm=res_mm,
        std_error=float(est.relative_std_error * s_final),
        iterations=iters,
        converged=conv,
        peak_spread=coarse.peak_spread,
        warnings=tuple(warnings),
        scale_edges=tuple(global_edges),
    )


def _all_matches(corrs) -> bool:
    """True when an edge's correspondences are all gated keypoint matches (both directions had at
    least MIN_MATCHES): those are s-independent and precise, so the edge stands on fewer than
    ``min_correspondences`` of them."""
    return bool(corrs) and all(len(c) and bool(np.all(c.is_match)) for c in corrs)


def _corrupt_step(corrupt, cams):
    """The fixed-point step, with depths of corrupted edges scaled (robustness injection)."""
    from fuseflow.calib.correspondences import _step

    if not corrupt:
        return _step
    from fuseflow.calib.scale import Correspondences, closed_form_scale

    def step(geoms, cams_, s, config):
        est, corrs = _step(geoms, cams_, s, config)
        out = []
        for c in corrs:
            f = corrupt.get((min(c.i, c.j), max(c.i, c.j)))
            if f is None:
                out.append(c)
            else:
                out.append(
                    Correspondences(c.i, c.j, c.RX, c.Y + f * c.t / np.linalg.norm(c.t), c.t, c.w, c.is_match, c.n)
                )
        return closed_form_scale(out, config.closed_form), out

    return step


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
        config: :class:`CalibConfig` (default preset: colmap backbone, full-3D, CC, no refinement).
        backbone_result: skip the backbone and use these poses (e.g. to rerun GMAC variants on
            one backbone run).

    Returns:
        :class:`fuseflow.Calibration`: camera-from-world 4x4 in metres for every placed camera
        (world = the backbone's frame with metric scale); the report holds s*, per-edge scales,
        correspondence counts, cycle residuals, pruned edges, unconnected cameras, warnings and
        timings.

    Raises:
        ValidationError: fewer than two cameras, cameras not in the rig, mismatched resolution.
        CalibrationError: a camera without depth, textureless images, no overlapping pair.
    """
    config = config or CalibConfig()
    timings: dict[str, float] = {}
    t_start = time.perf_counter()
    depth, K, drange = check_inputs(frame, rig)
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
    t = time.perf_counter()
    if backbone_result is None:
        backbone_result = get_backbone(config.backbone)(frame, rig, config)
    bb = backbone_result
    if bb.T_cam_world.shape[0] != len(ids):
        raise CalibrationError(f"backbone returned {bb.T_cam_world.shape[0]} poses for {len(ids)} cameras")
    timings["backbone"] = time.perf_counter() - t
    if bb.registered.sum() < 2:
        raise CalibrationError(
            f"the backbone placed fewer than two cameras ({[ids[k] for k in np.flatnonzero(bb.registered)]})"
        )
    t = time.perf_counter()
    cams = prepare_cameras(depth, K, drange, config.samples_per_camera, config.seed)
    sr = metric_scale(bb, cams, config)
    timings["scale"] = time.perf_counter() - t
    connected = sorted({n for e in sr.kept for n in e})
    unconnected = [ids[k] for k in range(len(ids)) if k not in connected]
    T = {}
    for k in connected:
        Tk = bb.T_cam_world[k].copy()
        Tk[:3, 3] *= sr.s
        T[ids[k]] = Tk
    refine_report: dict[str, Any] | None = None
    if config.refine:
        from fuseflow.calib.refine import refine_poses

        t = time.perf_counter()
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
        refine_report = asdict(rr)
        refine_report.pop("T_cam_world")
        timings["refine"] = time.perf_counter() - t
    agreement = depth_agreement(frame, rig, T) if config.min_depth_agreement > 0 and T else {}
    suspect = [c for c, a in agreement.items() if a is not None and a < config.min_depth_agreement]
    timings["total"] = time.perf_counter() - t_start
    name = lambda e: f"{ids[e[0]]}-{ids[e[1]]}"  # noqa: E731
    report = {
        "method": "GMAC",
        "backbone": bb.name,
        "backbone_info": bb.info,
        "config": asdict(config),
        "scale": sr.s,
        "scale_before_pruning": sr.s_initial,
        "scale_coarse": sr.s_coarse,
        "scale_naive_median_depth_ratio": sr.s_naive,
        "scale_std_error": sr.std_error,
        "closed_form": config.closed_form,
        "fixed_point": {"iterations": sr.iterations, "converged": sr.converged},
        "coarse_peak_spread": sr.peak_spread,
        "edge_scales": {name(e): v for e, v in sr.edge_scales.items()},
        "correspondence_counts": {name(e): v for e, v in sr.edge_counts.items()},
        "edges": [name(e) for e in sr.edges],
        "kept_edges": [name(e) for e in sr.kept],
        "scale_edges": [name(e) for e in sr.scale_edges],
        "pruned_edges": [name(e) for e in sr.pruned],
        "cycle_mode": sr.cycle_mode,
        "cycle_residuals_relative": _rename(sr.cycle_residuals, ids),
        "cycle_residuals_relative_before_pruning": _rename(sr.cycle_residuals_before, ids),
        "cycle_residuals_mm": _rename(sr.cycle_residuals_mm, ids),
        "unconnected_cameras": unconnected,
        "unregistered_cameras": [ids[k] for k in np.flatnonzero(~bb.registered)],
        "depth_agreement": agreement,
        "suspect_cameras": suspect,
        "warnings": [_edge_names(w, ids) for w in sr.warnings]
        + _placement_warnings(unconnected, [ids[k] for k in np.flatnonzero(~bb.registered)])
        + _agreement_warnings(suspect, agreement, config.min_depth_agreement),
        "ill_conditioned": any("ill-conditioned" in w for w in sr.warnings),
        "refinement": refine_report,
        "timings_s": timings,
    }
    return Calibration(T, report)


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
    import re

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
