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
   The point is then moved along its ray by the joint's depth below the skin (``JOINT_DEPTH``).
   Only the body joints (``BODY_JOINTS``: shoulders, elbows, wrists, hips, knees, ankles, heels,
   toes) are used: face landmarks seen from behind land on the back of the head.
3. Per camera pair (``keypoint_pose``): the joints both views lifted in the same frame are 3-D
   correspondences, pooled over frames (the rig is static, the person moves: every frame adds
   joints at new places). 3-point RANSAC + Kabsch with a loose inlier distance
   (``inlier_m``): joints lifted from different sides of a body disagree by 10-30 cm.
   The landmarks' left / right labels are used as the detector gives them, never swapped to
   gain inliers: a body is nearly mirror-symmetric, so a swapped labelling gets almost as many
   inliers and wins by count on wrong poses (docs/gmac-trust.md, "Person route").
4. Per pair (``refine_icp``): point-to-plane ICP on the two cameras' full clouds of the frames
   where both see the person (``icp_frames`` of them, one shared pose, points matched within
   their own frame), from the keypoint pose, coarse to fine: the keypoint pose is accurate to
   degrees, ICP brings it to the depth's precision when it starts in its basin.

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
from fuseflow.types import POSE_LANDMARKS, Frame, Rig

__all__ = [
    "LANDMARKS",
    "BODY_JOINTS",
    "JOINT_DEPTH",
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
    "PersonRoute",
]

#: The 33 MediaPipe Pose landmarks, in the detector's order (``types.POSE_LANDMARKS``).
LANDMARKS = POSE_LANDMARKS

#: Landmarks used as correspondences: the body's joints (no face, no fingers).
BODY_JOINTS = (11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32)

#: Depth of each body joint's centre behind the skin that faces a camera, metres (typical adult
#: half-thicknesses: shoulder 6, elbow 4, wrist 3, hip 9, knee 5, ankle 4, heel / toe 2 cm). A
#: lifted landmark sits on the surface the camera sees; moved this far along its ray it lands
#: near the joint from every side (views from opposite sides otherwise disagree by twice it).
JOINT_DEPTH = dict(
    zip(BODY_JOINTS, (0.06, 0.06, 0.04, 0.04, 0.03, 0.03, 0.09, 0.09, 0.05, 0.05, 0.04, 0.04, 0.02, 0.02, 0.02, 0.02))
)

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
    joint_depth: bool = True
    """Move each lifted landmark along its ray by ``JOINT_DEPTH`` (surface to joint centre)."""
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
    icp_normal_cos: float = -1.0
    """ICP pairs whose normals' cosine is below this are not used (-1: all pairs)."""
    icp_normal_radius: float = 0.12
    """Radius (m) of the neighbourhood each ICP point's normal is fitted in."""
    icp_frames: int = 4
    """ICP uses the frames (at most this many) in which the two views share the most joints."""
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
    if cfg.joint_depth:
        off = np.array([JOINT_DEPTH.get(int(k), 0.0) for k in idx])
        out[idx] += off[:, None] * out[idx] / np.linalg.norm(out[idx], axis=1, keepdims=True)
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


