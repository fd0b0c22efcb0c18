"""The compiled CPU path of FUSE: the arithmetic of mcm / cvgc / weights / ash / rps fused
into a few numba loops (docs/design.md 2; ../shared/notes/fuse-cpu-feasibility.md).

Same float32 operations in the same order as the PyTorch reference, so results agree up to
float rounding of exp / sqrt and float32 reductions (tests/fuse/test_numba.py states the
tolerance). Structure, and why:

1. ``_pixels`` (parallel over blocks of camera rows): MCM (eq. 16-18) on the 3x3 window
   (``_mcm_row``), the candidate test of eq. (27) *before* any projection (exact: omega <= 2c),
   back-projection, CVGC over <= K_max neighbours (eq. 19-21, ``_votes``) with the multi-view
   mean of the agreeing neighbours' points (cvgc.multiview_mean), the joint weight (22), the
   minimum-weight filter, the world point and its coarse cell. Each row runs as a few passes
   over row-sized scratch, one neighbour at a time, written so that the arithmetic passes
   vectorise (same float32 operations per point as the reference; bit-identical to the
   single-pass form it replaced). No full-size temporaries besides the outputs.
2. ``_cells`` / ``_scatter``: coarse cells hashed once per run of same-cell candidates of a
   row (serial), then the candidates' pixel indices and points written in coarse-cell order.
3. ``_fine_pass`` (parallel over chunks of coarse cells): eq. (24)-(25) fine keys, a stable
   local counting sort, fine-cell densities for rho_bar; point, omega and camera copied into
   slot order so that the later stages read them sequentially.
4. ``_select``: eq. (26), the weighted FPS of eq. (28) inside every fine cell and the
   consensus (rps.consensus); ``_emit`` builds the cloud per coarse cell.

numba is imported here only; ``import fuseflow`` does not load it.
"""

from __future__ import annotations

import math
import threading
from typing import NamedTuple

import numba
import numpy as np
import torch
from numba import njit, prange

from fuseflow.fuse.ash import COARSE_BITS, COARSE_OFFSET, FIXED_BITS, FIXED_OFFSET
from fuseflow.fuse.config import FuseConfig
from fuseflow.geometry.camera import relative_transforms
from fuseflow.types import FusedCloud

__all__ = [
    "fuse_numba",
    "gate_depth",
    "PixelParams",
    "CellParams",
    "SelectParams",
    "ConsensusParams",
    "kernel_params",
    "consensus_params",
]

_F = np.float32
#: Multiplier of the open-addressing hash tables of ``_cells`` and ``_fine_pass`` (Fibonacci
#: hashing: 2^64 / golden ratio, as a signed int64); the slot is the product's high bits.
_HASH_MUL = np.int64(-7046029254386353131)


# --- named kernel parameters --------------------------------------------------------------
# numba takes a NamedTuple of scalars as one argument and types each field by its Python value
# (np.float32 -> float32, float -> float64, bool -> boolean, int -> int64). The field types
# below are the ones the kernels compute with; ``kernel_params`` is the one place that builds
# them from a FuseConfig.


class PixelParams(NamedTuple):
    """Scalars of stage 1 (``_pixels``): MCM, eq. (27), CVGC, eq. (22), the coarse hash key."""

    alpha: np.float32
    """alpha of eq. (18)."""
    beta: np.float32
    """beta of eq. (18)."""
    eps: np.float32
    """epsilon of eq. (16), (17), (20), (22)."""
    r_c: np.float32
    """r_c of eq. (27): candidates need c(x) > r_c."""
    tau: np.float32
    """tau of eq. (21)."""
    min_weight: np.float32
    """FuseConfig.min_weight: candidates also need omega(x) >= this."""
    cell: np.float32
    """Cell size (m) of the first hash level: s_c with ASH, fixed_size without."""
    use_mcm: bool
    use_cvgc: bool
    visibility_aware: bool
    qlim: np.float32
    """Largest |cell index| the hash addresses (offset - 1); beyond it a point is out of range."""
    range_priority: bool
    """Also write the ranking value omega / sigma(z) (rps.selection_priority)."""
    noise_a: np.float32
    """a, b, z0 of sigma(z) = a + b (z - z0)^2 (FuseConfig.noise_sigma)."""
    noise_b: np.float32
    noise_z0: np.float32
    mcm_noise: bool
    """Noise-aware MCM (FuseConfig.mcm_noise): sigma(z)^2 taken out of g and v (mcm.py)."""
    mcm_max_missing: int
    """FuseConfig.mcm_max_missing: gap-tolerant 3x3 window (mcm.py); 0 = any missing -> c = 0."""
    mv_mean: bool
    """Multi-view depth averaging (FuseConfig.multiview_mean; cvgc.multiview_mean)."""
    mv_gate2: np.float32
    """FuseConfig.multiview_gate squared."""
    stride: int
    """FuseConfig.pixel_stride: candidates only at u % stride == 0 of rows v % stride == 0."""
    offset: int
    """Offset added to each cell index before packing (ash.COARSE_OFFSET or FIXED_OFFSET)."""
    bits: int
    """Bits per axis of the packed first-level key (14 with ASH, 21 without)."""


class CellParams(NamedTuple):
    """Scalars of ``_fine_pass``: eq. (23)-(25)."""

    s_c: np.float32
    """Coarse cell size (m), or fixed_size without ASH."""
    s0: np.float32
    """s_0 of eq. (24)."""
    s_min: np.float32
    s_max: np.float32
    eps: np.float32
    adaptive: bool
    """ASH on: fine cells of eq. (24)-(25); off: one fine cell per (fixed) coarse cell."""
    fixed_size: np.float32
    s_c3: np.float32
    """s_c^3 (the coarse cell volume of eq. 23), rounded once to float32."""
    offset: int
    """As PixelParams.offset (to unpack a coarse key into the cell's origin)."""
    bits: int
    """As PixelParams.bits."""


class SelectParams(NamedTuple):
    """Scalars of ``_select``: eq. (26) and the FPS of eq. (28)."""

    k0: np.float32
    """k_0 of eq. (26)."""
    ratio: np.float32
    """r of eq. (26)."""
    k_max: int
    """Most representatives per fine cell."""
    rho_bar: np.float32
    """Mean fine-cell density of eq. (26) (set after ``_fine_pass``; 1 when unused)."""
    fixed_k: bool
    """True: k = k_const in every cell (w/o ASH or w/o RPS); False: eq. (26)."""
    k_const: int
    lone_cell_mean: float
    """FuseConfig.lone_cell_mean (0 = off)."""
    lone_keep: int
    """FuseConfig.lone_cell_keep: a lone point confirmed by at least this many neighbours is kept
    (0 = never; also 0 without the multi-view mean, which counts the confirmations)."""


class KernelParams(NamedTuple):
    """The three parameter structs of one FuseConfig (``kernel_params``)."""

    pixel: PixelParams
    cell: CellParams
    select: SelectParams


