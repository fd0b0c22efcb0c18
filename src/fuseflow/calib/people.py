"""The person route: human-pose keypoints as semantic correspondences between RGB-D cameras.

A person in the capture volume is the commonest "target" a studio has. Outline
(``person_candidates``), for a static rig and one or several frames (a person walking through it):

1. Per view (``PoseDetector``): 2-D pose landmarks (33, the MediaPipe Pose order, ``LANDMARKS``)
   with a visibility each. Of several detections in one view, the most complete one (most
   landmarks above the visibility threshold) is kept.
2. Per landmark (``lift_landmarks``): the registered depth lifts it to 3-D in the camera frame:
   the median of the foreground depths in a small window (pixels within ``foreground_m`` of the
   window's nearest), rejected when the window has too few depths, when the landmark's visibility
   is below ``visibility``, or when its depth is more than ``body_extent_m`` from the median depth
   of the person's other landmarks (a landmark on the background, e.g. a wrist beside the body).
   Only the body joints (``BODY_JOINTS``: shoulders, elbows, wrists, hips, knees, ankles, heels,
   toes) are used: face landmarks seen from behind land on the back of the head.
3. Per camera pair (``keypoint_pose``): the joints both views lifted in the same frame are 3-D
   correspondences, pooled over frames (the rig is static, the person moves: every frame adds
   joints at new places). 3-point RANSAC + Kabsch with a loose inlier distance
   (``inlier_m``): joints lifted from different sides of a body disagree by 10-30 cm.
   The landmarks' left / right labels are used as the detector gives them, never swapped to
   gain inliers: a body is nearly mirror-symmetric, so a swapped labelling gets almost as many
   inliers and wins by count on wrong poses (docs/gmac.md, "Person route").
4. Per pair (``refine_icp``): point-to-plane ICP on the two cameras' full clouds (per-pixel
   median depth over the frames) from the keypoint pose, coarse to fine: the keypoint pose is
   accurate to degrees, ICP brings it to the depth's precision when it starts in its basin.

Each pair yields up to two candidates in the ``rgbd`` backbone's form ({"route", "T_ba",
"inliers", "X_a", "X_b"}: ``T_ba`` maps camera a's coordinates into camera b's): route
``people`` (keypoints only) and ``people+icp``. The backbone verifies them by depth like every
candidate and chooses edges by cycle consistency; nothing here accepts a pose.

Limits: one person per view is used (the most complete detection); with several people in the
volume, two views may pick different people, whose joints then give a wrong pose that
verification has to reject. A mannequin or a poster is a person to the detector. A view that
never sees the person gets no candidate from this route.

The detector (``MediapipePoseDetector``) needs the ``people`` extra (``pip install
'fuseflow[people]'``: mediapipe 0.10.21, whose wheel bundles the pose model; nothing is
downloaded at run time). Tests inject any object with a ``detect(image)`` method.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.geometric import kabsch
from fuseflow.types import Frame, Rig

__all__ = [
    "LANDMARKS",
    "BODY_JOINTS",
    "PoseDetection",
    "PoseDetector",
    "MediapipePoseDetector",
    "PeopleConfig",
    "people_unavailable",
    "lift_landmarks",
    "detect_joints",
    "keypoint_pose",
    "refine_icp",
    "depth_cloud",
    "person_candidates",
]

#: The 33 MediaPipe Pose landmarks, in the detector's order.
LANDMARKS = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip

#: Landmarks used as correspondences: the body's joints (no face, no fingers).
BODY_JOINTS = (11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32)

#: The extra that installs the detector.
EXTRA_HINT = "pip install 'fuseflow[people]' (mediapipe 0.10.21, its pose model ships in the wheel)"


@dataclass(frozen=True)
class PoseDetection:
    """One person in one image: uv (33, 2) float64 pixels (x right, y down), visibility (33,)
    float64 in [0, 1], landmarks in ``LANDMARKS`` order."""

    uv: np.ndarray
    visibility: np.ndarray

    def __post_init__(self) -> None:
        uv = np.asarray(self.uv, dtype=np.float64)
        vis = np.asarray(self.visibility, dtype=np.float64)
        if uv.shape != (len(LANDMARKS), 2) or vis.shape != (len(LANDMARKS),):
            raise CalibrationError(
                f"a pose detection needs uv ({len(LANDMARKS)}, 2) and visibility ({len(LANDMARKS)},), "
                f"got {uv.shape} and {vis.shape}"
            )
        object.__setattr__(self, "uv", uv)
        object.__setattr__(self, "visibility", vis)


class PoseDetector(Protocol):
    """Anything that finds people in an RGB image (H, W, 3) uint8."""

    def detect(self, image: np.ndarray) -> list[PoseDetection]: ...


def people_unavailable() -> str | None:
    """None when the MediaPipe detector can run here, else the one-line reason (with the extra to
    install)."""
    try:
        import mediapipe  # noqa: F401
    except ImportError:
        return f"mediapipe is not installed: {EXTRA_HINT}"
    except Exception as e:  # a broken install (wrong numpy ABI, missing shared library)
        return f"mediapipe does not import ({type(e).__name__}: {str(e).splitlines()[0][:120]}): {EXTRA_HINT}"
    model = _model_path()
    if model is None or not model.exists():
        return f"mediapipe is installed but its bundled pose model is missing ({model}): {EXTRA_HINT}"
    return None


def _model_path() -> Path | None:
    try:
        import mediapipe
    except Exception:
        return None
    return Path(mediapipe.__file__).parent / "modules" / "pose_landmark" / "pose_landmark_full.tflite"


class MediapipePoseDetector:
    """MediaPipe Pose (legacy ``solutions.pose`` API, model ``pose_landmark_full``), one person
    per image, static-image mode (every image detected afresh), CPU.

    Raises:
        CalibrationError: mediapipe or its bundled model is missing (names the extra).
    """

    def __init__(self, min_detection_confidence: float = 0.5):
        reason = people_unavailable()
        if reason is not None:
            raise CalibrationError(f"person route: {reason}")
        from mediapipe.python.solutions import pose as mp_pose

        self._pose = mp_pose.Pose(
            static_image_mode=True, model_complexity=1, min_detection_confidence=min_detection_confidence
        )

    def detect(self, image: np.ndarray) -> list[PoseDetection]:
        """The person in ``image`` (H, W, 3) uint8 RGB: zero or one detection."""
        img = np.ascontiguousarray(image, dtype=np.uint8)
        h, w = img.shape[:2]
        res = self._pose.process(img)
        if res.pose_landmarks is None:
            return []
        lm = res.pose_landmarks.landmark
        uv = np.array([[p.x * w, p.y * h] for p in lm])
        vis = np.array([p.visibility for p in lm])
        return [PoseDetection(uv, vis)]

    def close(self) -> None:
        self._pose.close()


@dataclass(frozen=True)
class PeopleConfig:
    """Parameters of the person route (module docstring)."""

    visibility: float = 0.5
    """Landmarks below this detector visibility are not used."""
    joints: tuple[int, ...] = BODY_JOINTS
    """Landmark indices used as correspondences."""
    window: int = 3
    """Half size in pixels of the depth window around a landmark."""
    foreground_m: float = 0.15
    """Depths of the window within this of its nearest depth are the landmark's surface."""
    body_extent_m: float = 0.6
    """A landmark whose depth is further than this from the median of the person's landmarks is
    on the background, rejected."""
    min_joints: int = 4
    """A view's detection with fewer lifted joints than this is not used."""
    inlier_m: float = 0.2
    """RANSAC inlier distance between corresponding joints, metres."""
    iterations: int = 400
    """RANSAC samples (3 joints each)."""
    min_inliers: int = 5
    """Fewest inlier joints for a keypoint pose."""
    icp: bool = True
    """Refine every keypoint pose by point-to-plane ICP on the full clouds."""
    icp_voxel: float = 0.03
    """Voxel size (metres) the clouds are thinned to for ICP."""
    icp_distances: tuple[float, ...] = (0.3, 0.15, 0.08, 0.04)
    """ICP correspondence distances, coarse to fine, metres."""
    seed: int = 0


