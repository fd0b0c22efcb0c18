"""Evaluation metrics, exactly as docs/design.md section 4 fixes them for the whole project.

Extrinsics: :func:`pose_errors` (with :func:`rotation_error_deg`, :func:`translation_error_mm`).
Point clouds without ground truth: :func:`plane_fitting_residual` (PFR), :func:`pncc` (PNCC),
:func:`outlier_ratio` (OR). Against reference surface samples: :func:`chamfer_distance` (CD),
:func:`f_score` (Tanks and Temples), :func:`outlier_share`, or all at once with
:func:`reference_metrics`. Speed and memory: :func:`measure` (a context manager) and
:func:`time_fn`.

Every function takes points as a :class:`fuseflow.FusedCloud`, a torch tensor or a numpy array
of shape (M, 3) in metres (world frame), and returns a dataclass. Distances are reported in mm
where the name says ``_mm``. Nearest-neighbour work uses ``scipy.spatial.cKDTree``; PNCC's normals use
Open3D (imported inside the function). PFR's RANSAC is seeded numpy (see its docstring).
"""

from __future__ import annotations

import math
import resource
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fuseflow.errors import ValidationError
from fuseflow.types import Calibration, Frame, FusedCloud, Rig, check_rigid

__all__ = [
    "ChamferResult",
    "FScoreResult",
    "Measurement",
    "OutlierRatioResult",
    "PFRResult",
    "PNCCResult",
    "Plane",
    "PoseErrors",
    "ReferenceMetrics",
    "SurfaceDistances",
    "TimingResult",
    "as_points",
    "chamfer_distance",
    "f_score",
    "measure",
    "outlier_ratio",
    "outlier_share",
    "plane_fitting_residual",
    "pncc",
    "pose_errors",
    "reference_metrics",
    "rotation_error_deg",
    "surface_distances",
    "time_fn",
    "translation_error_mm",
]


# --------------------------------------------------------------------------------------------
# input conversion
# --------------------------------------------------------------------------------------------


