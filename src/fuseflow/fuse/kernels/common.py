"""Helpers shared by the stages' kernels: sigma(z), the float32 ray tables of pixel_rays, the
hash multiplier, the camera of a flat pixel index and the cell ranges of parallel chunks."""

from __future__ import annotations

import numpy as np
from numba import njit

from fuseflow.geometry import noise
from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True, depends=(noise.__file__,))  # before any @njit(cache=True)

__all__ = ["sigma", "HASH_MUL", "ray_tables", "ray_x", "cam_of", "chunk_bounds"]

_F = np.float32
#: sigma(z) = a + b (z - z0)^2 of fuseflow.geometry.noise, compiled and inlined into the kernels.
sigma = noise.compiled_sigma()

#: Multiplier of the open-addressing hash tables of ``cells`` and ``fine_pass`` (Fibonacci
#: hashing: 2^64 / golden ratio, as a signed int64); the slot is the product's high bits.
HASH_MUL = np.int64(-7046029254386353131)


@njit(cache=True, error_model="numpy")
def ray_tables(Kf, h, w):
    """pixel_rays' normalised coordinates per camera, row and column: yt[j, v] = (v - cy) / fy
    and, when every camera has zero skew, xt[j, u] = (u - cx) / fx (with skew s = 0 the formula
    ((u - cx) - s yn) / fx gives exactly this value; returns skew0 False otherwise and the
    kernels compute x inline). Exact: the same float32 operations, done once per frame instead
    of once per pixel and per multi-view vote."""
    n = Kf.shape[0]
    yt = np.empty((n, h), dtype=np.float32)
    xt = np.empty((n, w), dtype=np.float32)
    skew0 = True
    for j in range(n):
        if Kf[j, 0, 1] != 0:
            skew0 = False
        for v in range(h):
            yt[j, v] = (_F(v) - Kf[j, 1, 2]) / Kf[j, 1, 1]
        for u in range(w):
            xt[j, u] = (_F(u) - Kf[j, 0, 2]) / Kf[j, 0, 0]
    return xt, yt, skew0


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def ray_x(Kf, xt, j, u, yn, skew0):
    """x of pixel_rays for column u of camera j whose y is yn (table when skew is zero)."""
    if skew0:
        return xt[j, u]
    return ((_F(u) - Kf[j, 0, 2]) - Kf[j, 0, 1] * yn) / Kf[j, 0, 0]


@njit(cache=True, inline="always", error_model="numpy")
def cam_of(p, hw, inv_hw):
    """p // hw without a 64-bit integer division (~40 cycles on this CPU): a float64 estimate
    (exact to +-1 for p < 2^52), corrected."""
    c = np.int64(np.float64(p) * inv_hw)
    if c * hw > p:
        c -= 1
    elif (c + 1) * hw <= p:
        c += 1
    return c


@njit(cache=True, error_model="numpy")
def chunk_bounds(start, n_chunks):
    """Cell ranges of about equal point counts: bounds (n_chunks + 1,) into the cells."""
    n_cells = start.shape[0] - 1
    total = start[n_cells]
    b = np.empty(n_chunks + 1, dtype=np.int64)
    b[0] = 0
    for k in range(1, n_chunks):
        c = np.searchsorted(start, (total * k) // n_chunks)
        b[k] = min(max(c, b[k - 1]), n_cells)
    b[n_chunks] = n_cells
    return b
