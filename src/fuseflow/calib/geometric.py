"""Route (c) of the metric RGB-D backbone: relative poses from depth geometry alone.

For camera pairs that no image or floor match places (textureless scenes, views 100-130 deg
apart, cameras looking up at a ceiling rig), the two depth clouds are registered without colour:

1. ``CloudFeatures``: each camera's median depth back-projected, voxel-downsampled
   (``voxel``), normals oriented to the camera, FPFH descriptors (Rusu et al. 2009, Open3D).
2. ``geometric_candidates``: mutual nearest neighbours in FPFH space; RANSAC on 3-point
   samples whose side lengths agree (rigid motion preserves them); the ``starts`` best distinct
   hypotheses (by inlier count) each refined by point-to-plane ICP (3 and 1.5 voxels, source
   cloud 2x coarser), converged poses within 2 deg / 4 cm pooled into one *cluster* (basin), one
   pose per basin refined at 0.75 voxel on the full cloud (basins meeting there merge).

Why clusters: on hocap-8rs, a right pose is reached from 7-28 of 30 different RANSAC starts,
while each wrong pose (180-deg flips, 50-130 deg turns) from 1-4, and many wrong poses *pass*
the pairwise depth verification (agreement 0.80-0.98 on small overlaps; FPFH + RANSAC alone was
70-180 deg off on every simulated pair of ../shared/notes/wide-baseline-calibration.md, with ICP
fitness that looked fine). So a pose is proposed only when its basin is wide
(``min_starts``) and at least twice as wide as any other pose that also passes; the caller
(``backbones.rgbd.geometric_route``) verifies it (``verify_pose``) and the cycle test sees it with
every other edge. Inlier counts and ICP fitness never decide.

Conventions as in :mod:`fuseflow.calib.backbones.rgbd`: camera frames (OpenCV axes), metres,
``T_ba`` maps camera a's coordinates to camera b's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fuseflow.calib.posegraph import rotation_angle_deg
from fuseflow.types import invert_rigid

__all__ = [
    "CloudFeatures",
    "PoseCluster",
    "RansacStarts",
    "cloud_features",
    "geometric_candidates",
    "ransac_starts",
    "kabsch",
    "pose_clusters",
]


#: Most points per cloud whose descriptors are matched (``geometric_candidates``).
MATCH_POINTS = 5000


@dataclass
class CloudFeatures:
    """One camera's downsampled cloud (camera frame, metres) and its FPFH descriptors."""

    points: np.ndarray  # (P, 3) float64
    normals: np.ndarray  # (P, 3) float64, oriented towards the camera
    fpfh: np.ndarray  # (P, 33) float64
    voxel: float