def kernel_params(cfg: FuseConfig) -> KernelParams:
    """The kernels' parameters from ``cfg`` (``select.rho_bar`` is 1 until ``_fine_pass`` ran)."""
    adaptive = cfg.use_ash
    s_c = cfg.coarse_size if adaptive else cfg.fixed_size
    offset = COARSE_OFFSET if adaptive else FIXED_OFFSET
    bits = COARSE_BITS if adaptive else FIXED_BITS
    qlim = offset - 1
    a, b, z0 = cfg.noise_sigma
    pixel = PixelParams(
        alpha=_F(cfg.alpha), beta=_F(cfg.beta), eps=_F(cfg.eps), r_c=_F(cfg.r_c), tau=_F(cfg.tau),
        min_weight=_F(cfg.min_weight), cell=_F(s_c), use_mcm=bool(cfg.use_mcm), use_cvgc=bool(cfg.use_cvgc),
        visibility_aware=bool(cfg.visibility_aware), qlim=_F(qlim), range_priority=bool(cfg.range_priority),
        noise_a=_F(a), noise_b=_F(b), noise_z0=_F(z0), mcm_noise=bool(cfg.mcm_noise),
        mcm_max_missing=int(cfg.mcm_max_missing), mv_mean=bool(cfg.multiview_mean and cfg.use_cvgc),
        mv_gate2=_F(cfg.multiview_gate * cfg.multiview_gate), stride=int(cfg.pixel_stride), offset=offset,
        bits=bits,
    )  # fmt: skip
    cell = CellParams(
        s_c=_F(s_c), s0=_F(cfg.s0), s_min=_F(cfg.s_min), s_max=_F(cfg.s_max), eps=_F(cfg.eps),
        adaptive=bool(adaptive), fixed_size=_F(cfg.fixed_size), s_c3=_F(s_c**3), offset=offset, bits=bits,
    )  # fmt: skip
    if cfg.use_rps and adaptive:
        fixed_k, k_const = False, 0
    elif cfg.use_rps:  # w/o ASH: rho_bar in place of rho(C_f) -> k = ceil(k0 r)
        fixed_k, k_const = True, int(min(max(np.ceil(cfg.k0 * cfg.ratio), 1), cfg.k_max))
    else:  # w/o RPS
        fixed_k, k_const = True, int(cfg.k_fixed)
    select = SelectParams(
        k0=_F(cfg.k0), ratio=_F(cfg.ratio), k_max=int(cfg.k_max), rho_bar=_F(1.0), fixed_k=fixed_k,
        k_const=k_const, lone_cell_mean=float(cfg.lone_cell_mean),
        lone_keep=int(cfg.lone_cell_keep) if (cfg.multiview_mean and cfg.use_cvgc) else 0,
    )  # fmt: skip
    return KernelParams(pixel, cell, select)


@njit(cache=True, error_model="numpy")
def _gate(depth, lo, hi, present, out, row_count):
    """api.valid_depth and the absent-view mask in one pass: out = depth where lo < depth < hi
    in a present view, else 0; row_count[row] = kept pixels of that row. Serial: ~1 ms on the
    ICL frame, less than starting both threads costs when another process holds a core."""
    n, h, w = depth.shape
    for row in range(n * h):
        i = row // h
        v = row - i * h
        cnt = 0
        a, b, ok = lo[i], hi[i], present[i]
        for u in range(w):
            z = depth[i, v, u]
            if ok and z > a and z < b:
                out[i, v, u] = z
                cnt += 1
            else:
                out[i, v, u] = 0.0
        row_count[row] = cnt


def gate_depth(depth: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor, present: torch.Tensor):
    """(gated depth (N, H, W) float32 tensor, valid pixels per view): what api._prepare computes
    with torch (valid_depth, then zero for absent views), as one compiled pass. The tensor is
    a view of this thread's FUSE workspace: the next ``fuse_numba`` call overwrites it after
    reading it (api._prepare's depth is read only by that call)."""
    d = depth.contiguous().numpy()
    n, h, w = d.shape
    # in this thread's workspace (fuse_numba reads it in _pixels, then the buffer holds the
    # points): valid until the next fuse_numba of this thread
    out = _workspace(n, h, w).depth()
    rows = np.empty(n * h, dtype=np.int64)
    _gate(d, lo.numpy(), hi.numpy(), present.numpy().astype(np.bool_), out, rows)
    return torch.from_numpy(out), tuple(int(x) for x in rows.reshape(n, h).sum(axis=1))


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _tolerant_window(d0, d1, d2, d3, z, d5, d6, d7, d8, mmiss):
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


@njit(cache=True, error_model="numpy")
def _ray_tables(Kf, h, w):
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
def _ray_x(Kf, xt, j, u, yn, skew0):
    """x of pixel_rays for column u of camera j whose y is yn (table when skew is zero)."""
    if skew0:
        return xt[j, u]
    return ((_F(u) - Kf[j, 0, 2]) - Kf[j, 0, 1] * yn) / Kf[j, 0, 0]


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _votes(dflat, Kf, M_rel, xt, yt, skew0, i, j, h, w, nc, X, Y, Z, v0, prm, zjs, idx, ius, ivs, dv, xq, yq,
           ag, vo, mx, my, mz, md, ns):  # fmt: skip
    """CVGC (eq. 19-21) and the multi-view mean (cvgc.multiview_mean) of neighbour j for the nc
    candidates (X, Y, Z: camera-i points; v0: their sigma(z)^2) of one row: adds to the vote
    counts ag / vo, the mean's sums mx, my, mz, md and its count of agreeing neighbours ns
    (cvgc.multiview_mean's ``support``). Three loops: projection (eq. 19) into a
    pixel index, the depth lookup, then the votes, so that the first and last are branch-free
    and vectorise; per point the float32 operations are those of cvgc.py / agreement.py."""
    eps, vis, mv, mv_g2, tau = prm.eps, prm.visibility_aware, prm.mv_mean, prm.mv_gate2, prm.tau
    na, nb, nz0 = prm.noise_a, prm.noise_b, prm.noise_z0
    half = _F(0.5)
    zero = _F(0.0)
    wm1 = _F(w - 1)
    hm1 = _F(h - 1)
    m00, m01, m02, m03 = M_rel[i, j, 0, 0], M_rel[i, j, 0, 1], M_rel[i, j, 0, 2], M_rel[i, j, 0, 3]
    m10, m11, m12, m13 = M_rel[i, j, 1, 0], M_rel[i, j, 1, 1], M_rel[i, j, 1, 2], M_rel[i, j, 1, 3]
    m20, m21, m22, m23 = M_rel[i, j, 2, 0], M_rel[i, j, 2, 1], M_rel[i, j, 2, 2], M_rel[i, j, 2, 3]
    k00, k01, k02 = Kf[j, 0, 0], Kf[j, 0, 1], Kf[j, 0, 2]
    k11, k12 = Kf[j, 1, 1], Kf[j, 1, 2]
    wi = np.int32(w)
    for t in range(nc):  # eq. (19): nearest pixel of camera j, -1 when behind or outside
        x = X[t]
        y = Y[t]
        z = Z[t]
        zj = m20 * x + m21 * y + m22 * z + m23
        xj = m00 * x + m01 * y + m02 * z + m03
        yj = m10 * x + m11 * y + m12 * z + m13
        xnj = xj / zj
        ynj = yj / zj
        uj = np.floor(k00 * xnj + k01 * ynj + k02 + half)
        vj = np.floor(k11 * ynj + k12 + half)
        inside = (zj > eps) & (uj >= zero) & (uj <= wm1) & (vj >= zero) & (vj <= hm1)
        uc = min(max(uj, zero), wm1)  # clamped, so that the conversion is defined everywhere
        vc = min(max(vj, zero), hm1)
        iu = np.int32(uc)
        iv = np.int32(vc)
        idx[t] = (iv * wi + iu) if inside else np.int32(-1)
        ius[t] = iu
        ivs[t] = iv
        zjs[t] = zj
    jb = j * h * w
    for t in range(nc):  # D_j at the pixel (0 = none), and the pixel's ray when averaging
        k = idx[t]
        if k < 0:
            dv[t] = zero
            continue
        dv[t] = dflat[jb + k]
        if mv:
            iu = ius[t]
            iv = ivs[t]
            yq[t] = yt[j, iv]
            xq[t] = _ray_x(Kf, xt, j, iu, yq[t], skew0)
    for t in range(nc):  # eq. (20)-(21)
        d = dv[t]
        zj = zjs[t]
        has = d > zero
        r = abs(zj - d) / (zj + eps)
        agree = has & (r < tau)
        ag[t] += np.int32(agree)
        vo[t] += np.int32(agree | (has & ((not vis) | (d > zj))))
    if mv:
        n00, n01, n02, n03 = M_rel[j, i, 0, 0], M_rel[j, i, 0, 1], M_rel[j, i, 0, 2], M_rel[j, i, 0, 3]
        n10, n11, n12, n13 = M_rel[j, i, 1, 0], M_rel[j, i, 1, 1], M_rel[j, i, 1, 2], M_rel[j, i, 1, 3]
        n20, n21, n22, n23 = M_rel[j, i, 2, 0], M_rel[j, i, 2, 1], M_rel[j, i, 2, 2], M_rel[j, i, 2, 3]
        for t in range(nc):  # cvgc.multiview_mean: j's measured point, inverse-variance weighted
            d = dv[t]
            zj = zjs[t]
            dzj = zj - nz0
            szj = na + nb * (dzj * dzj)
            dd = d - nz0
            sd = na + nb * (dd * dd)
            vd = sd * sd
            e = zj - d
            gate = (d > zero) & (e * e < mv_g2 * (szj * szj + vd))
            qx = xq[t] * d  # cvgc._neighbour_points: the pixel back-projected at D_j, in camera i
            qy = yq[t] * d
            ax = n00 * qx + n01 * qy + n02 * d + n03
            ay = n10 * qx + n11 * qy + n12 * d + n13
            az = n20 * qx + n21 * qy + n22 * d + n23
            rw = v0[t] / vd
            mx[t] = (mx[t] + rw * (ax - X[t])) if gate else mx[t]
            my[t] = (my[t] + rw * (ay - Y[t])) if gate else my[t]
            mz[t] = (mz[t] + rw * (az - Z[t])) if gate else mz[t]
            md[t] = (md[t] + rw) if gate else md[t]
            ns[t] += np.int32(gate)


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def _mcm_row(dflat, rb, w, prm, gq, vr, cc):
    """MCM (eq. 16-18) of the interior pixels u = 1 .. w - 2 of the image row starting at flat
    index rb (not the first or last row of its image): cc[u] = c(x), or -1 where the pixel has
    no depth or its window fails (any missing neighbour, or more than mcm_max_missing with the
    gap-tolerant window). The complete-window arithmetic runs first over the whole row in
    straight-line loops the compiler vectorises (gq, vr: scratch); per pixel the float32
    operations and their order are those of the reference (mcm.py)."""
    zero = _F(0.0)
    one = _F(1.0)
    half = _F(0.5)
    nine = _F(9.0)
    eps, alpha, beta = prm.eps, prm.alpha, prm.beta
    up = rb - w
    dn = rb + w
    for u in range(1, w - 1):
        d0, d1, d2 = dflat[up + u - 1], dflat[up + u], dflat[up + u + 1]
        d3, z, d5 = dflat[rb + u - 1], dflat[rb + u], dflat[rb + u + 1]
        d6, d7, d8 = dflat[dn + u - 1], dflat[dn + u], dflat[dn + u + 1]
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
        for u in range(1, w - 1):
            z = dflat[rb + u]
            if cc[u] > zero or not z > zero:
                continue
            d0, d1, d2 = dflat[up + u - 1], dflat[up + u], dflat[up + u + 1]
            d3, d5 = dflat[rb + u - 1], dflat[rb + u + 1]
            d6, d7, d8 = dflat[dn + u - 1], dflat[dn + u], dflat[dn + u + 1]
            gsq, var = _tolerant_window(d0, d1, d2, d3, z, d5, d6, d7, d8, mmiss)
            if gsq >= zero:  # else more neighbours missing than allowed
                cc[u] = one
            gq[u] = gsq
            vr[u] = var
    if prm.mcm_noise:  # noise-aware MCM: the expected noise sigma(z)^2 out of g and v
        na, nb, nz0 = prm.noise_a, prm.noise_b, prm.noise_z0
        for u in range(1, w - 1):
            z = dflat[rb + u]
            dzn = z - nz0
            sg = na + nb * (dzn * dzn)
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
        z = dflat[rb + u]
        g = np.sqrt(gq[u]) / (z + eps)
        vv = vr[u] / (z * z + eps)
        gq[u] = -alpha * g - beta * vv
    for u in range(1, w - 1):
        if cc[u] > zero:
            cc[u] = np.exp(gq[u])  # eq. (18)


