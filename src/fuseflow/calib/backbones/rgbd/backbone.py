"""Metric RGB-D backbone: camera poses in metres from sensor depth, for sparse wide-baseline rigs.

COLMAP cannot match across cameras 90-120 deg apart; the depth can. Outline
(``rgbd_backbone``), one or several frames of a static rig:

1. Per camera (``prepare_camera``): median colour / depth over the frames, the floor plane
   (:mod:`fuseflow.calib.floor`) and its metric top-down image with SIFT on it, keypoints of every
   frame's image (SIFT, or the learned ``RGBDConfig.matcher``, :mod:`fuseflow.calib.backbones.rgbd.matchers`)
   lifted to 3-D by that frame's depth, and a subsampled point set for checks.
2. Per camera pair, candidate relative poses from three routes (several hypotheses each,
   sequential RANSAC with a fixed seed):
   ``floor``: top-down SIFT matches, 4-DoF RANSAC (yaw + shift on the floor; both floor planes
   fix roll, pitch and height); ``sift3d``: image SIFT matches pooled over frames, lifted by
   depth, 6-DoF 3-D RANSAC (Kabsch); ``sift4``: the same 3-D matches, 4-DoF on the floor (two
   correct matches suffice). With a learned matcher, its matches replace SIFT's in ``sift3d`` and
   ``sift4`` (the route names stay).
   Where the ``people`` extra is installed, ``people`` / ``people+icp`` (route (d),
   :mod:`fuseflow.calib.people`): the joints of a person both views see, and that pose refined
   by ICP. With 3 or more frames, ``subject`` (route (e), :mod:`fuseflow.calib.subject`): the
   head of a person walking through the rig, tracked by depth alone; its tracks also refute any
   candidate of the pair that moves one head track from the other.
3. Verification (``verify_pose``): every candidate is scored by depth agreement between the two
   views (``fuseflow.geometry.project_votes``, visibility-aware, both directions), on all points
   and on the points off the floor (a 180-deg flip on the floor agrees on the floor), plus a
   free-space check (share of points that camera j sees through). Never by inlier count: wrong
   flips had many inliers. The best candidate above the thresholds becomes an edge.
4. Global (:mod:`fuseflow.calib.posegraph`): cycle test on the metric relative poses, maximum-
   score spanning tree, joint robust least squares on the edges' 3-D correspondences.

Deterministic and order-independent: cameras are processed in the order of their ids, every
RANSAC has a fixed seed, and the world frame is re-anchored at the first placed camera in rig
order at the end. The poses are metric (``BackboneResult.metric``): GMAC's scale is then a check.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
import torch

from fuseflow.calib import progress
from fuseflow.calib.backbones.base import BackboneResult
from fuseflow.calib.backbones.rgbd.matchers import ImageFeatures, Matcher, get_matcher, sift_uv
from fuseflow.calib.blas import one_blas_thread
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.floor import FloorPlane, TopDown, fit_floor_plane, floor_mask, render_topdown
from fuseflow.calib.geometric import kabsch
from fuseflow.calib.posegraph import Edge, prune_cycles, refine_poses, rotation_angle_deg, spanning_tree
from fuseflow.calib.symmetry import (
    SUBJECT_MAX_FREE_SPACE,
    SUBJECT_MIN_POINTS,
    Hypothesis,
    bridges,
    colocated,
    distinct_hypotheses,
    main_block,
    pose_gap,
    select_consistent,
    subject_free_space,
)
from fuseflow.errors import ValidationError
from fuseflow.geometry import one_torch_thread, project_votes
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = [
    "RGBDConfig",
    "rgbd_backbone",
    "prepare_camera",
    "verify_pose",
    "PairCheck",
    "CameraEvidence",
    "merge_repeats",
    "nanmedian_frames",
]


@dataclass(frozen=True)
class RGBDConfig:
    """Settings of the metric RGB-D backbone. Every field: meaning, default's source, range."""

    seed: int = 0
    """Seed of every RANSAC (deterministic results). Any int."""

    sift_features: int = 3000
    """SIFT keypoints per image (OpenCV). >= 100. Default: ~0.1 s per 640x480 image on one core."""

    ratio: float = 0.8
    """Lowe ratio test for SIFT matches. (0, 1). Default: Lowe's 0.8; verification, not the
    ratio, guards against wrong matches."""

    floor_res: float = 0.005
    """Top-down floor image resolution, metres per pixel. Default 5 mm: about one camera pixel
    at 3 m for a 530 px focal length (notes/wide-baseline-calibration.md)."""

    floor_band: float = 0.02
    """Plane-fit inlier band, metres. Default: ~3 sigma of Kinect-class depth noise at 2.5 m."""

    floor_max_range: float = 6.0
    """Floor farther than this from a camera is not rendered, metres. Default: beyond the
    Kinect/RealSense working range (4.5 m) with margin."""

    floor_inlier_m: float = 0.03
    """4-DoF RANSAC inlier distance on the floor, metres (6 top-down pixels at 5 mm)."""

    inlier_m: float = 0.03
    """6-DoF 3-D RANSAC inlier distance at 0 m; grows by ``inlier_rel`` * depth. Default: ~3
    sigma of a SIFT keypoint lifted by Kinect-class depth at 2 m."""

    inlier_rel: float = 0.01
    """Depth-proportional part of the 3-D inlier distance (per metre of depth)."""

    ransac_iterations: int = 2000
    """Hypotheses per RANSAC run. Default: >99 % success at 20 % inliers for the 3-point model."""

    hypotheses: int = 3
    """Candidate poses per route and pair (sequential RANSAC: the best, then the best of the
    remaining matches, ...). Default 3: a correct pose hidden behind a wrong, larger consensus
    (the ring's symmetry) still reaches the verification."""

    min_inliers: int = 4
    """Fewest RANSAC inliers for a candidate. Default 4 (floor pairs with 3-12 correct inliers
    were seen); the verification decides, not this count."""

    samples: int = 5000
    """Depth pixels per camera used for verification (regular grid). Default: as
    ``fuseflow.geometry.pair_agreement``."""

    tau: float = 0.05
    """Relative depth residual under which two views agree (the paper's tau, eq. 21)."""

    min_agreement: float = 0.8
    """Fewest share of agreeing votes (both directions, all points) for an edge. (0, 1).
    Default: measured separation (benchmarks/calib_wide.py, -v dumps): right candidates
    0.92-0.99 on simulated rings and on hocap-8rs (its reference extrinsics: 0.94), wrong ones
    0.11-0.86."""

    min_structure_agreement: float = 0.7
    """Same, on points off the floor (walls, furniture, people). Floor-aligned flips agree on
    the floor but not here: measured right 0.77-0.99, wrong 0.06-0.57 (one 4-deg-off pose 0.94,
    caught by the free-space test)."""

    max_free_space: float = 0.08
    """Largest share of projected points that the other camera sees through (free-space
    violations over points with depth there). Measured right 0.006-0.056, wrong 0.12-0.79."""

    min_agree_points: int = 150
    """Fewest agreeing samples (both directions): a pose verified by a sliver of overlap is no
    evidence."""

    min_structure_votes: int = 100
    """Fewest votes on off-floor points; fewer: the pair cannot be told from a flip, no edge."""

    cycle_rot_deg: float = 2.0
    """Cycle test: largest rotation of a triangle's composed transform, degrees."""

    cycle_trans_m: float = 0.08
    """Cycle test: largest translation of a triangle's composed transform, metres."""

    sigma0: float = 0.005
    """Noise of a 3-D correspondence at 0 m, metres (keypoint localisation)."""

    sigma2: float = 0.0015
    """Depth-squared part of the correspondence noise, metres per m^2 (Kinect-class axial noise
    grows with z^2)."""

    refine: bool = True
    """Joint robust refinement of all cameras on the edges' correspondences (posegraph)."""

    matcher: str = "sift"
    """Image matcher of the ``sift3d`` / ``sift4`` routes (:mod:`fuseflow.calib.backbones.rgbd.matchers`): "sift",
    or "xfeat", "aliked", "disk" with ``fuseflow[matchers]``. The floor route always uses SIFT
    (rotation-invariant; the top-down views differ by any yaw). Default SIFT: XFeat placed no more
    cameras right on 3-4 camera rings (no right pair of its own; SIFT 3 of 54), put hocap-8rs
    1.8 deg off where SIFT is 0.6 (ALIKED, DISK: 2.2), and costs 2-3x the time (docs/gmac-rgbd.md, "Learned matchers")."""

    geometric: bool = True
    """Route (c), geometry only (:mod:`fuseflow.calib.geometric`): for cameras the other routes
    leave unplaced, FPFH + RANSAC + ICP candidates against every other camera, proposed only
    from a wide basin of convergence and verified like every candidate. Default on: it runs
    only where a camera is left unplaced, so rigs the other routes place pay nothing; on
    hocap-8rs it places the two cameras that look up through the ceiling rig
    (docs/gmac-rgbd.md)."""

    geometric_voxel: float = 0.02
    """Voxel of the geometry route's clouds, metres (FPFH radius 5 voxels = 10 cm)."""

    geometric_starts: int = 20
    """Distinct RANSAC hypotheses refined by ICP per pair in the geometry route."""

    geometric_min_starts: int = 3
    """Fewest ICP starts that must converge to a pose for the geometry route to propose it
    (and twice as many as to any other pose that passes the verification). Measured on
    hocap-8rs, 30 starts: right poses 7-28, wrong ones 1-4 (``calib.geometric`` docstring)."""

    geometric_edges_per_camera: int = 1
    """Route (c) candidates an unplaced camera gets per round, at most: its pairs with a placed
    camera are tried in order of descriptor consensus (the best FPFH-RANSAC hypothesis's
    inliers: it orders the work, never accepts a pose) until this many are proposed. The ICP
    stage is ~1.2 s a pair; on hocap-8rs each up-looking camera has 6 such pairs, one gives a
    candidate, and it ranks first (48 and 36 inliers against 5-30). Default 1: hocap-8rs 28 ->
    ~17 s with the same edges (docs/history.md, 2026-11-24, "calibration time"); the cost, a camera held by
    one route (c) edge closes no cycle with it (it is flagged as unchecked, as on hocap-8rs
    before). A number >= the cameras tries every pair."""
    people: bool = False
    """Route (d), person keypoints (:mod:`fuseflow.calib.people`): each pair also gets the
    person's keypoint pose and its depth refinement as candidates. Off by default: on the
    simulated far-range 3-camera rig its poses were 10-19 cm off yet passed depth verification
    (docs/gmac-trust.md, "Person route"). Needs the ``people`` extra (mediapipe); where it is missing
    ``info["people"]`` says it was skipped and why."""

    subject: bool = True
    """Route (e), the moving subject (:mod:`fuseflow.calib.subject`): with 3 or more frames, the
    head of a person walking through the rig, tracked in every camera without a detector, gives
    each pair a candidate and judges every candidate of the pair (a pose that moves one head
    track away from the other is refuted). Steps aside without frames or a moving person."""

    min_separation: float = 0.2
    """Physical plausibility: a relative pose that puts the two camera centres closer than this
    (metres) is rejected, not scored, unless the two views are nearly the same (agreement >=
    ``SAME_VIEW_AGREEMENT`` everywhere and off the floor). A device is ~10 cm wide; in a room
    that repeats, the aliases that stack one camera on another land within the rig's placement
    tolerance of it (measured 0.05-0.14 m on the simulated symmetric studio, 2-5 cm on a real
    dome) and agree better than the true pose (:mod:`fuseflow.calib.symmetry`)."""

    pair_hypotheses: int = 3
    """Verified, mutually distinct poses kept per pair for the joint choice
    (:func:`fuseflow.calib.symmetry.select_consistent`). 1 = the best only (no joint choice)."""

    ambiguity_ratio: float = 0.8
    """A camera held only by edges on no cycle is ambiguous (left unplaced, with the reason) when
    one of its pairs has another passing hypothesis scoring at least this share of the chosen
    one: nothing tells the two apart. (0, 1)."""

    def __post_init__(self) -> None:
        from fuseflow.calib.backbones.rgbd.matchers import MATCHERS

        if self.matcher not in MATCHERS:
            raise ValidationError(f"RGBDConfig.matcher must be one of {', '.join(MATCHERS)}, got {self.matcher!r}")
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or f.name in ("seed", "matcher"):
                continue
            if not isinstance(v, (int, float)) or v <= 0:
                raise ValidationError(f"RGBDConfig.{f.name} must be a positive number, got {v!r}")
        for name in ("ratio", "tau", "min_agreement", "min_structure_agreement", "max_free_space", "ambiguity_ratio"):
            if not 0 < getattr(self, name) < 1:
                raise ValidationError(f"RGBDConfig.{name} must be in (0, 1), got {getattr(self, name)!r}")


