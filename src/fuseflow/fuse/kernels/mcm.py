"""MCM (eq. 16-18) compiled: c(x) of a camera row (``mcm_row``), with the gap-tolerant 3x3
window (``tolerant_window``); the same float32 operations in the same order as fuse/mcm.py."""

from __future__ import annotations

import numpy as np
from numba import njit

from fuseflow.fuse.kernels.common import sigma as _sigma
from fuseflow.geometry import noise
from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True, depends=(noise.__file__,))  # before any @njit(cache=True)

__all__ = ["mcm_row", "tolerant_window"]

_F = np.float32


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def tolerant_window(d0, d1, d2, d3, z, d5, d6, d7, d8, mmiss):
    """mcm.tolerant_gradient_and_variance for one pixel whose 3x3 window misses some depth
    (float32, the same operations in the same order): (gx^2 + gy^2, variance), or (-1, -1)
    when more than ``mmiss`` neighbours are missing."""
    zero = _F(0.0)
    half = _F(0.5)
    cnt = 0
    s = zero
    for d in (d0, d1, d2, d3, z, d5, d6, d7, d8):
        if d > 0:
            s = s + d
            cnt += 1
        else:
            s = s + zero
    if 9 - cnt > mmiss:
        return _F(-1.0), _F(-1.0)
    fc = _F(cnt)
    mean = s / fc
    var = zero
    for d in (d0, d1, d2, d3, z, d5, d6, d7, d8):
        e = d - mean
        if d > 0:
            var = var + e * e
        else:
            var = var + zero
    var = var / fc
    if d3 > 0 and d5 > 0:
        gx = (d5 - d3) * half
    elif d5 > 0:
        gx = d5 - z
    elif d3 > 0:
        gx = z - d3
    else:
        gx = zero
    if d1 > 0 and d7 > 0:
        gy = (d7 - d1) * half
    elif d7 > 0:
        gy = d7 - z
    elif d1 > 0:
        gy = z - d1
    else:
        gy = zero
    return gx * gx + gy * gy, var


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def mcm_row(up, row, dn, prm, u0, stride, gq, vr, cc):
    """MCM (eq. 16-18) of the image row ``row`` (not the first or last row of its image; ``up``
    and ``dn`` the rows above and below, all three contiguous arrays of the image's width w) at
    its grid columns u = u0, u0 + stride, ... <= w - 2 (u0 >= 1): cc[u] = c(x), or -1 where the
    pixel has no depth or its window fails (any missing neighbour, or more than
    mcm_max_missing with the gap-tolerant window). The arithmetic without branches runs over
    every interior column in straight-line loops over the three rows (gq, vr: scratch), which
    the compiler vectorises (a loop over every ``stride``-th column or with offsets into the
    whole depth map it does not: ~3x slower for half the columns); the gap-tolerant window and
    the exponential, one pixel at a time, only at the grid columns. Per pixel the float32
    operations and their order are those of the reference (mcm.py)."""
    zero = _F(0.0)
    one = _F(1.0)
    half = _F(0.5)
    nine = _F(9.0)
    eps, alpha, beta = prm.eps, prm.alpha, prm.beta
    w = row.shape[0]
    for u in range(1, w - 1):
        d0, d1, d2 = up[u - 1], up[u], up[u + 1]
        d3, z, d5 = row[u - 1], row[u], row[u + 1]
        d6, d7, d8 = dn[u - 1], dn[u], dn[u + 1]
        # same summation order as the window loop of the reference kernel (row-major)
        sm = (((((((zero + d0) + d1) + d2) + d3) + z) + d5) + d6) + d7
        mean = (sm + d8) / nine
        e0, e1, e2, e3, e4 = d0 - mean, d1 - mean, d2 - mean, d3 - mean, z - mean
        e5, e6, e7, e8 = d5 - mean, d6 - mean, d7 - mean, d8 - mean
        var = (((((((zero + e0 * e0) + e1 * e1) + e2 * e2) + e3 * e3) + e4 * e4) + e5 * e5) + e6 * e6) + e7 * e7
        vr[u] = (var + e8 * e8) / nine
        gx = (d5 - d3) * half
        gy = (d7 - d1) * half
        gq[u] = gx * gx + gy * gy
        full = (d0 > zero) & (d1 > zero) & (d2 > zero) & (d3 > zero) & (z > zero)
        full = full & (d5 > zero) & (d6 > zero) & (d7 > zero) & (d8 > zero)
        cc[u] = one if full else -one  # 1: c follows below; -1: no depth or an incomplete window
    mmiss = prm.mcm_max_missing
    if mmiss > 0:  # the gap-tolerant window where a neighbour is missing
        for u in range(u0, w - 1, stride):
            z = row[u]
            if cc[u] > zero or not z > zero:
                continue
            d0, d1, d2 = up[u - 1], up[u], up[u + 1]
            d3, d5 = row[u - 1], row[u + 1]
            d6, d7, d8 = dn[u - 1], dn[u], dn[u + 1]
            gsq, var = tolerant_window(d0, d1, d2, d3, z, d5, d6, d7, d8, mmiss)
            if gsq >= zero:  # else more neighbours missing than allowed
                cc[u] = one
            gq[u] = gsq
            vr[u] = var
    if prm.mcm_noise:  # noise-aware MCM: the expected noise sigma(z)^2 out of g and v
        na, nb, nz0 = prm.noise_a, prm.noise_b, prm.noise_z0
        for u in range(1, w - 1):
            z = row[u]
            sg = _sigma(z, na, nb, nz0)
            s2 = sg * sg
            gsq = gq[u] - s2
            if gsq < zero:
                gsq = zero
            var = vr[u] - s2
            if var < zero:
                var = zero
            gq[u] = gsq
            vr[u] = var
    for u in range(1, w - 1):  # the exponent of eq. (18), vectorised (sqrt and divisions)
        z = row[u]
        g = np.sqrt(gq[u]) / (z + eps)
        vv = vr[u] / (z * z + eps)
        gq[u] = -alpha * g - beta * vv
    for u in range(u0, w - 1, stride):
        if cc[u] > zero:
            cc[u] = np.exp(gq[u])  # eq. (18)
