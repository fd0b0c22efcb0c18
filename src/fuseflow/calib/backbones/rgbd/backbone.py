"""The rgbd backbone's entry point: ``rgbd_backbone`` checks the frames, then runs the package's
stages (its docstring's outline) in order and assembles the BackboneResult."""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from fuseflow.calib import progress
from fuseflow.calib.backbones.base import BackboneResult
from fuseflow.calib.backbones.rgbd.choice import joint_choice
from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.evidence import prepare_camera
from fuseflow.calib.backbones.rgbd.geometric_route import geometric_edges
from fuseflow.calib.backbones.rgbd.pairs import pair_edges, person_route, sphere_route, subject_route
from fuseflow.calib.backbones.rgbd.poses import camera_info, global_poses
from fuseflow.calib.blas import one_blas_thread
from fuseflow.calib.posegraph import prune_cycles
from fuseflow.calib.symmetry import main_block
from fuseflow.errors import ValidationError
from fuseflow.geometry import one_torch_thread
from fuseflow.types import Frame, Rig, invert_rigid


def rgbd_backbone(frames: Frame | Sequence[Frame], rig: Rig, config=None) -> BackboneResult:
    """Metric camera-from-world poses of a static rig from one or several RGB-D frames.

    Args:
        frames: one Frame or several of the same static rig, cameras in ``rig`` order
            (color (N, H, W, 3) uint8, depth (N, H, W) float32 metres). Matches are pooled over
            frames; the floor is taken from the per-pixel median over frames.
        rig: the rig (intrinsics K and depth ranges are used; extrinsics are ignored).
        config: an RGBDConfig, a CalibConfig (its ``rgbd``), or None (the defaults).

    Returns:
        BackboneResult with metric=True: T_cam_world (N, 4, 4) float64 metres, world frame =
        the first placed camera in rig order; registered (N,); info["pairs"] lists every pair
        with its candidates (route, inliers, checks) and the accepted edge's route and score;
        info["cameras"] the per-camera floor fit and the edges that placed it.

    Raises:
        ValidationError: frames empty or not matching the rig.
    """
    cfg = config if isinstance(config, RGBDConfig) else RGBDConfig() if config is None else config.rgbd
    frames = _check_frames(frames, rig)
    with one_blas_thread():  # thin (M, 3) products: BLAS threads only cost (calib.blas)
        return _rgbd_backbone(frames, rig, cfg)


def _rgbd_backbone(frames: list[Frame], rig: Rig, cfg: RGBDConfig) -> BackboneResult:
    """``rgbd_backbone`` on checked frames (the package docstring's outline)."""
    t0 = time.perf_counter()
    n = len(rig)
    order = sorted(range(n), key=lambda k: rig.cameras[k].id)  # canonical: by id
    cams = []
    for k in order:
        cams.append(prepare_camera(frames, rig, k, cfg))
        progress.report("rgbd: cameras", len(cams), n)
    t_prep = time.perf_counter() - t0
    people, people_skip = person_route(frames, rig, order, cfg)
    subject = subject_route(frames, rig, order, cams, cfg)
    spheres = sphere_route(frames, rig, order, cams, cfg)
    ids = [rig.cameras[k].id for k in order]
    with one_torch_thread():  # small verification tensors: threads only cost (geometry docs)
        edges, pairs_info, hyps, room = pair_edges(cams, cfg, people, subject, spheres)
        joint, ambiguous = {}, set()
        if cfg.pair_hypotheses > 1 and edges:
            edges, joint, ambiguous = joint_choice(cams, edges, hyps, pairs_info, ids, cfg)
    t_pairs = time.perf_counter() - t0 - t_prep
    kept, dropped, untested = prune_cycles(edges, cfg.cycle_rot_deg, cfg.cycle_trans_m)
    T_int, placed_int, refine_info = global_poses(n, kept, cfg)
    geo_info: list[dict] = []
    t1 = time.perf_counter()
    if cfg.geometric and not placed_int.all():
        progress.report("rgbd: geometric route")
        with one_torch_thread():
            geo_edges, geo_info, solved = geometric_edges(cams, T_int, placed_int, edges, cfg, ambiguous)
        if solved is not None:
            edges = {**edges, **geo_edges}
            kept, dropped, untested, T_int, placed_int, refine_info = solved
    t_geo = time.perf_counter() - t1
    block = main_block(sorted(kept))  # a 4- or 5-cycle checks its edges as a triangle does
    untested = [e for e in kept if not set(e) <= block]
    T = np.tile(np.eye(4), (n, 1, 1))
    registered = np.zeros(n, dtype=bool)
    for a, k in enumerate(order):
        T[k], registered[k] = T_int[a], placed_int[a]
    if registered.any():
        anchor = int(np.flatnonzero(registered)[0])
        T = np.where(registered[:, None, None], T @ invert_rigid(T[anchor]), T)
    info = {
        "metric": True,
        "joint_choice": joint,
        "room": room,
        "frames": len(frames),
        "pairs": [{**p, "cameras": [ids[p["pair"][0]], ids[p["pair"][1]]]} for p in pairs_info + geo_info],
        "cycle_dropped": [[ids[d["edge"][0]], ids[d["edge"][1]]] for d in dropped],
        "untested_edges": [[ids[a], ids[b]] for a, b in untested],
        "cameras": camera_info(cams, ids, kept, untested, placed_int, joint.get("ambiguous", {})),
        "refine": refine_info,
        "people": people_skip or people.info(),
        "subject": subject.info() if subject is not None else "skipped: fewer than 3 frames or off",
        "spheres": spheres.info() if spheres is not None else "skipped: fewer than 5 frames or off",
        "time_s": {"prepare": t_prep, "pairs": t_pairs, "geometric": t_geo, "total": time.perf_counter() - t0},
    }
    tracks = tuple(
        (ids[e.i], ids[e.j], e.X_i, e.X_j, e.sigma)
        for e in kept.values()
        if placed_int[e.i] and placed_int[e.j] and len(e.X_i)
    )
    return BackboneResult(T_cam_world=T, registered=registered, name="rgbd", info=info, metric=True, tracks=tracks)


def _check_frames(frames, rig: Rig) -> list[Frame]:
    if isinstance(frames, Frame):
        frames = [frames]
    frames = list(frames)
    if not frames:
        raise ValidationError("rgbd backbone: no frames given")
    for f in frames:
        if not isinstance(f, Frame):
            raise ValidationError(f"rgbd backbone: expected Frame objects, got {type(f).__name__}")
        if tuple(f.camera_ids) != rig.ids:
            raise ValidationError(
                f"rgbd backbone: frame {f.index} cameras {f.camera_ids} differ from the rig's {rig.ids}"
            )
        if f.resolution != rig.resolution:
            raise ValidationError(f"rgbd backbone: frame {f.index} is {f.resolution}, the rig {rig.resolution}")
    return [f.to("cpu") for f in frames]