@dataclass
class CameraEvidence:
    """What a camera contributes, computed once by ``prepare_camera`` (arrays in its own camera
    frame, metres)."""

    K: np.ndarray
    depth: np.ndarray  # (H, W) float32 median depth, gated
    plane: FloorPlane | None
    topdown: TopDown | None
    td_xy: np.ndarray  # (P, 2) floor coordinates of top-down keypoints
    td_desc: np.ndarray  # (P, 128) float32
    kp: list[tuple[np.ndarray, ImageFeatures]]  # per frame: X (Q, 3), the Q keypoints' features
    samples_X: torch.Tensor  # (M, 3) float32 verification points
    samples_floor: torch.Tensor  # (M,) bool
    depth_sub: torch.Tensor  # (h, w) float32 subsampled depth for lookups
    K_sub: torch.Tensor  # (3, 3) float32 intrinsics of depth_sub


@dataclass(frozen=True)
class PairCheck:
    """Verification of one candidate pose between cameras i and j (both directions pooled).

    Attributes:
        agreement: agreeing / voting samples (visibility-aware votes), all points.
        structure_agreement: the same on points off the floor (NaN without votes there).
        free_space: share of samples with depth in the other view that it sees through.
        agree: agreeing samples. structure_votes: votes on off-floor points.
    """

    agreement: float
    structure_agreement: float
    free_space: float
    agree: int
    structure_votes: int

    def passes(self, cfg: RGBDConfig) -> bool:
        """The depth and free-space tests (``plausible`` adds the physical one)."""
        return (
            self.agreement >= cfg.min_agreement
            and self.structure_votes >= cfg.min_structure_votes
            and self.structure_agreement >= cfg.min_structure_agreement
            and self.free_space <= cfg.max_free_space
            and self.agree >= cfg.min_agree_points
        )


#: Agreement (all points and off the floor) above which two views count as nearly the same, so
#: that co-located cameras are plausible (``plausible``): stacked aliases in a symmetric room
#: agreed 0.90-0.95 overall and at most 0.86 off the floor (symstudio seed 0).
SAME_VIEW_AGREEMENT = 0.97


#: Cameras closer than this share of their views' median depth see the scene from nearly the same
#: direction (0.15: 8.5 deg): their views must then be nearly the same too (``plausible``). An
#: alias one period of an 8-fold room from the truth put cameras 51 deg apart 0.29 m apart, 2.6 m
#: from the subject (symstudio seed 2), and passed the pair checks at 0.90 agreement.
CLOSE_DEPTH_SHARE = 0.15


def plausible(T_ba: np.ndarray, chk: PairCheck, cfg: RGBDConfig, depth: float = 0.0) -> bool:
    """Physical plausibility of a verified pose: the camera centres at least ``min_separation``
    and CLOSE_DEPTH_SHARE of the views' median ``depth`` (metres) apart, or the two views nearly
    the same (``SAME_VIEW_AGREEMENT``)."""
    if not colocated(T_ba, max(cfg.min_separation, CLOSE_DEPTH_SHARE * depth)):
        return True
    sa = chk.structure_agreement
    return chk.agreement >= SAME_VIEW_AGREEMENT and not np.isnan(sa) and sa >= SAME_VIEW_AGREEMENT


# ----------------------------------------------------------------------------- entry point


def rgbd_backbone(frames: Frame | Sequence[Frame], rig: Rig, config: RGBDConfig | None = None) -> BackboneResult:
    """Metric camera-from-world poses of a static rig from one or several RGB-D frames.

    Args:
        frames: one Frame or several of the same static rig, cameras in ``rig`` order
            (color (N, H, W, 3) uint8, depth (N, H, W) float32 metres). Matches are pooled over
            frames; the floor is taken from the per-pixel median over frames.
        rig: the rig (intrinsics K and depth ranges are used; extrinsics are ignored).
        config: an RGBDConfig (or any object; only an RGBDConfig is used, else the defaults).

    Returns:
        BackboneResult with metric=True: T_cam_world (N, 4, 4) float64 metres, world frame =
        the first placed camera in rig order; registered (N,); info["pairs"] lists every pair
        with its candidates (route, inliers, checks) and the accepted edge's route and score;
        info["cameras"] the per-camera floor fit and the edges that placed it.

    Raises:
        ValidationError: frames empty or not matching the rig.
    """
    cfg = (
        config
        if isinstance(config, RGBDConfig)
        else RGBDConfig(matcher=getattr(config, "matcher", "sift"), seed=getattr(config, "seed", 0))
    )
    frames = _check_frames(frames, rig)
    with one_blas_thread():  # thin (M, 3) products: BLAS threads only cost (calib.blas)
        return _rgbd_backbone(frames, rig, cfg)


