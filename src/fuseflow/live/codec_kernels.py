"""Compiled kernels of the compact frame codec (``fuseflow.live.codec``): grid cells and Morton
keys, a radix sort, the octree's occupancy bytes and the colour residuals, in a few linear passes
that release the GIL (the encoder runs in a thread of its own, beside fusion).

numba is imported here only; ``import fuseflow.live`` does not load it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__)  # before any @njit(cache=True) below

__all__ = ["bounds", "finite_min", "grid_cells", "compact_streams"]


@njit(cache=True, nogil=True)
def bounds(xyz):  # pragma: no cover - compiled
    """Per-axis (minimum, maximum) of (M, 3) points (one pass; numpy's axis-0 reductions over
    (M, 3) are several times slower)."""
    lo = np.full(3, np.inf, np.float32)
    hi = np.full(3, -np.inf, np.float32)
    for i in range(xyz.shape[0]):
        for a in range(3):
            v = xyz[i, a]
            if v < lo[a]:
                lo[a] = v
            if v > hi[a]:
                hi[a] = v
    return lo, hi


@njit(cache=True, nogil=True)
def finite_min(xyz):  # pragma: no cover - compiled
    """(per-axis minimum over the finite points, number of points with a non-finite coordinate)."""
    lo = np.full(3, np.inf)
    bad = 0
    for i in range(xyz.shape[0]):
        x, y, z = np.float64(xyz[i, 0]), np.float64(xyz[i, 1]), np.float64(xyz[i, 2])
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            bad += 1
            continue
        lo[0], lo[1], lo[2] = min(lo[0], x), min(lo[1], y), min(lo[2], z)
    return lo, bad


@njit(cache=True, nogil=True)
def grid_cells(xyz, origin, inv_step):  # pragma: no cover - compiled
    """(M, 3) int64 cells ``floor((p - origin) * inv_step)`` and the largest coordinate."""
    n = xyz.shape[0]
    cells = np.empty((n, 3), np.int64)
    top = 0
    for i in range(n):
        for a in range(3):
            c = np.int64(np.floor((np.float64(xyz[i, a]) - origin[a]) * inv_step))
            c = max(c, 0)
            cells[i, a] = c
            top = max(top, c)
    return cells, top


@njit(cache=True, nogil=True, inline="always")
def _part1by2(x):  # pragma: no cover - compiled
    x = np.uint64(x) & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@njit(cache=True, nogil=True)
def _sorted_keys(cells, bits):  # pragma: no cover - compiled
    """Morton keys (x high, z low within each 3-bit group) sorted by an LSD radix sort of
    ``bits`` bits, and the permutation that sorts them."""
    n = cells.shape[0]
    key = np.empty(n, np.uint64)
    for i in range(n):
        key[i] = (
            (_part1by2(cells[i, 0]) << np.uint64(2)) | (_part1by2(cells[i, 1]) << np.uint64(1)) | _part1by2(cells[i, 2])
        )
    order = np.arange(n)
    key2 = np.empty(n, np.uint64)
    order2 = np.empty(n, np.int64)
    passes = max(1, (bits + 15) // 16)  # as few scatter passes as 16-bit digits allow
    digit = (bits + passes - 1) // passes
    mask = np.uint64((1 << digit) - 1)
    count = np.empty(1 << digit, np.int64)
    for p in range(passes):
        shift = np.uint64(p * digit)
        count[:] = 0
        for i in range(n):
            count[(key[i] >> shift) & mask] += 1
        total = 0
        for d in range(count.shape[0]):
            c = count[d]
            count[d] = total
            total += c
        for i in range(n):
            d = (key[i] >> shift) & mask
            j = count[d]
            count[d] = j + 1
            key2[j] = key[i]
            order2[j] = order[i]
        key, key2 = key2, key
        order, order2 = order2, order
    return key, order


@njit(cache=True, nogil=True)
def _leaves(key, order, rgb):  # pragma: no cover - compiled
    """Unique sorted keys and the mean colour (float64) of the points in each."""
    n = key.shape[0]
    uniq = np.empty(n, np.uint64)
    mean = np.zeros((n, 3), np.float64)
    m = 0
    i = 0
    while i < n:
        j = i
        s0 = s1 = s2 = 0.0
        while j < n and key[j] == key[i]:
            p = order[j]
            s0 += rgb[p, 0]
            s1 += rgb[p, 1]
            s2 += rgb[p, 2]
            j += 1
        c = j - i
        uniq[m] = key[i]
        mean[m, 0], mean[m, 1], mean[m, 2] = s0 / c, s1 / c, s2 / c
        m += 1
        i = j
    return uniq[:m], mean[:m]


@njit(cache=True, nogil=True)
def _occupancy(leaves, levels):  # pragma: no cover - compiled
    """Breadth-first occupancy bytes (root first) of sorted unique keys of depth ``levels``."""
    cur = leaves.copy()
    n = cur.shape[0]
    buf = np.empty(max(2 * n, 64), np.uint8)
    starts = np.empty(levels + 1, np.int64)
    used = 0
    for lev in range(levels):  # leaves up: level ``lev`` holds the parents of the current nodes
        starts[lev] = used
        m = 0
        i = 0
        while i < n:
            parent = cur[i] >> np.uint64(3)
            byte = 0
            while i < n and (cur[i] >> np.uint64(3)) == parent:
                byte |= 1 << np.int64(cur[i] & np.uint64(7))
                i += 1
            if used == buf.shape[0]:
                bigger = np.empty(2 * used, np.uint8)
                bigger[:used] = buf
                buf = bigger
            buf[used] = byte
            used += 1
            cur[m] = parent
            m += 1
        n = m
    starts[levels] = used
    out = np.empty(used, np.uint8)
    k = 0
    for lev in range(levels - 1, -1, -1):
        for t in range(starts[lev], starts[lev + 1]):
            out[k] = buf[t]
            k += 1
    return out


@njit(cache=True, nogil=True)
def _colour_residuals(mean, luma_step, chroma_step, block):  # pragma: no cover - compiled
    """Luma residuals (one byte a point) and chroma residuals (Cb blocks, then Cr blocks), mod 256."""
    m = mean.shape[0]
    nb = (m + block - 1) // block
    luma = np.empty(m, np.uint8)
    chroma = np.empty(2 * nb, np.uint8)
    prev = 0
    pcb = 0
    pcr = 0
    for b in range(nb):
        scb = scr = 0.0
        for t in range(block):
            i = min(b * block + t, m - 1)  # the last block repeats its last point
            r, g, bl = mean[i, 0], mean[i, 1], mean[i, 2]
            y = np.floor((77.0 * r + 150.0 * g + 29.0 * bl + 128.0) / 256.0)
            scb += bl - y
            scr += r - y
            if b * block + t < m:
                q = np.int64(np.rint(y / luma_step))
                luma[i] = (q - prev) & 255
                prev = q
        qb = np.int64(np.rint(scb / block / chroma_step))
        qr = np.int64(np.rint(scr / block / chroma_step))
        chroma[b] = (qb - pcb) & 255
        chroma[nb + b] = (qr - pcr) & 255
        pcb, pcr = qb, qr
    return luma, chroma


@njit(cache=True, nogil=True)
def compact_streams(cells, levels, rgb, luma_step, chroma_step, block):  # pragma: no cover - compiled
    """(occupancy bytes, luma residuals, chroma residuals, points sent) of a frame's cells."""
    key, order = _sorted_keys(cells, 3 * levels)
    leaves, mean = _leaves(key, order, rgb)
    occ = _occupancy(leaves, levels)
    luma, chroma = _colour_residuals(mean, luma_step, chroma_step, block)
    return occ, luma, chroma, leaves.shape[0]
