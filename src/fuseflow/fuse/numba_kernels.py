"""The compiled CPU path of FUSE: the arithmetic of mcm / cvgc / weights / ash / rps fused
into a few numba loops (DESIGN.md 2; ../shared/notes/fuse-cpu-feasibility.md).

Same float32 operations in the same order as the PyTorch reference, so results agree up to
float rounding of exp / sqrt and float32 reductions (tests/fuse/test_numba.py states the
tolerance). Structure, and why:

1. ``_pixels`` (parallel over camera rows): MCM (eq. 16-18) on the 3x3 window, the candidate
   test of eq. (27) *before* any projection (exact: omega <= 2c), back-projection, CVGC over
   <= K_max neighbours (eq. 19-21), the joint weight (22), the minimum-weight filter, the world
   point and its coarse cell coordinates (eq. 23's key computed during back-projection). One
   pass over the depth maps, no full-size temporaries besides the outputs.
2. ``_compact``: per-row counts -> prefix sum -> parallel scatter into input order.
3. ``_coarse_ids``: an open-addressing hash of coarse keys with a last-key cache (neighbouring
   pixels share a coarse cell ~90 % of the time); counting sort of the points by coarse cell
   (stable, so input order is kept inside a cell) instead of a global sort.
4. ``_fine_pass`` / ``_select`` (parallel over coarse cells): eq. (24)-(25) fine keys, a stable
   local sort, fine-cell densities for rho_bar, then eq. (26) and the weighted FPS of eq. (28)
   inside every fine cell.

numba is imported here only; ``import fuseflow`` does not load it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from numba import njit, prange

from fuseflow.fuse.ash import COARSE_OFFSET, FIXED_OFFSET
from fuseflow.fuse.config import FuseConfig
from fuseflow.geometry.camera import relative_transforms
from fuseflow.types import FusedCloud

__all__ = ["fuse_numba", "gate_depth", "PixelParams", "CellParams", "SelectParams", "kernel_params"]

_F = np.float32


# --- named kernel parameters --------------------------------------------------------------
# numba takes a NamedTuple of scalars as one argument and types each field by its Python value
# (np.float32 -> float32, float -> float64, bool -> boolean, int -> int64). The field types
# below are the ones the kernels compute with; ``kernel_params`` is the one place that builds
# them from a FuseConfig.


class PixelParams(NamedTuple):
    """Scalars of stage 1 (``_pixels``, ``_compact``): MCM, eq. (27), CVGC, eq. (22), the hash."""

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


class KernelParams(NamedTuple):
    """The three parameter structs of one FuseConfig (``kernel_params``)."""

    pixel: PixelParams
    cell: CellParams
    select: SelectParams


def kernel_params(cfg: FuseConfig) -> KernelParams:
    """The kernels' parameters from ``cfg`` (``select.rho_bar`` is 1 until ``_fine_pass`` ran)."""
    adaptive = cfg.use_ash
    s_c = cfg.coarse_size if adaptive else cfg.fixed_size
    qlim = (COARSE_OFFSET if adaptive else FIXED_OFFSET) - 1
    a, b, z0 = cfg.noise_sigma
    pixel = PixelParams(
        alpha=_F(cfg.alpha), beta=_F(cfg.beta), eps=_F(cfg.eps), r_c=_F(cfg.r_c), tau=_F(cfg.tau),
        min_weight=_F(cfg.min_weight), cell=_F(s_c), use_mcm=bool(cfg.use_mcm), use_cvgc=bool(cfg.use_cvgc),
        visibility_aware=bool(cfg.visibility_aware), qlim=_F(qlim), range_priority=bool(cfg.range_priority),
        noise_a=_F(a), noise_b=_F(b), noise_z0=_F(z0), mcm_noise=bool(cfg.mcm_noise),
    )  # fmt: skip
    cell = CellParams(
        s_c=_F(s_c), s0=_F(cfg.s0), s_min=_F(cfg.s_min), s_max=_F(cfg.s_max), eps=_F(cfg.eps),
        adaptive=bool(adaptive), fixed_size=_F(cfg.fixed_size), s_c3=_F(s_c**3),
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
    )  # fmt: skip
    return KernelParams(pixel, cell, select)


