"""Depth-aware joint refinement of all placed cameras at once (beyond the paper).

Every backbone's poses are only as good as the keypoints and planes they came from: on the wider
ICL virtual rigs the rotation stays ~0.8 deg off, because a 3-D keypoint lifted by noisy depth
moves a wide-baseline edge by a degree and nothing afterwards looks at the dense depth. This
stage does: a multi-view point-to-plane Gauss-Newton over every overlapping camera pair at once.

Residuals, for a sample x of camera i's depth (world point X_i) and each neighbour j:

    r = n_j . (X_i - Q_j)         (metres)

where (u, v) is X_i projected into camera j (projective association, no k-d tree), Q_j is j's
own depth at (u, v) back-projected to the world and n_j its surface normal there. A pair is
kept only when the depths agree within a gate (metres, shrinking over the iterations, never
below 3 sigma(z)), the normals within ``NORMAL_DEG`` and the point is not occluded or in front
of j's surface; each residual is weighted by 1 / (sigma_i(z)^2 + sigma_j(z)^2) with the axial
noise of each camera's sensor (``Camera.sensor`` from rig.json; a structured-light sensor when
it names none: :data:`SIGMA_A`, :data:`SIGMA_B`, Nguyen et al. 2012; used as a relative weight only) and by a Huber IRLS weight. The unknowns are a small rigid update of
each camera's world-from-camera pose (6 per camera, the anchor fixed), solved with all pairs in
one normal-equation system. A weak prior holds every camera near its start (``PRIOR_DEG``,
``PRIOR_M``), which only matters for directions the depth does not constrain (a camera seeing
one plane can slide along it: the prior keeps it where the backbone put it).

The keypoint tracks of a metric backbone (the ``rgbd`` edges' verified 3-D matches) enter the
same system as point-to-point residuals: they hold the directions a few planes cannot (a
3-camera ring sees the floor and two walls). Dense-only refinement moved all 12 simulated rings
it was tried on away from the truth (0.07 -> 0.24 deg on average), so a camera with fewer than
``MIN_TRACKS`` track matches (a camera COLMAP placed, any camera of a scale-free backbone) is
held where its backbone put it and only serves as a neighbour. A dense sample counts
``DENSE_WEIGHT`` of a keypoint match.

The result is kept unless it fits the depth measurably worse (``JointRefineResult.accepted``):
the share of samples of the overlapping pairs whose point-to-plane residual is within 1 cm must
not fall by more than ``MAX_MEAN_DROP`` on average or ``MAX_CAMERA_DROP`` for any camera;
otherwise the input poses come back unchanged. The check uses a fixed gate, the same before and
after, not the shrinking one.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from fuseflow.calib.accuracy import CELL_M
from fuseflow.geometry.noise import SENSOR_NOISE, camera_noise, sigma
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = ["JointRefineResult", "depth_fit", "joint_refine", "SIGMA_A", "SIGMA_B"]

#: Axial depth noise sigma(z) = SIGMA_A + SIGMA_B (z - SIGMA_Z0)^2 (metres): the Kinect v1 row of
#: fuseflow.geometry.noise.SENSOR_NOISE, used as a relative weight between near and far samples.
SIGMA_A, SIGMA_B, SIGMA_Z0 = SENSOR_NOISE["kinect_v1"]
#: Samples per camera, split over the frames used (a regular pixel grid over the valid depth).
SAMPLES = 12000
#: Association gates (metres) per iteration; an iteration's gate is never below 3 sigma(z).
GATES_M = (0.06, 0.04, 0.03, 0.02, 0.015, 0.01, 0.01, 0.01, 0.01, 0.01)
#: Largest angle between the two cameras' surface normals at an associated pair.
NORMAL_DEG = 30.0
#: Weight of one dense sample relative to one keypoint match of the same sigma: neighbouring
#: samples share their errors (smoothing, multipath, calibration of the depth sensor), so the dense
#: term counts as fewer independent measurements than it has samples.
DENSE_WEIGHT = 0.05
#: A camera with fewer keypoint-track matches than this is held fixed: the dense term alone moved
#: every simulated ring of the measurement away from the truth (docs/gmac.md, ``--no-tracks``).
MIN_TRACKS = 10
#: Huber threshold in units of sigma.
HUBER_K = 2.0
#: Prior on each camera's total update: rotation (deg) and translation (m) standard deviations.
PRIOR_DEG = 2.0
PRIOR_M = 0.05
#: The acceptance check's gate (metres) and the largest allowed drop of the mean share and of
#: one camera's share (the share moves by up to ~0.01 between poses 0.05 deg apart on noisy
#: simulated depth, docs/gmac-rgbd.md: the check guards against a worse fit, it cannot rank
#: poses that close).
CHECK_M = 0.01
MAX_MEAN_DROP = 0.005
MAX_CAMERA_DROP = 0.02
#: Normals from point differences this many pixels apart (smooths sensor noise).
NORMAL_STEP = 2
#: Samples whose normal differs from a normal a few pixels away by more than this are dropped.
CREASE_DEG = 10.0
#: Box filter (pixels) over the point map before the normals are taken.
SMOOTH = 7
#: Two neighbouring points further apart in depth than this share of z are a depth edge.
EDGE_REL = 0.03


@dataclass
class JointRefineResult:
    """Refined poses and what the refinement measured.

    Attributes:
        T_cam_world: camera id -> (4, 4) camera-from-world (metres): refined when ``accepted``,
            else the input poses.
        accepted: whether the refined poses fit the depth better (module docstring).
        inlier_before / inlier_after: camera id -> share of its associated samples within
            ``CHECK_M`` (point to plane) over all its overlapping pairs, before / after.
        moved: camera id -> (rotation deg, translation mm) of the refinement.
        pairs: overlapping (i, j) camera-id pairs used.
        iterations: Gauss-Newton iterations run.
        reason: why the result was not accepted ("" when accepted).
        T_refined: the refined poses whether accepted or not (diagnostics).
        expected: camera id -> (deg, mm) expected error of each refined (not held) camera's
            refined pose (``_posterior``).
    """

    T_cam_world: dict[str, np.ndarray]
    accepted: bool
    inlier_before: dict[str, float] = field(default_factory=dict)
    inlier_after: dict[str, float] = field(default_factory=dict)
    moved: dict[str, tuple[float, float]] = field(default_factory=dict)
    pairs: list[tuple[str, str]] = field(default_factory=list)
    iterations: int = 0
    reason: str = ""
    T_refined: dict[str, np.ndarray] = field(default_factory=dict)
    expected: dict[str, tuple[float, float]] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """JSON-ready summary for the calibration report."""
        return {
            "accepted": self.accepted,
            "reason": self.reason,
            "iterations": self.iterations,
            "pairs": len(self.pairs),
            "inlier_1cm_before": {c: round(v, 4) for c, v in self.inlier_before.items()},
            "inlier_1cm_after": {c: round(v, 4) for c, v in self.inlier_after.items()},
            "moved_deg_mm": {c: [round(r, 4), round(t, 2)] for c, (r, t) in self.moved.items()},
            "expected_deg_mm": {c: [round(r, 4), round(t, 2)] for c, (r, t) in self.expected.items()},
        }


@dataclass(frozen=True)
class _View:
    """One camera's depth in one frame: the full-resolution point map (camera frame, metres),
    normals (camera frame, unit, NaN where unknown) and a sample of valid pixels."""

    K: np.ndarray
    depth: np.ndarray
    normals: np.ndarray
    points: np.ndarray
    samples: np.ndarray  # (S, 3) camera-frame points of the sample
    sample_normals: np.ndarray  # (S, 3)
    noise: tuple[float, float, float] = (SIGMA_A, SIGMA_B, SIGMA_Z0)  # the camera's sigma(z) (a, b, z0)


def sigma_z(z: np.ndarray) -> np.ndarray:
    """Axial depth noise (metres) at depth z (metres), the relative weighting model."""
    return sigma(z, SIGMA_A, SIGMA_B, SIGMA_Z0)


def _point_map(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    z = depth.astype(np.float64)
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)


def _normals(P: np.ndarray, valid: np.ndarray, step: int) -> np.ndarray:
    """(H, W, 3) unit normals facing the camera from central differences ``step`` pixels apart;
    NaN at the border, next to invalid depth or across a depth edge."""
    n = np.full(P.shape, np.nan)
    s = step
    c = P[s:-s, s:-s]
    dx = P[s:-s, 2 * s :] - P[s:-s, : -2 * s]
    dy = P[2 * s :, s:-s] - P[: -2 * s, s:-s]
    ok = valid[s:-s, s:-s] & valid[s:-s, 2 * s :] & valid[s:-s, : -2 * s] & valid[2 * s :, s:-s] & valid[: -2 * s, s:-s]
    ok &= (np.abs(dx[..., 2]) < EDGE_REL * 2 * s * c[..., 2]) & (np.abs(dy[..., 2]) < EDGE_REL * 2 * s * c[..., 2])
    nn = np.cross(dx, dy)
    norm = np.linalg.norm(nn, axis=-1, keepdims=True)
    ok &= norm[..., 0] > 0
    nn = nn / np.where(norm > 0, norm, 1.0)
    flip = np.sum(nn * c, axis=-1) > 0  # face the camera (the camera is at the origin)
    nn[flip] *= -1
    nn[~ok] = np.nan
    n[s:-s, s:-s] = nn
    return n


def _smooth(P: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """Box-filtered point map over valid pixels (normals of noisy depth need a wider support)."""
    import cv2

    if size <= 1:
        return P
    w = valid.astype(np.float32)
    den = cv2.boxFilter(w, -1, (size, size), normalize=False, borderType=cv2.BORDER_CONSTANT)
    out = np.empty_like(P)
    for k in range(3):
        num = cv2.boxFilter(
            (P[..., k] * w).astype(np.float32), -1, (size, size), normalize=False, borderType=cv2.BORDER_CONSTANT
        )
        out[..., k] = num / np.maximum(den, 1e-6)
    return out


def _near_crease(N: np.ndarray, h: int) -> np.ndarray:
    """(H, W) bool: the normal ``h`` pixels away in any of the four directions differs by more
    than ``CREASE_DEG`` (or is unknown): a corner or an edge, where a smoothed normal is neither
    surface's and the point-to-plane residual is biased."""
    cos = np.cos(np.radians(CREASE_DEG))
    out = np.zeros(N.shape[:2], dtype=bool)
    H, W = out.shape
    for dv, du in ((h, 0), (-h, 0), (0, h), (0, -h)):
        a = N[max(dv, 0) : H + min(dv, 0), max(du, 0) : W + min(du, 0)]
        b = N[max(-dv, 0) : H + min(-dv, 0), max(-du, 0) : W + min(-du, 0)]
        with np.errstate(invalid="ignore"):
            bad = ~(np.sum(a * b, axis=-1) > cos)
        out[max(-dv, 0) : H + min(-dv, 0), max(-du, 0) : W + min(-du, 0)] |= bad
    return out


