"""Pinhole camera primitives shared by FUSE, GMAC and the pipeline (docs/conventions.md, docs/architecture.md).

Conventions: metres, OpenCV axes (x right, y down, z forward), pixel centres at integer
coordinates, ``T_cam_world`` camera-from-world. Every function is a stateless tensor function.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch


__all__ = ["pixel_rays", "backproject", "relative_transforms"]


def pixel_rays(K: torch.Tensor, h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised ray coordinates (xn, yn) of every pixel centre, a point at depth z being
    (xn z, yn z, z) in the camera frame.

    Args:
        K: (N, 3, 3) float32 intrinsics (skew allowed). h, w: image size in pixels.

    Returns:
        xn, yn: each (N, H, W) float32, on K's device.
    """
    import torch

    dev = K.device
    v = torch.arange(h, device=dev, dtype=torch.float32)[None, :, None]
    u = torch.arange(w, device=dev, dtype=torch.float32)[None, None, :]
    fx, fy, s = K[:, 0, 0, None, None], K[:, 1, 1, None, None], K[:, 0, 1, None, None]
    cx, cy = K[:, 0, 2, None, None], K[:, 1, 2, None, None]
    yn = (v - cy) / fy
    xn = (u - cx - s * yn) / fx
    return xn.expand(-1, h, w), yn.expand(-1, h, w)


def backproject(depth: torch.Tensor, K: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera-frame points of every pixel with depth.

    Args:
        depth: (N, H, W) float32 metres, 0 = no measurement. K: (N, 3, 3) float32.

    Returns:
        X: (M, 3) float32 points, each in the frame of its own camera; index: (M, 3) int64
        (camera, row, column) of each point, in row-major order per camera.
    """
    import torch

    xn, yn = pixel_rays(K.to(torch.float32), depth.shape[1], depth.shape[2])
    valid = depth > 0
    z = depth[valid]
    X = torch.stack([xn[valid] * z, yn[valid] * z, z], dim=1)
    return X, torch.nonzero(valid)


def relative_transforms(T_cam_world: torch.Tensor | np.ndarray) -> torch.Tensor | np.ndarray:
    """(N, N, 3, 4) float32 [R_ji | t_ji] = E_j E_i^-1 (camera i to camera j, indexed [i, j]),
    from (N, 4, 4) camera-from-world. Composed in float64, then rounded once to float32 (the
    compiled kernels read the same numbers). A numpy array gives a numpy array (same numbers)."""
    if isinstance(T_cam_world, np.ndarray):
        T64 = T_cam_world.astype(np.float64)
        R, t = T64[:, :3, :3], T64[:, :3, 3]
        A, B = R[:, None, :, None, :], R[None, :, None, :, :]  # R_j[a, b], R_i[c, b]
        # sums in index order, the order torch's einsum adds in (bit-identical float64)
        R_ji = A[..., 0] * B[..., 0] + A[..., 1] * B[..., 1] + A[..., 2] * B[..., 2]  # R_j R_i^T
        ti = t[None, :, None, :]
        t_ji = t[:, None, :] - (R_ji[..., 0] * ti[..., 0] + R_ji[..., 1] * ti[..., 1] + R_ji[..., 2] * ti[..., 2])
        out = np.concatenate([R_ji, t_ji[..., None]], axis=-1).transpose(1, 0, 2, 3)
        return np.ascontiguousarray(out.astype(np.float32))
    import torch

    T = T_cam_world.detach().to("cpu", torch.float64)
    R, t = T[:, :3, :3], T[:, :3, 3]
    R_ji = torch.einsum("jab,icb->jiac", R, R)  # R_j R_i^T
    t_ji = t[:, None, :] - torch.einsum("jiab,ib->jia", R_ji, t)
    out = torch.cat([R_ji, t_ji[..., None]], dim=-1).transpose(0, 1)  # index [i, j]
    return out.to(torch.float32).to(T_cam_world.device).contiguous()
