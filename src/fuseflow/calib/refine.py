"""Optional rigid refinement of GMAC's metric poses (beyond the paper; off in paper mode).

A scale cannot change a rotation, so GMAC alone cannot lower rotation error (docs/design.md 3).
This stage registers overlapping pairs of RGB-D clouds with Open3D's coloured ICP (Park et al.
2017: geometry + photometric term), starting from the metric GMAC poses, and solves an Open3D
pose graph over those pairwise constraints (the first placed camera anchors the world frame).
Each camera contributes its ``refine_neighbors`` best edges (by correspondence count).

Why coloured ICP: on the synthetic room (large planes), point-to-plane ICP slid along the walls
(edge 0-1 of seed 0: 27 mm GMAC error -> 64 mm after point-to-plane ICP, 0.4 mm after coloured
ICP). A pair whose ICP result has fitness < ``min_fitness`` or moves the relative pose by more
than 5 deg / 0.3 m is not used (no overlap or divergence). Open3D is imported here only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fuseflow.calib.config import RefineSettings, refine_settings
from fuseflow.calib.errors import CalibrationError
from fuseflow.types import invert_rigid

if TYPE_CHECKING:  # the public entry point also takes a whole CalibConfig
    from fuseflow.calib.config import CalibConfig

__all__ = ["RefineResult", "refine_poses"]


@dataclass(frozen=True)
class RefineResult:
    """Refined poses and per-edge ICP diagnostics.

    Attributes:
        T_cam_world: camera index -> (4, 4) refined camera-from-world (metres).
        fitness: "i-j" -> ICP inlier share. rmse_mm: "i-j" -> ICP inlier RMSE in mm.
        moved_mm: camera index -> how far the refinement moved the camera centre, mm.
        edges_used: ICP edges given to the pose graph.
        accepted: whether the refined poses were kept. They are kept only when they fit the
            depth better than the GMAC poses on the refined edges (mean ICP inlier RMSE at
            ``icp_max_distance`` lower and mean fitness not lower); otherwise the GMAC poses
            are returned unchanged (a refinement must not make things worse).
        check: the numbers behind ``accepted``: mean fitness / RMSE (mm) before and after.
    """

    T_cam_world: dict[int, np.ndarray]
    fitness: dict[str, float]
    rmse_mm: dict[str, float]
    moved_mm: dict[str, float]
    edges_used: int
    accepted: bool = True
    check: dict[str, float] | None = None


#: ICP results below this inlier share are not used (no real overlap).
MIN_FITNESS = 0.1


def _cloud(o3d, depth: np.ndarray, K: np.ndarray, drange, voxel: float, color: np.ndarray | None = None):
    v, u = np.nonzero((depth > drange[0]) & (depth < drange[1]))
    z = depth[v, u].astype(np.float64)
    P = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(P))
    if color is not None:
        pc.colors = o3d.utility.Vector3dVector(color[v, u].astype(np.float64) / 255.0)
    pc = pc.voxel_down_sample(voxel)
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=4 * voxel, max_nn=30))
    pc.orient_normals_towards_camera_location(np.zeros(3))
    return pc


def refine_poses(
    T_cam_world: Mapping[int, np.ndarray],
    depth: np.ndarray,
    K: np.ndarray,
    depth_range: np.ndarray,
    edges: Sequence[tuple[int, int]],
    settings: RefineSettings | CalibConfig,
    color: np.ndarray | None = None,
    counts: Mapping[tuple[int, int], int] | None = None,
    matches: Mapping[tuple[int, int], tuple[np.ndarray, np.ndarray]] | None = None,
) -> RefineResult:
    """Point-to-plane ICP per edge + pose-graph optimisation.

    Args:
        T_cam_world: camera index -> (4, 4) metric camera-from-world (GMAC output).
        depth: (N, H, W) float32 metres. K: (N, 3, 3). depth_range: (N, 2).
        edges: overlapping pairs (i, j) to register. settings: the refinement's settings
            (``config.refine_settings``; a :class:`~fuseflow.calib.config.CalibConfig` is taken
            too and its settings used). color: (N, H, W, 3) uint8 (coloured ICP;
            None = point-to-plane). counts: edge -> correspondences, to pick each camera's best.
        matches: the backbone's keypoint matches (i, j) -> (uv_i, uv_j): held-out evidence for
            the acceptance check (ICP minimises the cloud residual, so that residual cannot judge
            it; the matches' 3-D misfit can).
    """
    try:
        import open3d as o3d
    except ImportError as exc:  # pragma: no cover - open3d is a dependency
        raise CalibrationError("refinement needs open3d: pip install open3d") from exc
    reg = o3d.pipelines.registration
    settings = refine_settings(settings)
    nodes = sorted(T_cam_world)
    if len(nodes) < 2:
        return RefineResult(dict(T_cam_world), {}, {}, {}, 0, False)
    clouds = {
        k: _cloud(o3d, depth[k], K[k], depth_range[k], settings.icp_voxel, None if color is None else color[k])
        for k in nodes
    }
    edges = _best_edges(nodes, edges, counts, settings.refine_neighbors)
    index = {k: n for n, k in enumerate(nodes)}
    graph = reg.PoseGraph()
    for k in nodes:
        graph.nodes.append(reg.PoseGraphNode(invert_rigid(T_cam_world[k])))
    fitness, rmse = {}, {}
    used = 0
    for i, j in edges:
        if i not in index or j not in index:
            continue
        edge = _register_pair(reg, clouds, i, j, T_cam_world, settings.icp_max_distance, color is not None)
        fitness[f"{i}-{j}"], rmse[f"{i}-{j}"] = edge.fitness, edge.rmse_mm
        if edge.transformation is not None:
            graph.edges.append(reg.PoseGraphEdge(index[i], index[j], edge.transformation, edge.info, uncertain=False))
            used += 1
    if used:
        _optimise(o3d, graph, settings.icp_max_distance)
    out = {k: invert_rigid(np.asarray(graph.nodes[index[k]].pose)) for k in nodes}
    accepted, check = False, None
    if used:
        accepted, check = _accept(reg, clouds, edges, T_cam_world, out, settings, matches, depth, K, depth_range)
    if not accepted:
        out = {k: np.array(T_cam_world[k], dtype=np.float64) for k in nodes}
    moved = {}
    for k in nodes:
        c_old = invert_rigid(T_cam_world[k])[:3, 3]
        moved[str(k)] = float(np.linalg.norm(invert_rigid(out[k])[:3, 3] - c_old) * 1000.0)
    return RefineResult(out, fitness, rmse, moved, used, accepted, check)


def _best_edges(nodes, edges, counts, per_camera: int) -> list[tuple[int, int]]:
    """Each camera's ``per_camera`` edges with the most correspondences, sorted, no repeats."""
    ranked = sorted(edges, key=lambda e: -(counts or {}).get(e, 0))
    chosen: list[tuple[int, int]] = []
    for k in nodes:
        chosen += [e for e in ranked if k in e][:per_camera]
    return sorted(set(chosen))


@dataclass(frozen=True)
class _PairRegistration:
    fitness: float
    rmse_mm: float
    transformation: np.ndarray | None = None
    """T_j<-i for the pose graph, None when the pair is not used (no overlap or divergence)."""
    info: np.ndarray | None = None


def _register_pair(reg, clouds, i: int, j: int, T_cam_world, max_dist: float, coloured: bool) -> _PairRegistration:
    """ICP of camera i's cloud (source) onto camera j's (target) from the GMAC poses."""
    crit = reg.ICPConvergenceCriteria(relative_fitness=1e-6, relative_rmse=1e-6, max_iteration=50)
    # source = camera i's cloud, target = camera j's: T_j<-i = T_j T_i^-1
    init = T_cam_world[j] @ invert_rigid(T_cam_world[i])
    # one level: a coarse-to-fine schedule (20 cm -> 5 cm) was tried on the synthetic room
    # and locked onto wrong planes (rotation 1.1 -> 14 deg); the single 5 cm level gave 0.73
    try:
        if coloured:
            res = reg.registration_colored_icp(
                clouds[i], clouds[j], max_dist, init, reg.TransformationEstimationForColoredICP(), crit
            )
        else:
            res = reg.registration_icp(
                clouds[i], clouds[j], max_dist, init, reg.TransformationEstimationPointToPlane(), crit
            )
    except RuntimeError:  # Open3D: "No correspondences found" = no overlap within reach; skip the pair
        return _PairRegistration(0.0, float("nan"))
    fit, rm = float(res.fitness), float(res.inlier_rmse * 1000.0)
    D = np.asarray(res.transformation) @ invert_rigid(init)
    angle = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
    if res.fitness < MIN_FITNESS or angle > 5.0 or np.linalg.norm(D[:3, 3]) > 0.3:
        return _PairRegistration(fit, rm)
    info = reg.get_information_matrix_from_point_clouds(clouds[i], clouds[j], max_dist, res.transformation)
    # Open3D: PoseGraphEdge(source, target, T) with world-from-camera node poses P means
    # T = P_target^-1 P_source, i.e. T_j<-i as registered above.
    return _PairRegistration(fit, rm, res.transformation, info)


def _optimise(o3d, graph, max_dist: float) -> None:
    """Open3D's global pose-graph optimisation (Levenberg-Marquardt), first node fixed."""
    reg = o3d.pipelines.registration
    option = reg.GlobalOptimizationOption(
        max_correspondence_distance=max_dist, edge_prune_threshold=0.25, reference_node=0
    )
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(
            graph, reg.GlobalOptimizationLevenbergMarquardt(), reg.GlobalOptimizationConvergenceCriteria(), option
        )


def _accept(reg, clouds, edges, T_before, T_after, settings, matches, depth, K, depth_range):
    """(keep the refined poses?, the numbers behind it): the held-out keypoint matches must fit
    better; without matches, the clouds' mean RMSE must drop and mean fitness not drop."""
    check = _fit_check(reg, clouds, edges, T_before, T_after, settings.icp_max_distance)
    m0 = _match_misfit(matches, T_before, depth, K, depth_range)
    if m0 is not None:
        check["match_misfit_before_mm"] = m0
        check["match_misfit_after_mm"] = _match_misfit(matches, T_after, depth, K, depth_range)
        return check["match_misfit_after_mm"] < m0, check
    accepted = check["rmse_after_mm"] < check["rmse_before_mm"] and check["fitness_after"] >= check["fitness_before"]
    return accepted, check


def _fit_check(reg, clouds, edges, T_before, T_after, max_dist: float) -> dict[str, float]:
    """Mean Open3D fitness / inlier RMSE (mm) of the depth clouds over ``edges`` under both pose sets."""
    out = {}
    for tag, T in (("before", T_before), ("after", T_after)):
        fit, rm = [], []
        for i, j in edges:
            if i in T and j in T:
                ev = reg.evaluate_registration(clouds[i], clouds[j], max_dist, T[j] @ invert_rigid(T[i]))
                fit.append(float(ev.fitness))
                rm.append(float(ev.inlier_rmse) * 1000.0)
        out[f"fitness_{tag}"] = float(np.mean(fit)) if fit else 0.0
        out[f"rmse_{tag}_mm"] = float(np.mean(rm)) if rm else float("inf")
    return out


#: The match-misfit check needs at least this many matches with depth in both cameras.
MIN_CHECK_MATCHES = 30


def _match_misfit(matches, T, depth, K, depth_range) -> float | None:
    """Median 3-D distance (mm) between matched sensor points after moving camera i's into j
    with poses T; None when there are fewer than MIN_CHECK_MATCHES usable matches."""
    if not matches:
        return None
    res = []
    for (i, j), (uv_i, uv_j) in matches.items():
        if i not in T or j not in T:
            continue
        pts = []
        for k, uv in ((i, uv_i), (j, uv_j)):
            H, W = depth[k].shape
            u = np.clip(np.floor(uv[:, 0] + 0.5).astype(int), 0, W - 1)
            v = np.clip(np.floor(uv[:, 1] + 0.5).astype(int), 0, H - 1)
            z = depth[k][v, u].astype(np.float64)
            z = np.where((z > depth_range[k][0]) & (z < depth_range[k][1]), z, 0.0)
            P = np.stack([(u - K[k][0, 2]) / K[k][0, 0] * z, (v - K[k][1, 2]) / K[k][1, 1] * z, z], axis=1)
            pts.append(P)
        ok = (pts[0][:, 2] > 0) & (pts[1][:, 2] > 0)
        M = T[j] @ invert_rigid(T[i])
        res.append(np.linalg.norm(pts[0][ok] @ M[:3, :3].T + M[:3, 3] - pts[1][ok], axis=1))
    r = np.concatenate(res) if res else np.zeros(0)
    return float(np.median(r) * 1000.0) if len(r) >= MIN_CHECK_MATCHES else None