def cloud_features(X: np.ndarray, voxel: float) -> CloudFeatures:
    """FPFH features of the camera-frame points ``X`` (M, 3) metres at voxel size ``voxel`` m
    (normals from a 2.5-voxel neighbourhood, FPFH from 5 voxels, Open3D's usual ratios)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(X, dtype=np.float64)))
    pc = pc.voxel_down_sample(voxel)
    if len(pc.points) < 10:
        z = np.zeros((0, 3))
        return CloudFeatures(z, z, np.zeros((0, 33)), voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    f = o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    )
    return CloudFeatures(np.asarray(pc.points), np.asarray(pc.normals), np.asarray(f.data).T.copy(), voxel)


def kabsch(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Batched rigid fit B ~ R A + t of (..., K, 3) point sets; (..., 4, 4)."""
    ca, cb = A.mean(axis=-2, keepdims=True), B.mean(axis=-2, keepdims=True)
    H = np.swapaxes(A - ca, -1, -2) @ (B - cb)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1
    D[..., 1, 1] = 1
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    T = np.zeros(H.shape[:-2] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = cb[..., 0, :] - (R @ np.swapaxes(ca, -1, -2))[..., 0]
    T[..., 3, 3] = 1
    return T


def _mutual_matches(fa: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """(K, 2) index pairs that are each other's nearest neighbour in descriptor space (exact,
    by chunked distance matrices: a k-d tree in 33 dimensions is slower). Ties go to the lower
    index on both sides. The distances are torch's ``cdist``; the reductions are numpy's
    (torch's column-wise ``min(dim=0)`` on a (4096, |B|) matrix is 8x slower than the whole
    numpy path, measured on the 2-core machine under load)."""
    import torch

    if len(fa) == 0 or len(fb) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    A = torch.from_numpy(np.ascontiguousarray(fa, dtype=np.float32))
    B = torch.from_numpy(np.ascontiguousarray(fb, dtype=np.float32))
    best_b = np.empty(len(A), dtype=np.int64)
    best_a_d = np.full(len(B), np.inf, dtype=np.float32)
    best_a = np.zeros(len(B), dtype=np.int64)
    for s in range(0, len(A), 4096):
        D = torch.cdist(A[s : s + 4096], B).numpy()  # (chunk, |B|)
        best_b[s : s + 4096] = D.argmin(axis=1)
        d = D.min(axis=0)
        i = _first_rows(D == d[None]) + s
        better = d < best_a_d  # an earlier chunk keeps a tie
        best_a_d = np.where(better, d, best_a_d)
        best_a = np.where(better, i, best_a)
    i = np.arange(len(A))
    keep = best_a[best_b] == i
    return np.stack([i[keep], best_b[keep]], axis=1).astype(np.int64)


def _first_rows(E: np.ndarray) -> np.ndarray:
    """(C,) the first row of each column of the bool matrix E (R, C) that is True (-1: none);
    ``E.argmax(axis=0)`` but from the few True entries (numpy reduces along axis 0 by copying)."""
    r, c = np.divmod(np.flatnonzero(E), E.shape[1])
    out = np.full(E.shape[1], -1, dtype=np.int64)
    o = np.lexsort((r, c))
    r, c = r[o], c[o]
    first = np.r_[True, c[1:] != c[:-1]] if len(c) else np.zeros(0, dtype=bool)
    out[c[first]] = r[first]
    return out


def _ransac_hypotheses(
    Xa: np.ndarray, Xb: np.ndarray, thr: float, iterations: int, starts: int, seed: int
) -> list[tuple[np.ndarray, int]]:
    """The ``starts`` best distinct (5 deg / 10 cm apart) rigid fits Xb ~ T Xa of random
    3-match samples whose side lengths agree within 10 % + 1 cm and exceed 10 cm; each with its
    inlier count (residual < thr)."""
    m = len(Xa)
    if m < 3:
        return []
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, m, size=(iterations, 3))
    la = np.linalg.norm(Xa[idx] - Xa[np.roll(idx, 1, axis=1)], axis=2)
    lb = np.linalg.norm(Xb[idx] - Xb[np.roll(idx, 1, axis=1)], axis=2)
    ok = np.all(np.abs(la - lb) < 0.1 * np.maximum(la, lb) + 0.01, axis=1) & np.all(la > 0.1, axis=1)
    idx = idx[ok]
    if not len(idx):
        return []
    T = kabsch(Xa[idx], Xb[idx])
    good = np.all(np.isfinite(T), axis=(1, 2))
    T = T[good]
    inl = np.zeros(len(T), dtype=np.int64)
    for s in range(0, len(T), 2048):  # bounded memory: (chunk, m, 3)
        q = np.einsum("hij,kj->hki", T[s : s + 2048, :3, :3], Xa) + T[s : s + 2048, None, :3, 3]
        inl[s : s + 2048] = (np.linalg.norm(q - Xb[None], axis=2) < thr).sum(axis=1)
    out: list[tuple[np.ndarray, int]] = []
    for h in np.argsort(-inl, kind="stable"):
        if len(out) >= starts or inl[h] < 3:
            break
        if any(_close(T[h], o, 5.0, 0.1) for o, _ in out):
            continue
        out.append((T[h], int(inl[h])))
    return out


def _close(A: np.ndarray, B: np.ndarray, deg: float, m: float) -> bool:
    D = A @ invert_rigid(B)
    return rotation_angle_deg(D[:3, :3]) < deg and float(np.linalg.norm(A[:3, 3] - B[:3, 3])) < m


def _se3(x: np.ndarray) -> np.ndarray:
    """(4, 4) rigid transform of the twist x = (w (3,), t (3,)) (rotation by Rodrigues)."""
    w, t = x[:3], x[3:]
    th = float(np.linalg.norm(w))
    Kx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    R = np.eye(3) if th < 1e-12 else np.eye(3) + np.sin(th) / th * Kx + (1 - np.cos(th)) / th**2 * Kx @ Kx
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def _icp(a: np.ndarray, b: CloudFeatures, T: np.ndarray, dists: tuple[float, ...], tree=None) -> np.ndarray:
    """Point-to-plane ICP (Gauss-Newton, Huber-weighted) of the points ``a`` (P, 3) onto b from
    T (4, 4): up to 20 steps per correspondence distance in ``dists`` (voxels of b), coarse to
    fine. Single-threaded numpy + a k-d tree: deterministic. ``tree``: b's cKDTree, if built."""
    from scipy.spatial import cKDTree

    tree = cKDTree(b.points) if tree is None else tree
    T = np.array(T, dtype=np.float64)
    for d in dists:
        dm = d * b.voxel
        for _ in range(20):
            q = a @ T[:3, :3].T + T[:3, 3]
            dist, j = tree.query(q, k=1, distance_upper_bound=dm)
            ok = np.isfinite(dist)
            if ok.sum() < 6:
                return T
            jj = j[ok]
            q, n, p = q[ok], b.normals[jj], b.points[jj]
            r = np.sum(n * (q - p), axis=1)
            J = _point_plane_jacobian(q, n)
            w = 1.0 / np.maximum(1.0, np.abs(r) / (0.5 * dm))
            H = (J * w[:, None]).T @ J
            if np.linalg.cond(H) > 1e10:
                return T
            x = -np.linalg.solve(H, (J * w[:, None]).T @ r)
            T = _se3(x) @ T
            if np.abs(x).max() < 1e-7:
                break
    return T


def _point_plane_jacobian(q: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(P, 6) d r / d (w, t) of r = n . (q - p) for q -> exp(w) q + t: [q x n, n]. The cross
    product written out (the same products and differences as ``np.cross``, without its
    overhead: this runs ~40 times per ICP start)."""
    J = np.empty((len(q), 6))
    q0, q1, q2 = q[:, 0], q[:, 1], q[:, 2]
    n0, n1, n2 = n[:, 0], n[:, 1], n[:, 2]
    J[:, 0] = q1 * n2 - q2 * n1
    J[:, 1] = q2 * n0 - q0 * n2
    J[:, 2] = q0 * n1 - q1 * n0
    J[:, 3:] = n
    return J


def _support(a: np.ndarray, b: CloudFeatures, T: np.ndarray, dm: float, tree, most: int = 400):
    """Correspondences that pin the ICP pose T for the pose graph: up to ``most`` points of a
    (P, 3) within ``dm`` metres of b after T, paired with their foot points on b's tangent
    planes (mapped back into b's frame): X_b - T X_a is the point-to-plane residual along b's
    normal. Returns (X_a (K, 3), X_b (K, 3))."""
    q = a @ T[:3, :3].T + T[:3, 3]
    dist, j = tree.query(q, k=1, distance_upper_bound=dm)
    ok = np.flatnonzero(np.isfinite(dist))
    ok = ok[:: max(1, len(ok) // most)]
    n, p = b.normals[j[ok]], b.points[j[ok]]
    foot = q[ok] - n * np.sum(n * (q[ok] - p), axis=1, keepdims=True)
    return a[ok], foot


def _coarse(c: CloudFeatures, factor: float = 2.0) -> CloudFeatures:
    """``c`` voxel-downsampled ``factor`` x coarser, normals averaged (no descriptors): the
    cheap clouds of the first ICP stage."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(c.points))
    pc.normals = o3d.utility.Vector3dVector(c.normals)
    pc = pc.voxel_down_sample(factor * c.voxel)
    n = np.asarray(pc.normals)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return CloudFeatures(np.asarray(pc.points), n, np.zeros((len(n), 0)), c.voxel)


@dataclass(frozen=True)
class PoseCluster:
    """ICP-refined poses that agree within 1 deg / 2 cm: ``T_ba`` (4, 4) of the first one
    (the start with the most RANSAC inliers), ``starts`` how many starts reached it,
    correspondences that pin it (``_support``: ``X_a``, ``X_b`` (K, 3) metres), and the
    descriptor matches it explains within 1.5 voxels (``M_a``, ``M_b`` (L, 3) metres)."""

    T_ba: np.ndarray
    starts: int
    X_a: np.ndarray
    X_b: np.ndarray
    M_a: np.ndarray
    M_b: np.ndarray


def pose_clusters(poses: list[np.ndarray], deg: float = 1.0, m: float = 0.02) -> list[tuple[np.ndarray, int]]:
    """Greedy clustering of (4, 4) poses in the given order: each joins the first cluster whose
    representative is within ``deg`` / ``m``. Returns [(representative, members)], largest first
    (ties: first formed)."""
    out: list[list] = []
    for T in poses:
        for c in out:
            if _close(T, c[0], deg, m):
                c[1] += 1
                break
        else:
            out.append([T, 1])
    return [(T, k) for T, k in sorted(out, key=lambda c: -c[1])]


@dataclass(frozen=True)
class RansacStarts:
    """The cheap first half of ``geometric_candidates``: the mutual FPFH matches (``X_a``,
    ``X_b`` (K, 3) metres) and the distinct RANSAC hypotheses ICP starts from, best first
    (``hypotheses``: [(T_ba (4, 4), inliers)]). ``consensus``: the best one's inliers (0: none);
    it orders route (c)'s pairs, it never accepts one."""

    X_a: np.ndarray
    X_b: np.ndarray
    hypotheses: list

    @property
    def consensus(self) -> int:
        return int(self.hypotheses[0][1]) if self.hypotheses else 0


def ransac_starts(
    a: CloudFeatures, b: CloudFeatures, starts: int = 20, iterations: int = 20000, seed: int = 0
) -> RansacStarts:
    """Mutual FPFH matches of camera a and b and the ``starts`` best distinct RANSAC hypotheses
    on them (step 2 of the module docstring, before any ICP)."""
    # descriptors of at most MATCH_POINTS regularly spaced points per cloud are matched (the
    # distance matrix is the cost); ICP and the checks use every point
    ia = np.arange(0, len(a.fpfh), max(1, len(a.fpfh) // MATCH_POINTS))
    ib = np.arange(0, len(b.fpfh), max(1, len(b.fpfh) // MATCH_POINTS))
    m = _mutual_matches(a.fpfh[ia], b.fpfh[ib])
    m = np.c_[ia[m[:, 0]], ib[m[:, 1]]]
    if len(m) < 3:
        return RansacStarts(np.zeros((0, 3)), np.zeros((0, 3)), [])
    Xa, Xb = a.points[m[:, 0]], b.points[m[:, 1]]
    return RansacStarts(Xa, Xb, _ransac_hypotheses(Xa, Xb, 1.5 * a.voxel, iterations, starts, seed))


def geometric_candidates(
    a: CloudFeatures,
    b: CloudFeatures,
    starts: int = 20,
    iterations: int = 20000,
    seed: int = 0,
    prepared: RansacStarts | None = None,
) -> list[PoseCluster]:
    """Clusters of ICP-refined FPFH-RANSAC poses from camera a to camera b (module docstring),
    largest first. Empty when either cloud has too few points or no 3 matches agree.
    ``prepared``: ``ransac_starts(a, b, starts, iterations, seed)``, if already computed."""
    rs = prepared if prepared is not None else ransac_starts(a, b, starts, iterations, seed)
    if len(rs.X_a) < 3:
        return []
    Xa, Xb, hyps = rs.X_a, rs.X_b, rs.hypotheses
    thr = 1.5 * a.voxel
    # every start converges on a 2x coarser source cloud (3 and 1.5 voxels); the basins are
    # counted there (2 deg / 4 cm), and only one pose per basin is refined at 0.75 voxel
    from scipy.spatial import cKDTree

    coarse_a, coarse_b = _coarse(a), _coarse(b)
    tree_c, tree = cKDTree(coarse_b.points), cKDTree(b.points)
    coarse = pose_clusters([_icp(coarse_a.points, coarse_b, T, (3.0, 1.5), tree_c) for T, _ in hyps], 2.0, 0.04)
    fine_a = a.points[:: max(1, len(a.points) // 4000)]  # ~4000 points pin 6 DoF
    fine = [(_icp(fine_a, b, T, (1.5, 0.75), tree), k) for T, k in coarse]
    merged: list[list] = []
    for T, k in fine:  # two coarse basins can meet at the fine scale
        for c in merged:
            if _close(T, c[0], 1.0, 0.02):
                c[1] += k
                break
        else:
            merged.append([T, k])
    out = []
    for T, k in sorted(merged, key=lambda c: -c[1]):
        X_a, X_b = _support(fine_a, b, T, 0.75 * b.voxel, tree)
        ok = np.linalg.norm(Xa @ T[:3, :3].T + T[:3, 3] - Xb, axis=1) < thr
        out.append(PoseCluster(T, k, X_a, X_b, Xa[ok], Xb[ok]))
    return out
