"""The moving-subject route: a person walking through a static rig as a detector-free target.

Every camera of a static rig sees the same person at the same instants. The person's head is
nearly a sphere, and the centre of a sphere fitted to the part of it a camera sees is the same
point from every side (the centroid of the visible surface is not: it lies towards the camera).
One head centre per frame per camera is a 3-D point correspondence between all cameras that saw
it; over frames of a walk they form a track. Outline (``SubjectRoute``), no model, no detector:

1. Per camera (``subject_masks``): the static scene is, per pixel, the farthest depth the
   frames agree on (a pixel whose farthest depth is seen in at least ``STATIC_SHARE`` of the
   frames, counting frames without depth there); a depth clearly in front of it, or at a pixel with no such static depth, that lies
   between ``MIN_HEIGHT_M`` and ``MAX_HEIGHT_M`` above the camera's own floor plane
   (:mod:`fuseflow.calib.floor`) is the subject. The largest connected blob and every blob within
   ``BLOB_M`` of it are kept (the head is often a separate blob above the torso).
2. Per frame (``head_centre``): the points within ``CAP_M`` of the subject's top are its head;
   a sphere of radius ``HEAD_RADIUS_M`` fitted to them (Gauss-Newton from the cap's centroid moved
   one radius away from the camera, points more than 3 cm off dropped once) gives the centre;
   rejected with fewer than ``MIN_CAP_POINTS`` points or an RMS above ``MAX_FIT_RMS_M``.
3. Per camera pair (``track_pose``): in each camera's floor frame (its floor plane fixes roll,
   pitch and height, as in the rgbd backbone's floor route) the two tracks differ by a yaw and a
   shift on the floor: a 2-point RANSAC (inlier ``INLIER_M``) and a least-squares refit on the
   inliers. Needs ``MIN_FRAMES`` common frames spread over at least ``MIN_SPREAD_M`` (a person
   standing still fixes no heading).

The pair candidate ({"route": "subject", "T_ba", "inliers", "X_a", "X_b"}: the head centres
of the inlier frames and their feet on the floor; for the expected accuracy "expected_m" (the
inlier head centres' RMS distance under the pose combined with ``HEAD_BIAS_M``), "spread_m"
(the track's extent) and "track_frames") goes through the rgbd backbone's verification like
every candidate; it is the one candidate there that needs no static structure off the floor
(a plain room: the floor and the person are all there is). The tracks also judge every other
candidate of the pair (``track_residual``): a pose that moves one camera's head track more than
``REFUTE_M`` (median) from the other's is refuted by the subject,
whatever the static depth says (at 3.5-4 m a 2-deg error moves the person 12-14 cm).

Limits: the frames of all cameras must be taken at the same instants (a 30-ms offset at walking
speed moves the person 3-4 cm between views); one moving person (several: the largest blob per
view, which two views may pick differently; their tracks then disagree and the route proposes
nothing); a single frame or a person standing still gives no track, and the route steps aside.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fuseflow.calib.floor import FloorPlane
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = [
    "SubjectRoute",
    "subject_masks",
    "head_cap",
    "head_centre",
    "camera_track",
    "track_pose",
    "track_residual",
    "HEAD_RADIUS_M",
    "REFUTE_M",
]

#: A pixel's farthest depth is its static depth when at least this share of its frames see it.
STATIC_SHARE = 0.6
#: The subject: heights above the camera's floor plane, metres.
MIN_HEIGHT_M, MAX_HEIGHT_M = 0.05, 2.4
#: Blobs within this distance (metres, 3-D, from the largest blob's median point) are the subject.
BLOB_M = 1.0
#: The head: points within this of the subject's top (99th height percentile), metres.
CAP_M = 0.2
#: Radius of the fitted head sphere, metres (an adult head is 0.08-0.11 m across half its width).
HEAD_RADIUS_M = 0.10
#: What the tracks' residual cannot show, metres: a head is not a sphere and its fitted radius
#: is off (far3's 0.11 m sphere fitted 0.103-0.106 m: pair poses 0.8-1.9 cm off at a 2-3 mm
#: residual; the articulated figure of ``synth.person``, hair offset 2.5 cm: 0.119-0.127 m,
#: 0.4-2.9 cm off), so every centre of a view sits a little towards or away from its camera.
HEAD_BIAS_M = 0.02
#: The head radius is fitted per camera within this range (metres), in this many rounds.
RADIUS_RANGE_M, RADIUS_ROUNDS = (0.07, 0.14), 6
#: Fewest head points for a fit, and the largest RMS of a kept fit (metres).
MIN_CAP_POINTS, MAX_FIT_RMS_M = 40, 0.02
#: Track pose: RANSAC inlier distance (metres), fewest common frames, least spread (metres).
INLIER_M, MIN_FRAMES, MIN_SPREAD_M = 0.06, 3, 0.5
#: A candidate whose median head-track residual exceeds this (metres) is refuted by the subject.
REFUTE_M = 0.08
#: Fewest frames in which two views see the subject's head for the subject to judge a pair.
MIN_JUDGE_FRAMES = 3


def _backproject(depth: np.ndarray, K: np.ndarray, mask: np.ndarray) -> np.ndarray:
    v, u = np.nonzero(mask)
    z = depth[v, u].astype(np.float64)
    return np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)


def subject_masks(depths: np.ndarray, K: np.ndarray, plane: FloorPlane) -> list[np.ndarray]:
    """Per frame, the (H, W) bool mask of the moving subject (step 1 of the module docstring) of
    one camera's depths (F, H, W) metres (0 = none), intrinsics K and floor plane."""
    import cv2

    D = np.asarray(depths, dtype=np.float64)
    valid = D > 0
    far = np.where(valid, D, 0.0).max(axis=0)
    tol = np.maximum(0.05, 0.02 * far)
    at_far = valid & (np.abs(D - far) < tol)
    static = at_far.sum(axis=0) >= STATIC_SHARE * len(D)  # seen there in most frames
    out = []
    for f in range(len(D)):
        cand = valid[f] & ~(static & at_far[f])
        X = _backproject(D[f], K, cand)
        h = plane.distance(X) if len(X) else np.zeros(0)
        m = np.zeros(D.shape[1:], np.uint8)
        v, u = np.nonzero(cand)
        keep = (h > MIN_HEIGHT_M) & (h < MAX_HEIGHT_M)
        m[v[keep], u[keep]] = 1
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        n, lab, stats, _ = cv2.connectedComponentsWithStats(m)
        if n < 2:
            out.append(np.zeros(m.shape, bool))
            continue
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        centre = np.median(_backproject(D[f], K, lab == big), axis=0)
        mask = np.zeros(m.shape, bool)
        for k in range(1, n):
            Xk = _backproject(D[f], K, lab == k)
            if np.linalg.norm(np.median(Xk, axis=0) - centre) < BLOB_M:
                mask |= lab == k
        out.append(mask)
    return out


