"""A triangle mesh per frame from a fused cloud (``--mesh``).

``mesh_cloud(cloud, rig)``:

1. normals: Open3D's PCA normals over each point's 20 nearest neighbours within 5 cm (FUSE
   keeps no normals), each turned to face the camera that measured the point (``cloud.camera``;
   the rig's mean camera centre for points without one);
2. surface: ``"range"`` (default, ``mesh_range``: each camera's fused points as a range image
   on its pixel grid, neighbours joined, every camera's triangles merged; no normals step, no
   trimming: the vertices are the fused points), ``"tsdf"`` (a TSDF of the frame's views,
   ``mesh_views``: needs the frame, not only the cloud), ``"poisson"`` (screened Poisson, Open3D,
   octree depth ``POISSON_DEPTH``) or ``"bpa"`` (ball pivoting, radii 1.5 and 3 times the median
   point spacing);
3. trimming: Poisson's vertices of the lowest ``POISSON_DENSITY_QUANTILE`` support density, every
   vertex farther than ``MAX_GAP_M`` from the nearest fused point (Poisson closes holes with
   surface nothing measured), and every vertex outside the capture volume; faces that lose a
   vertex go with it;
4. vertex colours: the colour of the nearest fused point.

Choice of method and numbers: docs/formats.md ("Meshes"), measured with
``benchmarks/outputs_mesh.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.geometry.volume import CaptureVolume
from fuseflow.types import FusedCloud, Rig, to_numpy

__all__ = [
    "Mesh",
    "MESH_METHODS",
    "mesh_cloud",
    "mesh_views",
    "mesh_frame",
    "camera_centres",
    "mesh_range",
    "cloud_normals",
    "POISSON_DEPTH",
    "MAX_GAP_M",
]

MESH_METHODS = ("tsdf", "poisson", "bpa", "range")
POISSON_DEPTH = 7
"""Octree depth of screened Poisson (2^7 cells across the cloud's bounding cube: 2.8 cm for a
3.6 m capture volume; depth 8 took 4x the time for no better accuracy, docs/formats.md)."""
POISSON_DENSITY_QUANTILE = 0.02
"""Share of Poisson vertices with the lowest support density that are removed."""
MAX_GAP_M = 0.03
"""Vertices farther than this from every fused point are removed (metres)."""


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh: vertices (V, 3) float32 metres (world), faces (F, 3) int64, colours
    (V, 3) uint8, unit normals (V, 3) float32."""

    vertices: np.ndarray
    faces: np.ndarray
    colors: np.ndarray
    normals: np.ndarray

    @staticmethod
    def empty() -> Mesh:
        return Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), np.zeros((0, 3), np.uint8),
                    np.zeros((0, 3), np.float32))  # fmt: skip


def _pcd(xyz: np.ndarray, rgb: np.ndarray):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz.astype(np.float64)))
    pcd.colors = o3d.utility.Vector3dVector(rgb.astype(np.float64) / 255.0)
    return pcd


def camera_centres(rig: Rig | None) -> np.ndarray | None:
    """(N, 3) world centres of the rig's cameras (NaN for a camera without extrinsics)."""
    if rig is None:
        return None
    return np.array([c.T_world_cam[:3, 3] if c.is_calibrated else np.full(3, np.nan) for c in rig])


def cloud_normals(xyz: np.ndarray, camera: np.ndarray, centres: np.ndarray | None) -> np.ndarray:
    """(M, 3) unit normals of ``xyz``, each facing ``centres[camera]`` (its source camera's centre;
    the mean centre where the index is -1, out of range or NaN)."""
    import open3d as o3d

    pcd = _pcd(xyz, np.zeros_like(xyz))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05, max_nn=20))
    n = np.asarray(pcd.normals)
    if centres is None or not np.isfinite(centres).any():
        return n.astype(np.float32)
    mean = np.nanmean(centres, axis=0)
    table = np.where(np.isfinite(centres), centres, mean)
    cam = np.asarray(camera, np.int64)
    ok = (cam >= 0) & (cam < len(table))
    eye = np.where(ok[:, None], table[np.clip(cam, 0, len(table) - 1)], mean)
    flip = np.einsum("ij,ij->i", n, eye - xyz) < 0
    n[flip] *= -1
    return n.astype(np.float32)


