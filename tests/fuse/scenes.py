"""Analytic scenes for the FUSE tests: cameras looking at axis-aligned rectangles (ray cast).

A plain module: tests import it as ``from tests.fuse.scenes import ...`` (pytest puts the
repository root on sys.path, ``pythonpath`` in pyproject.toml).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tests.conftest import look_at  # the one camera look-at helper of the suite

from fuseflow import Camera, Frame, Rig

__all__ = ["PLANE_Z", "Rect", "look_at", "make_rig", "render", "W", "H", "K"]

W, H = 80, 60
K = np.array([[70.0, 0.0, 39.5], [0.0, 70.0, 29.5], [0.0, 0.0, 1.0]])
PLANE_Z = 2.0


@dataclass(frozen=True)
class Rect:
    """The rectangle z = z0, x in [x0, x1], y in [y0, y1] (world metres)."""

    z0: float
    x0: float = -50.0
    x1: float = 50.0
    y0: float = -50.0
    y1: float = 50.0


def make_rig(eyes, target=(0.0, 0.0, PLANE_Z), w=W, h=H, k=K) -> Rig:
    return Rig(
        tuple(
            Camera(f"cam{i}", w, h, k, depth_range=(0.2, 8.0), T_cam_world=look_at(e, target, up=(0.0, -1.0, 0.0)))
            for i, e in enumerate(eyes)
        )
    )


def render(rig: Rig, rects, noise: float = 0.0, seed: int = 0, only: dict | None = None) -> Frame:
    """Ray-cast depth (metres along the optical axis) of ``rects`` in every camera.

    ``only`` maps a rect index to the set of camera indices that see it (an object that only
    some cameras see, e.g. a person standing right in front of one camera). ``noise`` is a
    relative Gaussian depth noise (sigma = noise * z).
    """
    rng = np.random.default_rng(seed)
    depths, colors = [], []
    for ci, cam in enumerate(rig.cameras):
        vv, uu = np.meshgrid(
            np.arange(cam.height, dtype=np.float64), np.arange(cam.width, dtype=np.float64), indexing="ij"
        )
        rays_c = np.stack([uu, vv, np.ones_like(uu)], -1) @ np.linalg.inv(cam.K).T  # z = 1 in camera
        T_wc = cam.T_world_cam
        d_w = rays_c @ T_wc[:3, :3].T
        o = T_wc[:3, 3]
        best = np.full(uu.shape, np.inf)
        for ri, r in enumerate(rects):
            if only is not None and ri in only and ci not in only[ri]:
                continue
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (r.z0 - o[2]) / d_w[..., 2]
            p = o + t[..., None] * d_w
            hit = (t > 0) & (p[..., 0] >= r.x0) & (p[..., 0] <= r.x1) & (p[..., 1] >= r.y0) & (p[..., 1] <= r.y1)
            best = np.where(hit & (t < best), t, best)
        z = np.where(np.isfinite(best), best, 0.0)  # t is the camera-frame depth since rays have z_c = 1
        if noise > 0:
            z = np.where(z > 0, z * (1.0 + noise * rng.standard_normal(z.shape)), 0.0)
        depths.append(z.astype(np.float32))
        colors.append(np.full((cam.height, cam.width, 3), 40 * (ci + 1) % 256, dtype=np.uint8))
    return Frame(
        index=0,
        camera_ids=rig.ids,
        color=torch.from_numpy(np.stack(colors)),
        depth=torch.from_numpy(np.stack(depths)),
        present=torch.ones(len(rig), dtype=torch.bool),
    )
