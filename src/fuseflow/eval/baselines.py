"""Baseline fusion methods with FUSE's signature: ``(frame, rig, ...) -> FusedCloud``.

* :func:`naive_fusion`: every valid depth pixel of every present view, back-projected, concatenated.
* :func:`voxel_downsampled_fusion`: naive, then Open3D ``voxel_down_sample``.
* :func:`sor_fusion`: (optionally voxel-downsampled) naive, then Open3D statistical outlier removal.
* :func:`tsdf_fusion`: Open3D TSDF fusion, tensor ``VoxelBlockGrid`` (default) or the legacy
  ``ScalableTSDFVolume``, then point extraction at the zero crossing.
* :func:`tsdf_fusion_at_thresholds` / :func:`best_tsdf_threshold`: VoxelBlockGrid extracted at
  several weight thresholds, and the one that maximises a score (F against the reference): every
  comparison reports VoxelBlockGrid at that threshold beside Open3D's default (3.0).

Conventions (docs/design.md section 1): pixel (u, v) with depth z (metres) back-projects to
X_cam = z K^-1 [u, v, 1]^T and X_world = T_cam_world^-1 X_cam. A depth is valid when
depth_range[0] <= z <= depth_range[1] of its camera (0 = no measurement). Views with
``frame.present`` False are skipped. Output: ``weight`` = 1 for every point (baselines have no
confidence), ``camera`` = index of the source camera in rig order, or -1 where a point is not
from one camera (averaged by voxel downsampling, or extracted from a TSDF).

Open3D is imported inside the functions that use it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from fuseflow.errors import ValidationError
from fuseflow.types import Camera, Frame, FusedCloud, Rig

__all__ = [
    "TSDFConfig",
    "OPEN3D_WEIGHT_THRESHOLD",
    "WEIGHT_THRESHOLDS",
    "BestThreshold",
    "tsdf_fusion_at_thresholds",
    "best_tsdf_threshold",
    "backproject_views",
    "naive_fusion",
    "sor_fusion",
    "tsdf_fusion",
    "voxel_downsampled_fusion",
]


def _check_inputs(frame: Any, rig: Any) -> list[tuple[int, int, Camera]]:
    """Validate and return (frame index, rig index, camera) for each present view."""
    if not isinstance(frame, Frame):
        raise ValidationError(f"frame must be a fuseflow.Frame, got {type(frame).__name__}")
    if not isinstance(rig, Rig):
        raise ValidationError(f"rig must be a fuseflow.Rig, got {type(rig).__name__}")
    w, h = frame.resolution
    present = frame.present.detach().cpu().tolist()
    out = []
    for i, cid in enumerate(frame.camera_ids):
        cam = rig[cid]  # ValidationError naming the id when it is not in the rig
        if (cam.width, cam.height) != (w, h):
            raise ValidationError(f"camera {cid!r} is {cam.width}x{cam.height} in the rig but the frame is {w}x{h}")
        if not present[i]:
            continue
        if cam.T_cam_world is None:
            raise ValidationError(f"camera {cid!r} has no extrinsics; baselines need a calibrated rig")
        out.append((i, rig.index(cid), cam))
    return out


def backproject_views(frame: Frame, rig: Rig) -> FusedCloud:
    """Back-project every valid depth pixel of every present view to world coordinates.

    Args:
        frame: colour (N, H, W, 3) uint8, depth (N, H, W) float32 metres, any device.
        rig: calibrated rig holding every camera of ``frame`` (matched by id).

    Returns:
        FusedCloud on the frame's device: xyz (M, 3) float32 world metres, rgb (M, 3) uint8,
        weight (M,) = 1, camera (M,) int16 = rig index of the source camera. Views are
        concatenated in frame order, pixels in row-major order.
    """
    views = _check_inputs(frame, rig)
    dev = frame.device
    w, h = frame.resolution
    vv, uu = torch.meshgrid(
        torch.arange(h, device=dev, dtype=torch.float32),
        torch.arange(w, device=dev, dtype=torch.float32),
        indexing="ij",
    )
    pix = torch.stack([uu, vv, torch.ones_like(uu)], dim=-1).reshape(-1, 3)  # (HW, 3)
    xyz, rgb, cam_idx = [], [], []
    for i, r, cam in views:
        z = frame.depth[i].reshape(-1)
        lo, hi = cam.depth_range
        valid = (z > 0) & (z >= lo) & (z <= hi)
        K_inv = torch.as_tensor(np.linalg.inv(cam.K), dtype=torch.float32, device=dev)
        T_wc = torch.as_tensor(cam.T_world_cam, dtype=torch.float32, device=dev)
        zv = z[valid]
        X_cam = (pix[valid] @ K_inv.T) * zv[:, None]
        xyz.append(X_cam @ T_wc[:3, :3].T + T_wc[:3, 3])
        rgb.append(frame.color[i].reshape(-1, 3)[valid])
        cam_idx.append(torch.full((int(zv.shape[0]),), r, dtype=torch.int16, device=dev))
    if not xyz:
        return FusedCloud.empty(dev)
    p = torch.cat(xyz)
    return FusedCloud(p, torch.cat(rgb), torch.ones(p.shape[0], dtype=torch.float32, device=dev), torch.cat(cam_idx))


def naive_fusion(frame: Frame, rig: Rig) -> FusedCloud:
    """Naive concatenation: every valid depth pixel of every present view, in world coordinates.

    Same as :func:`backproject_views` (weight 1, camera = source camera's rig index).
    """
    return backproject_views(frame, rig)


def _to_o3d(cloud: FusedCloud):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(cloud.xyz.detach().cpu().numpy().astype(np.float64))
    pcd.colors = o3d.utility.Vector3dVector(cloud.rgb.detach().cpu().numpy().astype(np.float64) / 255.0)
    return pcd


def _from_o3d(pcd, device: torch.device, camera: np.ndarray | None = None) -> FusedCloud:
    xyz = np.asarray(pcd.points, dtype=np.float32).reshape(-1, 3)
    m = len(xyz)
    if pcd.has_colors():
        rgb = np.clip(np.rint(np.asarray(pcd.colors) * 255.0), 0, 255).astype(np.uint8)
    else:
        rgb = np.zeros((m, 3), dtype=np.uint8)
    cam = np.full(m, -1, dtype=np.int16) if camera is None else camera.astype(np.int16)
    return FusedCloud.from_numpy(xyz, rgb, np.ones(m, dtype=np.float32), cam).to(device)


def _check_positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
        raise ValidationError(f"{name} must be a positive number, got {value!r}")
    return float(value)


def voxel_downsampled_fusion(frame: Frame, rig: Rig, voxel: float = 0.01) -> FusedCloud:
    """Naive concatenation, then Open3D ``voxel_down_sample(voxel)``.

    Each occupied voxel of edge ``voxel`` metres becomes one point at the mean position and
    mean colour of its points; ``camera`` is -1 (a voxel mixes cameras), weight 1.

    Args:
        voxel: voxel edge, metres (default 1 cm, the resolution of the TSDF baseline).
    """
    voxel = _check_positive("voxel", voxel)
    cloud = naive_fusion(frame, rig)
    if len(cloud) == 0:
        return cloud
    return _from_o3d(_to_o3d(cloud).voxel_down_sample(voxel), cloud.device)


def sor_fusion(
    frame: Frame, rig: Rig, nb_neighbors: int = 20, std_ratio: float = 2.0, voxel: float | None = 0.01
) -> FusedCloud:
    """Statistical outlier removal on the (voxel-downsampled) naive cloud.

    A point is removed when its mean distance to its ``nb_neighbors`` nearest neighbours exceeds
    the cloud-wide mean of that quantity by more than ``std_ratio`` standard deviations (Open3D
    ``remove_statistical_outlier``).

    Args:
        nb_neighbors: k of the neighbourhood (Open3D tutorial value 20).
        std_ratio: threshold in standard deviations (Open3D tutorial value 2.0).
        voxel: downsample first with this voxel edge in metres (default 1 cm; camera is then -1),
            or None to filter the full naive cloud (camera kept; slow for large frames).
    """
    if isinstance(nb_neighbors, bool) or not isinstance(nb_neighbors, (int, np.integer)) or nb_neighbors < 1:
        raise ValidationError(f"nb_neighbors must be a positive integer, got {nb_neighbors!r}")
    std_ratio = _check_positive("std_ratio", std_ratio)
    if voxel is not None:
        voxel = _check_positive("voxel", voxel)
    cloud = naive_fusion(frame, rig)
    if len(cloud) == 0:
        return cloud
    pcd = _to_o3d(cloud)
    camera = cloud.camera.detach().cpu().numpy()
    if voxel is not None:
        pcd = pcd.voxel_down_sample(voxel)
        camera = None
    if len(pcd.points) <= nb_neighbors:
        return _from_o3d(pcd, cloud.device, camera)
    filtered, kept = pcd.remove_statistical_outlier(int(nb_neighbors), std_ratio)
    return _from_o3d(filtered, cloud.device, None if camera is None else camera[np.asarray(kept, dtype=np.int64)])


@dataclass(frozen=True)
class TSDFConfig:
    """Parameters of :func:`tsdf_fusion`."""

    voxel: float = 0.01
    """Voxel edge, metres. 1 cm: the FUSE paper's scale of detail; valid > 0."""

    trunc_voxels: float = 4.0
    """Truncation distance in voxels (sdf_trunc = trunc_voxels * voxel). Open3D's examples use
    4 (legacy, 0.04 m at 1 cm) to 8 (tensor example); 4 keeps thin structures. Valid > 0."""

    block_resolution: int = 16
    """Voxels per block edge of the VoxelBlockGrid (Open3D example value)."""

    block_count: int | None = None
    """Hash-map capacity in blocks, or None (default) to size it from the frame: twice the
    number of distinct blocks the views' truncation bands touch, + 64. Open3D's example value
    50000 allocates 50000 x 16^3 voxels x 20 B = 4 GB up front at block_resolution 16; a map
    too small rehashes while integrating (both measured in docs/metrics.md). Valid >= 1."""

    weight_threshold: float = 1.0
    """Minimum integrated weight of a voxel for point extraction (VoxelBlockGrid). Each view adds
    at most 1, so Open3D's default of 3.0 would drop every voxel seen by fewer than 3 cameras;
    1.0 keeps voxels seen by at least 2 views. With fewer views than that (one camera), the
    threshold is lowered to views - 0.5, so a single view still gives its surface, not nothing."""

    backend: str = "vbg"
    """"vbg": tensor ``o3d.t.geometry.VoxelBlockGrid`` (default). "scalable": legacy
    ``ScalableTSDFVolume``; with open3d 0.20.0 (the pinned wheel) it returns an EMPTY cloud and
    mesh for every input, Open3D's own tutorial frame included (see docs/metrics.md), so it is
    kept only to show that. "uniform": legacy ``UniformTSDFVolume``, a dense cube around the
    frame's back-projected points (bounded by ``max_uniform_resolution``)."""

    max_uniform_resolution: int = 256
    """Largest voxel count per cube edge of the "uniform" backend (256^3 voxels x 20 B = 335 MB);
    a larger scene raises ValidationError asking for a larger voxel or the "vbg" backend."""

    device: str = "CPU:0"
    """Open3D device of the VoxelBlockGrid ("CPU:0" or "CUDA:0" on a CUDA build of Open3D)."""


def tsdf_fusion(frame: Frame, rig: Rig, voxel: float | None = None, config: TSDFConfig | None = None) -> FusedCloud:
    """TSDF fusion of the frame's views, then the zero-crossing points of the volume.

    Each present view is integrated once with its camera's intrinsics and T_cam_world (Open3D's
    "extrinsic" is camera-from-world, the same convention). Depth outside the camera's
    depth_range is cleared before integration; the camera's depth_range max is the integration
    depth limit. The extracted points carry the TSDF colour, weight 1 and camera -1.

    Args:
        voxel: voxel edge in metres; None means ``config.voxel`` (default 0.01). Giving both
            ``voxel`` and a ``config`` with another voxel is a ValidationError.
        config: full :class:`TSDFConfig` (default ``TSDFConfig()``).
    """
    cfg = _tsdf_config(voxel, config)
    prepared = _prepare_views(frame, rig)
    if not prepared:
        return FusedCloud.empty(frame.device)
    if cfg.backend == "vbg":
        vbg = _integrate_vbg(prepared, cfg)
        return _extract_vbg(vbg, min(cfg.weight_threshold, len(prepared) - 0.5), frame.device)
    return _tsdf_legacy(prepared, cfg, frame, rig)


OPEN3D_WEIGHT_THRESHOLD = 3.0
"""Open3D's default ``weight_threshold`` of ``VoxelBlockGrid.extract_point_cloud``."""

WEIGHT_THRESHOLDS = (0.0, 1.0, 2.0, 3.0)
"""The extraction weight thresholds a fair comparison tries (:func:`best_tsdf_threshold`)."""


def tsdf_fusion_at_thresholds(
    frame: Frame,
    rig: Rig,
    thresholds: Sequence[float] = WEIGHT_THRESHOLDS,
    voxel: float | None = None,
    config: TSDFConfig | None = None,
) -> dict[float, FusedCloud]:
    """VoxelBlockGrid TSDF fusion (:func:`tsdf_fusion`, backend "vbg") integrated once and
    extracted at each weight threshold exactly as given (no lowering for few views):
    threshold -> cloud. ``config.weight_threshold`` and ``config.backend`` are not used."""
    cfg = _tsdf_config(voxel, config)
    if not thresholds:
        raise ValidationError("thresholds: give at least one weight threshold")
    if any(not np.isfinite(t) or t < 0 for t in thresholds):
        raise ValidationError(f"weight thresholds must be finite and >= 0, got {list(thresholds)}")
    prepared = _prepare_views(frame, rig)
    if not prepared:
        return {float(t): FusedCloud.empty(frame.device) for t in thresholds}
    vbg = _integrate_vbg(prepared, cfg)
    return {float(t): _extract_vbg(vbg, float(t), frame.device) for t in thresholds}


@dataclass(frozen=True)
class BestThreshold:
    """The VoxelBlockGrid extraction threshold with the highest score on one frame and rig."""

    threshold: float
    """The weight threshold of the best score (the lowest one on a tie)."""
    cloud: FusedCloud
    """The cloud extracted at ``threshold``."""
    scores: dict[float, float]
    """Score of every threshold tried."""


def best_tsdf_threshold(
    frame: Frame,
    rig: Rig,
    score: Callable[[FusedCloud], float],
    thresholds: Sequence[float] = WEIGHT_THRESHOLDS,
    voxel: float | None = None,
    config: TSDFConfig | None = None,
) -> BestThreshold:
    """VoxelBlockGrid at the weight threshold that maximises ``score`` (an F-score against the
    rig's reference surface, say) over ``thresholds``: the baseline at its best on this rig, to
    report beside Open3D's default (:data:`OPEN3D_WEIGHT_THRESHOLD`)."""
    clouds = tsdf_fusion_at_thresholds(frame, rig, thresholds, voxel, config)
    scores = {t: float(score(c)) for t, c in clouds.items()}
    best = max(sorted(scores), key=lambda t: (scores[t], -t))
    return BestThreshold(best, clouds[best], scores)


def _tsdf_config(voxel: float | None, config: TSDFConfig | None) -> TSDFConfig:
    """The checked :class:`TSDFConfig` of ``voxel`` and ``config`` (:func:`tsdf_fusion`)."""
    if config is not None and not isinstance(config, TSDFConfig):
        raise ValidationError(f"config must be a TSDFConfig, got {type(config).__name__}")
    cfg = config if config is not None else TSDFConfig()
    if voxel is not None:
        if config is not None and voxel != config.voxel:
            raise ValidationError(f"voxel={voxel} contradicts config.voxel={config.voxel}; give one of them")
        cfg = replace(cfg, voxel=voxel)
    _check_positive("voxel", cfg.voxel)
    _check_positive("trunc_voxels", cfg.trunc_voxels)
    if cfg.backend not in ("vbg", "scalable", "uniform"):
        raise ValidationError(f"TSDF backend must be 'vbg', 'scalable' or 'uniform', got {cfg.backend!r}")
    if (cfg.block_count is not None and cfg.block_count < 1) or cfg.block_resolution < 1:
        raise ValidationError(
            f"block_count and block_resolution must be >= 1, got {cfg.block_count}, {cfg.block_resolution}"
        )
    return cfg


def _prepare_views(frame: Frame, rig: Rig) -> list:
    """(depth float32 with out-of-range depth cleared, colour, camera) of each present view that
    has depth; views that touch no block are left out (Open3D aborts their integration)."""
    views = _check_inputs(frame, rig)
    if not views:
        return []
    depth = frame.depth.detach().cpu().numpy()
    color = frame.color.detach().cpu().numpy()
    prepared = []
    for i, _, cam in views:
        d = depth[i].copy()
        lo, hi = cam.depth_range
        d[(d < lo) | (d > hi)] = 0.0
        if not (d > 0).any():
            continue  # Open3D aborts integration of a view that touches no block
        prepared.append((np.ascontiguousarray(d, dtype=np.float32), np.ascontiguousarray(color[i]), cam))
    return prepared


def _integrate_vbg(prepared, cfg: TSDFConfig):
    """A tensor VoxelBlockGrid with every prepared view integrated."""
    import open3d as o3d
    import open3d.core as o3c

    dev = o3c.Device(cfg.device)

    def grid(attrs: tuple[str, ...], channels: tuple[int, ...], block_count: int):
        return o3d.t.geometry.VoxelBlockGrid(
            attr_names=attrs,
            attr_dtypes=tuple(o3c.float32 for _ in attrs),
            attr_channels=channels,
            voxel_size=cfg.voxel,
            block_resolution=cfg.block_resolution,
            block_count=block_count,
            device=dev,
        )

    # the blocks each view's truncation band touches (a probe grid only computes coordinates)
    probe = grid(("tsdf", "weight"), (1, 1), 1)
    views = []
    for d, c, cam in prepared:
        depth_img = o3d.t.geometry.Image(o3c.Tensor(d)).to(dev)
        K = o3c.Tensor(cam.K, dtype=o3c.float64)
        T = o3c.Tensor(np.ascontiguousarray(cam.T_cam_world), dtype=o3c.float64)
        depth_max = float(cam.depth_range[1])
        blocks = probe.compute_unique_block_coordinates(depth_img, K, T, 1.0, depth_max, cfg.trunc_voxels)
        views.append((depth_img, c, K, T, depth_max, blocks))
    if cfg.block_count is None:
        coords = np.concatenate([v[5].cpu().numpy().reshape(-1, 3) for v in views])
        block_count = 2 * len(np.unique(coords, axis=0)) + 64
    else:
        block_count = cfg.block_count
    vbg = grid(("tsdf", "weight", "color"), (1, 1, 3), block_count)
    for depth_img, c, K, T, depth_max, blocks in views:
        color_img = o3d.t.geometry.Image(o3c.Tensor(c.astype(np.float32) / 255.0)).to(dev)
        vbg.integrate(blocks, depth_img, color_img, K, K, T, 1.0, depth_max, cfg.trunc_voxels)
    return vbg


def _extract_vbg(vbg, weight_threshold: float, device: torch.device) -> FusedCloud:
    pcd = vbg.extract_point_cloud(weight_threshold)
    if "positions" not in pcd.point or pcd.point.positions.shape[0] == 0:
        return FusedCloud.empty(device)
    return _from_o3d(pcd.to_legacy(), device)


def _tsdf_legacy(prepared, cfg: TSDFConfig, frame: Frame, rig: Rig) -> FusedCloud:
    import open3d as o3d

    integration = o3d.pipelines.integration
    trunc = cfg.trunc_voxels * cfg.voxel
    if cfg.backend == "scalable":
        vol = integration.ScalableTSDFVolume(
            voxel_length=cfg.voxel, sdf_trunc=trunc, color_type=integration.TSDFVolumeColorType.RGB8
        )
    else:
        pts = naive_fusion(frame, rig).xyz.detach().cpu().numpy()
        if len(pts) == 0:
            return FusedCloud.empty(frame.device)
        lo = pts.min(0) - 2 * trunc
        side = float((pts.max(0) + 2 * trunc - lo).max())
        res = int(np.ceil(side / cfg.voxel))
        if res > cfg.max_uniform_resolution:
            raise ValidationError(
                f"the frame spans {side:.2f} m, {res} voxels of {cfg.voxel} m per edge, above "
                f"max_uniform_resolution={cfg.max_uniform_resolution}; use a larger voxel or backend='vbg'"
            )
        vol = integration.UniformTSDFVolume(
            length=res * cfg.voxel,
            resolution=res,
            sdf_trunc=trunc,
            color_type=integration.TSDFVolumeColorType.RGB8,
            origin=lo.astype(np.float64).reshape(3, 1),
        )
    for d, c, cam in prepared:
        h, w = d.shape
        K = cam.K
        intr = o3d.camera.PinholeCameraIntrinsic(w, h, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        # depth is float32 metres: depth_scale must be 1 (the default 1000 assumes mm), and the
        # colour must stay RGB (the default converts it to intensity, which an RGB8 volume rejects).
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(c),
            o3d.geometry.Image(d),
            depth_scale=1.0,
            depth_trunc=float(cam.depth_range[1]),
            convert_rgb_to_intensity=False,
        )
        vol.integrate(rgbd, intr, np.ascontiguousarray(cam.T_cam_world))
    return _from_o3d(vol.extract_point_cloud(), frame.device)
