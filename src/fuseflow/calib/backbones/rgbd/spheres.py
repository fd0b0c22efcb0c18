"""Route (f), moving spheres: a round object carried through a static rig as a target.

A ball on a stick is the oldest calibration target of RGB-D rooms, and many captures of a
person moving through a studio have one (or a head: any moving body that is round in depth).
The centre of a sphere fitted to the part of it a camera sees is the same point from every side,
so one centre per frame per camera is a 3-D correspondence between every camera that saw it, and
over the frames of a moving object the centres form a track. No detector, no colour, no model.

1. Per camera (``moving_masks``): the static scene is, per pixel, the farthest depth the frames
   agree on (seen there in at least ``STATIC_SHARE`` of the frames); a depth more than
   ``FOREGROUND_M`` in front of it is moving. Depth edges (a jump over ``EDGE_M`` between
   neighbouring pixels) cut the moving pixels into blobs, so a ball held in front of a body is
   its own blob.
2. Per blob of at least ``MIN_BLOB_PX`` pixels (``fit_sphere``): RANSAC on 4 points (radius in
   ``RADIUS_M``, centre behind the surface seen), inliers within ``FIT_TOL_M``, a least-squares
   refit; kept when the inliers are at least ``MIN_SHARE`` of the blob (kinect3-room, all 25
   frames: the 0.21-m ball 68-100 % in every view; a torso 9-28 %; a head or a hand, 0.06-0.16 m,
   up to 94 %, which the radius test and the RANSAC of step 3 leave out).
3. Per camera pair (``sphere_pose``): the sphere pairs of the same frame whose radii differ by at
   most ``RADIUS_MATCH_M`` are correspondences; 3-point RANSAC + Kabsch over them (inliers
   within ``INLIER_M``, one per frame), a refit on the inliers; needs ``MIN_FRAMES`` inlier
   frames spread over ``MIN_SPREAD_M``. With both cameras' floor planes a second candidate keeps
   each floor (tilt, roll, height) and takes only the yaw and the shift on the floor from the
   centres (``subject.track_pose``), which holds where a track is nearly straight.

The candidates ({"route": "sphere", "T_ba", "inliers", "X_a", "X_b", "track_rms_m"}) go through
the backbone's verification like every candidate; the static depth then has to agree
(``min_agreement``), but its free-space test is relaxed to ``MAX_FREE_SPACE``: the track fixed
the pose to a few centimetres, and at 3.5-4 m a moving person and Kinect v2 flying pixels leave
10-22 % of a right pose's samples seen through (kinect3-room: its reference 0.11-0.22, the
sphere poses 0.01-0.15).

Limits: the cameras' frames must be taken at the same instants; one round object (two balls of
the same size confuse the pairing; RANSAC has to sort them out); a ball standing still, or
moving along a line without floor planes, fixes no pose.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fuseflow.calib.floor import FloorPlane
from fuseflow.calib.geometric import kabsch
from fuseflow.types import Frame, Rig

__all__ = ["SphereRoute", "moving_masks", "fit_sphere", "sphere_pose", "MAX_FREE_SPACE"]

#: A pixel's farthest depth is its static depth when at least this share of the frames see it.
STATIC_SHARE = 0.6
#: Moving: at least this far (metres) in front of the static depth.
FOREGROUND_M = 0.15
#: Neighbouring pixels whose depths differ by more than this (metres) belong to different blobs.
EDGE_M = 0.05
#: Smallest blob (pixels at full resolution) a sphere is fitted to.
MIN_BLOB_PX = 150
#: Sphere radii considered (metres): a head (0.08-0.12) to a large ball.
RADIUS_M = (0.05, 0.35)
#: RANSAC inlier distance of a point from the sphere (metres) and iterations per blob.
FIT_TOL_M, FIT_ITERS = 0.015, 200
#: Smallest share of a blob's points on its sphere for the sphere to count.
MIN_SHARE = 0.6
#: Points per blob used by the RANSAC (a random subset; the refit uses all).
FIT_POINTS = 3000
#: Two views' spheres of one frame are the same object when their radii differ by at most this.
RADIUS_MATCH_M = 0.03
#: Pair pose: RANSAC inlier distance (metres), fewest inlier frames, least extent of the track.
INLIER_M, MIN_FRAMES, MIN_SPREAD_M = 0.06, 5, 0.5
#: The free-space limit of a sphere candidate's verification (module docstring).
MAX_FREE_SPACE = 0.2


def moving_masks(depths: np.ndarray) -> list[np.ndarray]:
    """Per frame, the (H, W) int32 blob labels (0 = none) of what moves in one camera's depths
    (F, H, W) metres, 0 = no depth (steps 1 of the module docstring)."""
    import cv2

    D = np.asarray(depths, dtype=np.float64)
    valid = D > 0
    far = np.where(valid, D, 0.0).max(axis=0)
    at_far = valid & (np.abs(D - far) < np.maximum(0.05, 0.02 * far))
    static = at_far.sum(axis=0) >= STATIC_SHARE * len(D)
    out = []
    for f in range(len(D)):
        m = (valid[f] & ~(static & at_far[f]) & (D[f] < far - FOREGROUND_M)).astype(np.uint8)
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        m[np.abs(np.diff(D[f], axis=1, prepend=0.0)) > EDGE_M] = 0
        m[np.abs(np.diff(D[f], axis=0, prepend=0.0)) > EDGE_M] = 0
        _, lab = cv2.connectedComponents(m, connectivity=4)
        out.append(lab)
    return out


def _sphere_lsq(P: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic least-squares sphere (centre, radius) through the points P (M >= 4, 3)."""
    A = np.c_[2 * P, np.ones(len(P))]
    x = np.linalg.lstsq(A, (P**2).sum(axis=1), rcond=None)[0]
    c = x[:3]
    return c, float(np.sqrt(max(x[3] + c @ c, 0.0)))


