"""A plain geometric test scene: random boxes, spheres and cylinders on a floor, ray-cast.

The simulator's rooms and studios are built for fusion and calibration with texture; their large
planes and symmetric layouts give a point descriptor (FPFH) nothing to hold on to. This scene is
for the geometry-only calibration route (``fuseflow.calib.geometric``): distinct shapes, no
texture (a uniform grey image), exact depth from Open3D's ``RaycastingScene`` plus axial noise
growing with z^2, cameras on a circle looking at the centre.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from fuseflow.synth.rigs import look_at
from fuseflow.types import Camera, Frame, Rig

__all__ = ["primitive_views"]


def _scene(seed: int, objects: int):
    import open3d as o3d

    rng = np.random.default_rng(seed)
    mesh = o3d.geometry.TriangleMesh.create_box(6, 6, 0.02).translate((-3, -3, -0.02))
    for k in range(objects):
        if k % 3 == 0:
            m = o3d.geometry.TriangleMesh.create_box(*rng.uniform(0.15, 0.6, 3))
        elif k % 3 == 1:
            m = o3d.geometry.TriangleMesh.create_sphere(rng.uniform(0.1, 0.3))
        else:
            m = o3d.geometry.TriangleMesh.create_cylinder(rng.uniform(0.05, 0.2), rng.uniform(0.3, 1.2))
        m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, rng.uniform(0, np.pi))), center=(0, 0, 0))
        xy = rng.uniform(-1.0, 1.0, 2)
        m.translate((xy[0], xy[1], -m.get_axis_aligned_bounding_box().min_bound[2]))
        mesh += m
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def primitive_views(
    angles_deg: Sequence[float],
    seeds: Sequence[int] | None = None,
    resolution: tuple[int, int] = (320, 240),
    objects: int = 10,
    radius: float = 2.6,
    height: float = 1.6,
    noise: float = 0.002,
    noise_seed: int = 7,
) -> tuple[Frame, Rig, np.ndarray]:
    """One frame of cameras at ``angles_deg`` on a circle (``radius`` m, ``height`` m up),
    each looking at (0, 0, 0.3); camera k sees the scene of ``seeds[k]`` (default: all seed 0;
    different seeds give cameras that share no geometry).

    Returns (frame: uniform grey colour, depth (N, H, W) float32 metres with axial noise
    ``noise`` * z^2 (std, metres), bare rig (no extrinsics), T_cam_world (N, 4, 4) float64 truth).
    """
    import open3d as o3d

    w, h = resolution
    K = np.array([[280.0 * w / 320, 0.0, w / 2], [0.0, 280.0 * w / 320, h / 2], [0.0, 0.0, 1.0]])
    seeds = [0] * len(angles_deg) if seeds is None else list(seeds)
    scenes = {s: _scene(s, objects) for s in set(seeds)}
    Ts, depths = [], []
    for a, s in zip(angles_deg, seeds, strict=True):
        eye = np.array([radius * np.cos(np.radians(a)), radius * np.sin(np.radians(a)), height])
        Ts.append(look_at(eye, np.array([0.0, 0.0, 0.3])))
        rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(o3d.core.Tensor(K), o3d.core.Tensor(Ts[-1]), w, h)
        z = scenes[s].cast_rays(rays)["t_hit"].numpy()  # unnormalised pinhole rays: t is the z depth
        depths.append(np.where(np.isfinite(z), z, 0.0))
    D = np.stack(depths)
    D = np.where(D > 0, D + np.random.default_rng(noise_seed).normal(0.0, noise, D.shape) * D**2, 0.0)
    n = len(angles_deg)
    ids = tuple(f"cam{k:02d}" for k in range(n))
    rig = Rig(tuple(Camera(c, w, h, K, depth_range=(0.2, 8.0)) for c in ids))
    frame = Frame(0, ids, torch.full((n, h, w, 3), 128, dtype=torch.uint8), torch.from_numpy(D.astype(np.float32)),
                  torch.ones(n, dtype=torch.bool))  # fmt: skip
    return frame, rig, np.stack(Ts)