def _rgbd_backbone(frames: list[Frame], rig: Rig, cfg: RGBDConfig) -> BackboneResult:
    """``rgbd_backbone`` on checked frames (the module docstring's outline)."""
    t0 = time.perf_counter()
    n = len(rig)
    order = sorted(range(n), key=lambda k: rig.cameras[k].id)  # canonical: by id
    cams = []
    for k in order:
        cams.append(prepare_camera(frames, rig, k, cfg))
        progress.report("rgbd: cameras", len(cams), n)
    t_prep = time.perf_counter() - t0
    people, people_skip = _person_route(frames, rig, order, cfg)
    subject = _subject_route(frames, rig, order, cams, cfg)
    ids = [rig.cameras[k].id for k in order]
    with one_torch_thread():  # small verification tensors: threads only cost (geometry docs)
        edges, pairs_info, hyps = _pair_edges(cams, cfg, people, subject)
        joint, ambiguous = {}, set()
        if cfg.pair_hypotheses > 1 and edges:
            edges, joint, ambiguous = _joint_choice(cams, edges, hyps, pairs_info, ids, cfg)
    t_pairs = time.perf_counter() - t0 - t_prep
    kept, dropped, untested = prune_cycles(edges, cfg.cycle_rot_deg, cfg.cycle_trans_m)
    T_int, placed_int, refine_info = _global_poses(n, kept, cfg)
    geo_info: list[dict] = []
    t1 = time.perf_counter()
    if cfg.geometric and not placed_int.all():
        progress.report("rgbd: geometric route")
        with one_torch_thread():
            geo_edges, geo_info, solved = _geometric_edges(cams, T_int, placed_int, edges, cfg, ambiguous)
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
        "frames": len(frames),
        "pairs": [{**p, "cameras": [ids[p["pair"][0]], ids[p["pair"][1]]]} for p in pairs_info + geo_info],
        "cycle_dropped": [[ids[d["edge"][0]], ids[d["edge"][1]]] for d in dropped],
        "untested_edges": [[ids[a], ids[b]] for a, b in untested],
        "cameras": _camera_info(cams, ids, kept, untested, placed_int, joint.get("ambiguous", {})),
        "refine": refine_info,
        "people": people_skip or people.info(),
        "subject": subject.info() if subject is not None else "skipped: fewer than 3 frames or off",
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


# ----------------------------------------------------------------------------- per camera


def prepare_camera(frames: list[Frame], rig: Rig, k: int, cfg: RGBDConfig) -> CameraEvidence:
    """Everything camera ``k`` of ``rig`` contributes (step 1 of the module docstring), from
    ``frames`` (a list of Frames in rig order, checked by ``rgbd_backbone``)."""
    import cv2

    cam = rig.cameras[k]
    lo, hi = cam.depth_range
    images, greys, depths = [], [], []
    for f in frames:
        if not bool(f.present[k]):
            continue
        d = f.depth[k].numpy().astype(np.float32)
        depths.append(np.where((d >= lo) & (d <= hi), d, 0.0).astype(np.float32))
        images.append(f.color[k].numpy())
        greys.append(cv2.cvtColor(images[-1], cv2.COLOR_RGB2GRAY))
    K = cam.K.copy()
    if not depths:
        raise CalibrationError(f"rgbd backbone: camera {cam.id!r} has no view in any frame")
    grey_med, depth_med, depth_floor = _median_images(greys, depths)
    sift = cv2.SIFT_create(nfeatures=cfg.sift_features)
    kp = [_lift_keypoints(_image_matcher(cfg), im, d, K) for im, d in zip(images, depths)]
    X = _backproject(depth_med, K)
    plane = fit_floor_plane(X, band=cfg.floor_band, seed=cfg.seed)
    topdown, td_xy, td_desc = None, np.zeros((0, 2)), np.zeros((0, 128), np.float32)
    if plane is not None:
        # the floor where most frames saw it, not only where nothing ever moved: the floor the
        # cameras share is the middle of the rig, where people walk (studio 4-ring seed 2, 10
        # dynamic frames: 2 right floor matches of 23 for cameras 0-1 with the static depth, 20
        # of 34 on one frame)
        topdown = render_topdown(grey_med, depth_floor, K, plane, cfg.floor_res, cfg.floor_max_range)
        if topdown is not None:
            mask = cv2.erode(topdown.mask.astype(np.uint8), np.ones((7, 7), np.uint8))
            kps, desc = sift.detectAndCompute(topdown.image, mask)
            if desc is not None and len(kps):
                # a keypoint whose descriptor window reaches a hole of the floor image describes
                # the hole's outline: an object's occlusion shadow, which differs between views
                # (on a textureless floor the floor route matched only such outlines and put a
                # camera 6 deg / 24 cm off, verified: benchmarks/calib_geometric.py, 15 deg seed 3)
                free = cv2.distanceTransform(topdown.mask.astype(np.uint8), cv2.DIST_L2, 3)
                keep = [k for k, p in enumerate(kps) if free[int(p.pt[1]), int(p.pt[0])] > p.size]
                kps, desc = [kps[k] for k in keep], desc[keep]
            if desc is not None and len(kps):
                td_xy = topdown.to_floor(sift_uv(kps))
                td_desc = desc.astype(np.float32)
    return CameraEvidence(K, depth_med, plane, topdown, td_xy, td_desc, kp, *_samples(depth_med, K, plane, cfg))


#: A pixel whose depth in some frame differs from its median by more than this (metres, or this
#: share of the depth) saw something move: it has no static depth (``_median_images``).
DYNAMIC_MIN_M = 0.1
DYNAMIC_REL = 0.05


def _median_images(greys: list[np.ndarray], depths: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel median grey and depth (ignoring missing depth) over frames: people and other
    moving things leave the floor image of a static rig. Returns (grey, static depth, median
    depth): in the static depth, pixels where something moved have no depth (0): only the static
    scene is verified; the median depth keeps them (the floor where most frames saw the floor:
    the top-down floor image, ``prepare_camera``)."""
    if len(greys) == 1:
        return greys[0], depths[0], depths[0]
    g = np.median(np.stack(greys), axis=0).astype(np.uint8)
    D = np.stack(depths)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            d = nanmedian_frames(np.where(D > 0, D, np.nan))
            # a pixel something moved through has no single depth: the median of frames that saw
            # the person and frames that saw the floor is a surface that never existed, and the
            # verification (which compares median depths) would count it against a right pose
            moved = np.nanmax(np.where(D > 0, np.abs(D - d), np.nan), axis=0) > np.maximum(
                DYNAMIC_MIN_M, DYNAMIC_REL * d
            )
    d = np.nan_to_num(d, nan=0.0).astype(np.float32)
    return g, np.where(moved, 0.0, d).astype(np.float32), d


def nanmedian_frames(X: np.ndarray) -> np.ndarray:
    """``numpy.nanmedian(X, axis=0)`` of a (F, H, W) float stack, the same values (the mean of the
    two middle values in X's dtype; NaN where a pixel has none) from one sort. numpy's small-axis
    path goes through masked arrays and issues one (filtered) warning per all-NaN pixel: 10x
    slower on a 512x424 camera's 10 frames."""
    S = np.sort(X, axis=0)  # NaN last
    n = np.count_nonzero(~np.isnan(X), axis=0)
    h = n // 2
    low = np.take_along_axis(S, np.maximum(np.where(n % 2 == 1, h, h - 1), 0)[None], axis=0)[0]
    high = np.take_along_axis(S, np.minimum(h, len(X) - 1)[None], axis=0)[0]
    out = (low + high) / X.dtype.type(2)
    out[n == 0] = np.nan
    return out


def _backproject(depth: np.ndarray, K: np.ndarray, stride: int = 1) -> np.ndarray:
    """(M, 3) float64 camera-frame points of the pixels with depth (every ``stride``-th)."""
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
    z = depth[::stride, ::stride].astype(np.float64)
    m = z > 0
    z, u, v = z[m], u[m], v[m]
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)


def _image_matcher(cfg: RGBDConfig) -> Matcher:
    """The image matcher of cfg (loaded once per process; SIFT with cfg's features and ratio)."""
    if cfg.matcher == "sift":
        return get_matcher("sift", cfg.sift_features, cfg.ratio)
    return get_matcher(cfg.matcher)


#: Half-width (pixels) of the window whose depth lifts a keypoint (``_lift_keypoints``): 5x5.
LIFT_HALF = 2


def _lift_keypoints(
    matcher: Matcher, image: np.ndarray, depth: np.ndarray, K: np.ndarray
) -> tuple[np.ndarray, ImageFeatures]:
    """The matcher's keypoints of one (H, W, 3) uint8 image with valid depth, as camera-frame
    points (Q, 3) and their features. Depth: a least-squares plane through the (2 LIFT_HALF + 1)^2
    window around the nearest pixel, evaluated at the keypoint's sub-pixel position; only where
    every pixel has depth and none is more than 2 % of the depth off that plane (keypoints sit on
    edges; a depth edge gives no point). The depth at the rounded pixel was up to half a pixel's
    depth gradient off (~6 mm on the floor at 3 m), the same in every frame of a static scene, so
    pooling frames did not average it out (docs/history.md, 2026-11-24, "multi-frame pooling")."""
    feats = matcher.extract(image)
    if not len(feats):
        return np.zeros((0, 3)), feats
    uv = feats.uv
    h, w = depth.shape
    r = LIFT_HALF
    ui = np.clip(np.rint(uv[:, 0]).astype(int), r, w - 1 - r)
    vi = np.clip(np.rint(uv[:, 1]).astype(int), r, h - 1 - r)
    offs = np.array([(dv, du) for dv in range(-r, r + 1) for du in range(-r, r + 1)], dtype=np.float64)
    win = np.stack([depth[vi + int(dv), ui + int(du)] for dv, du in offs], axis=1).astype(np.float64)
    A = np.c_[np.ones(len(offs)), offs[:, 1], offs[:, 0]]  # z = c0 + c1 du + c2 dv
    coef = win @ np.linalg.pinv(A).T
    z = coef[:, 0] + coef[:, 1] * (uv[:, 0] - ui) + coef[:, 2] * (uv[:, 1] - vi)
    off_plane = np.abs(win - coef @ A.T).max(axis=1)
    ok = (win > 0).all(axis=1) & (z > 0) & (off_plane < 0.02 * np.maximum(z, 1e-6))
    uv, z = uv[ok], z[ok]
    X = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0] * z, (uv[:, 1] - K[1, 2]) / K[1, 1] * z, z], axis=1)
    return X, feats.subset(ok)