def _view(
    depth: np.ndarray, K: np.ndarray, drange: Sequence[float], samples: int, noise=(SIGMA_A, SIGMA_B, SIGMA_Z0)
) -> _View:
    valid = (depth > drange[0]) & (depth < drange[1]) & np.isfinite(depth)
    P = _point_map(np.where(valid, depth, 0.0), K)
    N = _normals(_smooth(P, valid, SMOOTH), valid, NORMAL_STEP)
    N[_near_crease(N, SMOOTH // 2 + NORMAL_STEP)] = np.nan
    good = valid & np.isfinite(N[..., 0])
    count = int(good.sum())
    stride = max(1, int(np.sqrt(count / max(samples, 1))))
    grid = np.zeros_like(good)
    grid[::stride, ::stride] = True
    v, u = np.nonzero(good & grid)
    return _View(K, np.where(valid, depth, 0.0), N, P, P[v, u], N[v, u], tuple(noise))


def _associate(vi: _View, vj: _View, Wi: np.ndarray, Wj: np.ndarray, gate: float):
    """Samples of camera i associated with camera j's depth under world-from-camera poses Wi, Wj.

    Returns (X world (m, 3), Q world (m, 3), n_j world (m, 3), sigma (m,)) or None."""
    Tji = invert_rigid(Wj) @ Wi
    Xj = vi.samples @ Tji[:3, :3].T + Tji[:3, 3]
    idx = np.flatnonzero(Xj[:, 2] > 1e-3)
    Xj = Xj[idx]
    K = vj.K
    h, w = vj.depth.shape
    x, y, z = Xj[:, 0], Xj[:, 1], Xj[:, 2]
    u = np.rint(K[0, 0] * x / z + K[0, 2]).astype(np.int64)
    v = np.rint(K[1, 1] * y / z + K[1, 2]).astype(np.int64)
    k = np.flatnonzero((u >= 0) & (u < w) & (v >= 0) & (v < h))
    # the gates one after the other, each on the survivors of the last (the same tests as one
    # mask over all samples, on fewer points: this runs ~3000 times per calibration); pixels as
    # flat indices into the C-ordered maps (one gather instead of a two-index one)
    Xj, idx, f = Xj[k], idx[k], v[k] * w + u[k]
    N = vj.normals.reshape(-1, 3)
    D = vj.depth.reshape(-1)[f]
    k = np.flatnonzero((D > 0) & np.isfinite(N[f, 0]))
    Xj, idx, f, D = Xj[k], idx[k], f[k], D[k]
    sig = np.sqrt(sigma(Xj[:, 2], *vi.noise) ** 2 + sigma(np.maximum(D, 1e-3), *vj.noise) ** 2)
    k = np.flatnonzero(np.abs(Xj[:, 2] - D) < np.maximum(gate, 3 * sig))
    Xj, idx, f, sig = Xj[k], idx[k], f[k], sig[k]
    nj = N[f]
    ni = vi.sample_normals[idx] @ Tji[:3, :3].T
    cos = ni[:, 0] * nj[:, 0] + ni[:, 1] * nj[:, 1] + ni[:, 2] * nj[:, 2]  # np.sum(ni * nj, axis=1)
    ok = cos > np.cos(np.radians(NORMAL_DEG))
    if ok.sum() < 3:
        return None
    Q = vj.points.reshape(-1, 3)[f[ok]]
    Rw, tw = Wj[:3, :3], Wj[:3, 3]
    return Xj[ok] @ Rw.T + tw, Q @ Rw.T + tw, nj[ok] @ Rw.T, sig[ok]


def _skew_rows(a: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Rows of d(n . (w x a + t)) / d(w, t) = [a x n, n] for the point a and normal n."""
    return np.concatenate([np.cross(a, n), n], axis=1)


def _exp_se3(xi: np.ndarray) -> np.ndarray:
    """4x4 rigid transform of the twist (w, t) (rotation vector w, translation t applied after)."""
    w, t = xi[:3], xi[3:]
    th = np.linalg.norm(w)
    if th < 1e-12:
        R = np.eye(3)
    else:
        k = w / th
        Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _pairs(views: list[list[_View]], W: list[np.ndarray], gate: float) -> list[tuple[int, int]]:
    """Ordered camera pairs (i, j) with at least 1 % of i's samples associated in the first frame."""
    out = []
    n = len(W)
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            a = _associate(views[0][i], views[0][j], W[i], W[j], gate)
            if a is not None and len(a[0]) >= max(50, 0.01 * len(views[0][i].samples)):
                out.append((i, j))
    return out


def _inlier_shares(views, W, pairs, n: int) -> np.ndarray:
    """Per camera: share of its associated samples (gate ``3 CHECK_M``) whose |r| < CHECK_M,
    over every pair it is in and every frame; NaN for a camera in no pair."""
    hit, tot = np.zeros(n), np.zeros(n)
    for frame_views in views:
        for i, j in pairs:
            a = _associate(frame_views[i], frame_views[j], W[i], W[j], 3 * CHECK_M)
            if a is None:
                continue
            X, Q, nj, _ = a
            r = np.abs(np.sum(nj * (X - Q), axis=1))
            for c in (i, j):
                hit[c] += float((r < CHECK_M).sum())
                tot[c] += len(r)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(tot > 0, hit / np.maximum(tot, 1), np.nan)


def _add_tracks(H: np.ndarray, g: np.ndarray, W, tracks, meat: np.ndarray | None = None) -> None:
    """Point-to-point terms of the keypoint tracks: r = W_i X_i - W_j X_j (world, 3 rows per
    match), Huber-weighted in units of the match's sigma. ``meat``: also add each cell's summed
    gradient's outer product to it (``_add_cells``)."""
    for i, j, Xi, Xj, sig in tracks:
        A = Xi @ W[i][:3, :3].T + W[i][:3, 3]
        B = Xj @ W[j][:3, :3].T + W[j][:3, 3]
        r = A - B
        e = np.linalg.norm(r, axis=1) / sig
        wgt = np.where(e <= HUBER_K, 1.0, HUBER_K / np.maximum(e, 1e-12)) / sig**2
        # d(W X)/d(w, t) = [-[X]x, I]; sums over the matches of J^T w J and J^T w r
        for (p, P), (q, Q) in (((i, A), (i, A)), ((i, A), (j, B)), ((j, B), (i, A)), ((j, B), (j, B))):
            sign = (1 if p == i else -1) * (1 if q == i else -1)
            H[6 * p : 6 * p + 6, 6 * q : 6 * q + 6] += sign * _point_block(P, Q, wgt)
        gi = np.concatenate([np.sum(wgt[:, None] * np.cross(A, r), axis=0), np.sum(wgt[:, None] * r, axis=0)])
        g[6 * i : 6 * i + 6] += gi
        gj = np.concatenate([np.sum(wgt[:, None] * np.cross(B, r), axis=0), np.sum(wgt[:, None] * r, axis=0)])
        g[6 * j : 6 * j + 6] -= gj
        if meat is not None:
            wr = wgt[:, None] * r
            per = np.concatenate([np.cross(A, wr), wr, -np.cross(B, wr), -wr], axis=1)
            _add_cells(meat, (i, j), A, per)


def _point_block(P: np.ndarray, Q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """sum_k w_k J(P_k)^T J(Q_k) with J(X) = [-[X]x, I] (3 x 6)."""
    out = np.zeros((6, 6))
    for k in range(3):
        e = np.zeros(3)
        e[k] = 1.0
        # row k of J(X): [-(X x e_k)... ] written via the identity -[X]x^T e_k = X x e_k... use cross
        Jp = np.concatenate([np.cross(P, e), np.tile(e, (len(P), 1))], axis=1)
        Jq = np.concatenate([np.cross(Q, e), np.tile(e, (len(Q), 1))], axis=1)
        out += (Jp * w[:, None]).T @ Jq
    return out


def _normal_equations(views, W, W0, pairs, gate: float, tracks=(), meat: np.ndarray | None = None):
    """The robust Gauss-Newton system (H (6n, 6n), g (6n,)) at the poses ``W``: keypoint tracks,
    dense depth pairs and the prior toward ``W0``. ``meat``: also add each cell's summed
    gradient's outer product to it (``_add_cells``), from the same associations."""
    n = len(W)
    H = np.zeros((6 * n, 6 * n))
    g = np.zeros(6 * n)
    _add_tracks(H, g, W, tracks, meat)
    _add_dense(H, g, views, W, pairs, gate, meat)
    prior = np.tile(np.r_[[np.radians(PRIOR_DEG) ** -2] * 3, [PRIOR_M**-2] * 3], n)
    drift = np.concatenate([_log_se3(W[k] @ invert_rigid(W0[k])) for k in range(n)])
    H += np.diag(prior)
    g += prior * drift
    return H, g


def _add_dense(H: np.ndarray, g: np.ndarray, views, W, pairs, gate: float, meat: np.ndarray | None = None) -> None:
    """Point-to-plane terms of the dense depth pairs (module docstring), Huber-weighted.
    ``meat``: also add each cell's summed gradient's outer product to it (``_add_cells``)."""
    for frame_views in views:
        for i, j in pairs:
            a = _associate(frame_views[i], frame_views[j], W[i], W[j], gate)
            if a is None:
                continue
            X, Q, nj, sig = a
            r = np.sum(nj * (X - Q), axis=1)
            e = np.abs(r) / sig
            wgt = DENSE_WEIGHT * np.where(e <= HUBER_K, 1.0, HUBER_K / np.maximum(e, 1e-12)) / sig**2
            Ji = _skew_rows(X, nj)
            Jj = -Ji  # j's point and normal move together: r is invariant under a common motion
            for (p, Jp), (q, Jq) in (((i, Ji), (i, Ji)), ((i, Ji), (j, Jj)), ((j, Jj), (i, Ji)), ((j, Jj), (j, Jj))):
                H[6 * p : 6 * p + 6, 6 * q : 6 * q + 6] += (Jp * wgt[:, None]).T @ Jq
            g[6 * i : 6 * i + 6] += Ji.T @ (wgt * r)
            g[6 * j : 6 * j + 6] += Jj.T @ (wgt * r)
            if meat is not None:
                wr = (wgt * r)[:, None]
                _add_cells(meat, (i, j), X, np.concatenate([Ji * wr, Jj * wr], axis=1))


def _add_cells(meat: np.ndarray, cams: tuple[int, int], X: np.ndarray, per: np.ndarray) -> None:
    """Add to ``meat`` (6n, 6n) the outer products of the gradient contributions ``per`` (m, 12:
    camera i's 6, then j's) summed within cells of ``CELL_M`` of the world points ``X`` (m, 3):
    samples of one patch share their error (depth bias, smoothing), so a cell is one measurement."""
    _, cell = np.unique(np.floor(X / CELL_M).astype(np.int64), axis=0, return_inverse=True)
    cell = cell.ravel()
    n = int(cell.max()) + 1
    G = np.stack([np.bincount(cell, per[:, k], n) for k in range(per.shape[1])], axis=1)
    idx = np.r_[6 * cams[0] : 6 * cams[0] + 6, 6 * cams[1] : 6 * cams[1] + 6]
    meat[np.ix_(idx, idx)] += G.T @ G


def _free(n: int, fixed: list[int]) -> np.ndarray:
    free = np.ones(6 * n, bool)
    for k in fixed:
        free[6 * k : 6 * k + 6] = False
    return free


def _gauss_newton_step(views, W, W0, pairs, fixed: list[int], gate: float, tracks=()) -> np.ndarray:
    """One robust Gauss-Newton step: (n, 6) twists (rotation vector, translation) in the world
    frame, zero for the ``fixed`` cameras (the anchor and those without keypoint tracks)."""
    n = len(W)
    H, g = _normal_equations(views, W, W0, pairs, gate, tracks)
    free = _free(n, fixed)
    xi = np.zeros(6 * n)
    xi[free] = -np.linalg.solve(H[np.ix_(free, free)] + 1e-9 * np.eye(int(free.sum())), g[free])
    return xi.reshape(n, 6)


def _posterior(views, W, W0, pairs, fixed: list[int], tracks) -> dict[int, tuple[float, float]]:
    """Camera index -> (expected rotation error deg, expected centre error mm) of each refined
    camera at the refined poses ``W`` (the final gate's system, the ``fixed`` cameras held): the
    cluster-robust covariance of the weighted least squares the refinement solves,
    H^-1 (sum over cells of g_c g_c^T) H^-1, with H its normal matrix (prior included) and g_c a
    cell's summed gradient of the keypoint and dense terms at the solution (``_add_cells``): the
    residuals say how noisy each term is, the cells how many independent measurements it has.
    The centre's error through its lever arm from the rig's centre."""
    n = len(W)
    free = _free(n, fixed)
    if not free.any():
        return {}
    meat = np.zeros((6 * n, 6 * n))
    H, _ = _normal_equations(views, W, W0, pairs, GATES_M[-1], tracks, meat)
    Hinv = np.linalg.inv(H[np.ix_(free, free)])
    cov = np.zeros((6 * n, 6 * n))
    cov[np.ix_(free, free)] = Hinv @ meat[np.ix_(free, free)] @ Hinv
    out = {}
    for k in range(n):
        if k in fixed:
            continue
        C = cov[6 * k : 6 * k + 6, 6 * k : 6 * k + 6]
        c = W[k][:3, 3]
        J = np.hstack([-np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]]), np.eye(3)])
        out[k] = (float(np.degrees(np.sqrt(np.trace(C[:3, :3])))), float(np.sqrt(np.trace(J @ C @ J.T)) * 1000))
    return out


def _log_se3(T: np.ndarray) -> np.ndarray:
    """(rotation vector, translation) of a rigid transform (first order, for the prior)."""
    R = T[:3, :3]
    cos = np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)
    th = np.arccos(cos)
    vee = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    w = vee / 2 if th < 1e-9 else th / (2 * np.sin(th)) * vee
    return np.r_[w, T[:3, 3]]