def head_cap(P: np.ndarray, plane: FloorPlane) -> np.ndarray | None:
    """The head points (step 2) of the subject's points P (M, 3), or None when too few."""
    if len(P) < MIN_CAP_POINTS:
        return None
    h = plane.distance(P)
    cap = P[h > np.percentile(h, 99) - CAP_M]
    return cap if len(cap) >= MIN_CAP_POINTS else None


def head_centre(cap: np.ndarray, radius: float = HEAD_RADIUS_M) -> tuple[np.ndarray, float] | None:
    """Camera-frame centre (3,) of a sphere of ``radius`` fitted to the head points ``cap``
    (M, 3) (step 2) and the mean distance of its inliers from the centre, or None."""
    c = cap.mean(axis=0)
    c = c + radius * c / np.linalg.norm(c)  # the centre lies behind the visible cap
    for it in range(2):
        for _ in range(15):
            v = cap - c
            dn = np.maximum(np.linalg.norm(v, axis=1), 1e-9)
            step = np.linalg.lstsq(-v / dn[:, None], dn - radius, rcond=None)[0]
            c = c - step
            if np.linalg.norm(step) < 1e-5:
                break
        dist = np.linalg.norm(cap - c, axis=1)
        if it == 0:
            cap = cap[np.abs(dist - radius) < 0.03]
            if len(cap) < MIN_CAP_POINTS:
                return None
    rms = float(np.sqrt(np.mean((dist - radius) ** 2)))
    return (c, float(dist.mean())) if rms <= MAX_FIT_RMS_M else None


def camera_track(depths: np.ndarray, K: np.ndarray, plane: FloorPlane) -> tuple[np.ndarray, float]:
    """(F, 3) camera-frame head centres of one camera's frames (NaN where none) and the head
    radius (metres) fitted to all of them (steps 1-2): one radius for every frame (alternating
    with the per-frame centres, within ``RADIUS_RANGE_M``), since a radius off by 1 cm moves
    every centre 1 cm towards or away from the camera."""
    D = np.asarray(depths, dtype=np.float64)
    out = np.full((len(D), 3), np.nan)
    if len(D) < MIN_FRAMES:
        return out, float("nan")
    caps = {}
    for f, m in enumerate(subject_masks(D, K, plane)):
        cap = head_cap(_backproject(D[f], K, m), plane) if m.any() else None
        if cap is not None:
            caps[f] = cap
    fits = {f: head_centre(cap, HEAD_RADIUS_M) for f, cap in caps.items()}
    fits = {f: v[0] for f, v in fits.items() if v is not None}
    if not fits:
        return out, float("nan")
    C, r = _joint_sphere({f: caps[f] for f in fits}, fits)
    for f, c in C.items():
        out[f] = c
    return out, r


