"""Noise-aware depth smoothing compiled (fuse/smooth.py has the definition and the torch form):
each valid depth at the grid's pixels becomes the mean of its window's depths within gate *
sigma(z); the same float32 operations in the same window order as fuse/smooth.py."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True)  # before any @njit(cache=True)

__all__ = ["smooth_depth_kernel"]


@njit(cache=True, parallel=True, error_model="numpy")
def smooth_depth_kernel(depth, r, gate, a, b, z0, stride):  # pragma: no cover - compiled
    """(N, H, W) float32 depth -> smoothed copy; pixels off the ``stride`` grid are copied."""
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