@njit(cache=True, parallel=True)
def _gate(depth, lo, hi, present, out, row_count):
    """api.valid_depth and the absent-view mask in one pass: out = depth where lo < depth < hi
    in a present view, else 0; row_count[row] = kept pixels of that row."""
    n, h, w = depth.shape
    for row in prange(n * h):
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
    with torch (valid_depth, then zero for absent views), as one compiled pass."""
    d = depth.contiguous().numpy()
    n, h, w = d.shape
    out = np.empty_like(d)
    rows = np.empty(n * h, dtype=np.int64)
    _gate(d, lo.numpy(), hi.numpy(), present.numpy().astype(np.bool_), out, rows)
    return torch.from_numpy(out), tuple(int(x) for x in rows.reshape(n, h).sum(axis=1))


@njit(cache=True, parallel=True, fastmath=False)
def _pixels(depth, Kf, M_rel, T_wc, nbr, present, prm, flags, out_P, out_w, out_pr, row_count):
    """Stage 1, one pass per pixel. prm: PixelParams. out_pr: the range-aware ranking value
    omega / sigma(z) (rps.selection_priority) when prm.range_priority, else unused (may have
    length 1)."""
    n, h, w = depth.shape
    alpha, beta, eps, r_c, tau, min_w, s_c = prm.alpha, prm.beta, prm.eps, prm.r_c, prm.tau, prm.min_weight, prm.cell
    use_mcm, use_cvgc, vis = prm.use_mcm, prm.use_cvgc, prm.visibility_aware
    qlim = prm.qlim
    rp, na, nb, nz0 = prm.range_priority, prm.noise_a, prm.noise_b, prm.noise_z0
    mn = prm.mcm_noise
    zero = _F(0.0)
    half = _F(0.5)
    two = _F(2.0)
    nine = _F(9.0)
    kn = nbr.shape[1]
    for row in prange(n * h):
        i = row // h
        v = row - i * h
        cnt = 0
        fx, s, cx = Kf[i, 0, 0], Kf[i, 0, 1], Kf[i, 0, 2]
        fy, cy = Kf[i, 1, 1], Kf[i, 1, 2]
        for u in range(w):
            base = (i * h + v) * w + u
            flags[base] = 0
            z = depth[i, v, u]
            if z <= 0:
                continue
            if use_mcm:
                # eq. (16)-(17) on the 3x3 window; a window pixel without depth -> c = 0
                if u == 0 or v == 0 or u == w - 1 or v == h - 1:
                    continue
                full = True
                sm = _F(0.0)
                for dv in range(-1, 2):
                    for du in range(-1, 2):
                        d = depth[i, v + dv, u + du]
                        if d <= 0:
                            full = False
                        sm += d
                if not full:
                    continue
                mean = sm / nine
                var = _F(0.0)
                for dv in range(-1, 2):
                    for du in range(-1, 2):
                        e = depth[i, v + dv, u + du] - mean
                        var += e * e
                var = var / nine
                gx = (depth[i, v, u + 1] - depth[i, v, u - 1]) * half
                gy = (depth[i, v + 1, u] - depth[i, v - 1, u]) * half
                gsq = gx * gx + gy * gy
                if mn:  # noise-aware MCM: the expected noise sigma(z)^2 out of g and v
                    dzn = z - nz0
                    sg = na + nb * (dzn * dzn)
                    s2 = sg * sg
                    gsq = gsq - s2
                    if gsq < zero:
                        gsq = zero
                    var = var - s2
                    if var < zero:
                        var = zero
                g = np.sqrt(gsq) / (z + eps)
                vv = var / (z * z + eps)
                c = np.exp(-alpha * g - beta * vv)  # eq. (18)
            else:
                c = _F(1.0)
            if not c > r_c:  # eq. (27)
                continue
            yn = (_F(v) - cy) / fy
            xn = ((_F(u) - cx) - s * yn) / fx
            x = xn * z
            y = yn * z
            wg = c
            if use_cvgc:
                agree = 0
                votes = 0
                for kk in range(kn):
                    j = nbr[i, kk]
                    if j < 0 or not present[j]:
                        continue
                    m = M_rel[i, j]
                    xj = m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3]
                    yj = m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3]
                    zj = m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3]
                    if not zj > eps:
                        continue
                    xnj = xj / zj
                    ynj = yj / zj
                    uj = np.floor(Kf[j, 0, 0] * xnj + Kf[j, 0, 1] * ynj + Kf[j, 0, 2] + half)
                    vj = np.floor(Kf[j, 1, 1] * ynj + Kf[j, 1, 2] + half)
                    if uj < 0 or uj > w - 1 or vj < 0 or vj > h - 1:
                        continue
                    d = depth[j, int(vj), int(uj)]
                    if d <= 0:
                        continue
                    r = abs(zj - d) / (zj + eps)  # eq. (20)
                    if r < tau:
                        agree += 1
                        votes += 1
                    elif (not vis) or d > zj:
                        votes += 1
                if votes > 0:
                    wg = _F(agree) / _F(votes)  # eq. (21)
            om = two * c * wg / (c + wg + eps)  # eq. (22)
            if not om >= min_w:
                continue
            t = T_wc[i]
            px = t[0, 0] * x + t[0, 1] * y + t[0, 2] * z + t[0, 3]
            py = t[1, 0] * x + t[1, 1] * y + t[1, 2] * z + t[1, 3]
            pz = t[2, 0] * x + t[2, 1] * y + t[2, 2] * z + t[2, 3]
            qx = np.floor(px / s_c)
            qy = np.floor(py / s_c)
            qz = np.floor(pz / s_c)
            flags[base] = 1 if (abs(qx) < qlim and abs(qy) < qlim and abs(qz) < qlim) else 2
            out_P[base, 0] = px
            out_P[base, 1] = py
            out_P[base, 2] = pz
            out_w[base] = om
            if rp:
                dz = z - nz0
                out_pr[base] = om / (na + nb * (dz * dz))
            cnt += 1
        row_count[row] = cnt


@njit(cache=True, parallel=True)
def _compact(flags, out_P, out_w, out_pr, prm, row_start, h, w, P, om, pr, q, pix, cam, oor):
    """Kept pixels of ``_pixels`` (flags 1 / 2) into input-order arrays; prm: PixelParams."""
    rp, s_c = prm.range_priority, prm.cell
    nrows = row_start.shape[0] - 1
    for row in prange(nrows):
        k = row_start[row]
        i = row // h
        base0 = row * w
        for u in range(w):
            f = flags[base0 + u]
            if f == 0:
                continue
            b = base0 + u
            P[k, 0] = out_P[b, 0]
            P[k, 1] = out_P[b, 1]
            P[k, 2] = out_P[b, 2]
            om[k] = out_w[b]
            if rp:
                pr[k] = out_pr[b]
            if f == 1:
                q[k, 0] = np.int64(np.floor(out_P[b, 0] / s_c))
                q[k, 1] = np.int64(np.floor(out_P[b, 1] / s_c))
                q[k, 2] = np.int64(np.floor(out_P[b, 2] / s_c))
            pix[k] = (row - i * h) * w + u
            cam[k] = i
            oor[k] = f == 2
            k += 1


@njit(cache=True)
def _coarse_ids(q, keep, offset, bits):
    """Coarse cell id (first-appearance order) of every kept point, -1 for the others."""
    m = q.shape[0]
    size = 1
    while size < 2 * m + 16:
        size *= 2
    mask = size - 1
    tkeys = np.full(size, -1, dtype=np.int64)
    tvals = np.empty(size, dtype=np.int64)
    ids = np.full(m, -1, dtype=np.int64)
    n_cells = 0
    last_key = -2
    last_id = -1
    for p in range(m):
        if not keep[p]:
            continue
        key = ((q[p, 0] + offset) << (2 * bits)) | ((q[p, 1] + offset) << bits) | (q[p, 2] + offset)
        if key == last_key:
            ids[p] = last_id
            continue
        hsh = (key * np.int64(-7046029254386353131)) >> 20
        slot = hsh & mask
        while True:
            tk = tkeys[slot]
            if tk == key:
                cid = tvals[slot]
                break
            if tk == -1:
                tkeys[slot] = key
                tvals[slot] = n_cells
                cid = n_cells
                n_cells += 1
                break
            slot = (slot + 1) & mask
        ids[p] = cid
        last_key = key
        last_id = cid
    return ids, n_cells


@njit(cache=True)
def _bucket(ids, n_cells):
    """Counting sort of points by cell id, stable: (start (C+1,), members (kept M,))."""
    counts = np.zeros(n_cells + 1, dtype=np.int64)
    for p in range(ids.shape[0]):
        if ids[p] >= 0:
            counts[ids[p] + 1] += 1
    for c in range(n_cells):
        counts[c + 1] += counts[c]
    start = counts.copy()
    members = np.empty(counts[n_cells], dtype=np.int64)
    fill = counts[:n_cells].copy()
    for p in range(ids.shape[0]):
        c = ids[p]
        if c >= 0:
            members[fill[c]] = p
            fill[c] += 1
    return start, members


@njit(cache=True, parallel=True)
def _fine_pass(P, q, start, members, prm, fkey, csize, cell_rho_sum, cell_fine_n):
    """Eq. (23)-(25) per coarse cell: fine keys, stable local sort (members reordered in place),
    and the per-cell sum of fine-cell densities (for rho_bar) and fine-cell count. prm: CellParams."""
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
    n_cells = start.shape[0] - 1
    for c in prange(n_cells):
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
        # fine keys, grouped by first appearance through a small open-addressing table
        # (an O(n) counting sort instead of a comparison sort); stable: input order kept
        keys = np.empty(n, dtype=np.int64)
        gid = np.empty(n, dtype=np.int64)
        tsize = 2 * n + 1
        tk = np.full(tsize, -1, dtype=np.int64)
        tv = np.empty(tsize, dtype=np.int64)
        ng = 0
        last_k = np.int64(-1)
        last_g = 0
        for t in range(n):
            p = members[a + t]
            k3 = np.int64(0)
            if adaptive:
                for ax in range(3):
                    o = _F(q[p, ax]) * s_c
                    f = np.floor((P[p, ax] - o) / sf)  # eq. (25)
                    fi = np.int64(f)
                    if fi < 0:
                        fi = 0
                    if fi > 127:
                        fi = 127
                    k3 = (k3 << 7) | fi
            keys[t] = k3
            if k3 == last_k:
                gid[t] = last_g
                continue
            slot = (k3 * 40503) % tsize
            while True:
                if tk[slot] == k3:
                    g = tv[slot]
                    break
                if tk[slot] == -1:
                    tk[slot] = k3
                    tv[slot] = ng
                    g = ng
                    ng += 1
                    break
                slot += 1
                if slot == tsize:
                    slot = 0
            gid[t] = g
            last_k = k3
            last_g = g
        gstart = np.zeros(ng + 1, dtype=np.int64)
        for t in range(n):
            gstart[gid[t] + 1] += 1
        for g in range(ng):
            gstart[g + 1] += gstart[g]
        fill = gstart[:ng].copy()
        tmp = np.empty(n, dtype=np.int64)
        for t in range(n):
            g = gid[t]
            tmp[fill[g]] = members[a + t]
            fkey[a + fill[g]] = g
            fill[g] += 1
        sf3 = sf * sf * sf
        rsum = 0.0
        for g in range(ng):
            rsum += _F(gstart[g + 1] - gstart[g]) / sf3
        for t in range(n):
            members[a + t] = tmp[t]
        nf = ng
        cell_rho_sum[c] = rsum
        cell_fine_n[c] = nf


@njit(cache=True, parallel=True)
def _select(P, om, start, members, fkey, csize, fine_n, prm, selected):
    """Eq. (26) and the confidence-weighted FPS of eq. (28) inside every fine cell. om: the
    ranking value (omega, or omega / sigma(z) with range_priority); only compared. fine_n:
    occupied fine cells per coarse cell (for prm.lone_cell_mean, 0 = off). prm: SelectParams."""
    k0, ratio, k_max, rho_bar = prm.k0, prm.ratio, prm.k_max, prm.rho_bar
    fixed_k, k_const, lone_mean = prm.fixed_k, prm.k_const, prm.lone_cell_mean
    n_cells = start.shape[0] - 1
    for c in prange(n_cells):
        a = start[c]
        b = start[c + 1]
        sf = csize[c]
        sf3 = sf * sf * sf
        t0 = a
        d2 = np.empty(k_max * 0 + (b - a), dtype=np.float32)
        while t0 < b:
            t1 = t0 + 1
            while t1 < b and fkey[t1] == fkey[t0]:
                t1 += 1
            n = t1 - t0
            if not fixed_k and lone_mean > 0 and n == 1 and float(b - a) >= lone_mean * float(fine_n[c]):
                t0 = t1  # a lone point in a densely sampled coarse cell: k = 0 (lone_cell_mean)
                continue
            if not fixed_k:
                rho = _F(n) / sf3
                kf = np.ceil(_F(k0) * (rho / rho_bar) * _F(ratio))  # eq. (26)
                k = int(kf)
                if k < 1:
                    k = 1
                if k > k_max:
                    k = k_max
            else:
                k = k_const
            # first pick: highest omega, ties -> first in input order
            best = t0
            for t in range(t0 + 1, t1):
                if om[members[t]] > om[members[best]]:
                    best = t
            selected[members[best]] = True
            for t in range(t0, t1):
                d2[t - t0] = np.inf
            last = members[best]
            for _r in range(1, k):
                bs = _F(0.0)
                bt = -1
                for t in range(t0, t1):
                    p = members[t]
                    if selected[p]:
                        continue
                    dx = P[p, 0] - P[last, 0]
                    dy = P[p, 1] - P[last, 1]
                    dz = P[p, 2] - P[last, 2]
                    dd = dx * dx + dy * dy + dz * dz
                    if dd < d2[t - t0]:
                        d2[t - t0] = dd
                    sc = np.sqrt(d2[t - t0]) * om[p]  # eq. (28)
                    if sc > bs:
                        bs = sc
                        bt = t
                if bt < 0:
                    break
                last = members[bt]
                selected[last] = True
            t0 = t1


@njit(cache=True, parallel=True)
def _consensus(P, om, cam, T_wc, T_cw, start, members, fkey, selected, gate, na, nb, nz0, outP, support):
    """rps.consensus for every selected point, fine cell by fine cell (parallel over coarse
    cells): outP / support of each selected point (indexed like P). Same arithmetic as the
    reference: float32 geometry, float64 sums, members in fine-cell order."""
    n_cells = start.shape[0] - 1
    for c in prange(n_cells):
        a = start[c]
        b = start[c + 1]
        seen = np.empty(b - a, dtype=np.int64)
        t0 = a
        while t0 < b:
            t1 = t0 + 1
            while t1 < b and fkey[t1] == fkey[t0]:
                t1 += 1
            for ts in range(t0, t1):
                s = members[ts]
                if not selected[s]:
                    continue
                i = cam[s]
                cx, cy, cz = T_wc[i, 0, 3], T_wc[i, 1, 3], T_wc[i, 2, 3]
                dx = P[s, 0] - cx
                dy = P[s, 1] - cy
                dz = P[s, 2] - cz
                t_s = np.sqrt(dx * dx + dy * dy + dz * dz)
                ux = dx / t_s
                uy = dy / t_s
                uz = dz / t_s
                zs = T_cw[i, 2, 0] * P[s, 0] + T_cw[i, 2, 1] * P[s, 1] + T_cw[i, 2, 2] * P[s, 2] + T_cw[i, 2, 3]
                dn = zs - nz0
                lim = gate * (na + nb * (dn * dn))
                num = 0.0
                den = 0.0
                ns = 0
                for t in range(t0, t1):
                    q = members[t]
                    tq = (P[q, 0] - cx) * ux + (P[q, 1] - cy) * uy + (P[q, 2] - cz) * uz
                    if not abs(tq - t_s) < lim:
                        continue
                    wq = np.float64(om[q])
                    num += wq * np.float64(tq)
                    den += wq
                    cq = cam[q]
                    new = True
                    for e in range(ns):
                        if seen[e] == cq:
                            new = False
                            break
                    if new:
                        seen[ns] = cq
                        ns += 1
                if den > 0:
                    tn = _F(num / den)
                else:
                    tn = t_s
                outP[s, 0] = cx + tn * ux
                outP[s, 1] = cy + tn * uy
                outP[s, 2] = cz + tn * uz
                support[s] = ns
            t0 = t1


@njit(cache=True)
def _out_positions(members, selected, pos):
    """pos[t] = output slot of members[t] when it is selected (fine-cell order), else -1."""
    k = 0
    for t in range(members.shape[0]):
        if selected[members[t]]:
            pos[t] = k
            k += 1
        else:
            pos[t] = -1
    return k


@njit(cache=True, parallel=True)
def _gather(members, pos, P, om, cam, pix, color, rig_index, hw, xyz, rgb, wgt, src):
    """The output cloud in one parallel pass (numpy fancy indexing took ~45 ms at N = 8)."""
    for t in prange(members.shape[0]):
        k = pos[t]
        if k < 0:
            continue
        a = members[t]
        xyz[k, 0] = P[a, 0]
        xyz[k, 1] = P[a, 1]
        xyz[k, 2] = P[a, 2]
        wgt[k] = om[a]
        c = cam[a]
        q = c * hw + pix[a]
        rgb[k, 0] = color[q, 0]
        rgb[k, 1] = color[q, 1]
        rgb[k, 2] = color[q, 2]
        src[k] = rig_index[c]


@njit(cache=True, parallel=True)
def _gather_i16(members, pos, val, out):
    """out[pos[t]] = val[members[t]] for the selected members (the support column)."""
    for t in prange(members.shape[0]):
        k = pos[t]
        if k >= 0:
            out[k] = val[members[t]]


class _Candidates(NamedTuple):
    """Stage-1 output, in input order (camera, row, column) of the M candidates."""

    P: np.ndarray  # (M, 3) float32 world points
    om: np.ndarray  # (M,) float32 joint weight, eq. (22)
    rank: np.ndarray  # (M,) float32 ranking value of eq. (28) (om itself without range_priority)
    q: np.ndarray  # (M, 3) int64 first-level cell index (valid where not out of range)
    pix: np.ndarray  # (M,) int64 pixel index v * W + u in the source view
    cam: np.ndarray  # (M,) int64 source view (frame order)
    oor: np.ndarray  # (M,) bool beyond the hash's addressable range


def _candidates(p, prm: PixelParams) -> _Candidates:
    """Stage 1 and 2: ``_pixels`` over every view, then ``_compact`` into input order."""
    depth = p.depth.contiguous().numpy()
    n, h, w = depth.shape
    Kf = p.K.numpy().astype(np.float32)
    M_rel = relative_transforms(p.T_cam_world).numpy()
    T_wc = p.T_world_cam.numpy().astype(np.float32)
    nbr = p.graph.index.numpy().astype(np.int64)
    present = p.present.numpy().astype(np.bool_)
    npx = n * h * w
    flags = np.empty(npx, dtype=np.int8)
    out_P = np.empty((npx, 3), dtype=np.float32)
    out_w = np.empty(npx, dtype=np.float32)
    rp = prm.range_priority
    out_pr = np.empty(npx if rp else 1, dtype=np.float32)
    row_count = np.zeros(n * h, dtype=np.int64)
    _pixels(depth, Kf, M_rel, T_wc, nbr, present, prm, flags, out_P, out_w, out_pr, row_count)
    row_start = np.zeros(n * h + 1, dtype=np.int64)
    np.cumsum(row_count, out=row_start[1:])
    m = int(row_start[-1])
    P = np.empty((m, 3), dtype=np.float32)
    om = np.empty(m, dtype=np.float32)
    rank = np.empty(m, dtype=np.float32) if rp else om
    q = np.empty((m, 3), dtype=np.int64)
    pix = np.empty(m, dtype=np.int64)
    cam = np.empty(m, dtype=np.int64)
    oor = np.empty(m, dtype=np.bool_)
    _compact(flags, out_P, out_w, out_pr, prm, row_start, h, w, P, om, rank, q, pix, cam, oor)
    return _Candidates(P, om, rank, q, pix, cam, oor)


def _select_points(c: _Candidates, prm: KernelParams, cons=None):
    """Stages 3 and 4: coarse cells, fine cells and representatives. Returns (members: point
    indices grouped by fine cell, pos: output slot of each member or -1), the point count and,
    when ``cons`` = (cam, T_wc, T_cw, gate, noise_sigma) is given, the consensus positions
    (M, 3) and support (M,) of the selected points (``_consensus``), else (None, None)."""
    adaptive = prm.cell.adaptive
    bits = 14 if adaptive else 21
    offset = COARSE_OFFSET if adaptive else FIXED_OFFSET
    ids, n_cells = _coarse_ids(c.q, ~c.oor, offset, bits)
    start, members = _bucket(ids, n_cells)
    fkey = np.empty(members.shape[0], dtype=np.int64)
    csize = np.empty(n_cells, dtype=np.float32)
    rho_sum = np.empty(n_cells, dtype=np.float64)
    fine_n = np.empty(n_cells, dtype=np.int64)
    _fine_pass(c.P, c.q, start, members, prm.cell, fkey, csize, rho_sum, fine_n)
    sel_prm = prm.select
    if not sel_prm.fixed_k:  # eq. (26)'s rho_bar: mean density over the occupied fine cells
        total = int(fine_n.sum())
        sel_prm = sel_prm._replace(rho_bar=_F(rho_sum.sum() / max(total, 1)))
    selected = np.zeros(c.P.shape[0], dtype=np.bool_)
    _select(c.P, c.rank, start, members, fkey, csize, fine_n, sel_prm, selected)
    # output in the fine-cell order of the members array
    pos = np.empty(members.shape[0], dtype=np.int64)
    k = _out_positions(members, selected, pos)
    if cons is None:
        return members, pos, k, None, None
    cam, T_wc, T_cw, gate, (na, nb, nz0) = cons
    outP = c.P.copy()
    support = np.zeros(c.P.shape[0], dtype=np.int16)
    _consensus(
        c.P, c.om, cam, T_wc, T_cw, start, members, fkey, selected, _F(gate), _F(na), _F(nb), _F(nz0), outP, support
    )
    return members, pos, k, outP, support


def fuse_numba(p, cfg: FuseConfig) -> tuple[FusedCloud, int, int, int]:
    """The compiled CPU path over api._Prepared inputs; same contract as api._fuse_torch."""
    prm = kernel_params(cfg)
    c = _candidates(p, prm.pixel)
    if cfg.target_points is not None:  # density control: search s0 on the hash + selection only
        from fuseflow.fuse.density import search_s0, with_s0

        def count_at(s0: float) -> int:
            return _select_points(c, kernel_params(with_s0(cfg, s0)))[2]

        s0, _ = search_s0(count_at, cfg.s0, cfg.target_points)
        cfg = with_s0(cfg, s0)
        prm = kernel_params(cfg)
    cons = None
    if cfg.consensus:
        T_wc = p.T_world_cam.numpy().astype(np.float32)
        T_cw = p.T_cam_world.numpy().astype(np.float32)
        cons = (c.cam, T_wc, T_cw, cfg.consensus_gate, cfg.noise_sigma)
    members, pos, k, outP, sup_all = _select_points(c, prm, cons)
    n, h, w = p.depth.shape
    xyz = np.empty((k, 3), dtype=np.float32)
    rgb = np.empty((k, 3), dtype=np.uint8)
    wgt = np.empty(k, dtype=np.float32)
    src = np.empty(k, dtype=np.int16)
    color = p.color.contiguous().reshape(n * h * w, 3).numpy()
    rig_index = p.rig_index.numpy().astype(np.int16)
    _gather(
        members, pos, c.P if outP is None else outP, c.om, c.cam, c.pix, color, rig_index, h * w, xyz, rgb, wgt, src
    )
    support = None
    if sup_all is not None:
        support = np.empty(k, dtype=np.int16)
        _gather_i16(members, pos, sup_all, support)
        support = torch.from_numpy(support)
    cloud = FusedCloud(
        torch.from_numpy(xyz), torch.from_numpy(rgb), torch.from_numpy(wgt), torch.from_numpy(src), support
    )
    out_of_range = int(c.oor.sum())
    return cloud, int(sum(p.valid_per_view)), int(c.P.shape[0]) - out_of_range, out_of_range