def as_points(points: Any, what: str = "points") -> np.ndarray:
    """Convert a FusedCloud, torch tensor, numpy array or Open3D PointCloud to (M, 3) float64.

    Raises ValidationError naming ``what`` for a wrong shape, a non-numeric input or NaN/inf.
    An empty cloud, shape (0, 3), is accepted.
    """
    if isinstance(points, FusedCloud):
        arr = points.xyz.detach().cpu().numpy()
    elif isinstance(points, torch.Tensor):
        arr = points.detach().cpu().numpy()
    elif type(points).__name__ == "PointCloud" and hasattr(points, "points"):
        arr = np.asarray(points.points)
    else:
        try:
            arr = np.asarray(points)
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"{what}: expected an (M, 3) array of metres, got {type(points).__name__}") from exc
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValidationError(f"{what}: expected a numeric (M, 3) array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValidationError(f"{what}: expected shape (M, 3) (metres, world frame), got {arr.shape}")
    arr = np.asarray(arr, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValidationError(f"{what}: contains NaN or inf ({int((~np.isfinite(arr)).any(1).sum())} points)")
    return arr


def _kdtree(points: np.ndarray):
    from scipy.spatial import cKDTree

    return cKDTree(points)


def _nn_dist(query: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Distance from each query point to its nearest reference point (metres)."""
    if len(query) == 0:
        return np.zeros(0)
    d, _ = _kdtree(ref).query(query, k=1, workers=-1)  # every core: the queries are independent
    return np.asarray(d, dtype=np.float64)


# --------------------------------------------------------------------------------------------
# extrinsics: rotation and translation error
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PoseErrors:
    """Relative-pose errors of estimated extrinsics against reference extrinsics.

    Attributes:
        rotation_deg: mean over camera pairs of the geodesic angle between estimated and
            reference relative rotations, degrees.
        translation_mm: mean over camera pairs of |t_ij - t_ij_ref|, mm, no scale alignment.
        pairs: the (id_i, id_j) pairs evaluated, i before j in input order.
        rotation_deg_per_pair: (P,) float64 degrees, in ``pairs`` order.
        translation_mm_per_pair: (P,) float64 mm, in ``pairs`` order.
        per_camera: id -> (mean rotation deg, mean translation mm) over the pairs with that camera.
        camera_ids: the cameras compared (present in both inputs), input order.
    """

    rotation_deg: float
    translation_mm: float
    pairs: tuple[tuple[str, str], ...]
    rotation_deg_per_pair: np.ndarray
    translation_mm_per_pair: np.ndarray
    per_camera: dict[str, tuple[float, float]]
    camera_ids: tuple[str, ...]


def _pose_set(T: Any, what: str) -> tuple[tuple[str, ...], np.ndarray, bool]:
    """(ids, (N, 4, 4) float64, keyed) from a mapping, Calibration, Rig, array or tensor."""
    if isinstance(T, Calibration):
        T = T.T_cam_world
    if isinstance(T, Rig):
        missing = [c.id for c in T if c.T_cam_world is None]
        if missing:
            raise ValidationError(f"{what}: rig cameras without extrinsics: {missing}")
        T = {c.id: c.T_cam_world for c in T}
    if isinstance(T, Mapping):
        ids = tuple(str(k) for k in T)
        mats = [check_rigid(np.asarray(_to_numpy(v)), f"{what}[{k!r}]") for k, v in T.items()]
        arr = np.stack(mats) if mats else np.zeros((0, 4, 4))
        return ids, arr, True
    try:
        arr = np.asarray(_to_numpy(T), dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(
            f"{what}: expected (N, 4, 4) camera-from-world matrices or a mapping id -> 4x4, got {type(T).__name__}"
        ) from exc
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValidationError(
            f"{what}: expected (N, 4, 4) camera-from-world matrices or a mapping id -> 4x4, got shape {arr.shape}"
        )
    for i in range(len(arr)):
        check_rigid(arr[i], f"{what}[{i}]")
    return tuple(str(i) for i in range(len(arr))), arr, False


def _to_numpy(x: Any) -> Any:
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().double().numpy()
    return x


def _geodesic_deg(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle of R_a^T R_b, degrees, batched over the leading axis.

    atan2(sin, cos) with sin from the skew part equals arccos((tr - 1) / 2) but keeps full
    precision near 0 and 180 degrees, where arccos loses half the digits.
    """
    M = np.einsum("...ji,...jk->...ik", R_a, R_b)
    cos = (np.trace(M, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = np.stack([M[..., 2, 1] - M[..., 1, 2], M[..., 0, 2] - M[..., 2, 0], M[..., 1, 0] - M[..., 0, 1]], -1)
    sin = np.linalg.norm(skew, axis=-1) / 2.0
    return np.degrees(np.arctan2(sin, cos))


def pose_errors(T_est: Any, T_ref: Any) -> PoseErrors:
    """Rotation and translation error of estimated extrinsics (docs/design.md section 4).

    Definition: for every unordered camera pair (i, j), i before j in the input order, the
    relative transform T_ij = T_i T_j^-1 maps camera j's coordinates to camera i's, with
    rotation R_ij = R_i R_j^T and translation t_ij = t_i - R_ij t_j. Then

    * rotation error of the pair = geodesic angle arccos((tr(R_ij_est^T R_ij_ref) - 1) / 2), deg;
    * translation error of the pair = |t_ij_est - t_ij_ref|, mm, with **no** scale or rigid
      alignment (a calibration that is not metric is penalised, as intended for GMAC).

    Both are averaged over all pairs. Relative errors make the result independent of the world
    frame each estimate was expressed in.

    Args:
        T_est, T_ref: camera-from-world 4x4 transforms in metres: an (N, 4, 4) numpy array or
            torch tensor (cameras matched by position), or a mapping id -> 4x4, a
            :class:`fuseflow.Calibration` or a calibrated :class:`fuseflow.Rig` (cameras matched
            by id; cameras present in only one input are ignored). Arrays and id-keyed inputs
            cannot be mixed.

    Raises:
        ValidationError: shapes differ, a matrix is not rigid, the inputs mix keyed and
            positional forms, or fewer than two cameras are common to both.
    """
    ids_e, A, keyed_e = _pose_set(T_est, "T_est")
    ids_r, B, keyed_r = _pose_set(T_ref, "T_ref")
    if keyed_e != keyed_r:
        raise ValidationError(
            "T_est and T_ref must both be arrays (matched by position) or both keyed by camera id "
            "(mapping, Calibration or Rig)"
        )
    if not keyed_e and len(A) != len(B):
        raise ValidationError(f"T_est has {len(A)} cameras, T_ref has {len(B)}; arrays are matched by position")
    common = tuple(i for i in ids_e if i in set(ids_r))
    if len(common) < 2:
        raise ValidationError(
            f"pose errors need at least two cameras common to both inputs, got {list(common)} "
            f"(T_est: {list(ids_e)}, T_ref: {list(ids_r)})"
        )
    A = A[[ids_e.index(c) for c in common]]
    B = B[[ids_r.index(c) for c in common]]
    ii, jj = np.triu_indices(len(common), k=1)

    def relative(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t = T[:, :3, :3], T[:, :3, 3]
        R_ij = np.einsum("pab,pcb->pac", R[ii], R[jj])
        t_ij = t[ii] - np.einsum("pab,pb->pa", R_ij, t[jj])
        return R_ij, t_ij

    R_e, t_e = relative(A)
    R_r, t_r = relative(B)
    rot = _geodesic_deg(R_e, R_r)
    trans = np.linalg.norm(t_e - t_r, axis=1) * 1000.0
    pairs = tuple((common[i], common[j]) for i, j in zip(ii.tolist(), jj.tolist()))
    per_camera = {}
    for k, cid in enumerate(common):
        sel = (ii == k) | (jj == k)
        per_camera[cid] = (float(rot[sel].mean()), float(trans[sel].mean()))
    return PoseErrors(
        rotation_deg=float(rot.mean()),
        translation_mm=float(trans.mean()),
        pairs=pairs,
        rotation_deg_per_pair=rot,
        translation_mm_per_pair=trans,
        per_camera=per_camera,
        camera_ids=common,
    )


def rotation_error_deg(T_est: Any, T_ref: Any) -> float:
    """Mean over camera pairs of the relative-rotation geodesic angle, degrees (see :func:`pose_errors`)."""
    return pose_errors(T_est, T_ref).rotation_deg


def translation_error_mm(T_est: Any, T_ref: Any) -> float:
    """Mean over camera pairs of |t_ij - t_ij_ref|, mm, no scale alignment (see :func:`pose_errors`)."""
    return pose_errors(T_est, T_ref).translation_mm


# --------------------------------------------------------------------------------------------
# PFR: plane fitting residual
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Plane:
    """One extracted plane: unit normal n and offset d with n . x + d = 0 (metres)."""

    normal: np.ndarray
    offset: float
    num_inliers: int
    mean_distance_mm: float


@dataclass(frozen=True)
class PFRResult:
    """Plane fitting residual.

    Attributes:
        pfr_mm: mean distance of all inliers of all extracted planes to their plane, mm
            (inlier-weighted). NaN when no plane with enough inliers was found (e.g. an empty
            or tiny cloud).
        planes: the extracted planes, largest first.
        num_points: points in the input cloud.
        inlier_share: share of the cloud's points that are inliers of some extracted plane.
    """

    pfr_mm: float
    planes: tuple[Plane, ...]
    num_points: int
    inlier_share: float


def _ransac_plane(
    pts: np.ndarray, band: float, num_iterations: int, sample_size: int, rng: np.random.Generator
) -> tuple[np.ndarray, float] | None:
    """Best plane (unit n, d) of ``num_iterations`` random 3-point hypotheses, scored on a subsample."""
    m = len(pts)
    sub = pts if m <= sample_size else pts[rng.choice(m, sample_size, replace=False)]
    tri = pts[rng.integers(0, m, (num_iterations, 3))]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-12
    if not ok.any():
        return None
    n = n[ok] / norm[ok, None]
    d = -np.einsum("ij,ij->i", n, tri[ok, 0])
    best, best_count = -1, -1
    for k in range(0, len(n), 64):  # (S, 64) distance blocks keep memory bounded
        counts = (np.abs(sub @ n[k : k + 64].T + d[k : k + 64]) <= band).sum(0)
        j = int(np.argmax(counts))
        if counts[j] > best_count:
            best, best_count = k + j, int(counts[j])
    return n[best], float(d[best])


def _fit_plane(pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit n, d) through points: the smallest singular vector of the centred set."""
    c = pts.mean(0)
    _, _, vt = np.linalg.svd(pts - c, full_matrices=False)
    return vt[2], float(-vt[2] @ c)


def _refine_plane(pts: np.ndarray, n: np.ndarray, d: float, threshold: float) -> tuple[np.ndarray, float]:
    """PFR step 2 (LO-RANSAC): refit the plane n.x + d = 0 to its inliers within ``threshold``
    metres by least squares, twice (stops early when fewer than 3 inliers remain)."""
    for _refine in range(2):
        inl = np.abs(pts @ n + d) <= threshold
        if inl.sum() < 3:
            break
        n, d = _fit_plane(pts[inl])
    return n, d


def plane_fitting_residual(
    points: Any,
    distance_threshold: float = 0.01,
    max_planes: int = 3,
    min_inlier_fraction: float = 0.05,
    min_inliers: int = 100,
    num_iterations: int = 1000,
    sample_size: int = 20000,
    seed: int = 0,
) -> PFRResult:
    """PFR, docs/design.md section 4: iterative RANSAC plane extraction, mean inlier distance in mm.

    Definition: repeat up to ``max_planes`` times on the points not yet assigned to a plane:

    1. RANSAC: ``num_iterations`` planes through 3 random points; the one with the most points
       within ``distance_threshold`` (counted on a random subsample of ``sample_size`` points)
       wins.
    2. Local refinement (LO-RANSAC): inliers = points within the band of the plane; refit the
       plane to them by least squares (SVD); repeat once with the refitted plane. This removes
       the bias of a plane through 3 noisy samples.
    3. Stop when the plane has fewer than max(``min_inliers``, ``min_inlier_fraction`` * M)
       inliers; otherwise record its inliers' distances to it and remove them.

    PFR = mean of all recorded distances (inlier-weighted over planes), mm. The RANSAC is numpy
    with a seeded generator (rather than Open3D's ``segment_plane``, which samples in parallel
    threads from a global seed), so equal input and seed give an identical result by construction.

    Args:
        points: (M, 3) metres (FusedCloud, tensor or array).
        distance_threshold: RANSAC inlier band, metres. 0.01 = the 1 cm of docs/design.md section 4.
        max_planes: most planes extracted ("top planes"); 3 suits a room corner or a box's faces.
        min_inlier_fraction: a plane needs at least this share of the whole cloud ...
        min_inliers: ... and at least this many points.
        num_iterations: RANSAC hypotheses per plane (1000 finds a plane holding 10 % of the
            points with probability 1 - (1 - 0.1^3)^1000 = 0.63, one holding 20 % with 0.9997).
        sample_size: points used to score hypotheses (the final inliers use every point).
        seed: seed of the numpy generator.

    Returns:
        PFRResult; pfr_mm is NaN when no plane qualifies (an empty or tiny cloud; not an error).
    """
    pts = as_points(points)
    if distance_threshold <= 0 or max_planes < 1 or not 0 <= min_inlier_fraction <= 1 or min_inliers < 3:
        raise ValidationError(
            "plane_fitting_residual: need distance_threshold > 0, max_planes >= 1, "
            f"0 <= min_inlier_fraction <= 1, min_inliers >= 3; got {distance_threshold}, {max_planes}, "
            f"{min_inlier_fraction}, {min_inliers}"
        )
    if num_iterations < 1 or sample_size < 3:
        raise ValidationError(f"need num_iterations >= 1, sample_size >= 3; got {num_iterations}, {sample_size}")
    rng = np.random.default_rng(seed)
    m = len(pts)
    need = max(min_inliers, int(math.ceil(min_inlier_fraction * m)))
    planes: list[Plane] = []
    dists: list[np.ndarray] = []
    remaining = pts
    for _ in range(max_planes):
        if len(remaining) < need:
            break
        hyp = _ransac_plane(remaining, distance_threshold, num_iterations, sample_size, rng)
        if hyp is None:
            break
        n, d = _refine_plane(remaining, *hyp, distance_threshold)
        inl = np.abs(remaining @ n + d) <= distance_threshold
        if inl.sum() < need:
            break
        dist = np.abs(remaining[inl] @ n + d)
        planes.append(Plane(n, d, int(inl.sum()), float(dist.mean() * 1000.0)))
        dists.append(dist)
        remaining = remaining[~inl]
    all_d = np.concatenate(dists) if dists else np.zeros(0)
    return PFRResult(
        pfr_mm=float(all_d.mean() * 1000.0) if len(all_d) else float("nan"),
        planes=tuple(planes),
        num_points=m,
        inlier_share=float(len(all_d) / m) if m else 0.0,
    )


# --------------------------------------------------------------------------------------------
# OR: outlier ratio, and outlier share against ground truth
# --------------------------------------------------------------------------------------------

#: Default n of OR: a point needs at least this many *other* points within the radius.
#: Three neighbours plus the point itself are the fewest that define a local surface patch
#: beyond a line; a surface sampled at spacing below ~4 mm gives every interior point >= 4.
OR_MIN_NEIGHBORS = 3


@dataclass(frozen=True)
class OutlierRatioResult:
    """Outlier ratio.

    Attributes:
        ratio: share of points that are outliers, in [0, 1] (multiply by 100 for the paper's %).
            0.0 for an empty cloud (documented convention).
        num_outliers: count of outlier points.
        num_points: points in the cloud.
        radius: radius used, metres.
        min_neighbors: n used.
        outlier_mask: (M,) bool, True for outliers.
    """

    ratio: float
    num_outliers: int
    num_points: int
    radius: float
    min_neighbors: int
    outlier_mask: np.ndarray


def outlier_ratio(points: Any, radius: float = 0.005, min_neighbors: int = OR_MIN_NEIGHBORS) -> OutlierRatioResult:
    """OR, docs/design.md section 4: share of points with fewer than n neighbours within radius.

    Definition: a point is an outlier when fewer than ``min_neighbors`` *other* points of the
    cloud lie within Euclidean distance ``radius`` of it (the point itself is not counted).
    OR = outliers / M. The outliers are exactly those that Open3D's
    ``remove_radius_outlier(nb_points=n, radius)`` removes (checked on the ICL frames: equal counts).

    The result depends on sampling density: a cloud voxel-downsampled at 1 cm has almost every
    point isolated at 5 mm. Compare methods at similar density or report the density with it.

    Args:
        points: (M, 3) metres.
        radius: metres; 0.005 = the paper's 5 mm.
        min_neighbors: n; default :data:`OR_MIN_NEIGHBORS` = 3 (see its comment).
    """
    pts = as_points(points)
    if radius <= 0 or min_neighbors < 1:
        raise ValidationError(f"outlier_ratio: need radius > 0 and min_neighbors >= 1, got {radius}, {min_neighbors}")
    m = len(pts)
    if m == 0:
        return OutlierRatioResult(0.0, 0, 0, radius, min_neighbors, np.zeros(0, dtype=bool))
    # the (n+1)-th nearest point (the point itself is the first) lies beyond the radius exactly
    # when fewer than n others are within it; a bounded k-NN query is 2.5x faster than counting
    # every neighbour with query_ball_point on dense clouds
    k = min_neighbors + 1
    if m < k:
        return OutlierRatioResult(1.0, m, m, radius, min_neighbors, np.ones(m, dtype=bool))
    d, _ = _kdtree(pts).query(pts, k=k, distance_upper_bound=radius)
    mask = ~np.isfinite(d[:, -1])
    n_out = int(mask.sum())
    return OutlierRatioResult(n_out / m, n_out, m, radius, min_neighbors, mask)


def outlier_share(points: Any, gt_points: Any, threshold: float = 0.02) -> float:
    """Share of points farther than ``threshold`` metres from the nearest reference surface sample.

    Definition: |{p : min_g |p - g| > threshold}| / M with g over ``gt_points``. 0.0 for an
    empty cloud. ``gt_points`` must be non-empty (ValidationError otherwise).

    Args:
        points: (M, 3) metres, the reconstruction.
        gt_points: (G, 3) metres, samples of the reference surface (denser than ``threshold``).
        threshold: metres, default 2 cm.
    """
    pts = as_points(points)
    gt = _check_reference(gt_points)
    if threshold <= 0:
        raise ValidationError(f"outlier_share: threshold must be > 0 metres, got {threshold}")
    if len(pts) == 0:
        return 0.0
    return float((_nn_dist(pts, gt) > threshold).mean())


# --------------------------------------------------------------------------------------------
# CD and F-score against reference surface samples
# --------------------------------------------------------------------------------------------


def _check_reference(gt_points: Any) -> np.ndarray:
    gt = as_points(gt_points, "gt_points")
    if len(gt) == 0:
        raise ValidationError("gt_points: the reference surface samples are empty")
    return gt


@dataclass(frozen=True)
class ChamferResult:
    """Chamfer distance.

    Attributes:
        chamfer_mm: (accuracy_mm + completeness_mm) / 2, mm. inf for an empty prediction.
        accuracy_mm: mean distance prediction -> reference, mm. NaN for an empty prediction.
        completeness_mm: mean distance reference -> prediction, mm. inf for an empty prediction.
        num_points, num_reference: sizes of the two clouds.
    """

    chamfer_mm: float
    accuracy_mm: float
    completeness_mm: float
    num_points: int
    num_reference: int


@dataclass(frozen=True)
class FScoreResult:
    """F-score at one distance threshold (Tanks and Temples).

    Attributes:
        threshold: d, metres.
        precision: share of predicted points with distance to the reference < d, in [0, 1].
        recall: share of reference points with distance to the prediction < d, in [0, 1].
        f_score: 2PR / (P + R), 0 when P + R = 0.
    """

    threshold: float
    precision: float
    recall: float
    f_score: float


@dataclass(frozen=True)
class ReferenceMetrics:
    """All ground-truth metrics from one pair of nearest-neighbour passes."""

    chamfer: ChamferResult
    fscore: FScoreResult
    outlier_share: float


@dataclass(frozen=True)
class SurfaceDistances:
    """Nearest-neighbour distances between a reconstruction and reference surface samples, both
    ways, from which CD, F-score and the outlier share follow (one pair of KD-tree passes for
    all of them; :func:`surface_distances` builds it).

    Attributes:
        to_reference: (Q,) float64 metres, each queried predicted point -> nearest reference
            sample (empty for an empty prediction).
        to_prediction: (R,) float64 metres, each queried reference sample -> nearest predicted
            point (inf for an empty prediction).
    """

    to_reference: np.ndarray
    to_prediction: np.ndarray

    def chamfer(self) -> ChamferResult:
        """CD as :func:`chamfer_distance` defines it, from these distances."""
        d_pred, d_gt = self.to_reference, self.to_prediction
        if len(d_pred) == 0:
            return ChamferResult(float("inf"), float("nan"), float("inf"), 0, len(d_gt))
        acc = float(d_pred.mean() * 1000.0)
        comp = float(d_gt.mean() * 1000.0)
        return ChamferResult((acc + comp) / 2.0, acc, comp, len(d_pred), len(d_gt))

    def fscore(self, threshold: float = 0.01) -> FScoreResult:
        """F-score at ``threshold`` metres as :func:`f_score` defines it, from these distances."""
        if threshold <= 0:
            raise ValidationError(f"f_score: threshold must be > 0 metres, got {threshold}")
        d_pred, d_gt = self.to_reference, self.to_prediction
        p = float((d_pred < threshold).mean()) if len(d_pred) else 0.0
        r = float((d_gt < threshold).mean()) if len(d_pred) else 0.0
        f = 2 * p * r / (p + r) if p + r > 0 else 0.0
        return FScoreResult(threshold, p, r, f)

    def outlier_share(self, threshold: float = 0.02) -> float:
        """Share of queried predicted points farther than ``threshold`` metres from the reference
        (:func:`outlier_share`'s definition); 0.0 for an empty prediction."""
        if threshold <= 0:
            raise ValidationError(f"outlier_share: threshold must be > 0 metres, got {threshold}")
        d_pred = self.to_reference
        return float((d_pred > threshold).mean()) if len(d_pred) else 0.0


def surface_distances(points: Any, gt_points: Any, sample: int | None = None, seed: int = 0) -> SurfaceDistances:
    """Nearest-neighbour distances both ways between ``points`` and ``gt_points``.

    Args:
        points: (M, 3) metres, the reconstruction (FusedCloud, tensor or array).
        gt_points: (G, 3) metres, the reference surface samples (non-empty, else ValidationError).
        sample: query at most this many random points of each side (seeded by ``seed``); the
            KD-trees still hold every point. None = every point.
        seed: seed of the random queries.
    """
    pts = as_points(points)
    gt = _check_reference(gt_points)
    if len(pts) == 0:
        return SurfaceDistances(np.zeros(0), np.full(min(len(gt), sample or len(gt)), np.inf))
    rng = np.random.default_rng(seed)

    def queries(a: np.ndarray) -> np.ndarray:
        return a if sample is None or len(a) <= sample else a[rng.choice(len(a), sample, replace=False)]

    return SurfaceDistances(_nn_dist(queries(pts), gt), _nn_dist(queries(gt), pts))


def chamfer_distance(points: Any, gt_points: Any) -> ChamferResult:
    """CD, docs/design.md section 4: symmetric mean nearest-neighbour distance, mm.

    Definition: accuracy = mean over predicted p of min_g |p - g|; completeness = mean over
    reference g of min_p |g - p|; CD = (accuracy + completeness) / 2, all in mm. The reference
    is a set of surface samples (denser than the prediction's spacing, or CD has a floor of
    about half the sample spacing).

    Empty prediction: accuracy NaN, completeness and CD inf. Empty reference: ValidationError.

    Args:
        points: (M, 3) metres, the reconstruction.
        gt_points: (G, 3) metres, the reference surface samples.
    """
    return surface_distances(points, gt_points).chamfer()


def f_score(points: Any, gt_points: Any, threshold: float = 0.01) -> FScoreResult:
    """F-score at distance ``threshold``, as Tanks and Temples defines it (Knapitsch et al. 2017).

    precision P = share of predicted points whose nearest reference sample is closer than d;
    recall R = share of reference samples whose nearest predicted point is closer than d;
    F = 2PR / (P + R) (0 when both are 0). An empty prediction gives P = R = F = 0.

    Args:
        points: (M, 3) metres, the reconstruction.
        gt_points: (G, 3) metres, the reference surface samples.
        threshold: d in metres (Tanks and Temples sets it per scene; default 1 cm).
    """
    return surface_distances(points, gt_points).fscore(threshold)


def reference_metrics(
    points: Any,
    gt_points: Any,
    f_threshold: float = 0.01,
    outlier_threshold: float = 0.02,
    sample: int | None = None,
    seed: int = 0,
) -> ReferenceMetrics:
    """CD, F-score and outlier share from one pair of KD-tree passes (same definitions as above).

    ``sample``: query at most this many random points of each side (seeded by ``seed``); the
    KD-trees still hold every point, so each mean is an unbiased estimate of the full one. None
    (default) = every point, exact."""
    if outlier_threshold <= 0:
        raise ValidationError(f"outlier_threshold must be > 0 metres, got {outlier_threshold}")
    if sample is not None and sample < 1:
        raise ValidationError(f"sample must be >= 1 or None, got {sample}")
    dist = surface_distances(points, gt_points, sample, seed)
    return ReferenceMetrics(dist.chamfer(), dist.fscore(f_threshold), dist.outlier_share(outlier_threshold))


# --------------------------------------------------------------------------------------------
# PNCC: photometric normalised cross-correlation
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PNCCResult:
    """Photometric NCC score.

    Attributes:
        pncc: mean NCC over the evaluated points, in [-1, 1]; NaN when no point was evaluated.
        num_points: points considered (the cloud, or its random subset of ``max_points``).
        num_evaluated: points seen by two cameras with textured patches in both.
        num_not_covisible: points visible (depth test) in fewer than two cameras.
        num_flat: co-visible points skipped because a patch had (near) zero variance.
        ncc: (num_evaluated,) the per-point NCC values.
    """

    pncc: float
    num_points: int
    num_evaluated: int
    num_not_covisible: int
    num_flat: int
    ncc: np.ndarray


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear sample of a (H, W) image at float pixel coordinates (caller keeps them inside)."""
    u0 = np.floor(u).astype(np.int64)
    v0 = np.floor(v).astype(np.int64)
    du, dv = u - u0, v - v0
    h, w = img.shape
    u1 = np.minimum(u0 + 1, w - 1)
    v1 = np.minimum(v0 + 1, h - 1)
    return (
        img[v0, u0] * (1 - du) * (1 - dv)
        + img[v0, u1] * du * (1 - dv)
        + img[v1, u0] * (1 - du) * dv
        + img[v1, u1] * du * dv
    )


def pncc(
    points: Any,
    frame: Frame,
    rig: Rig,
    depth_tolerance: float = 0.02,
    depth_tolerance_rel: float = 0.02,
    normal_knn: int = 20,
    min_std: float = 1.0,
    max_points: int | None = 200_000,
    seed: int = 0,
) -> PNCCResult:
    """PNCC, docs/design.md section 4: mean NCC of 3x3 grey patches in the two best views of each point.

    Definition, per fused point X (world):

    1. Visibility: X is visible in camera j when the view is present, X projects in front of
       the camera inside the image with a 1-pixel margin (room for the 3x3 patch), and passes
       the depth test |z_j(X) - D_j(nearest pixel)| <= depth_tolerance + depth_tolerance_rel * z
       with D_j > 0 (a surface in front of X means X is occluded there).
    2. "Sees it best": among visible cameras, the two with the largest |cos| between the
       point's normal (Open3D PCA normal over ``normal_knn`` neighbours among the evaluated
       points) and the viewing ray,
       i.e. the most frontal views. With fewer than ``normal_knn`` points, the two nearest
       cameras are used instead.
    3. Grey = 0.299 R + 0.587 G + 0.114 B. A 3x3 patch is sampled bilinearly at the projected
       sub-pixel position + offsets {-1, 0, 1}^2 pixels in both images.
    4. NCC = sum (a - mean a)(b - mean b) / sqrt(sum (a - mean a)^2 sum (b - mean b)^2). Patches
       whose grey standard deviation is below ``min_std`` (grey levels) have no defined NCC and
       are skipped (counted in ``num_flat``).

    PNCC = mean NCC over the points with two visible cameras and textured patches. Clouds larger
    than ``max_points`` are evaluated on a uniform random subset of that size (seeded): PNCC is a
    mean, and 200 000 samples put its sampling error near 0.001 (per-point NCC std is ~0.4 on the
    ICL frames), while a 1.2 M-point naive cloud takes 12 s in full (docs/metrics.md).

    Args:
        points: (M, 3) metres, world frame (FusedCloud, tensor or array).
        frame: the frame the cloud was fused from (colour and depth; any device).
        rig: calibrated rig holding every camera of ``frame``.
        depth_tolerance, depth_tolerance_rel: the depth test (metres, and a share of depth).
        normal_knn: neighbours for the PCA normal.
        min_std: minimum grey standard deviation of a patch, grey levels (0-255).
        max_points: evaluate at most this many points (random subset), or None for all.
        seed: seed of the subset.
    """
    pts, cams = _pncc_inputs(points, frame, rig, max_points, seed)
    m = len(pts)
    if m == 0:
        return PNCCResult(float("nan"), 0, 0, 0, 0, np.zeros(0))
    color = frame.color.detach().cpu().numpy().astype(np.float64)
    grey = color[..., 0] * 0.299 + color[..., 1] * 0.587 + color[..., 2] * 0.114
    depth = frame.depth.detach().cpu().numpy()
    present = frame.present.detach().cpu().numpy()
    normals = _pca_normals(pts, normal_knn) if m >= normal_knn else None
    visible, score, uv = _pncc_visibility(pts, cams, depth, present, normals, depth_tolerance, depth_tolerance_rel)

    covis = visible.sum(0) >= 2
    num_not_covisible = int((~covis).sum())
    pidx = np.nonzero(covis)[0]
    if len(pidx) == 0:
        return PNCCResult(float("nan"), m, 0, num_not_covisible, 0, np.zeros(0))
    best = np.argsort(-score[:, pidx], axis=0, kind="stable")[:2]  # (2, P): the two best views
    ncc, textured = _patch_ncc(grey, uv, best, pidx, min_std)
    return PNCCResult(
        pncc=float(ncc.mean()) if len(ncc) else float("nan"),
        num_points=m,
        num_evaluated=len(ncc),
        num_not_covisible=num_not_covisible,
        num_flat=int((~textured).sum()),
        ncc=ncc,
    )


def _pncc_inputs(points: Any, frame: Frame, rig: Rig, max_points: int | None, seed: int) -> tuple[np.ndarray, list]:
    """PNCC's checks at the boundary, then the (M, 3) float64 points (random subset of
    ``max_points``, seeded) and the rig's cameras in the frame's order."""
    pts = as_points(points)
    if not isinstance(frame, Frame):
        raise ValidationError(f"pncc: frame must be a fuseflow.Frame, got {type(frame).__name__}")
    if not isinstance(rig, Rig):
        raise ValidationError(f"pncc: rig must be a fuseflow.Rig, got {type(rig).__name__}")
    cams = [rig[cid] for cid in frame.camera_ids]
    missing = [c.id for c in cams if c.T_cam_world is None]
    if missing:
        raise ValidationError(f"pncc: cameras without extrinsics: {missing}")
    w, h = frame.resolution
    bad = [c.id for c in cams if (c.width, c.height) != (w, h)]
    if bad:
        raise ValidationError(f"pncc: cameras {bad} have a resolution other than the frame's {w}x{h}")
    if max_points is not None and max_points < 1:
        raise ValidationError(f"pncc: max_points must be >= 1 or None, got {max_points}")
    if max_points is not None and len(pts) > max_points:
        pts = pts[np.sort(np.random.default_rng(seed).choice(len(pts), max_points, replace=False))]
    return pts, cams


def _pca_normals(pts: np.ndarray, knn: int) -> np.ndarray:
    """(M, 3) unit normals of (M, 3) points: Open3D PCA over ``knn`` nearest neighbours."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn))
    return np.asarray(pcd.normals)


def _pncc_visibility(
    pts: np.ndarray,
    cams: list,
    depth: np.ndarray,
    present: np.ndarray,
    normals: np.ndarray | None,
    depth_tolerance: float,
    depth_tolerance_rel: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PNCC steps 1-2 per camera j: visible (n, M) bool (in front, inside the 1-pixel margin,
    passing the depth test against ``depth`` (n, H, W) metres), score (n, M) (|cos| between
    normal and ray, or -z without normals; -inf where not visible) and uv (n, M, 2) pixels."""
    n, m = len(cams), len(pts)
    h, w = depth.shape[1:]
    visible = np.zeros((n, m), dtype=bool)
    score = np.full((n, m), -np.inf)
    uv = np.zeros((n, m, 2))
    for j, cam in enumerate(cams):
        if not present[j]:
            continue
        T = cam.T_cam_world
        Xc = pts @ T[:3, :3].T + T[:3, 3]
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = Xc @ cam.K.T
            u = proj[:, 0] / proj[:, 2]
            v = proj[:, 1] / proj[:, 2]
        ok = (z > 0) & (u >= 1) & (u <= w - 2) & (v >= 1) & (v <= h - 2)
        ok &= np.isfinite(u) & np.isfinite(v)
        idx = np.nonzero(ok)[0]
        ui = np.rint(u[idx]).astype(np.int64)
        vi = np.rint(v[idx]).astype(np.int64)
        d = depth[j, vi, ui]
        vis = (d > 0) & (np.abs(z[idx] - d) <= depth_tolerance + depth_tolerance_rel * z[idx])
        idx = idx[vis]
        visible[j, idx] = True
        uv[j, idx, 0] = u[idx]
        uv[j, idx, 1] = v[idx]
        if normals is not None:
            ray = Xc[idx] / np.linalg.norm(Xc[idx], axis=1, keepdims=True)
            n_cam = normals[idx] @ T[:3, :3].T
            # a degenerate neighbourhood (duplicates, a line) can give a NaN normal: rank it last
            score[j, idx] = np.nan_to_num(np.abs(np.sum(ray * n_cam, axis=1)), nan=0.0)
        else:
            score[j, idx] = -z[idx]
    return visible, score, uv


def _patch_ncc(
    grey: np.ndarray, uv: np.ndarray, best: np.ndarray, pidx: np.ndarray, min_std: float
) -> tuple[np.ndarray, np.ndarray]:
    """PNCC steps 3-4: NCC of the bilinear 3x3 grey patches of points ``pidx`` in their two best
    cameras ``best`` (2, P). grey: (n, H, W) float64 grey levels. Returns the NCC of the textured
    points and the (P,) bool mask of points whose two patches are both textured."""
    h, w = grey.shape[1:]
    offs = np.array([-1.0, 0.0, 1.0])
    du, dv = np.meshgrid(offs, offs)
    du, dv = du.ravel(), dv.ravel()
    patches = []
    for r in range(2):
        cam_idx = best[r]
        u = uv[cam_idx, pidx, 0][:, None] + du[None]
        v = uv[cam_idx, pidx, 1][:, None] + dv[None]
        u = np.clip(u, 0, w - 1)
        v = np.clip(v, 0, h - 1)
        vals = np.empty_like(u)
        for j in np.unique(cam_idx):
            sel = cam_idx == j
            vals[sel] = _bilinear(grey[j], u[sel], v[sel])
        patches.append(vals)
    a = patches[0] - patches[0].mean(1, keepdims=True)
    b = patches[1] - patches[1].mean(1, keepdims=True)
    sa = np.sqrt((a * a).sum(1))
    sb = np.sqrt((b * b).sum(1))
    textured = (sa / 3.0 >= min_std) & (sb / 3.0 >= min_std)  # std over 9 samples = norm / 3
    ncc = (a * b).sum(1)[textured] / (sa * sb)[textured]
    return ncc, textured


# --------------------------------------------------------------------------------------------
# FPS and peak memory
# --------------------------------------------------------------------------------------------


def _read_status_kb(field: str) -> int | None:
    """A ``field:`` of /proc/self/status in bytes (e.g. VmHWM, VmRSS), or None where unavailable."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _read_vm_hwm() -> int | None:
    """Peak RSS (VmHWM) of this process in bytes from /proc, or None where unavailable."""
    return _read_status_kb("VmHWM")


def _reset_vm_hwm() -> bool:
    """Reset the kernel's peak-RSS counter (Linux >= 4.0: write 5 to clear_refs); True only when
    the reset took (VmHWM came down to about the current VmRSS: some kernels accept the write and
    keep the lifetime peak, which made a 40 MB allocation invisible late in a test run)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        return False
    hwm, rss = _read_vm_hwm(), _read_status_kb("VmRSS")
    return hwm is not None and rss is not None and hwm <= rss + max(rss // 20, 1 << 20)


def _ru_maxrss_bytes() -> int:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(r if sys.platform == "darwin" else r * 1024)


@dataclass
class Measurement:
    """Filled in when the :func:`measure` block exits.

    Attributes:
        wall_s: wall-clock seconds of the block (CUDA synchronised before and after).
        peak_rss_bytes: peak resident set size of the process during the block. On Linux the
            kernel's high-water mark is reset on entry, so this is the block's own peak
            (including memory already resident at entry); elsewhere it is the process-lifetime
            peak (``rss_peak_is_lifetime`` True).
        rss_peak_is_lifetime: True when the peak could not be reset (lifetime high-water mark).
        peak_cuda_bytes: torch.cuda.max_memory_allocated during the block, or None off CUDA.
        device: the device measured.
    """

    wall_s: float = float("nan")
    peak_rss_bytes: int = 0
    rss_peak_is_lifetime: bool = False
    peak_cuda_bytes: int | None = None
    device: str = "cpu"


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@contextmanager
def measure(device: torch.device | str = "cpu") -> Iterator[Measurement]:
    """Measure wall time and peak memory of a block: ``with measure("cuda") as m: ...``.

    CPU memory is the process's peak RSS (Linux VmHWM, reset on entry via /proc/self/clear_refs;
    ``resource.getrusage`` lifetime peak elsewhere). On a CUDA device, the peak of
    ``torch.cuda.max_memory_allocated`` (reset on entry) is reported as well. CUDA work is
    synchronised before the clock starts and before it stops.
    """
    dev = torch.device(device)
    m = Measurement(device=str(dev))
    _sync(dev)
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats(dev)
    reset = _reset_vm_hwm()
    t0 = time.perf_counter()
    try:
        yield m
    finally:
        _sync(dev)
        m.wall_s = time.perf_counter() - t0
        hwm = _read_vm_hwm() if reset else None
        m.peak_rss_bytes = hwm if hwm is not None else _ru_maxrss_bytes()
        m.rss_peak_is_lifetime = hwm is None
        if dev.type == "cuda":
            m.peak_cuda_bytes = int(torch.cuda.max_memory_allocated(dev))


@dataclass(frozen=True)
class TimingResult:
    """Repeated timing of one call.

    Attributes:
        times_s: (repeats,) wall seconds of each timed run (after warm-up).
        median_s, mean_s, std_s: statistics of ``times_s``.
        fps: 1 / median_s (calls per second).
        peak_rss_bytes: largest peak RSS over the timed runs (see :class:`Measurement`).
        peak_cuda_bytes: largest CUDA peak allocation over the timed runs, or None off CUDA.
        device: the device measured.
    """

    times_s: np.ndarray
    median_s: float
    mean_s: float
    std_s: float
    fps: float
    peak_rss_bytes: int
    peak_cuda_bytes: int | None
    device: str


def time_fn(
    fn: Callable[..., Any],
    *args: Any,
    repeats: int = 5,
    warmup: int = 1,
    device: torch.device | str = "cpu",
    **kwargs: Any,
) -> TimingResult:
    """Call ``fn(*args, **kwargs)`` ``warmup`` times untimed, then ``repeats`` times under :func:`measure`.

    FPS = 1 / median wall time, the figure the paper's tables call FPS when ``fn`` fuses one frame.
    """
    if repeats < 1 or warmup < 0:
        raise ValidationError(f"time_fn: need repeats >= 1 and warmup >= 0, got {repeats}, {warmup}")
    for _ in range(warmup):
        fn(*args, **kwargs)
    ms: list[Measurement] = []
    for _ in range(repeats):
        with measure(device) as m:
            fn(*args, **kwargs)
        ms.append(m)
    t = np.array([x.wall_s for x in ms])
    med = float(np.median(t))
    cuda = [x.peak_cuda_bytes for x in ms if x.peak_cuda_bytes is not None]
    return TimingResult(
        times_s=t,
        median_s=med,
        mean_s=float(t.mean()),
        std_s=float(t.std()),
        fps=1.0 / med if med > 0 else float("inf"),
        peak_rss_bytes=max(x.peak_rss_bytes for x in ms),
        peak_cuda_bytes=max(cuda) if cuda else None,
        device=ms[0].device,
    )