def fit_sphere(P: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float, float] | None:
    """(centre (3,), radius, share of P on it) of the sphere best supported by the camera-frame
    points P (M, 3) (step 2), or None (no sphere with a radius in RADIUS_M and its centre behind
    the points)."""
    S = P[rng.choice(len(P), FIT_POINTS, replace=False)] if len(P) > FIT_POINTS else P
    back = float(np.median(S[:, 2]))
    best, best_n = None, 0
    for _ in range(FIT_ITERS):
        c, r = _sphere_lsq(S[rng.choice(len(S), 4, replace=False)])
        if not RADIUS_M[0] < r < RADIUS_M[1] or c[2] < back:
            continue
        n = int((np.abs(np.linalg.norm(S - c, axis=1) - r) < FIT_TOL_M).sum())
        if n > best_n:
            best, best_n = (c, r), n
    if best is None:
        return None
    c, r = best
    for _ in range(2):
        inl = np.abs(np.linalg.norm(P - c, axis=1) - r) < FIT_TOL_M
        if inl.sum() < 4:
            return None
        c, r = _sphere_lsq(P[inl])
    if not RADIUS_M[0] < r < RADIUS_M[1]:
        return None
    share = float((np.abs(np.linalg.norm(P - c, axis=1) - r) < FIT_TOL_M).mean())
    return c, r, share


def camera_spheres(depths: np.ndarray, K: np.ndarray, seed: int = 0) -> list[list[tuple[np.ndarray, float]]]:
    """Per frame, the (centre, radius) of every moving sphere one camera sees (steps 1-2), from
    its depths (F, H, W) metres and intrinsics K."""
    D = np.asarray(depths, dtype=np.float64)
    rng = np.random.default_rng(seed)
    out = []
    for f, lab in enumerate(moving_masks(D)):
        found = []
        counts = np.bincount(lab.ravel())
        for k in np.flatnonzero(counts >= MIN_BLOB_PX):
            if k == 0:
                continue
            v, u = np.nonzero(lab == k)
            z = D[f, v, u]
            P = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
            fit = fit_sphere(P, rng)
            if fit is not None and fit[2] >= MIN_SHARE:
                found.append((fit[0], fit[1]))
        out.append(found)
    return out