def joint_refine(
    T_cam_world: Mapping[str, np.ndarray],
    frames: Sequence[Frame],
    rig: Rig,
    anchor: str | None = None,
    max_frames: int = 3,
    samples: int = SAMPLES,
    tracks: Sequence[tuple[str, str, np.ndarray, np.ndarray, np.ndarray]] = (),
    only: Collection[str] | None = None,
) -> JointRefineResult:
    """Refine every placed camera at once on the dense depth of ``frames`` (module docstring).

    Args:
        T_cam_world: camera id -> (4, 4) camera-from-world (metres) for the placed cameras.
        frames: frames of a static rig (depth (N, H, W) float32 metres); up to ``max_frames``
            spread over them are used (a person walking through adds overlap).
        rig: intrinsics and depth ranges of the frames' cameras.
        anchor: the camera held fixed (default: the first placed camera in rig order).
        samples: depth samples per camera, split over the frames used.
        tracks: keypoint correspondences (camera id a, camera id b, X_a (m, 3) and X_b (m, 3)
            the same points in each camera's frame, metres, sigma (m,) metres), e.g. the
            verified 3-D matches of the ``rgbd`` backbone's edges; pairs with an unplaced
            camera are ignored.
        only: when given, exactly these cameras are refined, on the dense depth alone where they
            have no tracks, and every other camera is held (a camera turned by whole room periods
            after the refinement: its tracks are the aliased matches the turn left behind, and
            its neighbours were already refined).

    Returns:
        :class:`JointRefineResult` (the input poses when fewer than two cameras overlap or the
        check rejects the refinement).
    """
    ids = [c for c in frames[0].camera_ids if c in T_cam_world]
    if len(ids) < 2:
        return JointRefineResult(dict(T_cam_world), False, reason="fewer than two placed cameras")
    anchor = anchor if anchor in ids else next(c for c in rig.ids if c in ids)
    views = _frame_views(frames, rig, ids, max_frames, samples)
    W0 = [invert_rigid(np.asarray(T_cam_world[c], dtype=np.float64)) for c in ids]
    C = np.eye(4)  # conditioning: rotate about the rig's centre, not the anchor's
    C[:3, 3] = -np.mean([w[:3, 3] for w in W0], axis=0)
    W0 = [C @ w for w in W0]
    pairs = _pairs(views, W0, GATES_M[0])
    if not pairs:
        return JointRefineResult(dict(T_cam_world), False, reason="no overlapping pair")
    tr = [
        (ids.index(ca), ids.index(cb), np.asarray(Xa, float), np.asarray(Xb, float), np.asarray(sg, float))
        for ca, cb, Xa, Xb, sg in tracks
        if ca in ids and cb in ids and len(Xa)
    ]
    counts = np.zeros(len(ids), int)
    for i, j, Xa, _, _ in tr:
        counts[[i, j]] += len(Xa)
    if only is not None:
        fixed = [k for k, c in enumerate(ids) if c not in only or c == anchor]
    else:
        fixed = sorted({ids.index(anchor)} | {k for k in range(len(ids)) if counts[k] < MIN_TRACKS})
    if len(fixed) == len(ids) and only is not None:
        return JointRefineResult(dict(T_cam_world), False, reason="no camera to refine")
    if len(fixed) == len(ids):
        reason = f"no camera has {MIN_TRACKS} keypoint matches: dense depth alone slides sparse rigs (docs/gmac.md)"
        return JointRefineResult(dict(T_cam_world), False, reason=reason)
    W, iterations = _solve(views, W0, pairs, fixed, tr)
    expected = {ids[k]: v for k, v in _posterior(views, W, W0, pairs, fixed, tr).items()}
    before = _inlier_shares(views, W0, pairs, len(ids))
    after = _inlier_shares(views, W, pairs, len(ids))
    Cinv = invert_rigid(C)
    T_new = {c: invert_rigid(Cinv @ W[k]) for k, c in enumerate(ids)}
    for k in fixed:  # held fixed (the anchor, cameras without tracks or not in ``only``), bit for bit
        T_new[ids[k]] = np.asarray(T_cam_world[ids[k]], dtype=np.float64)
    share_b = {c: float(before[k]) for k, c in enumerate(ids) if np.isfinite(before[k])}
    share_a = {c: float(after[k]) for k, c in enumerate(ids) if np.isfinite(after[k])}
    reason = _verdict(share_b, share_a)
    out = {**T_cam_world, **T_new} if not reason else dict(T_cam_world)
    names = [(ids[i], ids[j]) for i, j in pairs]
    moved = {c: _motion(W0[k], W[k]) for k, c in enumerate(ids)}
    return JointRefineResult(out, not reason, share_b, share_a, moved, names, iterations, reason, T_new, expected)


