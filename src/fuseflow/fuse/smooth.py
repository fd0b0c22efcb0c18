"""Noise-aware depth smoothing before MCM (beyond the paper; ``FuseConfig.depth_smoothing``).

Each valid depth z becomes the mean of the valid depths in its (2r+1) x (2r+1) window that lie
within ``gate`` * sigma(z) of it (sigma: the sensor's axial noise, ``FuseConfig.noise_sigma``).
On a smooth surface that averages up to (2r+1)^2 independent measurements, dividing the axial
noise by up to 2r+1; across a depth edge the far side lies many sigma away and is left out, so
edges, flying pixels and thin structures keep their own depth. Missing pixels (0) stay missing.

Two forms with the same float32 operations in the same window order: ``smooth_depth_numpy``
(compiled with numba, parallel over rows; numpy arrays) and ``smooth_depth_torch`` (tensors,
any device). tests/fuse/test_smooth.py checks that they agree and what the filter keeps.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["smooth_depth", "smooth_depth_numpy", "smooth_depth_torch"]

_KERNEL: Any = None


def _compiled():
    """The numba kernel, compiled on first use (numba is imported only here)."""
    global _KERNEL
    if _KERNEL is None:
        from numba import njit, prange

        from fuseflow.io.numba_cache import use_usable_cache

        use_usable_cache(__file__)

        @njit(cache=True, parallel=True, error_model="numpy")
        def kernel(depth, r, gate, a, b, z0, stride):  # pragma: no cover - compiled
            N, H, W = depth.shape
            out = depth.copy()
            for row in prange(N * H):
                i = row // H
                y = row % H
                if y % stride != 0:
                    continue
                for x in range(0, W, stride):
                    z = depth[i, y, x]
                    if z <= 0:
                        continue
                    dz = z - z0
                    lim = gate * (a + b * (dz * dz))
                    s = np.float32(0.0)
                    n = np.float32(0.0)
                    for dy in range(-r, r + 1):
                        yy = y + dy
                        if yy < 0 or yy >= H:
                            continue
                        for dx in range(-r, r + 1):
                            xx = x + dx
                            if xx < 0 or xx >= W:
                                continue
                            zn = depth[i, yy, xx]
                            if zn > 0 and abs(zn - z) < lim:
                                s += zn
                                n += np.float32(1.0)
                    out[i, y, x] = s / n
            return out

        _KERNEL = kernel
    return _KERNEL


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
    return _compiled()(d, int(radius), np.float32(gate), a, b, z0, int(stride))


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
