"""Noise-aware depth smoothing before MCM (beyond the paper; ``FuseConfig.smoothing``).

Each valid depth z becomes the mean of the valid depths in its (2r+1) x (2r+1) window that lie
within ``gate`` * sigma(z) of it (sigma: the sensor's axial noise, ``FuseConfig.noise_sigma``).
On a smooth surface that averages up to (2r+1)^2 independent measurements, dividing the axial
noise by up to 2r+1; across a depth edge the far side lies many sigma away and is left out, so
edges, flying pixels and thin structures keep their own depth. Missing pixels (0) stay missing.

Two forms with the same float32 operations in the same window order: ``smooth_depth_numpy``
(numpy arrays; the numba kernel of fuse/kernels/smooth.py, parallel over rows) and
``smooth_depth_torch`` (tensors, any device). tests/fuse/test_smooth.py checks that they agree and what the filter keeps.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["smooth_depth", "smooth_depth_numpy", "smooth_depth_torch"]


def smooth_depth_numpy(
    depth: np.ndarray, radius: int, gate: float, model: tuple[float, float, float], stride: int = 1
) -> np.ndarray:
    """(N, H, W) float32 depth (0 = missing) smoothed (module docstring) at the pixels (u, v) with
    u and v multiples of ``stride`` (FuseConfig.pixel_stride: the candidates), the others as they
    were; radius 0 returns ``depth`` itself."""
    if radius <= 0:
        return depth
    a, b, z0 = (np.float32(v) for v in model)
    d = np.ascontiguousarray(depth, dtype=np.float32)
    from fuseflow.fuse.kernels.smooth import smooth_depth_kernel

    return smooth_depth_kernel(d, int(radius), np.float32(gate), a, b, z0, int(stride))


def smooth_depth_torch(depth: Any, radius: int, gate: float, model: tuple[float, float, float], stride: int = 1) -> Any:
    """The same filter on a (N, H, W) float32 tensor (any device)."""
    import torch

    if radius <= 0:
        return depth
    N, H, W = depth.shape
    a, b, z0 = (torch.tensor(v, dtype=torch.float32, device=depth.device) for v in model)
    dz = depth - z0
    lim = torch.tensor(gate, dtype=torch.float32, device=depth.device) * (a + b * (dz * dz))
    pad = torch.nn.functional.pad(depth, (radius, radius, radius, radius))
    s = torch.zeros_like(depth)
    n = torch.zeros_like(depth)
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            zn = pad[:, dy : dy + H, dx : dx + W]
            ok = (zn > 0) & ((zn - depth).abs() < lim)
            s = s + torch.where(ok, zn, torch.zeros_like(zn))
            n = n + ok.to(torch.float32)
    out = torch.where(depth > 0, s / n.clamp_min(1.0), torch.zeros_like(depth))
    if stride > 1:
        keep = depth.clone()
        keep[:, ::stride, ::stride] = out[:, ::stride, ::stride]
        out = keep
    return out


def smooth_depth(depth: Any, radius: int, gate: float, model: tuple[float, float, float], stride: int = 1) -> Any:
    """numpy arrays -> :func:`smooth_depth_numpy`; tensors -> the compiled form on CPU (same
    result), :func:`smooth_depth_torch` elsewhere."""
    if radius <= 0:
        return depth
    if isinstance(depth, np.ndarray):
        return smooth_depth_numpy(depth, radius, gate, model, stride)
    import torch

    if depth.device.type == "cpu":
        return torch.from_numpy(smooth_depth_numpy(depth.numpy(), radius, gate, model, stride))
    return smooth_depth_torch(depth, radius, gate, model, stride)