def lift_landmarks(det: PoseDetection, depth: np.ndarray, K: np.ndarray, cfg: PeopleConfig) -> np.ndarray:
    """(33, 3) camera-frame points (metres) of a detection's landmarks lifted by ``depth`` (H, W)
    metres (0 = none); NaN rows for landmarks not used (not in ``cfg.joints``, low visibility,
    outside the image, no foreground depth, or off the body)."""
    h, w = depth.shape
    r = cfg.window
    out = np.full((len(LANDMARKS), 3), np.nan)
    z = np.full(len(LANDMARKS), np.nan)
    for k in cfg.joints:
        u, v = det.uv[k]
        if det.visibility[k] < cfg.visibility or not (0 <= u < w and 0 <= v < h):
            continue
        ui, vi = int(u), int(v)
        win = depth[max(vi - r, 0) : vi + r + 1, max(ui - r, 0) : ui + r + 1].ravel()
        win = win[win > 0]
        if len(win) < max(3, win.size // 4):
            continue
        fg = win[win <= win.min() + cfg.foreground_m]
        z[k] = float(np.median(fg))
    ok = np.isfinite(z)
    if ok.sum() >= 2:
        ok &= np.abs(z - np.median(z[ok])) <= cfg.body_extent_m
    idx = np.flatnonzero(ok)
    uv1 = np.c_[det.uv[idx], np.ones(len(idx))]
    out[idx] = (uv1 @ np.linalg.inv(K).T) * z[idx, None]
    return out


def _most_complete(dets: list[PoseDetection], cfg: PeopleConfig) -> PoseDetection | None:
    if not dets:
        return None
    joints = list(cfg.joints)
    return max(dets, key=lambda d: int((d.visibility[joints] >= cfg.visibility).sum()))


@dataclass
class DetectedJoints:
    """Lifted joints of every view: points (N cameras, F frames, 33, 3) camera-frame metres, NaN
    where not lifted; per-view detection times (seconds) and counts for the report."""

    points: np.ndarray
    detect_s: list[float] = field(default_factory=list)
    views_with_person: list[int] = field(default_factory=list)


def detect_joints(
    frames: Sequence[Frame], rig: Rig, order: Sequence[int], detector: PoseDetector, cfg: PeopleConfig
) -> DetectedJoints:
    """Detect and lift the person in every frame of the cameras ``order`` (rig indices)."""
    pts = np.full((len(order), len(frames), len(LANDMARKS), 3), np.nan)
    times, seen = [], [0] * len(order)
    for a, k in enumerate(order):
        K = rig.cameras[k].K
        for f, fr in enumerate(frames):
            if not bool(fr.present[k]):
                continue
            t0 = time.perf_counter()
            det = _most_complete(detector.detect(fr.color[k].numpy()), cfg)
            times.append(time.perf_counter() - t0)
            if det is None:
                continue
            X = lift_landmarks(det, fr.depth[k].numpy(), K, cfg)
            if np.isfinite(X[:, 0]).sum() >= cfg.min_joints:
                pts[a, f] = X
                seen[a] += 1
    return DetectedJoints(pts, times, seen)


def _common(Ja: np.ndarray, Jb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joints lifted in both views in the same frame, pooled over frames: (M, 3) each."""
    ok = np.isfinite(Ja[..., 0]) & np.isfinite(Jb[..., 0])
    return Ja[ok], Jb[ok]


def keypoint_pose(Xa: np.ndarray, Xb: np.ndarray, cfg: PeopleConfig) -> tuple[np.ndarray, np.ndarray] | None:
    """T_ba (4, 4) with Xb ~ R Xa + t from corresponding joints (M, 3) each, by 3-point RANSAC +
    Kabsch (inlier distance ``cfg.inlier_m``; most inliers, ties by the smaller summed residual),
    refit on the inliers twice. Returns (T_ba, inlier mask (M,)) or None with fewer than
    ``cfg.min_inliers`` inliers."""
    m = len(Xa)
    if m < max(cfg.min_inliers, 3):
        return None
    rng = np.random.default_rng(cfg.seed)
    idx = np.stack([rng.choice(m, 3, replace=False) for _ in range(cfg.iterations)])
    A = Xa[idx]
    area = np.linalg.norm(np.cross(A[:, 1] - A[:, 0], A[:, 2] - A[:, 0]), axis=1)
    idx = idx[area > 0.005]  # near-collinear triples fix no rotation
    if not len(idx):
        return None
    T = kabsch(Xa[idx], Xb[idx])
    res = np.linalg.norm(np.einsum("hij,kj->hki", T[:, :3, :3], Xa) + T[:, None, :3, 3] - Xb[None], axis=2)
    inl = res < cfg.inlier_m
    cost = np.where(inl, res, cfg.inlier_m).sum(axis=1)
    best = int(np.lexsort((cost, -inl.sum(axis=1)))[0])
    mask = inl[best]
    for _ in range(2):
        if mask.sum() < 3:
            break
        Tb = kabsch(Xa[mask][None], Xb[mask][None])[0]
        mask = np.linalg.norm(Xa @ Tb[:3, :3].T + Tb[:3, 3] - Xb, axis=1) < cfg.inlier_m
    if mask.sum() < cfg.min_inliers:
        return None
    return kabsch(Xa[mask][None], Xb[mask][None])[0], mask


def depth_cloud(depth: np.ndarray, K: np.ndarray, voxel: float):
    """Open3D cloud (camera frame) of a depth image, voxel-thinned, with normals."""
    import open3d as o3d

    h, w = depth.shape
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    X = np.c_[(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(X)).voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * voxel, max_nn=30))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    return pc


def refine_icp(cloud_a, cloud_b, T_ba: np.ndarray, cfg: PeopleConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point-to-plane ICP of camera a's cloud onto camera b's (Open3D clouds, ``depth_cloud``) from
    T_ba, over ``cfg.icp_distances``. Returns (T_ba refined, X_a (P, 3), X_b (P, 3)): up to 400
    closest-point pairs within the finest distance, the pose's support for the joint solve."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    T = np.asarray(T_ba, dtype=np.float64)
    for d in cfg.icp_distances:
        T = reg.registration_icp(
            cloud_a, cloud_b, d, T, reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(max_iteration=30),
        ).transformation  # fmt: skip
    A = np.asarray(cloud_a.points)
    Bp = np.asarray(cloud_b.points)
    from scipy.spatial import cKDTree

    q = A @ T[:3, :3].T + T[:3, 3]
    dist, j = cKDTree(Bp).query(q, distance_upper_bound=cfg.icp_distances[-1])
    ok = np.flatnonzero(np.isfinite(dist))
    if len(ok) > 400:
        ok = ok[np.linspace(0, len(ok) - 1, 400).astype(int)]
    return T, A[ok], Bp[j[ok]]


def person_candidates(
    frames: Sequence[Frame],
    rig: Rig,
    order: Sequence[int],
    depths: Sequence[np.ndarray],
    detector: PoseDetector,
    cfg: PeopleConfig | None = None,
) -> tuple[dict[tuple[int, int], list[dict]], dict]:
    """Candidate relative poses of every camera pair from the person in the frames.

    Args:
        frames: Frames of a static rig (colour RGB, depth metres), cameras in rig order.
        rig: the rig (intrinsics used).
        order: rig indices of the cameras in the caller's order; pairs are (a, b), a < b
            positions in ``order``.
        depths: per position in ``order``, the (H, W) depth used for ICP (e.g. the per-pixel
            median over the frames, which drops the walking person: static structure only).
        detector: a ``PoseDetector``.
        cfg: PeopleConfig (defaults when None).

    Returns:
        ({(a, b): [candidate dict, ...]}, info): candidates {"route": "people" | "people+icp",
        "T_ba" (4, 4), "inliers" (joints), "X_a", "X_b" (P, 3) supporting points}; info has the
        per-view detection times, the frames each camera saw the person in and per pair the
        common and inlier joints.
    """
    cfg = cfg or PeopleConfig()
    t0 = time.perf_counter()
    J = detect_joints(frames, rig, order, detector, cfg)
    t_detect = time.perf_counter() - t0
    clouds: dict[int, object] = {}
    out: dict[tuple[int, int], list[dict]] = {}
    pairs = []
    for a in range(len(order)):
        for b in range(a + 1, len(order)):
            Xa, Xb = _common(J.points[a], J.points[b])
            fit = keypoint_pose(Xa, Xb, cfg)
            pairs.append(
                {"pair": [a, b], "common_joints": int(len(Xa)), "inliers": 0 if fit is None else int(fit[1].sum())}
            )
            if fit is None:
                continue
            T, mask = fit
            cands = [{"route": "people", "T_ba": T, "inliers": int(mask.sum()), "X_a": Xa[mask], "X_b": Xb[mask]}]
            if cfg.icp:
                for k in (a, b):
                    if k not in clouds:
                        clouds[k] = depth_cloud(np.asarray(depths[k]), rig.cameras[order[k]].K, cfg.icp_voxel)
                T_icp, Pa, Pb = refine_icp(clouds[a], clouds[b], T, cfg)
                cands.append({"route": "people+icp", "T_ba": T_icp, "inliers": int(mask.sum()), "X_a": Pa, "X_b": Pb})
            out[(a, b)] = cands
    info = {
        "frames_with_person": J.views_with_person,
        "detect_s_per_view": round(float(np.mean(J.detect_s)), 4) if J.detect_s else None,
        "detect_s": round(t_detect, 3),
        "total_s": round(time.perf_counter() - t0, 3),
        "pairs": pairs,
    }
    return out, info