def _samples(depth: np.ndarray, K: np.ndarray, plane: FloorPlane | None, cfg: RGBDConfig):
    """Verification points on a regular grid (about cfg.samples), their floor flags, and the
    subsampled depth with its intrinsics (pixel centres at integer coordinates)."""
    from fuseflow.geometry import subsample_stride

    h, w = depth.shape
    s = subsample_stride(h, w, cfg.samples)
    d = depth[::s, ::s]
    Ks = K.copy()
    Ks[:2, :] /= s
    X = _backproject(d, Ks)
    fm = np.zeros(d.shape, dtype=bool) if plane is None else floor_mask(d, Ks, plane, cfg.floor_band)
    on_floor = fm[d > 0]
    return (
        torch.from_numpy(X.astype(np.float32)),
        torch.from_numpy(on_floor),
        torch.from_numpy(np.ascontiguousarray(d, dtype=np.float32)),
        torch.from_numpy(Ks.astype(np.float32)),
    )


# ----------------------------------------------------------------------------- verification


def verify_pose(a: CameraEvidence, b: CameraEvidence, T_ba: np.ndarray, tau: float) -> PairCheck:
    """Depth agreement and free-space check of the candidate ``T_ba`` (camera a's coordinates
    to camera b's, (4, 4) metres) in both directions (see PairCheck)."""
    agree = vote = s_agree = s_vote = viol = has = 0
    for src, dst, T in ((a, b, T_ba), (b, a, invert_rigid(T_ba))):
        M = torch.from_numpy(T[:3, :].astype(np.float32))
        ag, vo = project_votes(src.samples_X, M, dst.K_sub, dst.depth_sub, tau, True)
        _, present = project_votes(src.samples_X, M, dst.K_sub, dst.depth_sub, tau, False)
        off = ~src.samples_floor
        agree += int(ag.sum())
        vote += int(vo.sum())
        s_agree += int((ag & off).sum())
        s_vote += int((vo & off).sum())
        viol += int((vo & ~ag).sum())
        has += int(present.sum())
    return PairCheck(
        agreement=agree / vote if vote else 0.0,
        structure_agreement=s_agree / s_vote if s_vote else float("nan"),
        free_space=viol / has if has else 1.0,
        agree=agree,
        structure_votes=s_vote,
    )


# ----------------------------------------------------------------------------- pairs


def _match(da: np.ndarray, db: np.ndarray, ratio: float) -> np.ndarray:
    """(K, 2) index pairs of ratio-test SIFT matches from descriptors a to b."""
    import cv2

    if len(da) < 2 or len(db) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    out = [(m[0].queryIdx, m[0].trainIdx) for m in knn if len(m) == 2 and m[0].distance < ratio * m[1].distance]
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def _ransac_sequential(fit_batch, fit_refine, residual, thr, m: int, k_min: int, cfg: RGBDConfig, seed: int):
    """Sequential RANSAC: up to cfg.hypotheses models, each the largest consensus of the matches
    the previous ones did not explain. fit_batch(idx (H, k_min)) -> models (H, 4, 4);
    residual(models (H, 4, 4), idx) -> (H, |idx|) distances, residual(models, idx, thr_idx) ->
    (H,) counts of distances under thr_idx (``calib.backbones.rgbd.ransac_kernels``); thr (m,) per-match threshold.
    Returns [(model (4, 4), inlier indices)]."""
    rng = np.random.default_rng(seed)
    left = np.arange(m)
    out = []
    for _ in range(cfg.hypotheses):
        if len(left) < max(cfg.min_inliers, k_min):
            break
        iters = cfg.ransac_iterations if k_min > 2 else cfg.ransac_iterations // 2
        idx = rng.integers(0, len(left), size=(iters, k_min))
        distinct = np.all(np.sort(idx, axis=1)[:, 1:] != np.sort(idx, axis=1)[:, :-1], axis=1)
        idx = idx[distinct]
        models = fit_batch(left[idx])
        ok = np.all(np.isfinite(models), axis=(1, 2))
        models = models[ok]
        if not len(models):
            break
        best = int(np.argmax(residual(models, left, thr[left])))
        sel = left[residual(models[best][None], left)[0] < thr[left]]
        if len(sel) < cfg.min_inliers:
            break
        model = models[best]
        for _ in range(3):  # refit on the consensus, re-collect
            model = fit_refine(sel)
            new = left[residual(model[None], left)[0] < thr[left]]
            if len(new) < cfg.min_inliers:
                break
            sel = new
        out.append((model, sel))
        left = np.setdiff1d(left, sel)
    return out


