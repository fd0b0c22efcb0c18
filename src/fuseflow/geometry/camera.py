"""Pinhole camera primitives shared by FUSE, GMAC and the pipeline (docs/design.md 1 and 5).

Conventions: metres, OpenCV axes (x right, y down, z forward), pixel centres at integer
coordinates, ``T_cam_world`` camera-from-world. Every function is a stateless tensor function.
"""

from __future__ import annotations

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
    xn, yn = pixel_rays(K.to(torch.float32), depth.shape[1], depth.shape[2])
    valid = depth > 0
    z = depth[valid]
    X = torch.stack([xn[valid] * z, yn[valid] * z, z], dim=1)
    return X, torch.nonzero(valid)


def relative_transforms(T_cam_world: torch.Tensor) -> torch.Tensor:
    """(N, N, 3, 4) float32 [R_ji | t_ji] = E_j E_i^-1 (camera i to camera j, indexed [i, j]),
    from (N, 4, 4) camera-from-world. Composed in float64, then rounded once to float32 (the
    compiled kernels read the same numbers)."""
    T = T_cam_world.detach().to("cpu", torch.float64)
    R, t = T[:, :3, :3], T[:, :3, 3]
    R_ji = torch.einsum("jab,icb->jiac", R, R)  # R_j R_i^T
    t_ji = t[:, None, :] - torch.einsum("jiab,ib->jia", R_ji, t)
    out = torch.cat([R_ji, t_ji[..., None]], dim=-1).transpose(0, 1)  # index [i, j]
    return out.to(torch.float32).to(T_cam_world.device).contiguous()
