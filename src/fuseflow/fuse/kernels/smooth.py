"""Noise-aware depth smoothing compiled (fuse/smooth.py has the definition and the torch form):
each valid depth at the grid's pixels becomes the mean of its window's depths within gate *
sigma(z); the same float32 operations in the same window order as fuse/smooth.py.

The kernel runs one grid row at a time, window offset by window offset: for each (dy, dx) of
the window, in the reference's order, one straight loop over the row's grid columns adds the
neighbour at that offset where it passes the gate and 0.0 elsewhere (which leaves a float32 sum
of positive depths unchanged), so the loops carry no per-pixel branch and the compiler
vectorises them. On a grid coarser than every pixel each neighbour row is first split into its
``stride`` column phases (zero-padded: a missing pixel never passes the gate), so that those
loops read contiguous memory too. The sums per pixel are those of the pixel-by-pixel form, bit
for bit (tests/fuse/test_smooth.py)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True)  # before any @njit(cache=True)

__all__ = ["smooth_depth_kernel"]

_F = np.float32


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _add(rp, sh, m, zc, lim, ss, nn):
    """ss[k] += rp[k + sh] and nn[k] += 1 where rp[k + sh] is a depth within lim[k] of zc[k]
    (k < m; sh, m uint64: no negative-index handling in the loop)."""
    zero = _F(0.0)
    one = _F(1.0)
    for k in range(m):
        zn = rp[k + sh]
        ok = (zn > zero) & (abs(zn - zc[k]) < lim[k])
        ss[k] = ss[k] + (zn if ok else zero)
        nn[k] = nn[k] + (one if ok else zero)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _window_rows(flat, base0, y, H, W, r, stride, q, zc, lim, ss, nn, ph):
    """The window sums of grid row y (its first pixel at flat index base0 - y W): rows y - r
    .. y + r inside the image, offsets dx = -r .. r in that order."""
    m = zc.shape[0]
    for yy in range(max(y - r, 0), min(y + r, H - 1) + 1):
        base = base0 + (yy - y) * W
        if stride == 1:  # the image row itself: columns k + dx inside the row
            for dx in range(-r, r + 1):
                k0 = max(-dx, 0)
                k1 = min(m, W - dx)
                _add(flat[base + k0 + dx : base + k1 + dx], np.uint64(0), np.uint64(k1 - k0), zc[k0:k1], lim[k0:k1],
                     ss[k0:k1], nn[k0:k1])  # fmt: skip
            continue
        src = flat[base : base + W]  # a contiguous row: no offsets into the whole map in the loops
        if stride == 2:  # both phases in one loop of constant stride, which the compiler vectorises
            ev = ph[0]
            od = ph[1]
            for t in range(W // 2):
                ev[q + t] = src[2 * t]
                od[q + t] = src[2 * t + 1]
            if W % 2:
                ev[q + W // 2] = src[W - 1]
            phases = 0
        else:
            phases = stride
        for p in range(phases):  # phase p: ph[p, t] = column (t - q) stride + p, zero outside
            t1 = min(q + (W - p + stride - 1) // stride, ph.shape[1])
            for t in range(q, t1):
                ph[p, t] = src[(t - q) * stride + p]
        for dx in range(-r, r + 1):
            p = dx % stride
            _add(ph[p], np.uint64((dx - p) // stride + q), np.uint64(m), zc, lim, ss, nn)


@njit(cache=True, parallel=True, error_model="numpy")
def smooth_depth_kernel(depth, r, gate, a, b, z0, stride):  # pragma: no cover - compiled
    """(N, H, W) float32 depth -> smoothed copy; pixels off the ``stride`` grid are copied.
    Parallel over blocks of rows; a block fills its rows of the copy, grid rows smoothed."""
    N, H, W = depth.shape
    out = np.empty_like(depth)
    flat = depth.reshape(N * H * W)
    of = out.reshape(N * H * W)
    zero = _F(0.0)
    m = (W + stride - 1) // stride
    q = (r + stride - 1) // stride  # zero padding of the phases, in grid columns
    rows_per = 8
    n_blk = (N * H + rows_per - 1) // rows_per
    for blk in prange(n_blk):
        zc = np.empty(m, dtype=np.float32)
        lim = np.empty(m, dtype=np.float32)
        ss = np.empty(m, dtype=np.float32)
        nn = np.empty(m, dtype=np.float32)
        ph = np.zeros((stride, m + 2 * q + 1), dtype=np.float32)
        for row in range(blk * rows_per, min((blk + 1) * rows_per, N * H)):
            y = row % H
            rb = row * W
            of[rb : rb + W] = flat[rb : rb + W]
            if y % stride != 0:
                continue
            for k in range(m):
                z = flat[rb + k * stride]
                zc[k] = z
                dz = z - z0
                lim[k] = gate * (a + b * (dz * dz))
                ss[k] = zero
                nn[k] = zero
            _window_rows(flat, rb, y, H, W, r, stride, q, zc, lim, ss, nn, ph)
            for k in range(m):
                if zc[k] > zero:
                    of[rb + k * stride] = ss[k] / nn[k]
    return out