def _f64(a: np.ndarray) -> np.ndarray:
    """a as a C-contiguous float64 array (the compiled residuals' input; exact for float32)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _planar_models(pa: np.ndarray, pb: np.ndarray) -> callable:
    """Batched 2-point rigid 2-D fits pb ~ R(theta) pa + t, as 4x4 floor-frame transforms."""

    def fit(idx: np.ndarray) -> np.ndarray:
        A, B = pa[idx], pb[idx]  # (H, k, 2)
        ca, cb = A.mean(axis=1), B.mean(axis=1)
        a, b = A - ca[:, None], B - cb[:, None]
        s = np.sum(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0], axis=1)
        c = np.sum(a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1], axis=1)
        th = np.arctan2(s, c)
        T = np.tile(np.eye(4), (len(idx), 1, 1))
        T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = np.cos(th), -np.sin(th), np.sin(th), np.cos(th)
        T[:, :2, 3] = cb - np.einsum("hij,hj->hi", T[:, :2, :2], ca)
        if idx.shape[1] == 2:  # minimal sample: the two distances must agree
            la = np.linalg.norm(A[:, 0] - A[:, 1], axis=1)
            lb = np.linalg.norm(B[:, 0] - B[:, 1], axis=1)
            T[np.abs(la - lb) > 0.05 + 0.02 * la] = np.nan
        return T

    return fit


def _floor_candidates(a: CameraEvidence, b: CameraEvidence, cfg: RGBDConfig, frame_pairs) -> list[dict]:
    """Candidates of the two 4-DoF routes: ``floor`` (top-down SIFT) and ``sift4`` (image SIFT
    matches expressed on the floor). frame_pairs: (X_a (K, 3), X_b (K, 3)) pooled 3-D matches."""
    if a.plane is None or b.plane is None:
        return []
    from fuseflow.calib.backbones.rgbd.ransac_kernels import planar_counts

    Fa, Fb = a.plane.T_cam_floor(), b.plane.T_cam_floor()
    out = []
    routes = []
    if len(a.td_desc) and len(b.td_desc):
        mm = _match(a.td_desc, b.td_desc, cfg.ratio)
        if len(mm):
            pa, pb = a.td_xy[mm[:, 0]], b.td_xy[mm[:, 1]]
            za = np.zeros(len(pa))
            routes.append(("floor", pa, pb, za, za, None, None))
    Xa, Xb = frame_pairs
    if len(Xa):
        Pa = (Xa - Fa[:3, 3]) @ Fa[:3, :3]  # floor coordinates
        Pb = (Xb - Fb[:3, 3]) @ Fb[:3, :3]
        routes.append(("sift4", Pa[:, :2], Pb[:, :2], Pa[:, 2], Pb[:, 2], Xa, Xb))
    for route, pa, pb, ha, hb, Xa_, Xb_ in routes:
        fit = _planar_models(pa, pb)
        thr_h = cfg.floor_inlier_m if route == "floor" else cfg.inlier_m + cfg.inlier_rel * Xb_[:, 2]
        thr = np.broadcast_to(
            np.asarray(cfg.floor_inlier_m if route == "floor" else thr_h, dtype=np.float64), (len(pa),)
        )

        def residual(models, idx, thr_idx=None, pa=pa, pb=pb, ha=ha, hb=hb):
            dh = np.abs(ha[idx] - hb[idx])  # heights must agree too
            if thr_idx is not None:
                return planar_counts(models, _f64(pa[idx]), _f64(pb[idx]), _f64(dh), _f64(thr_idx))
            q = np.einsum("hij,kj->hki", models[:, :2, :2], pa[idx]) + models[:, None, :2, 3]
            return np.maximum(np.linalg.norm(q - pb[idx][None], axis=2), dh[None])

        models = _ransac_sequential(fit, lambda s, fit=fit: fit(s[None])[0], residual, thr, len(pa), 2, cfg, cfg.seed)
        for model, sel in models:
            T_ba = Fb @ model @ invert_rigid(Fa)
            if route == "floor":
                Xa_s = np.c_[pa[sel], np.zeros(len(sel))] @ Fa[:3, :3].T + Fa[:3, 3]
                Xb_s = np.c_[pb[sel], np.zeros(len(sel))] @ Fb[:3, :3].T + Fb[:3, 3]
            else:
                Xa_s, Xb_s = Xa_[sel], Xb_[sel]
            out.append({"route": route, "T_ba": T_ba, "inliers": int(len(sel)), "X_a": Xa_s, "X_b": Xb_s})
    return out


def _sift3d_candidates(Xa: np.ndarray, Xb: np.ndarray, cfg: RGBDConfig) -> list[dict]:
    """6-DoF 3-D RANSAC (Kabsch) on depth-lifted image matches."""
    if len(Xa) < max(cfg.min_inliers, 3):
        return []
    from fuseflow.calib.backbones.rgbd.ransac_kernels import rigid_counts

    thr = cfg.inlier_m + cfg.inlier_rel * Xb[:, 2]

    def fit(idx):
        T = kabsch(Xa[idx], Xb[idx])
        if idx.shape[1] == 3:  # minimal sample: reject near-degenerate (collinear, tiny) triples
            A = Xa[idx]
            area = np.linalg.norm(np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0]), axis=1)
            T[area < 0.01] = np.nan
        return T

    def residual(models, idx, thr_idx=None):
        if thr_idx is not None:
            return rigid_counts(models, _f64(Xa[idx]), _f64(Xb[idx]), _f64(thr_idx))
        q = np.einsum("hij,kj->hki", models[:, :3, :3], Xa[idx]) + models[:, None, :3, 3]
        return np.linalg.norm(q - Xb[idx][None], axis=2)

    models = _ransac_sequential(fit, lambda s: fit(s[None])[0], residual, thr, len(Xa), 3, cfg, cfg.seed + 1)
    return [{"route": "sift3d", "T_ba": T, "inliers": int(len(s)), "X_a": Xa[s], "X_b": Xb[s]} for T, s in models]


#: Matches of different frames whose keypoints are within this many pixels of each other in both
#: images (Chebyshev distance over the four coordinates) are one scene point (``merge_repeats``).
SAME_MATCH_PX = 1.0


def _pooled_matches(a: CameraEvidence, b: CameraEvidence, cfg: RGBDConfig) -> tuple[np.ndarray, np.ndarray]:
    """3-D matches of the image route (cfg.matcher), pooled over frames (same instant in both
    cameras), a static point matched in several frames counted once (``merge_repeats``)."""
    XA, XB, UV = [], [], []
    for (xa, da), (xb, db) in zip(a.kp, b.kp):
        mm = _image_matcher(cfg).match(da, db)
        XA.append(xa[mm[:, 0]])
        XB.append(xb[mm[:, 1]])
        UV.append(np.c_[da.uv[mm[:, 0]], db.uv[mm[:, 1]]])
    if not XA:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return merge_repeats(np.concatenate(UV), np.concatenate(XA), np.concatenate(XB))


def merge_repeats(uv: np.ndarray, Xa: np.ndarray, Xb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One 3-D match per scene point: matches (uv (M, 4) pixel coordinates in image a then b,
    Xa, Xb (M, 3) their lifted points) whose keypoints lie within ``SAME_MATCH_PX`` of each other
    in both images (chains of them) become one, at the mean of their points, in the order of
    their first member. A static rig re-detects the same keypoints in every frame, with the same
    localisation error (the image is the same, only the depth noise differs): pooled k times, one
    keypoint's error counted k times against the floor route's, computed once from the median
    image, and pooling 10 frames came out less accurate than 1 (docs/history.md, "multi-frame
    pooling"). The mean keeps the depth noise averaged over the frames."""
    if len(uv) < 2:
        return Xa, Xb
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(uv).query_pairs(SAME_MATCH_PX, p=np.inf, output_type="ndarray")
    m = len(uv)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(m, m))
    k, label = connected_components(graph, directed=False)
    count = np.bincount(label, minlength=k)[:, None]
    A, B = np.zeros((k, 3)), np.zeros((k, 3))
    np.add.at(A, label, Xa)
    np.add.at(B, label, Xb)
    return A / count, B / count


#: Verified candidates of a pair are ranked by their agreeing samples at this share of tau (the
#: pass / fail test stays at tau): tau = 5 % cannot tell 0.1 deg from 1 deg (``_better``).
RANK_TAU_SHARE = 0.2


def _person_route(frames: list[Frame], rig: Rig, order: list[int], cfg: RGBDConfig):
    """(``people.PersonRoute`` over the frames, None) or (None, the one-line reason it is skipped)."""
    if not cfg.people:
        return None, "skipped: RGBDConfig.people is off"
    from fuseflow.calib.people import MediapipePoseDetector, PeopleConfig, PersonRoute, people_unavailable

    reason = people_unavailable()
    if reason is not None:
        return None, f"skipped: {reason}"
    detector = MediapipePoseDetector()
    return PersonRoute(frames, rig, order, detector, PeopleConfig(seed=cfg.seed)), None


def _subject_route(frames: list[Frame], rig: Rig, order: list[int], cams: list[CameraEvidence], cfg: RGBDConfig):
    """``subject.SubjectRoute`` over the frames (route (e)), or None (off, or under 3 frames)."""
    from fuseflow.calib.subject import MIN_FRAMES, SubjectRoute

    if not cfg.subject or len(frames) < MIN_FRAMES:
        return None
    return SubjectRoute.build(frames, rig, order, [c.plane for c in cams])