def depth_cloud(
    depth: np.ndarray, K: np.ndarray, voxel: float, normal_radius: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Points (P, 3) and unit normals (P, 3) (camera frame, normals towards the camera) of a depth
    image (H, W) metres, thinned to one point per ``voxel``; normals fitted within
    ``normal_radius`` m (default 4 voxels)."""
    import open3d as o3d

    v, u = np.nonzero(np.asarray(depth) > 0)
    z = np.asarray(depth)[v, u].astype(np.float64)
    X = np.c_[(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z]
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(X)).voxel_down_sample(voxel)
    r = 4 * voxel if normal_radius is None else normal_radius
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=r, max_nn=max(30, int(3 * (r / voxel) ** 2))))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    return np.asarray(pc.points), np.asarray(pc.normals)


def refine_icp(clouds_a: list, clouds_b: list, T_ba: np.ndarray, cfg: PeopleConfig) -> tuple[np.ndarray, ...]:
    """Point-to-plane ICP of camera a's clouds onto camera b's from T_ba, the frames' clouds
    (``depth_cloud`` pairs, same frames in the same order in both lists) sharing one pose and
    each point matched only within its own frame: the person stands at a new place in every
    frame, and together the frames constrain the pose where one frame's floor and person alone
    would let it slide. Correspondence distances ``cfg.icp_distances``, coarse to fine, 10
    Gauss-Newton steps each. Returns (T_ba refined, X_a (P, 3), X_b (P, 3)): up to 400
    closest-point pairs within the finest distance, the pose's support for the joint solve."""
    from scipy.spatial import cKDTree

    trees = [cKDTree(b[0]) for b in clouds_b]
    T = np.asarray(T_ba, dtype=np.float64).copy()
    for dist in cfg.icp_distances:
        for _ in range(10):
            q, n, r = _icp_pairs(clouds_a, clouds_b, trees, T, dist, cfg.icp_normal_cos)
            if len(r) < 6:
                break
            J = np.c_[np.cross(q, n), n]
            x = np.linalg.lstsq(J, -r, rcond=None)[0]
            T = _exp_se3(x) @ T
            if np.linalg.norm(x) < 1e-6:
                break
    XA, XB = [], []
    for (A, _), (B, _), tree in zip(clouds_a, clouds_b, trees):
        d, j = tree.query(A @ T[:3, :3].T + T[:3, 3], distance_upper_bound=cfg.icp_distances[-1])
        ok = np.isfinite(d)
        XA.append(A[ok])
        XB.append(B[j[ok]])
    XA, XB = np.concatenate(XA), np.concatenate(XB)
    keep = np.linspace(0, len(XA) - 1, min(len(XA), 400)).astype(int)
    return T, XA[keep], XB[keep]


def _icp_pairs(clouds_a, clouds_b, trees, T, dist, min_cos: float):
    """Stacked point-to-plane correspondences of every frame: transformed points q (M, 3), target
    normals n (M, 3), residuals n . (q - b) (M,). A pair counts only when its two normals agree
    (cosine >= ``min_cos``; each cloud's normals face its own camera, so a surface both cameras
    see has agreeing normals): views 120 deg apart see different sides of a person, and nearest
    points on the wrong side would pull the shells onto each other."""
    Q, N, R = [], [], []
    for (A, na), (B, nb), tree in zip(clouds_a, clouds_b, trees):
        q = A @ T[:3, :3].T + T[:3, 3]
        d, j = tree.query(q, distance_upper_bound=dist)
        ok = np.flatnonzero(np.isfinite(d))
        if min_cos > -1:
            ok = ok[np.einsum("ij,ij->i", na[ok] @ T[:3, :3].T, nb[j[ok]]) >= min_cos]
        q, b, n = q[ok], B[j[ok]], nb[j[ok]]
        Q.append(q)
        N.append(n)
        R.append(np.einsum("ij,ij->i", n, q - b))
    return np.concatenate(Q), np.concatenate(N), np.concatenate(R)


def _exp_se3(x: np.ndarray) -> np.ndarray:
    """(4, 4) rigid transform of the small motion x = (rotation vector (3,), translation (3,))."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
    T[:3, 3] = x[3:]
    return T


class PersonRoute:
    """The person route over one set of frames, computed lazily: the views are detected and
    lifted at the first ``pair`` call, each camera's ICP cloud when a pair first needs it.

    Args:
        frames: Frames of a static rig (colour RGB, depth metres), cameras in rig order.
        rig: the rig (intrinsics used).
        order: rig indices of the cameras in the caller's order; pairs are (a, b), positions
            in ``order``.
        detector: a ``PoseDetector``.
        cfg: PeopleConfig (defaults when None).
    """

    def __init__(self, frames, rig: Rig, order: Sequence[int], detector: PoseDetector, cfg=None):
        self.frames, self.rig, self.order = list(frames), rig, list(order)
        self.detector, self.cfg = detector, cfg or PeopleConfig()
        self._joints: DetectedJoints | None = None
        self._clouds: dict[tuple[int, int], tuple] = {}
        self._pairs: list[dict] = []
        self._time = {"detect": 0.0, "pairs": 0.0}

    def joints(self) -> DetectedJoints:
        if self._joints is None:
            t0 = time.perf_counter()
            self._joints = detect_joints(self.frames, self.rig, self.order, self.detector, self.cfg)
            self._time["detect"] += time.perf_counter() - t0
        return self._joints

    def pair(self, a: int, b: int) -> list[dict]:
        """Candidates of the pair (a, b): [] or {"route": "people" | "people+icp", "T_ba" (4, 4)
        camera a -> camera b, "inliers" (joints), "X_a", "X_b" (P, 3) supporting points}."""
        J = self.joints()
        t0 = time.perf_counter()
        cfg = self.cfg
        Xa, Xb = _common(J.points[a], J.points[b])
        fit = keypoint_pose(Xa, Xb, cfg)
        self._pairs.append({"pair": [a, b], "common_joints": int(len(Xa)), "inliers": 0 if fit is None else int(fit[1].sum())})  # fmt: skip
        if fit is None:
            self._time["pairs"] += time.perf_counter() - t0
            return []
        T, mask = fit
        out = [{"route": "people", "T_ba": T, "inliers": int(mask.sum()), "X_a": Xa[mask], "X_b": Xb[mask]}]
        if cfg.icp:
            both = np.isfinite(J.points[a][..., 0]) & np.isfinite(J.points[b][..., 0])
            use = np.argsort(-both.sum(axis=1), kind="stable")[: cfg.icp_frames]
            use = sorted(int(f) for f in use if both[f].sum() > 0)
            T_icp, Pa, Pb = refine_icp([self._cloud(a, f) for f in use], [self._cloud(b, f) for f in use], T, cfg)
            out.append({"route": "people+icp", "T_ba": T_icp, "inliers": int(mask.sum()), "X_a": Pa, "X_b": Pb})
        self._time["pairs"] += time.perf_counter() - t0
        return out

    def _cloud(self, a: int, f: int):
        if (a, f) not in self._clouds:
            k = self.order[a]
            self._clouds[(a, f)] = depth_cloud(
                self.frames[f].depth[k].numpy(), self.rig.cameras[k].K, self.cfg.icp_voxel
            )
        return self._clouds[(a, f)]

    def info(self) -> dict:
        """The frames each camera saw the person in, the mean detection time per view, seconds
        spent, and per pair examined its common and inlier joints."""
        J = self._joints
        return {
            "frames_with_person": None if J is None else J.views_with_person,
            "detect_s_per_view": round(float(np.mean(J.detect_s)), 4) if J is not None and J.detect_s else None,
            "time_s": {k: round(v, 3) for k, v in self._time.items()},
            "pairs": list(self._pairs),
        }


def person_candidates(
    frames: Sequence[Frame],
    rig: Rig,
    order: Sequence[int],
    detector: PoseDetector,
    cfg: PeopleConfig | None = None,
) -> tuple[dict[tuple[int, int], list[dict]], dict]:
    """Candidates of every camera pair (a < b, positions in ``order``) from the person in the
    frames (``PersonRoute``, same arguments): ({(a, b): [candidate, ...]} for the pairs with
    any, ``PersonRoute.info()``)."""
    route = PersonRoute(frames, rig, order, detector, cfg)
    out = {}
    for a in range(len(order)):
        for b in range(a + 1, len(order)):
            if cands := route.pair(a, b):
                out[(a, b)] = cands
    return out, route.info()