@njit(cache=True, parallel=True, fastmath=False, error_model="numpy")
def _pixels(depth, Kf, M_rel, T_wc, nbr, present, prm, out_P, out_w, out_pr, out_sup, runs, r_n, row_info):
    """Stage 1, parallel over blocks of camera rows. Writes, at the pixel's own index
    p = (i H + v) W + u: out_P[p] (world point of a candidate), out_w[p] (omega, eq. 22, of an
    in-range candidate, negated (sign bit set, also for 0) for the first of a run; NaN for every
    other pixel: a dropped pixel or a candidate beyond the hash's range) and, when
    prm.range_priority, out_pr[p] (omega / sigma(z), rps.selection_priority) and, with the
    multi-view mean, out_sup[p] (how many neighbours agree within its gate, at most 255;
    FuseConfig.lone_cell_keep). Also the row's *runs*: maximal stretches of in-range candidates of one coarse cell,
    runs[row, r] = the cell key, r_n[row, r] = its candidates (both (N H, W), in buffers that
    are free until ``_scatter``); row_info[row] = (candidates, beyond range, runs).

    Each row runs in passes over row-sized scratch: MCM and eq. (27)'s test (``_mcm_row``) ->
    the row's candidates and their camera-frame points -> CVGC one neighbour at a time over all
    candidates (that neighbour's matrix and intrinsics stay in registers, its depth map is
    swept in order) -> weight, world point and coarse runs. Per point the float32 operations
    and their order are those of the single-pass form (votes in graph order), so the results
    are bit-identical to it."""
    n, h, w = depth.shape
    eps, r_c, min_w, s_c = prm.eps, prm.r_c, prm.min_weight, prm.cell
    use_mcm, use_cvgc = prm.use_mcm, prm.use_cvgc
    qlim, off, bits = prm.qlim, prm.offset, prm.bits
    rp, na, nb, nz0 = prm.range_priority, prm.noise_a, prm.noise_b, prm.noise_z0
    mv, stride = prm.mv_mean, prm.stride
    zero = _F(0.0)
    two = _F(2.0)
    nan = _F(np.nan)
    dflat = depth.reshape(n * h * w)
    xt, yt, skew0 = _ray_tables(Kf, h, w)
    # the neighbours that vote (in the graph and present) first, in graph order
    vn = np.empty_like(nbr)
    nbr_n = np.zeros(n, dtype=np.int64)
    for i in range(n):
        for kk in range(nbr.shape[1]):
            j = nbr[i, kk]
            if j >= 0 and present[j]:
                vn[i, nbr_n[i]] = j
                nbr_n[i] += 1
    rows_per = 4
    n_blk = (n * h + rows_per - 1) // rows_per
    for blk in prange(n_blk):
        cc = np.empty(w, dtype=np.float32)  # c(x) per column (-1: no candidate)
        gq = np.empty(w, dtype=np.float32)
        vr = np.empty(w, dtype=np.float32)
        cu = np.empty(w, dtype=np.int64)  # the row's candidates: column, c, point, votes
        cw = np.empty(w, dtype=np.float32)
        cx_ = np.empty(w, dtype=np.float32)
        cy_ = np.empty(w, dtype=np.float32)
        cz_ = np.empty(w, dtype=np.float32)
        ag = np.empty(w, dtype=np.int32)
        vo = np.empty(w, dtype=np.int32)
        v0 = np.empty(w, dtype=np.float32)
        oms = np.empty(w, dtype=np.float32)  # omega, world point and its cell per candidate
        pwx = np.empty(w, dtype=np.float32)
        pwy = np.empty(w, dtype=np.float32)
        pwz = np.empty(w, dtype=np.float32)
        qxs = np.empty(w, dtype=np.float32)
        qys = np.empty(w, dtype=np.float32)
        qzs = np.empty(w, dtype=np.float32)
        zjs = np.empty(w, dtype=np.float32)  # per-neighbour scratch of _votes
        idx = np.empty(w, dtype=np.int32)
        ius = np.empty(w, dtype=np.int32)
        ivs = np.empty(w, dtype=np.int32)
        dv = np.empty(w, dtype=np.float32)
        xq = np.empty(w, dtype=np.float32)
        yq = np.empty(w, dtype=np.float32)
        mx = np.empty(w, dtype=np.float32)
        my = np.empty(w, dtype=np.float32)
        mz = np.empty(w, dtype=np.float32)
        md = np.empty(w, dtype=np.float32)
        ns = np.empty(w, dtype=np.int32)
        for row in range(blk * rows_per, min((blk + 1) * rows_per, n * h)):
            i = row // h
            v = row - i * h
            rb = row * w
            for u in range(w):
                out_w[rb + u] = nan
            # MCM and eq. (27): the row's candidates
            nc = 0
            # no candidate in the row: off the pixel_stride grid, or (MCM) a window pixel
            # outside the image -> c = 0
            if (stride > 1 and v % stride != 0) or (use_mcm and (v == 0 or v == h - 1)):
                row_info[row, 0] = 0
                row_info[row, 1] = 0
                row_info[row, 2] = 0
                continue
            if use_mcm:
                _mcm_row(dflat, rb, w, prm, gq, vr, cc)
                u0 = 1 if stride == 1 else stride  # the first column u >= 1 with u % stride == 0
                for u in range(u0, w - 1, stride):
                    c = cc[u]
                    if c >= zero and c > r_c:  # -1: no depth or a failed window
                        cu[nc] = u
                        cw[nc] = c
                        nc += 1
            elif _F(1.0) > r_c:
                for u in range(0, w, stride):
                    if dflat[rb + u] > 0:
                        cu[nc] = u
                        cw[nc] = _F(1.0)
                        nc += 1
            yn = yt[i, v]
            for t in range(nc):
                u = cu[t]
                z = dflat[rb + u]
                xn = _ray_x(Kf, xt, i, u, yn, skew0)
                cx_[t] = xn * z
                cy_[t] = yn * z
                cz_[t] = z
            if use_cvgc:
                for t in range(nc):
                    ag[t] = 0
                    vo[t] = 0
                    mx[t] = zero
                    my[t] = zero
                    mz[t] = zero
                    md[t] = _F(1.0)
                    ns[t] = 0
                    if mv:
                        z = cz_[t]
                        dz0 = z - nz0
                        s0 = na + nb * (dz0 * dz0)
                        v0[t] = s0 * s0
                for kk in range(nbr_n[i]):
                    _votes(dflat, Kf, M_rel, xt, yt, skew0, i, vn[i, kk], h, w, nc, cx_, cy_, cz_, v0, prm,
                           zjs, idx, ius, ivs, dv, xq, yq, ag, vo, mx, my, mz, md, ns)  # fmt: skip
            t00, t01, t02, t03 = T_wc[i, 0, 0], T_wc[i, 0, 1], T_wc[i, 0, 2], T_wc[i, 0, 3]
            t10, t11, t12, t13 = T_wc[i, 1, 0], T_wc[i, 1, 1], T_wc[i, 1, 2], T_wc[i, 1, 3]
            t20, t21, t22, t23 = T_wc[i, 2, 0], T_wc[i, 2, 1], T_wc[i, 2, 2], T_wc[i, 2, 3]
            cnt = 0
            n_oor = 0
            nr = 0
            last_key = np.int64(-1)
            run_n = 0
            for t in range(nc):  # eq. (21)-(22), the world point and its cell, vectorised
                c = cw[t]
                x = cx_[t]
                y = cy_[t]
                z = cz_[t]
                wg = c
                xw, yw, zw = x, y, z  # the point written out (multi-view mean when mv)
                if use_cvgc:
                    wg = (_F(ag[t]) / _F(vo[t])) if vo[t] > 0 else c  # eq. (21)
                    if mv:
                        xw = x + mx[t] / md[t]
                        yw = y + my[t] / md[t]
                        zw = z + mz[t] / md[t]
                oms[t] = two * c * wg / (c + wg + eps)  # eq. (22)
                px = t00 * xw + t01 * yw + t02 * zw + t03
                py = t10 * xw + t11 * yw + t12 * zw + t13
                pz = t20 * xw + t21 * yw + t22 * zw + t23
                pwx[t] = px
                pwy[t] = py
                pwz[t] = pz
                qxs[t] = np.floor(px / s_c)
                qys[t] = np.floor(py / s_c)
                qzs[t] = np.floor(pz / s_c)
            for t in range(nc):
                om = oms[t]
                if not om >= min_w:
                    continue
                u = cu[t]
                base = rb + u
                z = cz_[t]
                px, py, pz = pwx[t], pwy[t], pwz[t]
                qx, qy, qz = qxs[t], qys[t], qzs[t]
                out_P[base, 0] = px
                out_P[base, 1] = py
                out_P[base, 2] = pz
                if rp:
                    dz = z - nz0
                    out_pr[base] = om / (na + nb * (dz * dz))
                if mv:
                    out_sup[base] = np.uint8(min(ns[t], 255))
                cnt += 1
                if abs(qx) < qlim and abs(qy) < qlim and abs(qz) < qlim:
                    key = (
                        ((np.int64(qx) + off) << (2 * bits)) | ((np.int64(qy) + off) << bits) | (np.int64(qz) + off)
                    )  # eq. (23)'s coarse cell, packed as in ash.py
                    if key != last_key:
                        if run_n > 0:
                            runs[row, nr] = last_key
                            r_n[row, nr] = run_n
                            nr += 1
                        last_key = key
                        run_n = 0
                        out_w[base] = -om  # a run's first point (exact: _fine_pass takes abs)
                    else:
                        out_w[base] = om
                    run_n += 1
                else:
                    n_oor += 1
            if run_n > 0:
                runs[row, nr] = last_key
                r_n[row, nr] = run_n
                nr += 1
            row_info[row, 0] = cnt
            row_info[row, 1] = n_oor
            row_info[row, 2] = nr