def _joint_sphere(caps: dict, centres: dict) -> tuple[dict, float]:
    """Centres (frame -> (3,)) and one radius of spheres fitted to every frame's head points at
    once (Gauss-Newton from ``centres`` and HEAD_RADIUS_M; points more than 3 cm off their
    sphere are dropped; the radius within ``RADIUS_RANGE_M``)."""
    keys = sorted(caps)
    c = np.concatenate([centres[f] for f in keys])
    r = HEAD_RADIUS_M
    pts = [caps[f] for f in keys]
    for _ in range(RADIUS_ROUNDS):
        rows, res = [], []
        for k, P in enumerate(pts):
            v = P - c[3 * k : 3 * k + 3]
            dn = np.maximum(np.linalg.norm(v, axis=1), 1e-9)
            keep = np.abs(dn - r) < 0.03
            J = np.zeros((int(keep.sum()), len(c) + 1))
            J[:, 3 * k : 3 * k + 3] = -v[keep] / dn[keep, None]
            J[:, -1] = -1.0
            rows.append(J)
            res.append(dn[keep] - r)
        step = np.linalg.lstsq(np.concatenate(rows), -np.concatenate(res), rcond=None)[0]
        c, r = c + step[:-1], float(np.clip(r + step[-1], *RADIUS_RANGE_M))
    return {f: c[3 * k : 3 * k + 3] for k, f in enumerate(keys)}, r


def _to_floor(P: np.ndarray, plane: FloorPlane) -> np.ndarray:
    T = invert_rigid(plane.T_cam_floor())
    return P @ T[:3, :3].T + T[:3, 3]


def _fit2d(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3, 3) 2-D rigid transform with b ~ R a + t (least squares, (M, 2) each)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    H = (a - ca).T @ (b - cb)
    ang = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    S = np.eye(3)
    S[:2, :2], S[:2, 2] = R, cb - R @ ca
    return S


def track_pose(
    Pa: np.ndarray, Pb: np.ndarray, plane_a: FloorPlane, plane_b: FloorPlane
) -> tuple[np.ndarray, np.ndarray] | None:
    """T_ba (4, 4) (camera a -> camera b) from the head tracks (F, 3) of the two cameras (NaN rows:
    not seen) and their floor planes (step 3), and the inlier mask over the common frames; None
    with fewer than MIN_FRAMES common inliers or a spread under MIN_SPREAD_M."""
    ok = np.isfinite(Pa[:, 0]) & np.isfinite(Pb[:, 0])
    if ok.sum() < MIN_FRAMES:
        return None
    A, B = _to_floor(Pa[ok], plane_a)[:, :2], _to_floor(Pb[ok], plane_b)[:, :2]
    best = None
    for i in range(len(A)):
        for j in range(i + 1, len(A)):
            if np.linalg.norm(A[i] - A[j]) < MIN_SPREAD_M / 2:
                continue
            S = _fit2d(A[[i, j]], B[[i, j]])
            r = np.linalg.norm(A @ S[:2, :2].T + S[:2, 2] - B, axis=1)
            key = (int((r < INLIER_M).sum()), -float(np.minimum(r, INLIER_M).sum()))
            if best is None or key > best[0]:
                best = (key, r < INLIER_M)
    if best is None:
        return None
    inl = best[1]
    for _ in range(2):
        if inl.sum() < MIN_FRAMES:
            return None
        S = _fit2d(A[inl], B[inl])
        inl = np.linalg.norm(A @ S[:2, :2].T + S[:2, 2] - B, axis=1) < INLIER_M
    spread = np.linalg.norm(A[inl] - A[inl].mean(axis=0), axis=1).max() * 2 if inl.any() else 0.0
    if inl.sum() < MIN_FRAMES or spread < MIN_SPREAD_M:
        return None
    S = _fit2d(A[inl], B[inl])
    F = np.eye(4)  # floor b <- floor a: yaw about z and a shift on the floor
    F[:2, :2], F[:2, 3] = S[:2, :2], S[:2, 2]
    T = plane_b.T_cam_floor() @ F @ invert_rigid(plane_a.T_cam_floor())
    mask = np.zeros(len(Pa), bool)
    mask[np.flatnonzero(ok)[inl]] = True
    return T, mask