def _pair_edges(cams: list[CameraEvidence], cfg: RGBDConfig, people=None, subject=None):
    """Candidates, verification and the accepted edge of every camera pair (canonical order);
    ``people``: a ``people.PersonRoute`` adding route (d)'s candidates, or None. Returns (edges:
    the best plausible candidate of each pair, per-pair info, hypotheses: pair -> its distinct
    plausible verified poses, best first, for the joint choice)."""
    edges: dict[tuple[int, int], Edge] = {}
    hyps: dict[tuple[int, int], list[Hypothesis]] = {}
    info = []
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            a, b = cams[i], cams[j]
            Xa, Xb = _pooled_matches(a, b, cfg)
            cands = _floor_candidates(a, b, cfg, (Xa, Xb)) + _sift3d_candidates(Xa, Xb, cfg)
            cands += people.pair(i, j) if people is not None else []
            cands += subject.pair(i, j) if subject is not None else []
            judge = _subject_judge(a, b, cands, cfg, subject, i, j)
            rows, passing = [], []
            for c in cands:
                chk = verify_pose(a, b, c["T_ba"], cfg.tau)
                ok = chk.passes(cfg) or (c["route"] == "subject" and judge is not None)
                rows.append({"route": c["route"], "inliers": c["inliers"], "ok": ok, **_round(chk),
                             "T_ji": np.round(c["T_ba"], 6).tolist()})  # fmt: skip
                if judge is not None and (verdict := judge(c["T_ba"])) is not None:
                    rows[-1]["subject_m"] = round(verdict, 4)
                    if ok and verdict > judge.limit:  # the person says no (calib.subject)
                        rows[-1].update(ok=False, rejected="subject")
                        ok = False
                if ok and not plausible(c["T_ba"], chk, cfg, _median_depth(a, b)):
                    # stacked on the other camera: rejected, not scored (calib.symmetry)
                    rows[-1].update(ok=False, rejected="co-located")
                    ok = False
                if ok and not _subject_ok(a, b, c["T_ba"], cfg, rows[-1]):
                    ok = False  # the other camera sees through its subject: an alias (calib.symmetry)
                # rank by how much depth confirms the pose, not by the share alone: a wrong pose
                # that turns the cameras apart leaves a sliver of overlap that agrees 100 %
                # (ICL, 40 frames apart: 529 samples at 1.0 against 7800 at 0.98); counted at
                # RANK_TAU_SHARE of tau, which tells a 0.5-deg pose from a 2.3-deg one (at tau
                # the 2.3-deg one agreed on more samples than the true pose: docs/gmac.md)
                if ok:
                    fine = verify_pose(a, b, c["T_ba"], cfg.tau * RANK_TAU_SHARE).agree
                    rows[-1]["agree_fine"] = fine
                    passing.append(Hypothesis(i, j, c["T_ba"], float(fine), (c, chk, cands)))
            entry = {"pair": [i, j], "matches": int(len(Xa)), "candidates": rows, "edge": None}
            progress.report("rgbd: pairs", len(info) + 1, len(cams) * (len(cams) - 1) // 2)
            kept = distinct_hypotheses(passing, JOINT_ROT_DEG, JOINT_TRANS_M, cfg.pair_hypotheses)
            if kept:
                hyps[(i, j)] = kept
                edges[(i, j)], entry["edge"] = _edge_of(a, b, kept[0], cfg)
                entry["hypotheses"] = len(kept)
            info.append(entry)
    return edges, info, hyps


#: A candidate whose head tracks stay further apart than this (metres, median) is refuted, or
#: than the subject's own pose leaves them plus SUBJECT_MARGIN_M, whichever is smaller: at
#: 3.5-4 m a pose 0.5 deg off moves the head 3 cm; a right pose of another route (a textured
#: near-range studio: 0.05 deg / 3 mm where the subject's was 0.2 deg / 12 mm) stays within it.
SUBJECT_REFUTE_M, SUBJECT_MARGIN_M = 0.08, 0.03


@dataclass(frozen=True)
class _SubjectJudge:
    """The subject's judge of one pair: pose -> median head-track residual (metres) over the
    subject pose's inlier frames; a candidate beyond ``limit`` is refuted."""

    route: object
    i: int
    j: int
    frames: np.ndarray
    limit: float

    def __call__(self, T_ba: np.ndarray) -> float | None:
        got = self.route.judge(self.i, self.j, T_ba, self.frames)
        return None if got is None else got[0]


def _subject_judge(a: CameraEvidence, b: CameraEvidence, cands: list[dict], cfg: RGBDConfig, subject, i: int, j: int):
    """The subject's judge of pair (i, j) (``_SubjectJudge``), or None: no subject candidate, or
    it fails the depth checks on the static scene (agreement, free space), so the two views may
    have tracked different things."""
    own = [c for c in cands if c["route"] == "subject"]
    if subject is None or not own:
        return None
    chk = verify_pose(a, b, own[0]["T_ba"], cfg.tau)
    if chk.agreement < cfg.min_agreement or chk.free_space > cfg.max_free_space or chk.agree < cfg.min_agree_points:
        return None
    judge = _SubjectJudge(subject, i, j, own[0]["inliers_mask"], SUBJECT_REFUTE_M)
    base = judge(own[0]["T_ba"])
    if base is None:
        return None
    return _SubjectJudge(subject, i, j, judge.frames, min(SUBJECT_REFUTE_M, base + SUBJECT_MARGIN_M))


def _subject_ok(a: CameraEvidence, b: CameraEvidence, T_ba: np.ndarray, cfg: RGBDConfig, row: dict) -> bool:
    """The subject check of a verified pose (``symmetry.subject_free_space``, at tau): False
    (``row`` marked rejected) when the other camera sees through more than SUBJECT_MAX_FREE_SPACE
    of the subject points it sees, with at least SUBJECT_MIN_POINTS of them."""
    share, seen = subject_free_space(a, b, T_ba, cfg.tau)
    if seen < SUBJECT_MIN_POINTS:
        return True
    row["subject_free_space"] = round(share, 4)
    if share > SUBJECT_MAX_FREE_SPACE:
        row.update(ok=False, rejected="subject seen through")
        return False
    return True


def _median_depth(a: CameraEvidence, b: CameraEvidence) -> float:
    """The median depth (metres) of two cameras' verification points."""
    z = torch.cat([a.samples_X[:, 2], b.samples_X[:, 2]])
    return float(z.median()) if len(z) else 0.0


def _edge_of(a: CameraEvidence, b: CameraEvidence, h: Hypothesis, cfg: RGBDConfig) -> tuple[Edge, dict]:
    """The edge of hypothesis ``h`` (refit on every route's correspondences it explains) and its
    info entry."""
    c, chk, cands = h.ref
    # route (e)'s floor points restate its own pose: evidence for its edge only
    cands = [x for x in cands if x["route"] != "subject" or x is c]
    c, chk = _refit(a, b, c, chk, cands, cfg)
    X_i, X_j = _support(c["T_ba"], cands, cfg)
    sigma = cfg.sigma0 + cfg.sigma2 * X_j[:, 2] ** 2
    entry = {"route": c["route"], "agreement": round(chk.agreement, 4), "support": int(len(X_i)),
             "T_ji": np.round(c["T_ba"], 6).tolist()}  # fmt: skip
    entry.update({k: round(c[k], 4) for k in ("expected_m", "spread_m", "track_frames") if k in c})  # route (e)
    return Edge(h.i, h.j, c["T_ba"], float(chk.agree), X_i, X_j, sigma), entry


#: Tolerance of the joint choice (hypotheses closer than this are one; a pair agrees with a
#: solution within it): wider than the cycle test's (2 deg / 8 cm), since a growth chains
#: unrefined poses (hocap-8rs: at 2 deg / 8 cm 5 right pairs fell out); an alias of a 12-fold room
#: is 30 deg away.
JOINT_ROT_DEG, JOINT_TRANS_M = 5.0, 0.2
#: A verified hypothesis this far (deg) from the chosen solution is an alias (``_refutes``).
ALIAS_MIN_DEG = 10.0
#: The joint choice compares the best solutions (``symmetry.select_consistent``: at most this
#: many, with at most one consistent pair fewer than the best) by ``_views_agreement``.
JOINT_SOLUTIONS = 8
#: ``_views_agreement``'s depth tolerance, a share of tau (2 % at tau = 5 %): symstudio seed 0,
#: every pair of the 5 cameras: true poses 0.88 overall / 0.82 on the subject, the solution of two
#: agreeing wrong edges 0.80 / 0.71 (at tau: 0.97 / 0.91 against 0.93 / 0.85).
VIEWS_TAU_SHARE = 0.4
#: The subject: points within this distance (metres, horizontally) of the point nearest to every
#: camera's optical axis, where a studio's cameras converge (``_views_agreement``).
SUBJECT_RADIUS_M = 1.0
#: A lone camera (``_joint_choice``) whose chosen pose beats each rival pose by at least this much
#: ``_views_agreement`` with the other cameras is not ambiguous.
AMBIGUITY_MARGIN = 0.05
#: With at least this many pairs whose verified poses include one the chosen solution refutes,
#: the room repeats: every camera outside the solution's main cycle-checked group
#: (``symmetry.main_block``) is ambiguous, and the geometry-only route places none of them.
ALIASED_PAIRS = 2


def _joint_choice(cams, edges: dict, hyps: dict, info: list[dict], ids: list[str], cfg: RGBDConfig):
    """Choose each pair's hypothesis jointly: the consistent solutions of
    ``symmetry.select_consistent``, the best few compared by ``_views_agreement``; the edges of
    the chosen hypotheses (other pairs lose theirs), and the ambiguous cameras (``_ambiguous``),
    which lose their edges. Returns (edges, info, ambiguous camera indices)."""
    flat = [h for hs in hyps.values() for h in hs]
    sols = select_consistent(flat, JOINT_ROT_DEG, JOINT_TRANS_M, cfg.min_separation)
    top = [sol for sol in sols if len(sol.chosen) >= len(sols[0].chosen) - 1][:JOINT_SOLUTIONS]
    views = [_views_agreement(cams, sol.poses, cfg) for sol in top] if len(top) > 1 else [float("nan")]
    best = top[int(np.nanargmax(views))] if len(top) > 1 else top[0]
    chosen = {p: flat[k] for p, k in best.chosen.items()}
    by_pair = {tuple(e["pair"]): e for e in info}
    out = {}
    for p, h in chosen.items():
        if h is hyps[p][0]:
            out[p] = edges[p]
        else:
            out[p], entry = _edge_of(cams[p[0]], cams[p[1]], h, cfg)
            by_pair[p]["edge"] = {**entry, "joint_choice": True}
    for p in set(edges) - set(out):
        by_pair[p]["edge"] = None
        by_pair[p]["not_consistent"] = True
    refuted = sorted(p for p, hs in hyps.items() if set(p) <= set(best.poses) and _refutes(hs, best.poses))
    if len(refuted) >= ALIASED_PAIRS:
        block = main_block(sorted(out))
        names = ", ".join(f"{ids[a]}-{ids[b]}" for a, b in refuted[:4]) + (" ..." if len(refuted) > 4 else "")
        held = _subject_held(cams, out, chosen, hyps, block, cfg)
        ambiguous = {k: (f"ambiguous: the room repeats ({len(refuted)} pairs have verified poses the consistent "
                         f"solution refutes: {names}) and no cycle checks this camera against the main group")
                     for k in sorted({k for p in out for k in p} - block - held)}  # fmt: skip
    else:
        ambiguous = _ambiguous(cams, out, chosen, hyps, best.poses, ids, cfg)
    out = {p: e for p, e in out.items() if not set(p) & set(ambiguous)}
    sel = {"solutions": len(sols), "compared": [round(v, 4) for v in views], "consistent_pairs": len(chosen),
           "refuted_pairs": len(refuted), "ambiguous": {ids[k]: r for k, r in ambiguous.items()}}  # fmt: skip
    return out, sel, set(ambiguous) | (set(range(len(cams))) - block if len(refuted) >= ALIASED_PAIRS else set())


def _subject_held(cams, out: dict, chosen: dict, hyps: dict, block: set[int], cfg: RGBDConfig) -> set[int]:
    """Cameras outside the cycle-checked ``block`` that are not ambiguous: one of their chosen
    pair poses is the pair's only remaining hypothesis and the subject confirms it
    (``symmetry.subject_free_space`` on at least SUBJECT_MIN_POINTS points, within
    SUBJECT_MAX_FREE_SPACE): the alternatives were refuted. They stay placed, unchecked by a cycle
    (the verdict says "check it")."""
    held = set()
    for p in out:
        if len(hyps[p]) != 1 or set(p) <= block:
            continue
        h = chosen[p]
        share, seen = subject_free_space(cams[h.i], cams[h.j], h.T_ji, cfg.tau)
        if seen >= SUBJECT_MIN_POINTS and share <= SUBJECT_MAX_FREE_SPACE:
            held |= set(p) - block
    return held


def _refutes(hs: list[Hypothesis], poses: dict) -> bool:
    """Does a solution (``poses``) refute one of a pair's verified hypotheses by more than
    ALIAS_MIN_DEG (an alias, not the noise of a right pose)?"""
    for h in hs:
        r, _ = pose_gap(h.T_ji @ poses[h.i], poses[h.j])
        if r > ALIAS_MIN_DEG:
            return True
    return False


def _ambiguous(cams, out: dict, chosen: dict, hyps: dict, poses: dict, ids: list[str], cfg: RGBDConfig) -> dict:
    """Camera -> reason, for the cameras held only by edges on no cycle (``symmetry.bridges``) one
    of whose pairs has another passing hypothesis scoring at least ``ambiguity_ratio`` of the
    chosen one, unless the chosen pose agrees better with all other views by AMBIGUITY_MARGIN."""
    lone = bridges(sorted(out))
    found = {}
    for k in sorted({k for p in out for k in p}):
        mine = [p for p in out if k in p]
        if any(p not in lone for p in mine) or k not in poses:
            continue
        for p in mine:
            rivals = [h for h in hyps[p] if h is not chosen[p] and h.score >= cfg.ambiguity_ratio * chosen[p].score]
            other = p[0] if p[1] == k else p[1]
            here = _views_agreement(cams, poses, cfg, only=k)
            margins = []
            for h in rivals:
                T = h.T_ji @ poses[other] if k == h.j else invert_rigid(h.T_ji) @ poses[other]
                margins.append(here - _views_agreement(cams, {**poses, k: T}, cfg, only=k))
            if rivals and min(margins) < AMBIGUITY_MARGIN:
                found[k] = (
                    f"ambiguous: its only link {ids[p[0]]}-{ids[p[1]]} closes no cycle and has {len(rivals) + 1} "
                    f"verified poses {_gap(chosen[p], rivals[0]):.0f} deg apart that score alike and agree alike "
                    f"with the other views (margin {min(margins):.3f}): a repeating room; nothing tells them apart"
                )
                break
    return found


def _views_agreement(cams, poses: dict, cfg: RGBDConfig, only: int | None = None) -> float:
    """What all views say of a solution (``poses``: camera -> camera-from-world): the mean of the
    share of agreeing votes over every ordered pair of placed cameras (tolerance VIEWS_TAU_SHARE
    of tau) and the same share on the subject (points within SUBJECT_RADIUS_M of the cameras'
    convergence point): the subject does not repeat, the walls may. ``only``: pairs with that
    camera only. NaN without votes."""
    ks = sorted(poses)
    world = {k: invert_rigid(poses[k]) for k in ks}
    A, b = np.zeros((3, 3)), np.zeros(3)
    for k in ks:
        d = world[k][:3, 2]
        M = np.eye(3) - np.outer(d, d)
        A, b = A + M, b + M @ world[k][:3, 3]
    centre = np.linalg.lstsq(A, b, rcond=None)[0]
    tau = cfg.tau * VIEWS_TAU_SHARE
    n = np.zeros(4)  # agree, votes, subject agree, subject votes
    for x in ks:
        Xw = cams[x].samples_X.numpy().astype(np.float64) @ world[x][:3, :3].T + world[x][:3, 3]
        subject = torch.from_numpy(np.linalg.norm(Xw[:, :2] - centre[:2], axis=1) < SUBJECT_RADIUS_M)
        for y in ks:
            if x == y or (only is not None and only not in (x, y)):
                continue
            M = torch.from_numpy((poses[y] @ world[x])[:3, :].astype(np.float32))
            ag, vo = project_votes(cams[x].samples_X, M, cams[y].K_sub, cams[y].depth_sub, tau, True)
            n += [int(ag.sum()), int(vo.sum()), int((ag & subject).sum()), int((vo & subject).sum())]
    if not n[1]:
        return float("nan")
    return 0.5 * n[0] / n[1] + 0.5 * (n[2] / n[3] if n[3] else n[0] / n[1])


def _gap(h: Hypothesis, g: Hypothesis) -> float:
    return rotation_angle_deg(h.T_ji[:3, :3] @ g.T_ji[:3, :3].T)


def _geometric_edges(
    cams: list[CameraEvidence],
    T: np.ndarray,
    placed: np.ndarray,
    edges: dict[tuple[int, int], Edge],
    cfg: RGBDConfig,
    exclude: set[int] = frozenset(),
) -> tuple[dict[tuple[int, int], Edge], list[dict], tuple]:
    """Route (c) (:mod:`fuseflow.calib.geometric`) on every pair with an unplaced camera and no
    edge yet. A pair's passing pose cluster with the most ICP starts is its candidate when at
    least ``geometric_min_starts`` starts reached it and at least twice as many as reached any
    other passing pose. Candidates become edges in rounds, from the placed cameras outwards
    (pairs of two unplaced cameras wait while anything is placed, so that their pose can be
    judged against every placed view, ``_better``); after each round the poses are re-solved.
    Within a round, an unplaced camera's pairs are run in order of descriptor consensus
    (``RansacStarts.consensus``) until it has ``geometric_edges_per_camera`` candidates; the
    rest wait in case it is still unplaced after the round. Cameras in ``exclude`` (ambiguous
    ones, ``_joint_choice``) get no candidate. Returns (new edges, per-pair info, (kept, dropped, untested, T, placed, refine info) of the
    last solve, or None when nothing was added)."""
    from fuseflow.calib.geometric import RansacStarts, ransac_starts

    feat = _cloud_cache(cams, cfg)
    n = len(cams)
    todo = [(i, j) for i in range(n) for j in range(i + 1, n)
            if not (placed[i] and placed[j]) and (i, j) not in edges and not {i, j} & exclude]  # fmt: skip
    cands: dict[tuple[int, int], tuple] = {}
    starts: dict[tuple[int, int], RansacStarts] = {}
    info = []
    out: dict[tuple[int, int], Edge] = {}
    solved = None
    while True:
        # a pair's candidates are computed when a round first considers it: a pair of two
        # unplaced cameras waits while anything is placed, and is never needed when both are
        # placed in the same round (hocap-8rs: 12 of its 13 pairs were needed)
        due = [e for e in todo if not (placed.any() and placed[e[0]] == placed[e[1]])]
        cap = cfg.geometric_edges_per_camera if placed.any() and cfg.geometric_edges_per_camera < n else None
        if cap is not None:  # most consensus first; a camera with `cap` candidates skips the rest
            for e in due:
                if e not in starts:
                    starts[e] = ransac_starts(feat(e[0]), feat(e[1]), cfg.geometric_starts, seed=cfg.seed + 2)
            due = sorted(due, key=lambda e: (-starts[e].consensus, e))
        found: dict[int, int] = {}
        for i, j in due:
            u = j if placed[i] else i  # the unplaced camera of the pair
            if cap is not None and found.get(u, 0) >= cap:
                continue  # stays in todo: needed again only if u is unplaced after this round
            todo.remove((i, j))
            entry, cand = _geometric_pair(cams, i, j, feat, cfg, starts.get((i, j)))
            info.append(entry)
            if cand is not None:
                cands[(i, j)] = cand
                found[u] = found.get(u, 0) + 1
        new = {}
        for i, j in sorted(cands):
            c, chk, entry = cands[(i, j)]
            if (i, j) in out or (placed.any() and placed[i] == placed[j]):
                continue
            a, b = cams[i], cams[j]
            T_ba, X_a, X_b, how = c.T_ba, c.X_a, c.X_b, "icp"
            # the ICP pose, or the rigid fit of the descriptor matches it explains: on clean
            # geometry ICP is the more precise (synthetic pair: 0.1 vs 1.2 deg), on hocap-8rs the
            # fit (ICP slides on the up-looking cameras' overlap); ``_better`` decides
            if len(c.M_a) >= 6:
                T_fit = kabsch(c.M_a[None], c.M_b[None])[0]
                chk_fit = verify_pose(a, b, T_fit, cfg.tau)
                if chk_fit.passes(cfg) and _better(cams, T, placed, i, j, T_fit, T_ba, cfg):
                    T_ba, X_a, X_b, chk, how = T_fit, c.M_a, c.M_b, chk_fit, "descriptor fit"
            sigma = np.maximum(cfg.geometric_voxel / 2, cfg.sigma0 + cfg.sigma2 * X_b[:, 2] ** 2)
            new[(i, j)] = Edge(i, j, T_ba, float(chk.agree), X_a, X_b, sigma)
            entry["edge"] = {"route": "geometric", "pose": how, "agreement": round(chk.agreement, 4),
                             "starts": c.starts, "support": int(len(X_a)), "T_ji": np.round(T_ba, 6).tolist()}  # fmt: skip
        if not new:
            return out, info, solved
        out.update(new)
        kept, dropped, untested = prune_cycles({**edges, **out}, cfg.cycle_rot_deg, cfg.cycle_trans_m)
        T, placed, refine_info = _global_poses(n, kept, cfg)
        solved = (kept, dropped, untested, T, placed, refine_info)


def _geometric_pair(
    cams: list[CameraEvidence], i: int, j: int, feat, cfg: RGBDConfig, prepared=None
) -> tuple[dict, tuple | None]:
    """Route (c) on the pair (i, j): its info entry (every pose cluster with its verification)
    and its candidate (cluster, check, entry), or None: the passing cluster with the most starts
    when at least ``geometric_min_starts`` and twice as many as any other passing cluster
    reached it. ``prepared``: the pair's ``geometric.ransac_starts``, if already computed."""
    from fuseflow.calib.geometric import geometric_candidates

    a, b = cams[i], cams[j]
    clusters = geometric_candidates(feat(i), feat(j), cfg.geometric_starts, seed=cfg.seed + 2, prepared=prepared)
    rows, passing = [], []
    for c in clusters:
        chk = verify_pose(a, b, c.T_ba, cfg.tau)
        ok = chk.passes(cfg) and plausible(c.T_ba, chk, cfg, _median_depth(a, b))
        rows.append({"route": "geometric", "inliers": int(len(c.X_a)), "starts": c.starts, "ok": ok,
                     **_round(chk), "T_ji": np.round(c.T_ba, 6).tolist()})  # fmt: skip
        ok = ok and _subject_ok(a, b, c.T_ba, cfg, rows[-1])
        if ok:
            passing.append((c, chk))
    entry = {"pair": [i, j], "stage": "geometric", "candidates": rows, "edge": None}
    if passing:
        c, chk = passing[0]  # clusters come largest first
        runner_up = passing[1][0].starts if len(passing) > 1 else 0
        if c.starts >= cfg.geometric_min_starts and c.starts >= 2 * runner_up and len(c.X_a) >= 3:
            return entry, (c, chk, entry)
    return entry, None


def _better(cams, T: np.ndarray, placed: np.ndarray, i: int, j: int, T_new, T_old, cfg: RGBDConfig) -> bool:
    """Is the relative pose T_new (camera i -> j) closer to the truth than T_old? With one of
    the two cameras placed (poses T (N, 4, 4)), by the depth agreement of the other, at the pose
    each implies, with every placed camera (a pair's overlap can favour a pose the other views
    refute: hocap-8rs); else by the pair's agreement at a fifth of tau (tau = 5 % cannot tell
    0.1 deg from 1 deg)."""
    if placed[i] != placed[j]:
        others = [v for v in range(len(cams)) if placed[v]]
        if placed[i]:  # T_j = T_ji T_i
            u, pose = j, (lambda R: R @ T[i])
        else:  # T_i = T_ji^-1 T_j
            u, pose = i, (lambda R: invert_rigid(R) @ T[j])
        return _agreement_with(cams, u, pose(T_new), T, others, cfg) > _agreement_with(
            cams, u, pose(T_old), T, others, cfg
        )
    tau = cfg.tau / 5
    return verify_pose(cams[i], cams[j], T_new, tau).agree > verify_pose(cams[i], cams[j], T_old, tau).agree


def _agreement_with(cams, u: int, T_u: np.ndarray, T: np.ndarray, others: list[int], cfg: RGBDConfig) -> float:
    """Pooled depth agreement (``verify_pose``) of camera u at pose T_u (4, 4) with the cameras
    ``others`` at their poses in T."""
    agree = votes = 0
    for v in others:
        chk = verify_pose(cams[u], cams[v], T[v] @ invert_rigid(T_u), cfg.tau)
        agree += chk.agree
        votes += round(chk.agree / chk.agreement) if chk.agree else 0
    return agree / votes if votes else 0.0


def _cloud_cache(cams: list[CameraEvidence], cfg: RGBDConfig):
    """k -> camera k's ``geometric.CloudFeatures`` (median depth, every 2nd pixel), each
    computed once."""
    from fuseflow.calib.geometric import cloud_features

    cache: dict[int, object] = {}

    def feat(k: int):
        if k not in cache:
            cache[k] = cloud_features(_backproject(cams[k].depth, cams[k].K, 2), cfg.geometric_voxel)
        return cache[k]

    return feat


def _round(chk: PairCheck) -> dict:
    return {
        "agreement": round(chk.agreement, 4),
        "structure_agreement": None if np.isnan(chk.structure_agreement) else round(chk.structure_agreement, 4),
        "free_space": round(chk.free_space, 4),
        "agree": chk.agree,
        "structure_votes": chk.structure_votes,
    }


def _refit(a: CameraEvidence, b: CameraEvidence, c: dict, chk: PairCheck, cands: list[dict], cfg: RGBDConfig):
    """Refit the accepted pose on the correspondences of every route that it explains (6-DoF
    Kabsch, three times, re-collecting): the verified candidates of a pair are all roughly right
    (depth agreement at tau = 5 % cannot tell 0.1 deg from 1 deg), their pooled evidence is more
    precise than any one of them (the 4-DoF floor poses are). Kept when it still passes, agrees
    within 0.02 of the candidate and keeps at least 90 % of its agreeing samples."""
    T = c["T_ba"]
    if c["route"] == "subject":  # head centres and both floors: other routes' matches are coarser
        return c, chk
    for _ in range(3):
        Xa, Xb = _support(T, cands, cfg)
        if len(Xa) < 6:
            return c, chk
        T = kabsch(Xa[None], Xb[None])[0]
    new = verify_pose(a, b, T, cfg.tau)
    if new.passes(cfg) and new.agreement >= chk.agreement - 0.02 and new.agree >= 0.9 * chk.agree:
        return {**c, "T_ba": T, "route": c["route"] + "+refit"}, new
    return c, chk


def _support(T_ba: np.ndarray, cands: list[dict], cfg: RGBDConfig) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate's correspondences (all routes) that the accepted pose explains: the
    edge's evidence for the joint solve."""
    XA = np.concatenate([c["X_a"] for c in cands])
    XB = np.concatenate([c["X_b"] for c in cands])
    r = np.linalg.norm(XA @ T_ba[:3, :3].T + T_ba[:3, 3] - XB, axis=1)
    ok = r < cfg.inlier_m + cfg.inlier_rel * XB[:, 2]
    XA, XB = XA[ok], XB[ok]
    _, first = np.unique(np.round(np.c_[XA, XB], 6), axis=0, return_index=True)  # a match seen twice counts once
    first.sort()
    return XA[first], XB[first]


# ----------------------------------------------------------------------------- global


def _global_poses(n: int, edges: dict[tuple[int, int], Edge], cfg: RGBDConfig):
    """Poses (canonical order) of the largest connected component of the kept edges (ties: the
    one with the lowest index), anchored at its lowest index."""
    comps, seen = [], set()
    for s in range(n):
        if s in seen:
            continue
        comp, stack = set(), [s]
        while stack:
            k = stack.pop()
            if k in comp:
                continue
            comp.add(k)
            stack += [b if a == k else a for (a, b) in edges if k in (a, b)]
        seen |= comp
        comps.append(sorted(comp))
    comp = max(comps, key=lambda c: (len(c), -c[0]))
    if len(comp) < 2:
        return np.tile(np.eye(4), (n, 1, 1)), np.zeros(n, dtype=bool), {"note": "no verified pair"}
    anchor = comp[0]
    T, placed = spanning_tree(n, edges, anchor)
    info: dict = {"anchor": anchor}
    if cfg.refine:
        T, info = refine_poses(T, placed, edges, anchor)
        info["anchor"] = anchor
    return T, placed, info


def _camera_info(cams, ids, kept, untested, placed, ambiguous: dict[str, str]) -> dict:
    out = {}
    for k, c in enumerate(cams):
        mine = [e for e in kept if k in e]
        out[ids[k]] = {
            "placed": bool(placed[k]),
            "floor": None
            if c.plane is None
            else {
                "height_m": round(c.plane.height, 4),
                "inliers": c.plane.inliers,
                "rms_m": round(c.plane.rms, 4),
                "normal": np.round(c.plane.normal, 6).tolist(),
            },
            "topdown_keypoints": int(len(c.td_xy)),
            "edges": [ids[b] if a == k else ids[a] for a, b in mine],
            # a camera held by edges none of which closes a cycle has had no independent check
            "cycle_checked": any(e not in untested for e in mine),
        }
        if ids[k] in ambiguous:  # left unplaced: why (``_joint_choice``)
            out[ids[k]]["ambiguous"] = ambiguous[ids[k]]
    return out


def relative_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(rotation deg, translation m) between two relative transforms (4, 4)."""
    D = T_a @ invert_rigid(T_b)
    return rotation_angle_deg(D[:3, :3]), float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