def _matches(sa: list, sb: list) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A (M, 3), B (M, 3), frame (M,)) of the same-frame sphere pairs of similar radius."""
    A, B, F = [], [], []
    for f, (xa, xb) in enumerate(zip(sa, sb, strict=True)):
        for ca, ra in xa:
            for cb, rb in xb:
                if abs(ra - rb) <= RADIUS_MATCH_M:
                    A.append(ca)
                    B.append(cb)
                    F.append(f)
    return np.array(A).reshape(-1, 3), np.array(B).reshape(-1, 3), np.array(F, dtype=int)


def _inliers(A: np.ndarray, B: np.ndarray, F: np.ndarray, T: np.ndarray) -> np.ndarray:
    """The correspondences within INLIER_M under T, the closest one per frame."""
    r = np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1)
    keep = np.zeros(len(A), bool)
    for f in np.unique(F):
        idx = np.flatnonzero(F == f)
        k = idx[int(np.argmin(r[idx]))]
        keep[k] = r[k] < INLIER_M
    return keep


def sphere_pose(sa: list, sb: list, seed: int = 0, iters: int = 500) -> tuple[np.ndarray, np.ndarray] | None:
    """(T_ba (4, 4), inlier mask over ``_matches``) from two cameras' per-frame spheres (step 3),
    or None: fewer than MIN_FRAMES inlier frames or a track extent under MIN_SPREAD_M."""
    A, B, F = _matches(sa, sb)
    if len(np.unique(F)) < MIN_FRAMES:
        return None
    rng = np.random.default_rng(seed)
    best, best_key = None, (0, 0.0)
    for _ in range(iters):
        idx = rng.choice(len(A), 3, replace=False)
        if len(np.unique(F[idx])) < 3 or np.linalg.norm(np.cross(A[idx[1]] - A[idx[0]], A[idx[2]] - A[idx[0]])) < 1e-3:
            continue
        T = kabsch(A[idx], B[idx])
        inl = _inliers(A, B, F, T)
        key = (int(inl.sum()), -float(np.linalg.norm(A[inl] @ T[:3, :3].T + T[:3, 3] - B[inl], axis=1).sum()))
        if key > best_key:
            best, best_key = inl, key
    if best is None:
        return None
    inl = best
    for _ in range(2):
        if inl.sum() < MIN_FRAMES:
            return None
        T = kabsch(A[inl], B[inl])
        inl = _inliers(A, B, F, T)
    spread = 2 * float(np.linalg.norm(A[inl] - A[inl].mean(axis=0), axis=1).max()) if inl.any() else 0.0
    if inl.sum() < MIN_FRAMES or spread < MIN_SPREAD_M:
        return None
    return kabsch(A[inl], B[inl]), inl


@dataclass
class SphereRoute:
    """Route (f) over a static rig's frames (module docstring): ``spheres`` per camera (in the
    backbone's ``order``), per frame, the (centre, radius) of each moving sphere; ``planes``
    each camera's floor (None: none found)."""

    spheres: list[list[list[tuple[np.ndarray, float]]]]
    planes: list[FloorPlane | None]
    seed: int = 0

    @classmethod
    def build(cls, frames: Sequence[Frame], rig: Rig, order: Sequence[int], planes, seed: int = 0) -> SphereRoute:
        """The spheres of the cameras ``order`` (rig indices) in ``frames``, with their floor
        ``planes`` (same order)."""
        spheres = []
        for k in order:
            lo, hi = rig.cameras[k].depth_range
            D = np.stack([f.depth[k].numpy() if bool(f.present[k]) else np.zeros(f.depth[k].shape) for f in frames])
            D = np.where((D >= lo) & (D <= hi), D, 0.0)
            spheres.append(camera_spheres(D, rig.cameras[k].K, seed))
        return cls(spheres, list(planes), seed)

    def pair(self, a: int, b: int) -> list[dict]:
        """[] or the pair's candidates (module docstring, step 3)."""
        fit = sphere_pose(self.spheres[a], self.spheres[b], self.seed)
        if fit is None:
            return []
        T, inl = fit
        A, B, _ = _matches(self.spheres[a], self.spheres[b])
        A, B = A[inl], B[inl]
        out = [_candidate(T, A, B)]
        pa, pb = self.planes[a], self.planes[b]
        if pa is not None and pb is not None:
            out += _floor_candidate(A, B, pa, pb)
        return out

    def info(self) -> dict:
        return {"frames_with_sphere": [sum(bool(s) for s in cam) for cam in self.spheres]}


def _candidate(T: np.ndarray, A: np.ndarray, B: np.ndarray, X_a=None, X_b=None, route: str = "sphere") -> dict:
    r = np.linalg.norm(A @ T[:3, :3].T + T[:3, 3] - B, axis=1)
    return {"route": route, "T_ba": T, "inliers": len(A), "X_a": A if X_a is None else X_a,
            "X_b": B if X_b is None else X_b, "track_rms_m": float(np.sqrt(np.mean(r**2)))}  # fmt: skip


def _floor_candidate(A: np.ndarray, B: np.ndarray, pa: FloorPlane, pb: FloorPlane) -> list[dict]:
    """The floor-held candidate (module docstring, step 3): both floors kept, yaw and shift from
    the centres, their feet on the floors as correspondences too."""
    from fuseflow.calib.subject import track_pose

    fit = track_pose(A, B, pa, pb)
    if fit is None:
        return []
    T, mask = fit
    Fa = A[mask] - pa.distance(A[mask])[:, None] * pa.normal[None]
    Fb = Fa @ T[:3, :3].T + T[:3, 3]
    return [_candidate(T, A[mask], B[mask], np.r_[A[mask], Fa], np.r_[B[mask], Fb], "sphere+floor")]
