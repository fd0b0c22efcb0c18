"""ASH (eq. 23-25) compiled: coarse cells of the rows' runs (``cells``), the candidates grouped
by coarse cell (``scatter``), then the fine cells of every coarse cell with a stable counting
sort into slot order and the fine-cell densities for eq. (26)'s rho_bar (``fine_pass``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from fuseflow.fuse.kernels.common import HASH_MUL, cam_of
from fuseflow.geometry import noise
from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True, depends=(noise.__file__,))  # before any @njit(cache=True)

__all__ = ["cells", "scatter", "fine_pass"]

_F = np.float32


@njit(cache=True, error_model="numpy")
def cells(runs, r_n, row_info, run_slot):
    """Coarse cells of the runs (serial, one hash lookup per run, not per point): cell ids in
    first-appearance order (input order); run_slot[roff[row] + r] = the first slot of run r of
    the row in the cell-grouped order (runs compacted: ``runs`` and ``r_n`` live in buffers that
    ``scatter`` overwrites). The hash table and the per-cell arrays grow with the cells, not
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
            slot = ((key * HASH_MUL) >> 20) & mask
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
                                s2 = ((tkeys[e] * HASH_MUL) >> 20) & mask
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
                        slot = ((key * HASH_MUL) >> 20) & mask
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
def scatter(om, run_slot, roff, row_info, w, P, members, Pm):
    """members[slot] = pixel index of every candidate, grouped by coarse cell (``cells``), and
    Pm[slot] = its point P[pixel]: P is read in pixel order here (the scattered side is the
    write), so that ``fine_pass`` reads the points of a cell in order instead of gathering
    them by pixel index (a cache miss at every run of a cell). The row's in-range candidates
    (om not NaN, ``pixels``) in column order, a new run at each om with the sign bit set
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


@njit(cache=True, parallel=True, error_model="numpy")
def fine_pass(Pc, start, cell_key, prm, chunks, largest, reorder, members, fkey, csize, cell_rho_sum, cell_fine_n,
               om, rank, copy_rank, hw, omc, rkc, camc, sup):  # fmt: skip
    """Pc, members: the points and pixel indices of the candidates grouped by coarse cell
    (``scatter``); with ``reorder`` both are sorted into slot order **in place** (a cell's
    range is copied to the chunk's scratch first), so no second point buffer is needed.

    Eq. (23)-(25) per coarse cell (parallel over chunks of cells, scratch allocated once per
    chunk): fine keys, stable local counting sort of members (and Pc), fkey = fine
    group of each slot (0, 1, ... per coarse cell), the per-cell sum of fine-cell densities
    (for rho_bar) and fine-cell count. prm: CellParams. ``reorder`` False (a count only, for
    density control): Pc and members untouched, fkey[start[c] + g] = size of fine cell g instead
    and camc[start[c] + g] = sup (per pixel, pixels' out_sup) of its last point (of its only
    point for a lone cell: the count's FuseConfig.rps.lone_cell_keep test).
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
            for t in range(n):  # the cell's points (in scatter's order)
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
                slot = ((k3 * HASH_MUL) >> 24) & tmask
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
                    omc[q] = abs(om[p])  # the sign marks a run's first point (pixels)
                    camc[q] = cam_of(p, hw, inv_hw)
                    if copy_rank:
                        rkc[q] = rank[p]
                    gstart[g] += 1
            cell_rho_sum[c] = rsum
            cell_fine_n[c] = ng
