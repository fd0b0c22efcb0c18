"""Per-camera evidence and pose verification (steps 1 and 3 of the package outline):
``prepare_camera`` (median images, floor plane and top-down view, lifted keypoints, verification
samples) and ``verify_pose`` (two-way depth agreement, free space), with ``plausible``, the
check that rejects a pose stacking two views in a symmetric room."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.matchers import ImageFeatures, Matcher, get_matcher, sift_uv
from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.floor import FloorPlane, TopDown, fit_floor_plane, floor_mask, render_topdown
from fuseflow.calib.symmetry import colocated
from fuseflow.geometry import project_votes
from fuseflow.types import Frame, Rig, invert_rigid


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
    images: tuple[np.ndarray, ...] = ()  # per frame (H, W, 3) uint8 colour, the frames' own arrays (``room_view``)


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
    kp = [_lift_keypoints(image_matcher(cfg), im, d, K) for im, d in zip(images, depths)]
    X = backproject(depth_med, K)
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
    samples = _samples(depth_med, K, plane, cfg)
    return CameraEvidence(K, depth_med, plane, topdown, td_xy, td_desc, kp, *samples, images=tuple(images))


#: Pixel stride of the points ``room_view`` gives the one-view room search.
ROOM_VIEW_STRIDE = 2


def room_view(cam: CameraEvidence) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(points (P, 3), their colours scaled to a mean of 128, the floor normal) of the camera's
    median depth every ROOM_VIEW_STRIDE pixels, for ``symmetry.view_room``; None without a floor
    or a colour image. The colour is the frames' median, taken here: only the rooms no pair shows
    need it."""
    if cam.plane is None or not cam.images:
        return None
    ims = cam.images
    colour = ims[0] if len(ims) == 1 else np.median(np.stack(ims), axis=0).astype(np.uint8)
    s = ROOM_VIEW_STRIDE
    z = cam.depth[::s, ::s]
    X = backproject(cam.depth, cam.K, s)
    col = colour[::s, ::s][z > 0].astype(np.float64)
    return X, col / np.maximum(col.mean(axis=0), 1.0) * 128.0, np.asarray(cam.plane.normal, np.float64)


def room_points(cam: CameraEvidence) -> tuple[np.ndarray] | None:
    """(points (P, 3),) of the camera's median depth every ROOM_VIEW_STRIDE pixels, in its frame,
    for ``symmetry.joint_axes`` (``room_view`` without the colour); None without a floor."""
    if cam.plane is None:
        return None
    return (backproject(cam.depth, cam.K, ROOM_VIEW_STRIDE),)


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


def backproject(depth: np.ndarray, K: np.ndarray, stride: int = 1) -> np.ndarray:
    """(M, 3) float64 camera-frame points of the pixels with depth (every ``stride``-th)."""
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
    z = depth[::stride, ::stride].astype(np.float64)
    m = z > 0
    z, u, v = z[m], u[m], v[m]
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)


def image_matcher(cfg: RGBDConfig) -> Matcher:
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
    edges; a depth edge gives no point). The depth at the rounded pixel is up to half a pixel's
    depth gradient off (~6 mm on the floor at 3 m), the same in every frame of a static scene, so
    pooling frames does not average it out."""
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
    X = backproject(d, Ks)
    fm = np.zeros(d.shape, dtype=bool) if plane is None else floor_mask(d, Ks, plane, cfg.floor_band)
    on_floor = fm[d > 0]
    return (
        torch.from_numpy(X.astype(np.float32)),
        torch.from_numpy(on_floor),
        torch.from_numpy(np.ascontiguousarray(d, dtype=np.float32)),
        torch.from_numpy(Ks.astype(np.float32)),
    )


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
