"""Synthetic rigs with analytic depth for GMAC tests: a textured box room with boxes inside.

Depth is ray-cast exactly (slab intersection with axis-aligned boxes), so the true metric
extrinsics are known and noise-free; ``make_scene`` builds a Frame and a Rig; ``truth_backbone``
returns the true poses with translations divided by a known factor (the scale GMAC must find).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tests.conftest import look_at

from fuseflow import Camera, Frame, Rig
from fuseflow.calib.backbones import BackboneResult
from fuseflow.calib.scale import Correspondences, closed_form_scale
from fuseflow.calib.scale_stage import rc_step

ROOM = (np.array([-3.0, -2.0, -3.0]), np.array([3.0, 1.0, 3.0]))  # y down: floor at y = 1
OBJECTS = [
    (np.array([-0.6, 0.2, -0.5]), np.array([0.1, 1.0, 0.3])),
    (np.array([0.5, -0.3, 0.2]), np.array([1.1, 1.0, 0.9])),
    (np.array([-1.2, 0.5, 0.8]), np.array([-0.7, 1.0, 1.4])),
]


def _texture(P: np.ndarray) -> np.ndarray:
    """Deterministic high-frequency colour from world position (SIFT-friendly, no randomness)."""
    f = np.array([[7.1, 3.3, 5.9], [4.3, 8.7, 2.1], [2.9, 5.3, 9.7]])
    c = 0.5 + 0.25 * np.sin(P @ f.T * 3.0) + 0.25 * np.sign(np.sin(P @ f.T * 1.1))
    return (np.clip(c, 0, 1) * 255).astype(np.uint8)


def render(T_cam_world: np.ndarray, K: np.ndarray, size: tuple[int, int], objects=OBJECTS):
    """(depth (H, W) float32 metres, colour (H, W, 3) uint8) of the room seen by one camera."""
    W, H = size
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    R, t = T_cam_world[:3, :3], T_cam_world[:3, 3]
    o = -R.T @ t
    d = rays_c @ R  # world directions with camera z = 1, so the ray parameter is the depth
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        lo, hi = (ROOM[0] - o) * inv, (ROOM[1] - o) * inv
        depth = np.minimum(lo, hi).max(1) * 0 + np.maximum(lo, hi).min(1)  # room: exit distance
        for a, b in objects:
            lo, hi = (a - o) * inv, (b - o) * inv
            tn, tf = np.minimum(lo, hi).max(1), np.maximum(lo, hi).min(1)
            hit = (tn <= tf) & (tn > 0)
            depth = np.where(hit & (tn < depth), tn, depth)
    P = o + d * depth[:, None]
    return depth.reshape(H, W).astype(np.float32), _texture(P).reshape(H, W, 3)


def make_scene(n: int = 5, size=(160, 120), radius: float = 1.9, seed: int = 0, heights=None):
    """(frame, bare rig, true T (N, 4, 4)) for n cameras on a circle looking at the room centre."""
    rng = np.random.default_rng(seed)
    W, H = size
    f = 0.9 * W
    K = np.array([[f, 0, W / 2 - 0.5], [0, f, H / 2 - 0.5], [0, 0, 1]])
    Ts, depths, colors = [], [], []
    for k in range(n):
        a = 2 * np.pi * k / n + rng.uniform(-0.1, 0.1)
        h = -0.4 if heights is None else heights[k]
        eye = np.array([radius * np.cos(a), h + rng.uniform(-0.2, 0.2), radius * np.sin(a)])
        T = look_at(eye, [rng.uniform(-0.3, 0.3), 0.4, rng.uniform(-0.3, 0.3)])
        d, c = render(T, K, size)
        Ts.append(T)
        depths.append(d)
        colors.append(c)
    cams = tuple(Camera(f"c{k}", W, H, K, depth_range=(0.1, 10.0)) for k in range(n))
    frame = Frame(
        0,
        tuple(c.id for c in cams),
        torch.from_numpy(np.stack(colors)),
        torch.from_numpy(np.stack(depths)),
        torch.ones(n, dtype=torch.bool),
    )
    return frame, Rig(cams), np.stack(Ts)


def truth_backbone(T_true: np.ndarray, factor: float, rot_noise_deg: float = 0.0, seed: int = 0) -> BackboneResult:
    """True poses with translations divided by ``factor`` (GMAC must find s* = factor)."""
    T0 = T_true.copy()
    T0[:, :3, 3] /= factor
    if rot_noise_deg:
        from scipy.spatial.transform import Rotation

        rng = np.random.default_rng(seed)
        for k in range(len(T0)):
            dR = Rotation.from_rotvec(np.radians(rot_noise_deg) * rng.normal(size=3) / np.sqrt(3)).as_matrix()
            C = -T0[k, :3, :3].T @ T0[k, :3, 3]
            T0[k, :3, :3] = dR @ T0[k, :3, :3]
            T0[k, :3, 3] = -T0[k, :3, :3] @ C
    return BackboneResult(T0, np.ones(len(T0), bool), name="truth")


@pytest.fixture(scope="session")
def scene5():
    return make_scene(5)


@pytest.fixture(scope="session")
def scene_builder():
    return make_scene


@pytest.fixture(scope="session")
def backbone_builder():
    return truth_backbone


def shifted_step(offsets: dict[tuple[int, int], float]):
    """A fixed-point step (``metric_scale(..., step=)``) that corrupts edges: for edge (i, j)
    (i < j) -> offset metres, that edge's points in camera j are shifted along the baseline,
    Y' = Y + offset t / |t|, so the edge alone implies a baseline ``offset`` too long, as an edge
    with wrong matches would (robustness check of CC)."""

    def step(geoms, cams, s, config):
        _, corrs = rc_step(geoms, cams, s, config)
        out = []
        for c in corrs:
            f = offsets.get((min(c.i, c.j), max(c.i, c.j)))
            if f is None:
                out.append(c)
            else:
                out.append(
                    Correspondences(c.i, c.j, c.RX, c.Y + f * c.t / np.linalg.norm(c.t), c.t, c.w, c.is_match, c.n)
                )
        return closed_form_scale(out, config.closed_form), out

    return step


@pytest.fixture(scope="session")
def corrupt_step():
    return shifted_step