def _surface(xyz: np.ndarray, rgb: np.ndarray, normals: np.ndarray, method: str):
    """(vertices, faces, per-vertex keep mask before the gap and volume trims)."""
    import open3d as o3d

    pcd = _pcd(xyz, rgb)
    pcd.normals = o3d.utility.Vector3dVector(normals.astype(np.float64))
    if method == "poisson":
        mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=POISSON_DEPTH)
        dens = np.asarray(dens)
        keep = dens >= np.quantile(dens, POISSON_DENSITY_QUANTILE) if len(dens) else np.zeros(0, bool)
    else:
        spacing = float(np.median(np.asarray(pcd.compute_nearest_neighbor_distance())))
        radii = o3d.utility.DoubleVector([1.5 * spacing, 3.0 * spacing])
        mesh = o3d.geometry.TriangleMesh.create_from_point_cloud_ball_pivoting(pcd, radii)
        keep = np.ones(len(mesh.vertices), bool)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles).astype(np.int64), keep


def _trim(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Drop faces with a removed vertex, then unreferenced vertices; returns the kept vertex
    indices (into ``vertices``) and the re-indexed faces."""
    faces = faces[keep[faces].all(axis=1)]
    mask = np.zeros(len(vertices), bool)
    mask[faces.ravel()] = True
    used = np.nonzero(mask)[0]
    remap = np.full(len(vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    return used, vertices[used], remap[faces]


def mesh_cloud(
    cloud: FusedCloud, centres: np.ndarray | None = None, method: str = "poisson", volume: CaptureVolume | None = None
) -> Mesh:
    """The trimmed, coloured mesh of ``cloud`` (see the module docstring); ``centres``: (N, 3)
    camera centres indexed by ``cloud.camera`` (``camera_centres(rig)``), for the normals' side.
    An empty Mesh for a cloud of fewer than 4 points (no surface can be fitted)."""
    from scipy.spatial import cKDTree

    if method not in ("poisson", "bpa"):
        raise ValidationError(f"mesh_cloud: method must be poisson or bpa (tsdf: mesh_views), got {method!r}")
    c = cloud.numpy()
    xyz, rgb = c.xyz.astype(np.float64), c.rgb
    if len(xyz) < 4:
        return Mesh.empty()
    normals = cloud_normals(xyz, c.camera, centres)
    vertices, faces, keep = _surface(xyz, rgb, normals, method)
    if len(vertices) == 0:
        return Mesh.empty()
    dist, nearest = cKDTree(xyz).query(vertices, k=1, workers=-1)
    keep &= dist <= MAX_GAP_M
    if volume is not None:
        keep &= volume.contains(vertices)
    used, v, f = _trim(vertices, faces, keep)
    if len(f) == 0:
        return Mesh.empty()
    vn = _vertex_normals(v, f)
    return Mesh(v.astype(np.float32), f, rgb[nearest[used]].astype(np.uint8), vn)


def mesh_frame(
    cloud: FusedCloud,
    frame,
    rig: Rig,
    method: str = "range",
    volume: CaptureVolume | None = None,
    centres: np.ndarray | None = None,
) -> Mesh:
    """The mesh of one frame by ``method`` (one of ``MESH_METHODS``): "tsdf" from ``frame``'s
    views (``mesh_views``; ``rig`` in the frame's camera order), "range" from ``cloud`` and
    ``rig`` (``mesh_range``: ``cloud.camera`` indexes ``rig``), the others from ``cloud``
    (``mesh_cloud`` with ``centres``, default the rig's camera centres)."""
    if method not in MESH_METHODS:
        raise ValidationError(f"mesh method must be one of {', '.join(MESH_METHODS)}, got {method!r}")
    if method == "tsdf":
        return mesh_views(frame, rig, volume)
    if method == "range":
        return mesh_range(cloud, rig, volume)
    return mesh_cloud(cloud, camera_centres(rig) if centres is None else centres, method, volume)


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals of the triangles (unit; zero for isolated vertices)."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros(v.shape, np.float64)
    for a in range(3):
        vn[:, a] = np.bincount(f.ravel(), np.repeat(fn[:, a], 3), len(v))
    norm = np.linalg.norm(vn, axis=1, keepdims=True)
    return (vn / np.maximum(norm, 1e-12)).astype(np.float32)


TSDF_VOXEL_M = 0.01
"""Voxel edge of ``mesh_views``' TSDF (metres); truncation 4 voxels."""


def _in_volume(depth: np.ndarray, cam, volume: CaptureVolume) -> np.ndarray:
    """(H, W) bool: pixels whose depth back-projects into ``volume`` (False without depth)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([u.ravel(), v.ravel(), np.ones(u.size)]).T @ np.linalg.inv(cam.K).T
    Xc = rays * depth.reshape(-1, 1)
    R, t = cam.T_cam_world[:3, :3], cam.T_cam_world[:3, 3]
    inside = volume.contains((Xc - t) @ R).reshape(h, w)
    return inside & (depth > 0)


def mesh_views(frame, rig: Rig, volume: CaptureVolume | None = None, voxel: float = TSDF_VOXEL_M) -> Mesh:
    """A TSDF (Open3D VoxelBlockGrid, ``voxel`` metres, 4-voxel truncation, depth within each
    camera's depth range) of the present views of ``frame`` (placed ``rig``, same order), marching
    cubes, trimmed to ``volume``; colours from the views."""
    import open3d as o3d
    import open3d.core as o3c

    depth = to_numpy(frame.depth)
    color = to_numpy(frame.color)
    present = to_numpy(frame.present)
    views = []
    for i, cam in enumerate(rig):
        d = depth[i].copy()
        d[(d < cam.depth_range[0]) | (d > cam.depth_range[1])] = 0.0
        if volume is not None:  # integrate only what lies in the volume (walls cost most voxels)
            d[~_in_volume(d, cam, volume)] = 0.0
        if present[i] and (d > 0).any():
            views.append((o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(d, np.float32))), color[i], cam))
    if not views:
        return Mesh.empty()
    grid = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (o3c.float32,) * 3, (1, 1, 3), voxel, 16, 1)
    blocks = []
    for d, _, cam in views:
        K, T = o3c.Tensor(cam.K), o3c.Tensor(np.ascontiguousarray(cam.T_cam_world))
        blocks.append(grid.compute_unique_block_coordinates(d, K, T, 1.0, float(cam.depth_range[1]), 4.0))
    count = 2 * len(np.unique(np.concatenate([b.numpy().reshape(-1, 3) for b in blocks]), axis=0)) + 64
    grid = o3d.t.geometry.VoxelBlockGrid(("tsdf", "weight", "color"), (o3c.float32,) * 3, (1, 1, 3), voxel, 16, count)
    for (d, c, cam), b in zip(views, blocks):
        K, T = o3c.Tensor(cam.K), o3c.Tensor(np.ascontiguousarray(cam.T_cam_world))
        rgb = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(c, np.float32) / 255.0))
        grid.integrate(b, d, rgb, K, K, T, 1.0, float(cam.depth_range[1]), 4.0)
    m = grid.extract_triangle_mesh(1.0).to_legacy()
    v, f = np.asarray(m.vertices), np.asarray(m.triangles).astype(np.int64)
    cols = (np.clip(np.asarray(m.vertex_colors), 0, 1) * 255).round().astype(np.uint8) if len(v) else np.zeros((0, 3))
    keep = volume.contains(v) if volume is not None else np.ones(len(v), bool)
    used, v, f = _trim(v, f, keep)
    if len(f) == 0:
        return Mesh.empty()
    return Mesh(v.astype(np.float32), f, cols[used].astype(np.uint8), _vertex_normals(v, f))


RANGE_EDGE = 4.0
"""``mesh_range`` joins grid neighbours whose edge is under this many pixel footprints (the
pixel stride times depth / focal length): wider gaps are depth edges, not surface."""


def _project(xyz: np.ndarray, cam) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, z) of world points in ``cam`` (pixels; z <= 0 for points behind it)."""
    Xc = xyz @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
    z = Xc[:, 2]
    zs = np.where(z > 1e-3, z, 1.0)
    u = cam.K[0, 0] * Xc[:, 0] / zs + cam.K[0, 1] * Xc[:, 1] / zs + cam.K[0, 2]
    return u, cam.K[1, 1] * Xc[:, 1] / zs + cam.K[1, 2], z


def _camera_grid(u: np.ndarray, v: np.ndarray, z: np.ndarray, cam, stride: int) -> np.ndarray:
    """Grid of point indices (-1: none) on ``cam``'s pixel grid of ``stride``; the points come
    in increasing weight, so a cell keeps its highest-weight point."""
    h, w = cam.height // stride + 2, cam.width // stride + 2
    ui, vi = np.rint(u / stride).astype(np.int64), np.rint(v / stride).astype(np.int64)
    ok = (z > 1e-3) & (ui >= 0) & (ui < w) & (vi >= 0) & (vi < h)
    grid = np.full((h, w), -1, np.int64)
    idx = np.nonzero(ok)[0]
    grid[vi[idx], ui[idx]] = idx
    return grid


def _joined(grid: np.ndarray) -> float:
    """Share of a grid's filled cells whose right neighbour is filled too."""
    filled = grid >= 0
    return float((filled[:, :-1] & filled[:, 1:]).sum()) / max(int(filled.sum()), 1)


def _grid_faces(grid: np.ndarray, xyz: np.ndarray, z: np.ndarray, limit_per_m: float) -> np.ndarray:
    """(F, 3) triangles of 2x2 grid cells whose three corners exist and whose edges are short."""
    a, b, c, d = grid[:-1, :-1].ravel(), grid[:-1, 1:].ravel(), grid[1:, :-1].ravel(), grid[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    faces = faces[(faces >= 0).all(axis=1)]
    if len(faces) == 0:
        return faces
    p = xyz[faces]
    e = [np.einsum("ij,ij->i", p[:, i] - p[:, (i + 1) % 3], p[:, i] - p[:, (i + 1) % 3]) for i in range(3)]
    limit = limit_per_m * z[faces].max(axis=1)
    return faces[np.maximum.reduce(e) < limit * limit]


def mesh_range(cloud: FusedCloud, rig: Rig, volume: CaptureVolume | None = None) -> Mesh:
    """Each camera's fused points (``cloud.camera`` indexes ``rig``) as a range image on that
    camera's pixel grid, grid neighbours joined into triangles, every camera's triangles merged:
    the vertices are the fused points themselves (their colours), the normals the faces'. The
    grid's stride (1, 2 or 3 pixels) is the finest on which most filled cells have a filled
    neighbour (FUSE's pixel grid); an edge longer than ``RANGE_EDGE`` pixel footprints is a depth
    edge and is left open."""
    c = cloud.numpy()
    xyz, rgb = np.asarray(c.xyz, np.float64), np.asarray(c.rgb)
    cam_idx, weight = np.asarray(c.camera, np.int64), np.asarray(c.weight)
    all_faces = []
    for k, cam in enumerate(rig):
        sel = np.nonzero(cam_idx == k)[0]
        if len(sel) < 3 or not cam.is_calibrated:
            continue
        sel = sel[np.argsort(weight[sel], kind="stable")]
        pts = xyz[sel]
        u, v, z = _project(pts, cam)
        for stride in (1, 2, 3):  # FUSE's pixel grid: the finest whose neighbours mostly meet
            grid = _camera_grid(u, v, z, cam, stride)
            if _joined(grid) >= 0.5:
                break
        all_faces.append(sel[_grid_faces(grid, pts, z, RANGE_EDGE * stride / cam.K[0, 0])])
    faces = np.concatenate(all_faces) if all_faces else np.zeros((0, 3), np.int64)
    if len(faces) == 0:
        return Mesh.empty()
    keep = volume.contains(xyz) if volume is not None else np.ones(len(xyz), bool)
    used, v, f = _trim(xyz, faces, keep)
    if len(f) == 0:
        return Mesh.empty()
    return Mesh(v.astype(np.float32), f, rgb[used].astype(np.uint8), _vertex_normals(v, f))
