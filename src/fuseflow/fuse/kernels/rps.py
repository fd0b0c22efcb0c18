"""RPS (eq. 26-28) compiled: k per fine cell (``cell_k``, eq. 26), the count the density
search uses (``count_kept``), the weighted FPS of eq. (28) with the consensus of rps.consensus
(``select``, ``consensus_point``) and the output cloud (``emit``)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from fuseflow.fuse.kernels.common import sigma as _sigma
from fuseflow.geometry import noise
from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True, depends=(noise.__file__,))  # before any @njit(cache=True)

__all__ = ["cell_k", "count_kept", "select", "consensus_point", "emit"]

_F = np.float32


@njit(cache=True, inline="always", error_model="numpy")
def cell_k(n, n_coarse, fine_cells, sf3, prm, sup1):
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
def count_kept(start, gsize, gsup, csize, fine_n, prm, cell_count):
    """Points that selection keeps per coarse cell, from the fine-cell sizes alone (``fine_pass``
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
            cnt += min(cell_k(n, start[c + 1] - a, fine_n[c], sf3, prm, np.int64(gsup[a + g])), n)
        cell_count[c] = cnt


@njit(cache=True, parallel=True, error_model="numpy")
def select(Pc, rkc, omc, camc, start, members, fkey, csize, fine_n, prm, chunks, largest, cons, T_wc, T_cw, hw,
            stage_src, stage_sup, cell_nsel, sup):  # fmt: skip
    """Eq. (26) and the confidence-weighted FPS of eq. (28) inside every fine cell, then (when
    cons.on) rps.consensus for the representatives of that fine cell while it is in cache.
    Pc, omc, rkc: point, omega and ranking value (omega, or omega / sigma(z) with
    range_priority; only compared) per slot (``fine_pass``); members: the pixel of each slot.
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
                k = cell_k(n, b - a, fine_n[c], sf3, prm, np.int64(sup[members[t0]]))
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
                        consensus_point(Pc, omc, camc, t0, t1, ts, i, T_wc, T_cw, gate, na, nb, nz0,
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
def consensus_point(Pc, omc, camc, t0, t1, s, i, T_wc, T_cw, gate, na, nb, nz0, stamp, tick, out_P, out_sup, k, ks):
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
    lim = gate * _sigma(zs, na, nb, nz0)
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
def emit(start, cell_nsel, cell_out, stage_src, stage_sup, use_stage, members, Pc, omc, camc, color, rig_index,
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