@njit(cache=True, error_model="numpy")
def _cells(runs, r_n, row_info, run_slot):
    """Coarse cells of the runs (serial, one hash lookup per run, not per point): cell ids in
    first-appearance order (input order); run_slot[roff[row] + r] = the first slot of run r of
    the row in the cell-grouped order (runs compacted: ``runs`` and ``r_n`` live in buffers that
    ``_scatter`` overwrites). The hash table and the per-cell arrays grow with the cells, not
    with the runs (the simulated ring has ~1.5 k cells but ~10^5-10^6 runs). Returns (start
    (C+1,): each cell's slots, cell_key (C,): its packed key, the largest cell's size, roff
    (rows + 1,): each row's first run)."""
    n_rows = row_info.shape[0]
    roff = np.empty(n_rows + 1, dtype=np.int64)
    roff[0] = 0
    for row in range(n_rows):
        roff[row + 1] = roff[row] + row_info[row, 2]
    size = 1024
    mask = size - 1
    tkeys = np.full(size, -1, dtype=np.int64)
    tvals = np.empty(size, dtype=np.int64)
    cell_key = np.empty(size // 2, dtype=np.int64)
    counts = np.zeros(size // 2 + 1, dtype=np.int64)
    n_cells = 0
    for row in range(n_rows):
        for r in range(row_info[row, 2]):
            key = runs[row, r]
            slot = ((key * _HASH_MUL) >> 20) & mask
            while True:
                tk = tkeys[slot]
                if tk == key:
                    cid = tvals[slot]
                    break
                if tk == -1:
                    if 2 * (n_cells + 1) > size:  # keep the load <= 1/2: twice the room, rehash
                        size *= 2
                        mask = size - 1
                        nk = np.full(size, -1, dtype=np.int64)
                        nv = np.empty(size, dtype=np.int64)
                        for e in range(size // 2):
                            if tkeys[e] != -1:
                                s2 = ((tkeys[e] * _HASH_MUL) >> 20) & mask
                                while nk[s2] != -1:
                                    s2 = (s2 + 1) & mask
                                nk[s2] = tkeys[e]
                                nv[s2] = tvals[e]
                        tkeys = nk
                        tvals = nv
                        ck = np.empty(size // 2, dtype=np.int64)
                        ck[:n_cells] = cell_key[:n_cells]
                        cell_key = ck
                        cn = np.zeros(size // 2 + 1, dtype=np.int64)
                        cn[: n_cells + 1] = counts[: n_cells + 1]
                        counts = cn
                        slot = ((key * _HASH_MUL) >> 20) & mask
                        continue  # probe the new table
                    tkeys[slot] = key
                    tvals[slot] = n_cells
                    cell_key[n_cells] = key
                    cid = n_cells
                    n_cells += 1
                    break
                slot = (slot + 1) & mask
            runs[row, r] = cid
            counts[cid + 1] += r_n[row, r]
    largest = 0
    for c in range(n_cells):
        if counts[c + 1] > largest:
            largest = counts[c + 1]
        counts[c + 1] += counts[c]
    start = counts[: n_cells + 1].copy()
    fill = counts[:n_cells]
    for row in range(n_rows):  # stable: runs in input order, so points keep input order in a cell
        o = roff[row]
        for r in range(row_info[row, 2]):
            cid = runs[row, r]
            run_slot[o + r] = fill[cid]
            fill[cid] += r_n[row, r]
    return start, cell_key[:n_cells].copy(), largest, roff


@njit(cache=True, parallel=True, error_model="numpy")
def _scatter(om, run_slot, roff, row_info, w, P, members, Pm):
    """members[slot] = pixel index of every candidate, grouped by coarse cell (``_cells``), and
    Pm[slot] = its point P[pixel]: P is read in pixel order here (the scattered side is the
    write), so that ``_fine_pass`` reads the points of a cell in order instead of gathering
    them by pixel index (a cache miss at every run of a cell). The row's in-range candidates
    (om not NaN, ``_pixels``) in column order, a new run at each om with the sign bit set
    (run_slot[roff[row] + r] = its first slot)."""
    for row in prange(row_info.shape[0]):
        if row_info[row, 2] == 0:
            continue
        rb = row * w
        r = roff[row] - 1
        k = 0
        for u in range(w):
            p = rb + u
            f = om[p]
            if f == f:
                if math.copysign(1.0, f) < 0.0:
                    r += 1
                    k = run_slot[r]
                members[k] = p
                Pm[k, 0] = P[p, 0]
                Pm[k, 1] = P[p, 1]
                Pm[k, 2] = P[p, 2]
                k += 1


@njit(cache=True, error_model="numpy")
def _chunks(start, n_chunks):
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


@njit(cache=True, parallel=True, error_model="numpy")
def _fine_pass(Pc, start, cell_key, prm, chunks, largest, reorder, members, fkey, csize, cell_rho_sum, cell_fine_n,
               om, rank, copy_rank, hw, omc, rkc, camc, sup):  # fmt: skip
    """Pc, members: the points and pixel indices of the candidates grouped by coarse cell
    (``_scatter``); with ``reorder`` both are sorted into slot order **in place** (a cell's
    range is copied to the chunk's scratch first), so no second point buffer is needed.

    Eq. (23)-(25) per coarse cell (parallel over chunks of cells, scratch allocated once per
    chunk): fine keys, stable local counting sort of members (and Pc), fkey = fine
    group of each slot (0, 1, ... per coarse cell), the per-cell sum of fine-cell densities
    (for rho_bar) and fine-cell count. prm: CellParams. ``reorder`` False (a count only, for
    density control): Pc and members untouched, fkey[start[c] + g] = size of fine cell g instead
    and camc[start[c] + g] = sup (per pixel, _pixels' out_sup) of its last point (of its only
    point for a lone cell: the count's FuseConfig.lone_cell_keep test).
    With ``reorder`` also the weight and ranking value of each slot, in slot order:
    omc, camc (the camera, p // hw) and rkc (only when ``copy_rank``: without
    range_priority the ranking value is omega and the selection reads omc), so that the
    selection reads them in order instead of gathering them by pixel index."""
    s_c, s0, s_min, s_max, eps, adaptive, fixed = (
        prm.s_c,
        prm.s0,
        prm.s_min,
        prm.s_max,
        prm.eps,
        prm.adaptive,
        prm.fixed_size,
    )
    s_c3 = prm.s_c3
    bits, off = prm.bits, prm.offset
    bmask = (np.int64(1) << bits) - 1
    inv_hw = 1.0 / np.float64(hw)
    f0 = _F(0.0)
    f127 = _F(127.0)
    tcap = 16
    while tcap < 2 * largest + 1:
        tcap *= 2
    for ch in prange(chunks.shape[0] - 1):
        gid = np.empty(largest, dtype=np.int32)  # fine keys < 2^21, then groups < largest
        gstart = np.empty(largest + 1, dtype=np.int32)
        tk = np.empty(tcap, dtype=np.int64)
        tx = np.empty(largest, dtype=np.float32)
        ty = np.empty(largest, dtype=np.float32)
        tz = np.empty(largest, dtype=np.float32)
        tm = np.empty(largest if reorder else 0, dtype=members.dtype)
        for c in range(chunks[ch], chunks[ch + 1]):
            a = start[c]
            b = start[c + 1]
            n = b - a
            if adaptive:
                rho = _F(n) / s_c3  # eq. (23)
                sf = s0 / np.sqrt(rho + eps)  # eq. (24)
                if sf < s_min:
                    sf = s_min
                if sf > s_max:
                    sf = s_max
            else:
                sf = fixed
            csize[c] = sf
            key = cell_key[c]
            ox = _F(((key >> (2 * bits)) & bmask) - off) * s_c
            oy = _F(((key >> bits) & bmask) - off) * s_c
            oz = _F((key & bmask) - off) * s_c
            # fine keys grouped by first appearance through a small open-addressing table
            # (an O(n) counting sort, stable: input order kept inside a fine cell)
            # room for twice the distinct fine keys: at most n, and at most nf^3 with nf fine
            # cells per axis (eq. 25's clamp keeps the indices in 0 .. 127)
            nf = min(np.int64(s_c / sf) + 2, 128) if adaptive else 1
            nk = min(n, nf * nf * nf)
            tsize = 16
            while tsize < 2 * nk + 1:
                tsize *= 2
            tmask = tsize - 1
            for e in range(tsize):
                tk[e] = -1
            ng = 0
            last_k = np.int64(-1)
            last_g = 0
            for t in range(n):  # the cell's points (in _scatter's order)
                tx[t] = Pc[a + t, 0]
                ty[t] = Pc[a + t, 1]
                tz[t] = Pc[a + t, 2]
            if reorder:
                for t in range(n):
                    tm[t] = members[a + t]
            if adaptive:
                for t in range(n):  # eq. (25), a branch-free loop that vectorises
                    # clamped to 0..127 as floats, then converted (the same integers as
                    # converting first; int32 conversions vectorise, int64 ones do not on AVX2)
                    fx = np.floor((tx[t] - ox) / sf)
                    fy = np.floor((ty[t] - oy) / sf)
                    fz = np.floor((tz[t] - oz) / sf)
                    fxi = np.int32(min(max(fx, f0), f127))
                    fyi = np.int32(min(max(fy, f0), f127))
                    fzi = np.int32(min(max(fz, f0), f127))
                    gid[t] = (((fxi << 7) | fyi) << 7) | fzi
            else:
                for t in range(n):
                    gid[t] = 0
            for t in range(n):  # fine key -> fine group, in place
                k3 = np.int64(gid[t])
                if k3 == last_k:
                    gid[t] = last_g
                    continue
                slot = ((k3 * _HASH_MUL) >> 24) & tmask
                while True:  # entries: key << 32 | group (keys < 2^21), -1 = empty
                    e = tk[slot]
                    if e == -1:
                        tk[slot] = (k3 << 32) | ng
                        g = ng
                        ng += 1
                        break
                    if (e >> 32) == k3:
                        g = e & 0xFFFFFFFF
                        break
                    slot = (slot + 1) & tmask
                gid[t] = g
                last_k = k3
                last_g = g
                if not reorder:
                    camc[a + g] = sup[members[a + t]]
            for g in range(ng + 1):
                gstart[g] = 0
            for t in range(n):
                gstart[gid[t] + 1] += 1
            sf3 = sf * sf * sf
            rsum = 0.0
            for g in range(ng):
                rsum += _F(gstart[g + 1]) / sf3
                if not reorder:
                    fkey[a + g] = gstart[g + 1]
                gstart[g + 1] += gstart[g]
            if reorder:
                for t in range(n):  # gstart[g] is now the next free slot of group g
                    g = gid[t]
                    p = tm[t]
                    q = a + gstart[g]
                    members[q] = p
                    fkey[q] = g
                    Pc[q, 0] = tx[t]
                    Pc[q, 1] = ty[t]
                    Pc[q, 2] = tz[t]
                    omc[q] = abs(om[p])  # the sign marks a run's first point (_pixels)
                    camc[q] = _cam_of(p, hw, inv_hw)
                    if copy_rank:
                        rkc[q] = rank[p]
                    gstart[g] += 1
            cell_rho_sum[c] = rsum
            cell_fine_n[c] = ng


@njit(cache=True, inline="always", error_model="numpy")
def _cell_k(n, n_coarse, fine_cells, sf3, prm, sup1):
    """k of a fine cell of n points: eq. (26) (or the fixed k), 0 for a lone point in a densely
    sampled coarse cell of n_coarse points in fine_cells occupied fine cells (lone_cell_mean)
    unless sup1, the neighbours confirming that point, reaches prm.lone_keep (> 0).
    prm: SelectParams."""
    if prm.fixed_k:
        return prm.k_const
    if prm.lone_cell_mean > 0 and n == 1 and float(n_coarse) >= prm.lone_cell_mean * float(fine_cells):
        if prm.lone_keep == 0 or sup1 < prm.lone_keep:
            return 0
    rho = _F(n) / sf3
    kf = np.ceil(_F(prm.k0) * (rho / prm.rho_bar) * _F(prm.ratio))  # eq. (26)
    k = int(kf)
    if k < 1:
        k = 1
    if k > prm.k_max:
        k = prm.k_max
    return k


@njit(cache=True, parallel=True, error_model="numpy")
def _count(start, gsize, gsup, csize, fine_n, prm, cell_count):
    """Points that selection keeps per coarse cell, from the fine-cell sizes alone (``_fine_pass``
    with reorder False; gsup: the confirming neighbours of each lone cell's point): min(k, n)
    per fine cell, which the FPS of eq. (28) picks unless points of the cell coincide (it stops
    early then): the density search's count."""
    for c in prange(start.shape[0] - 1):
        a = start[c]
        sf = csize[c]
        sf3 = sf * sf * sf
        cnt = 0
        for g in range(fine_n[c]):
            n = gsize[a + g]
            cnt += min(_cell_k(n, start[c + 1] - a, fine_n[c], sf3, prm, np.int64(gsup[a + g])), n)
        cell_count[c] = cnt


@njit(cache=True, parallel=True, error_model="numpy")
def _select(Pc, rkc, omc, camc, start, members, fkey, csize, fine_n, prm, chunks, largest, cons, T_wc, T_cw, hw,
            stage_src, stage_sup, cell_nsel, sup):  # fmt: skip
    """Eq. (26) and the confidence-weighted FPS of eq. (28) inside every fine cell, then (when
    cons.on) rps.consensus for the representatives of that fine cell while it is in cache.
    Pc, omc, rkc: point, omega and ranking value (omega, or omega / sigma(z) with
    range_priority; only compared) per slot (``_fine_pass``); members: the pixel of each slot.
    fine_n: occupied fine cells per coarse cell (for prm.lone_cell_mean, 0 = off); sup: the
    confirming neighbours per pixel (prm.lone_keep). prm: SelectParams. cons: ConsensusParams. The representatives of coarse cell c, in slot order,
    go to stage_src[start[c] + j] (their slot) and, with consensus, stage_sup (supporting
    cameras) while Pc of each representative is replaced by its moved position once its fine
    cell is done (nothing reads it later); cell_nsel[c] = how many."""
    on, gate, na, nb, nz0 = cons.on, cons.gate, cons.noise_a, cons.noise_b, cons.noise_z0
    n_cam = T_wc.shape[0]
    for ch in prange(chunks.shape[0] - 1):
        d2 = np.empty(largest, dtype=np.float32)
        sel = np.zeros(largest, dtype=np.bool_)
        moved = np.empty((largest if on else 0, 3), dtype=np.float32)
        stamp = np.zeros(n_cam, dtype=np.int64)
        tick = 0
        for c in range(chunks[ch], chunks[ch + 1]):
            a = start[c]
            b = start[c + 1]
            sf = csize[c]
            sf3 = sf * sf * sf
            ns_c = 0
            t0 = a
            while t0 < b:
                t1 = t0 + 1
                while t1 < b and fkey[t1] == fkey[t0]:
                    t1 += 1
                n = t1 - t0
                k = _cell_k(n, b - a, fine_n[c], sf3, prm, np.int64(sup[members[t0]]))
                if k == 0:  # a lone point in a densely sampled coarse cell (lone_cell_mean)
                    t0 = t1
                    continue
                # first pick: highest rank, ties -> first in input order
                best = t0
                for t in range(t0 + 1, t1):
                    if rkc[t] > rkc[best]:
                        best = t
                if k > 1:
                    for t in range(n):
                        sel[t] = False
                        d2[t] = np.inf
                    sel[best - t0] = True
                    last = best
                    for _r in range(1, k):
                        bs = _F(0.0)
                        bt = -1
                        lx, ly, lz = Pc[last, 0], Pc[last, 1], Pc[last, 2]
                        for t in range(t0, t1):
                            if sel[t - t0]:
                                continue
                            dx = Pc[t, 0] - lx
                            dy = Pc[t, 1] - ly
                            dz = Pc[t, 2] - lz
                            dd = dx * dx + dy * dy + dz * dz
                            if dd < d2[t - t0]:
                                d2[t - t0] = dd
                            sc = np.sqrt(d2[t - t0]) * rkc[t]  # eq. (28)
                            if sc > bs:
                                bs = sc
                                bt = t
                        if bt < 0:
                            break
                        last = bt
                        sel[bt - t0] = True
                n0 = ns_c
                for ts in range(t0, t1):
                    if k > 1:
                        if not sel[ts - t0]:
                            continue
                    elif ts != best:
                        continue
                    stage_src[a + ns_c] = ts
                    if on:
                        i = camc[ts]
                        tick += 1
                        _consensus_point(Pc, omc, camc, t0, t1, ts, i, T_wc, T_cw, gate, na, nb, nz0,
                                         stamp, tick, moved, stage_sup, ns_c - n0, a + ns_c)  # fmt: skip
                    ns_c += 1
                if on:  # the cell's representatives move only after all of them were computed
                    for e in range(ns_c - n0):
                        s = stage_src[a + n0 + e]
                        Pc[s, 0] = moved[e, 0]
                        Pc[s, 1] = moved[e, 1]
                        Pc[s, 2] = moved[e, 2]
                t0 = t1
            cell_nsel[c] = ns_c


@njit(cache=True, inline="always", error_model="numpy")
def _cam_of(p, hw, inv_hw):
    """p // hw without a 64-bit integer division (~40 cycles on this CPU): a float64 estimate
    (exact to +-1 for p < 2^52), corrected."""
    c = np.int64(np.float64(p) * inv_hw)
    if c * hw > p:
        c -= 1
    elif (c + 1) * hw <= p:
        c += 1
    return c


@njit(cache=True, inline="always", error_model="numpy")
def _consensus_point(Pc, omc, camc, t0, t1, s, i, T_wc, T_cw, gate, na, nb, nz0, stamp, tick, out_P, out_sup, k, ks):
    """rps.consensus for the representative in slot s (camera i) of the fine cell of slots
    t0 .. t1 - 1: out_P[k] = it moved along its ray to the omega-weighted mean of the cell's
    candidates within ``gate`` sigma(z) of it, out_sup[ks] = their distinct cameras. Same
    arithmetic as the reference: float32 geometry, float64 sums, members in fine-cell order."""
    cx, cy, cz = T_wc[i, 0, 3], T_wc[i, 1, 3], T_wc[i, 2, 3]
    dx = Pc[s, 0] - cx
    dy = Pc[s, 1] - cy
    dz = Pc[s, 2] - cz
    t_s = np.sqrt(dx * dx + dy * dy + dz * dz)
    ux = dx / t_s
    uy = dy / t_s
    uz = dz / t_s
    zs = T_cw[i, 2, 0] * Pc[s, 0] + T_cw[i, 2, 1] * Pc[s, 1] + T_cw[i, 2, 2] * Pc[s, 2] + T_cw[i, 2, 3]
    dn = zs - nz0
    lim = gate * (na + nb * (dn * dn))
    num = 0.0
    den = 0.0
    ns = 0
    for t in range(t0, t1):
        tq = (Pc[t, 0] - cx) * ux + (Pc[t, 1] - cy) * uy + (Pc[t, 2] - cz) * uz
        if not abs(tq - t_s) < lim:
            continue
        wq = np.float64(omc[t])
        num += wq * np.float64(tq)
        den += wq
        cq = camc[t]
        if stamp[cq] != tick:
            stamp[cq] = tick
            ns += 1
    if den > 0:
        tn = _F(num / den)
    else:
        tn = t_s
    out_P[k, 0] = cx + tn * ux
    out_P[k, 1] = cy + tn * uy
    out_P[k, 2] = cz + tn * uz
    out_sup[ks] = ns


@njit(cache=True, parallel=True, error_model="numpy")
def _emit(start, cell_nsel, cell_out, stage_src, stage_sup, use_stage, members, Pc, omc, camc, color, rig_index,
          xyz, rgb, wgt, src, sup):  # fmt: skip
    """The output cloud in one parallel pass over the coarse cells: representative j of cell c
    goes to row cell_out[c] + j (cells in order, fine-cell order inside)."""
    for c in prange(start.shape[0] - 1):
        a = start[c]
        o = cell_out[c]
        for j in range(cell_nsel[c]):
            q = stage_src[a + j]  # the slot
            p = members[q]
            k = o + j
            if use_stage:
                sup[k] = stage_sup[a + j]
            xyz[k, 0] = Pc[q, 0]
            xyz[k, 1] = Pc[q, 1]
            xyz[k, 2] = Pc[q, 2]
            wgt[k] = omc[q]
            rgb[k, 0] = color[p, 0]  # p is the flat (camera, row, column) pixel index
            rgb[k, 1] = color[p, 1]
            rgb[k, 2] = color[p, 2]
            src[k] = rig_index[camc[q]]


# --- orchestration ------------------------------------------------------------------------


class ConsensusParams(NamedTuple):
    """Scalars of the consensus step inside ``_select`` (rps.consensus)."""

    on: bool
    gate: np.float32
    """Gate in sigma(z) (FuseConfig.consensus_gate)."""
    noise_a: np.float32
    noise_b: np.float32
    noise_z0: np.float32


def consensus_params(cfg: FuseConfig, on: bool | None = None) -> ConsensusParams:
    """ConsensusParams of ``cfg`` (``on`` overrides cfg.consensus)."""
    a, b, z0 = cfg.noise_sigma
    on = bool(cfg.consensus) if on is None else bool(on)
    return ConsensusParams(on, _F(cfg.consensus_gate), _F(a), _F(b), _F(z0))


class _Workspace:
    """Per-thread buffers of one frame shape, reused from frame to frame: a fresh 100+ MB of
    arrays per frame cost as much in page faults as some kernels (the kernel zero-fills every
    new page). Buffers hold no result; the cloud is built from new arrays.

    33 bytes per pixel (ICL, 8 x 640 x 480: 77 MiB), by reusing buffers whose
    lifetimes do not overlap (stages: 1 ``_gate`` / ``_pixels``, 2 ``_cells``, 3 ``_scatter``,
    4 ``_fine_pass``, 5 ``_select``, 6 ``_emit``):

    - ``pbuf`` (12 B): the gated depth (its first 4 B per pixel, 1; ``gate_depth``) and the
      rows' coarse runs (key, 8 B per pixel's room, 1-2); then ``Pc``, the points by coarse
      cell (3), sorted into slot order in place (4), moved by the consensus (5).
    - ``buf`` (12 B): the points by pixel (``P``, 1-3); once ``_scatter`` has read them, fkey
      (4 B), omega and camera by slot (4 + 2 B) and the representatives' support (2 B).
    - ``members`` (4 B): the runs' sizes (1-2), then the pixel index per slot (3-6).
    - ``om`` (4 B): omega by pixel (1-4; NaN = no in-range candidate, sign = a run's first
      point, so no flags), then ``stage_src`` (5-6).
    - ``sup`` (1 B): the neighbours confirming each candidate within the multi-view mean's
      gate (1-5; FuseConfig.lone_cell_keep).
    - with ``range_priority`` only: ``pr`` (omega / sigma by pixel) and ``rkc`` (by slot), 8 B.

    The only per-frame arrays besides the cloud are sized by cells or runs (``_cells``)."""

    def __init__(self, n: int, h: int, w: int) -> None:
        npx = n * h * w
        self.shape = (n, h, w)
        idx = np.int32 if npx < 2**31 else np.int64  # pixel indices
        self.pbuf = np.empty(12 * npx + 8, dtype=np.uint8)
        self.Pc = self.pbuf[: 12 * npx].view(np.float32).reshape(npx, 3)
        o = (4 * npx + 7) // 8 * 8  # 8-aligned, after the gated depth
        self.runs = self.pbuf[o : o + 8 * npx].view(np.int64).reshape(n * h, w)
        self.buf = np.empty(12 * npx, dtype=np.uint8)
        self.P = self.buf.view(np.float32).reshape(npx, 3)
        self.fkey = self.buf[: 4 * npx].view(np.int32)
        self.omc = self.buf[4 * npx : 8 * npx].view(np.float32)
        self.camc = self.buf[8 * npx : 10 * npx].view(np.int16)  # camera of each slot
        self.stage_sup = self.buf[10 * npx :].view(np.int16)
        self.members = np.empty(npx, dtype=idx)
        self.run_n = self.members.reshape(n * h, w)
        self.om = np.empty(npx, dtype=np.float32)
        self.sup = np.empty(npx, dtype=np.uint8)  # confirming neighbours by pixel (lone_cell_keep)
        # the representatives' slots: omega by pixel is not read after _fine_pass
        self.stage_src = self.om.view(np.int32) if idx is np.int32 else np.empty(npx, dtype=idx)
        self.pr = np.empty(1, dtype=np.float32)
        self.rkc = np.empty(1, dtype=np.float32)
        self.row_info = np.empty((n * h, 3), dtype=np.int64)

    def depth(self) -> np.ndarray:
        """The gated depth's buffer (N, H, W) float32: the first third of Pc, which nothing
        writes before ``_scatter``, i.e. after ``_pixels`` has read the depth."""
        n, h, w = self.shape
        return self.Pc.reshape(-1)[: n * h * w].reshape(n, h, w)

    def rank(self, on: bool) -> np.ndarray:
        """The buffer for the range-aware ranking value (length 1 when unused)."""
        if on and self.pr.shape[0] != self.om.shape[0]:
            self.pr = np.empty(self.om.shape[0], dtype=np.float32)
            self.rkc = np.empty(self.om.shape[0], dtype=np.float32)
        return self.pr


_LOCAL = threading.local()


def _workspace(n: int, h: int, w: int) -> _Workspace:
    """This thread's workspace for frames of shape (n, h, w); another shape replaces it (the
    old buffers are released first)."""
    ws = getattr(_LOCAL, "ws", None)
    if ws is None or ws.shape != (n, h, w):
        _LOCAL.ws = ws = None  # drop the old buffers before allocating new ones
        _LOCAL.ws = ws = _Workspace(n, h, w)
    return ws


def release_workspace() -> None:
    """Free this thread's workspace (it is otherwise kept for the next frame of the same shape)."""
    _LOCAL.ws = None


class _Cells(NamedTuple):
    """Stage 1-2 output: candidates at their pixel index, grouped by coarse cell."""

    P: np.ndarray  # (M, 3) float32 world points of the members, in members' order (_scatter)
    om: np.ndarray  # (N H W,) float32 joint weight, eq. (22)
    rank: np.ndarray  # ranking value of eq. (28) (om itself without range_priority)
    start: np.ndarray  # (C + 1,) int64 slots of each coarse cell
    cell_key: np.ndarray  # (C,) int64 packed coarse key
    members: np.ndarray  # (M,) int32 pixel indices of the in-range candidates, grouped by cell
    largest: int  # points in the largest coarse cell
    candidates: int
    out_of_range: int


def _candidates(p, prm: PixelParams, ws: _Workspace) -> _Cells:
    """Stages 1-2: ``_pixels`` over every view, coarse cells per run, members grouped by cell."""
    depth = p.depth.contiguous().numpy()
    n, h, w = depth.shape
    Kf = p.K.numpy().astype(np.float32)
    M_rel = relative_transforms(p.T_cam_world).numpy()
    T_wc = p.T_world_cam.numpy().astype(np.float32)
    nbr = p.graph.index.numpy().astype(np.int64)
    present = p.present.numpy().astype(np.bool_)
    rank = ws.rank(prm.range_priority)
    with numba.parallel_chunksize(8):  # rows differ in cost (and a shared core may stall)
        _pixels(depth, Kf, M_rel, T_wc, nbr, present, prm, ws.P, ws.om, rank, ws.sup, ws.runs, ws.run_n,
                ws.row_info)  # fmt: skip
    run_slot = np.empty(int(ws.row_info[:, 2].sum()), dtype=ws.members.dtype)
    start, cell_key, largest, roff = _cells(ws.runs, ws.run_n, ws.row_info, run_slot)
    m = int(start[-1])
    members = ws.members[:m]
    Pc = ws.Pc[:m]
    with numba.parallel_chunksize(8):
        _scatter(ws.om, run_slot, roff, ws.row_info, w, ws.P, members, Pc)
    del run_slot
    cand = int(ws.row_info[:, 0].sum())
    oor = int(ws.row_info[:, 1].sum())
    return _Cells(Pc, ws.om, rank if prm.range_priority else ws.om, start, cell_key, members, int(largest), cand, oor)


class _Selection(NamedTuple):
    start: np.ndarray
    cell_nsel: np.ndarray  # (C,) representatives per coarse cell
    points: int


def _select_points(
    c: _Cells, prm: KernelParams, ws: _Workspace, cons: ConsensusParams, T_wc, T_cw, hw: int, count_only: bool = False
):
    """Stages 3 and 4 on the grouped candidates: fine cells, eq. (26), FPS and (cons.on) the
    consensus; the representatives staged per coarse cell in ``ws`` (``_select``). With
    ``count_only`` only how many points selection keeps (``_count``; density control)."""
    n_cells = c.start.shape[0] - 1
    m = c.members.shape[0]
    chunks = _chunks(c.start, min(max(n_cells, 1), 16 * numba.get_num_threads()))
    members, fkey = c.members, ws.fkey[:m]
    csize = np.empty(n_cells, dtype=np.float32)
    rho_sum = np.empty(n_cells, dtype=np.float64)
    fine_n = np.empty(n_cells, dtype=np.int64)
    # slot-ordered omega, camera and rank (read by _select and _emit): fkey, omc and camc in
    # the buffer of the points by pixel, which nothing reads after _scatter; Pc and members
    # sorted in place
    Pc, camc, omc = c.P, ws.camc[:m], ws.omc[:m]
    copy_rank = c.rank is not c.om
    rkc = ws.rkc[:m] if copy_rank else omc
    with numba.parallel_chunksize(1):  # chunks handed out as threads free up (a shared core may stall)
        _fine_pass(Pc, c.start, c.cell_key, prm.cell, chunks, c.largest, not count_only, members, fkey,
                   csize, rho_sum, fine_n, c.om, c.rank, copy_rank, hw, omc, rkc, camc, ws.sup)  # fmt: skip
    sel_prm = prm.select
    if not sel_prm.fixed_k:  # eq. (26)'s rho_bar: mean density over the occupied fine cells
        total = int(fine_n.sum())
        sel_prm = sel_prm._replace(rho_bar=_F(rho_sum.sum() / max(total, 1)))
    nsel = np.empty(n_cells, dtype=np.int64)
    if count_only:
        _count(c.start, fkey, camc, csize, fine_n, sel_prm, nsel)
        return _Selection(c.start, nsel, int(nsel.sum()))
    with numba.parallel_chunksize(1):
        _select(Pc, rkc if copy_rank else omc, omc, camc, c.start, members, fkey, csize, fine_n, sel_prm, chunks, c.largest,
                cons, T_wc, T_cw, hw, ws.stage_src, ws.stage_sup, nsel, ws.sup)  # fmt: skip
    return _Selection(c.start, nsel, int(nsel.sum()))


def fuse_numba(p, cfg: FuseConfig) -> tuple[FusedCloud, int, int, int]:
    """The compiled CPU path over api._Prepared inputs; same contract as api._fuse_torch."""
    prm = kernel_params(cfg)
    n, h, w = p.depth.shape
    ws = _workspace(n, h, w)
    c = _candidates(p, prm.pixel, ws)
    T_wc = p.T_world_cam.numpy().astype(np.float32)
    T_cw = p.T_cam_world.numpy().astype(np.float32)
    hw = h * w
    if cfg.target_points is not None:  # density control: search s0 on the hash + selection only
        from fuseflow.fuse.density import search_s0, with_s0

        off = consensus_params(cfg, on=False)

        def count_at(s0: float) -> int:
            return _select_points(c, kernel_params(with_s0(cfg, s0)), ws, off, T_wc, T_cw, hw, count_only=True).points

        # 8 count passes (hash + eq. 26 only): with multiview_mean the count falls more steeply
        # with s0 on small frames (4-camera 160x120: -20 % for +2.5 % s0) and 6 left it 11 % off
        s0, _ = search_s0(count_at, cfg.s0, cfg.target_points, max_evals=8)
        cfg = with_s0(cfg, s0)
        prm = kernel_params(cfg)
    cons = consensus_params(cfg)
    s = _select_points(c, prm, ws, cons, T_wc, T_cw, hw)
    k = s.points
    cell_out = np.zeros(s.cell_nsel.shape[0], dtype=np.int64)
    if cell_out.shape[0] > 1:
        np.cumsum(s.cell_nsel[:-1], out=cell_out[1:])
    xyz = np.empty((k, 3), dtype=np.float32)
    rgb = np.empty((k, 3), dtype=np.uint8)
    wgt = np.empty(k, dtype=np.float32)
    src = np.empty(k, dtype=np.int16)
    sup = np.empty(k if cons.on else 0, dtype=np.int16)
    color = p.color.contiguous().reshape(n * h * w, 3).numpy()
    rig_index = p.rig_index.numpy().astype(np.int16)
    with numba.parallel_chunksize(4):  # a few hundred coarse cells of very different sizes
        _emit(s.start, s.cell_nsel, cell_out, ws.stage_src, ws.stage_sup, cons.on, ws.members, ws.Pc,
              ws.omc, ws.camc, color, rig_index, xyz, rgb, wgt, src, sup)  # fmt: skip
    support = torch.from_numpy(sup) if cons.on else None
    cloud = FusedCloud(
        torch.from_numpy(xyz), torch.from_numpy(rgb), torch.from_numpy(wgt), torch.from_numpy(src), support
    )
    return cloud, int(sum(p.valid_per_view)), c.candidates - c.out_of_range, c.out_of_range
