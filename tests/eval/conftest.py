"""Hand-built scenes for the evaluation tests: cameras looking at a textured plane."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tests.conftest import look_at

from fuseflow import Camera, Frame, Rig

W, H = 160, 120
K = np.array([[140.0, 0.0, 79.5], [0.0, 140.0, 59.5], [0.0, 0.0, 1.0]])
PLANE_Z = 2.0  # the plane is world z = PLANE_Z
EYES = [(-0.3, 0.0, 0.0), (0.3, 0.0, 0.0), (0.0, 0.25, 0.1)]


def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth grey texture of the plane (periods of 5-7 cm, several pixels at 2 m)."""
    return 128.0 + 90.0 * np.sin(2 * np.pi * x / 0.05) * np.cos(2 * np.pi * y / 0.07)


def render_plane(cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Analytic depth (H, W) metres and colour (H, W, 3) uint8 of the plane z = PLANE_Z."""
    T = cam.T_cam_world
    R, t = T[:3, :3], T[:3, 3]
    c = -R.T @ t
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T  # z = 1 in camera
    dirs = rays @ R  # world directions (R^T d), same length scale: depth = t
    depth = (PLANE_Z - c[2]) / dirs[..., 2]
    X = c + depth[..., None] * dirs
    g = np.clip(np.rint(texture(X[..., 0], X[..., 1])), 0, 255).astype(np.uint8)
    return depth.astype(np.float32), np.repeat(g[..., None], 3, axis=2)


def make_scene(n_cams: int = 2, present: list[bool] | None = None) -> tuple[Frame, Rig]:
    cams = [
        Camera(f"cam{i}", W, H, K, depth_range=(0.2, 5.0), T_cam_world=look_at(EYES[i], (0.0, 0.0, PLANE_Z)))
        for i in range(n_cams)
    ]
    rig = Rig(tuple(cams))
    rendered = [render_plane(c) for c in cams]
    frame = Frame(
        index=0,
        camera_ids=rig.ids,
        color=torch.from_numpy(np.stack([r[1] for r in rendered])),
        depth=torch.from_numpy(np.stack([r[0] for r in rendered])),
        present=torch.tensor(present if present is not None else [True] * n_cams),
    )
    return frame, rig


@pytest.fixture
def plane_scene():
    return make_scene