def track_residual(Pa: np.ndarray, Pb: np.ndarray, T_ba: np.ndarray) -> tuple[float, int]:
    """(median distance (metres) between camera b's head centres and camera a's carried by
    ``T_ba``, number of common frames)."""
    ok = np.isfinite(Pa[:, 0]) & np.isfinite(Pb[:, 0])
    if not ok.any():
        return float("nan"), 0
    r = np.linalg.norm(Pa[ok] @ T_ba[:3, :3].T + T_ba[:3, 3] - Pb[ok], axis=1)
    return float(np.median(r)), int(ok.sum())


def _floor_points(P: np.ndarray, plane: FloorPlane, T_ba: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Floor correspondences of a track pose: the feet of the head centres P (M, 3) on camera a's
    floor, and where T_ba puts them (on camera b's floor, which T_ba maps a's floor onto). They
    carry both floor planes (tilt, height) into a joint solve, where head centres along a
    straight walk leave the rotation about the walking line free."""
    F = P - plane.distance(P)[:, None] * plane.normal[None]
    return F, F @ T_ba[:3, :3].T + T_ba[:3, 3]


@dataclass
class SubjectRoute:
    """The moving-subject route over a static rig's frames (module docstring). ``tracks``:
    (N, F, 3) camera-frame head centres, cameras in ``order``; ``planes`` each camera's floor."""

    tracks: np.ndarray
    planes: list[FloorPlane | None]
    radii: list[float]

    @classmethod
    def build(cls, frames: Sequence[Frame], rig: Rig, order: Sequence[int], planes) -> SubjectRoute:
        """Tracks of the cameras ``order`` (rig indices) with the floor planes ``planes`` (same
        order; None: no floor, no track) from ``frames`` (each camera's views in rig order)."""
        tracks = np.full((len(order), len(frames), 3), np.nan)
        radii = [float("nan")] * len(order)
        for a, k in enumerate(order):
            if planes[a] is None or len(frames) < MIN_FRAMES:
                continue
            lo, hi = rig.cameras[k].depth_range
            D = np.stack([f.depth[k].numpy() if bool(f.present[k]) else np.zeros(f.depth[k].shape) for f in frames])
            D = np.where((D >= lo) & (D <= hi), D, 0.0)
            tracks[a], radii[a] = camera_track(D, rig.cameras[k].K, planes[a])
        return cls(tracks, list(planes), radii)

    def frames_seen(self) -> list[int]:
        return [int(np.isfinite(t[:, 0]).sum()) for t in self.tracks]

    def pair(self, a: int, b: int) -> list[dict]:
        """[] or the pair's candidate {"route": "subject", "T_ba", "inliers", "X_a", "X_b"}."""
        if self.planes[a] is None or self.planes[b] is None:
            return []
        fit = track_pose(self.tracks[a], self.tracks[b], self.planes[a], self.planes[b])
        if fit is None:
            return []
        T, mask = fit
        Pa, Pb = self.tracks[a][mask], self.tracks[b][mask]
        Fa, Fb = _floor_points(Pa, self.planes[a], T)
        r = np.linalg.norm(Pa @ T[:3, :3].T + T[:3, 3] - Pb, axis=1)
        spread = 2 * float(np.linalg.norm(Pa - Pa.mean(axis=0), axis=1).max())
        return [{"route": "subject", "T_ba": T, "inliers": int(mask.sum()), "inliers_mask": mask,
                 "X_a": np.r_[Pa, Fa], "X_b": np.r_[Pb, Fb],
                 "expected_m": float(np.hypot(np.sqrt(np.mean(r**2)), HEAD_BIAS_M)), "spread_m": spread,
                 "track_frames": int(mask.sum())}]  # fmt: skip

    def judge(self, a: int, b: int, T_ba: np.ndarray, frames: np.ndarray | None = None) -> tuple[float, int] | None:
        """(median head-track residual (m), frames) of a candidate pose of pair (a, b) over the
        ``frames`` (bool (F,), default all), or None when the two views share fewer than
        MIN_JUDGE_FRAMES head centres there."""
        keep = np.ones(self.tracks.shape[1], bool) if frames is None else np.asarray(frames, bool)
        r, n = track_residual(self.tracks[a][keep], self.tracks[b][keep], T_ba)
        return (r, n) if n >= MIN_JUDGE_FRAMES else None

    def info(self) -> dict:
        return {"frames_with_head": self.frames_seen(), "head_radius_m": [round(r, 4) for r in self.radii]}