def _frame_views(frames: Sequence[Frame], rig: Rig, ids: list[str], max_frames: int, samples: int):
    """Per used frame, per placed camera, its :class:`_View` (a dropped view has no depth)."""
    picks = np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round().astype(int))
    views = []
    for t in picks:
        f = frames[int(t)]
        depth = f.depth.detach().cpu().numpy()
        present = f.present.cpu().numpy()
        row = []
        for c in ids:
            k = f.camera_ids.index(c)
            d = depth[k] if present[k] else np.zeros_like(depth[k])
            noise = camera_noise(rig[c].sensor, (SIGMA_A, SIGMA_B, SIGMA_Z0))  # rig.json's sensor, else Kinect v1
            row.append(_view(d, rig[c].K, rig[c].depth_range, max(1, samples // len(picks)), noise))
        views.append(row)
    return views


def _solve(views, W0, pairs, fixed: list[int], tracks) -> tuple[list[np.ndarray], int]:
    """Gauss-Newton over the gate schedule; returns the world-from-camera poses and iterations."""
    W = list(W0)
    for it, gate in enumerate(GATES_M, start=1):
        xi = _gauss_newton_step(views, W, W0, pairs, fixed, gate, tracks)
        W = [_exp_se3(xi[k]) @ W[k] for k in range(len(W))]
        if np.abs(xi).max() < 1e-7:
            return W, it
    return W, len(GATES_M)


def _verdict(before: dict[str, float], after: dict[str, float]) -> str:
    """Why the refined poses are not kept ("" when they are): the mean inlier share dropped by
    more than ``MAX_MEAN_DROP`` or one camera's by more than ``MAX_CAMERA_DROP``."""
    mean_b = float(np.mean(list(before.values()))) if before else 0.0
    mean_a = float(np.mean([after.get(c, 0.0) for c in before])) if before else 0.0
    if mean_a < mean_b - MAX_MEAN_DROP:
        return f"the share of depth samples within {CHECK_M * 100:.0f} cm fell ({mean_b:.3f} -> {mean_a:.3f})"
    drops = [c for c in before if after.get(c, 0.0) < before[c] - MAX_CAMERA_DROP]
    if drops:
        return "cameras " + ", ".join(drops) + " fit their neighbours' depth worse"
    return ""


def _motion(W_before: np.ndarray, W_after: np.ndarray) -> tuple[float, float]:
    """(rotation deg, camera-centre translation mm) between two world-from-camera poses."""
    D = W_after @ invert_rigid(W_before)
    ang = float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))
    return ang, float(np.linalg.norm(W_after[:3, 3] - W_before[:3, 3]) * 1000)


def depth_fit(
    frame: Frame, rig: Rig, T_cam_world: Mapping[str, np.ndarray], only: str | None = None
) -> tuple[float, float]:
    """How well camera-from-world poses fit the depth of one frame, with the acceptance check's
    association (``CHECK_M`` gate, ``SAMPLES`` samples per camera, the default sensor noise):
    (mean over overlapping ordered camera pairs of the share of samples within ``CHECK_M`` point
    to plane of the neighbour's surface, median |point-to-plane| residual in mm). Pairs with
    fewer than 50 associated samples are left out; ``only`` keeps the pairs of that camera (both
    directions). Cameras not in ``T_cam_world`` are left out. NaN when no pair overlaps."""
    ids = [c for c in frame.camera_ids if c in T_cam_world]
    depth = frame.depth.numpy()
    views = [_view(depth[frame.camera_ids.index(c)], rig[c].K, rig[c].depth_range, SAMPLES) for c in ids]
    W = [invert_rigid(T_cam_world[c]) for c in ids]
    res, shares = [], []
    for i in range(len(ids)):
        for j in range(len(ids)):
            if i == j or (only is not None and only not in (ids[i], ids[j])):
                continue
            a = _associate(views[i], views[j], W[i], W[j], 3 * CHECK_M)
            if a is None or len(a[0]) < 50:
                continue
            r = np.abs(np.sum(a[2] * (a[0] - a[1]), axis=1))
            res.append(r)
            shares.append(float(np.mean(r < CHECK_M)))
    if not shares:
        return float("nan"), float("nan")
    return float(np.mean(shares)), float(np.median(np.concatenate(res)) * 1000)
