"""Stage 1 of the compiled path, per camera row: the depth gate, MCM and eq. (27)'s candidate
test (kernels.mcm), back-projection, CVGC over the neighbours (kernels.cvgc), the joint weight
of eq. (22), the world point and its coarse cell (ash.py's packing), written as runs of
same-cell candidates for kernels.ash."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from fuseflow.fuse.kernels.common import ray_tables, ray_x
from fuseflow.fuse.kernels.common import sigma as _sigma
from fuseflow.fuse.kernels.cvgc import votes
from fuseflow.fuse.kernels.mcm import mcm_row
from fuseflow.geometry import noise
from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True, depends=(noise.__file__,))  # before any @njit(cache=True)

__all__ = ["gate_rows", "pixels"]

_F = np.float32


@njit(cache=True, error_model="numpy")
def gate_rows(depth, lo, hi, present, out, row_count):
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


@njit(cache=True, parallel=True, fastmath=False, error_model="numpy")
def pixels(depth, Kf, M_rel, T_wc, nbr, present, prm, out_P, out_w, out_pr, out_sup, runs, r_n, row_info):
    """Stage 1, parallel over blocks of camera rows. Writes, at the pixel's own index
    p = (i H + v) W + u: out_P[p] (world point of a candidate), out_w[p] (omega, eq. 22, of an
    in-range candidate, negated (sign bit set, also for 0) for the first of a run; NaN for every
    other pixel: a dropped pixel or a candidate beyond the hash's range) and, when
    prm.range_priority, out_pr[p] (omega / sigma(z), rps.selection_priority) and, with the
    multi-view mean, out_sup[p] (how many neighbours agree within its gate, at most 255;
    FuseConfig.rps.lone_cell_keep). Also the row's *runs*: maximal stretches of in-range candidates of one coarse cell,
    runs[row, r] = the cell key, r_n[row, r] = its candidates (both (N H, W), in buffers that
    are free until ``scatter``); row_info[row] = (candidates, beyond range, runs).

    Each row runs in passes over row-sized scratch: MCM and eq. (27)'s test (``mcm_row``) ->
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
    xt, yt, skew0 = ray_tables(Kf, h, w)
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
        zjs = np.empty(w, dtype=np.float32)  # per-neighbour scratch of votes
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
                u0 = 1 if stride == 1 else stride  # the first column u >= 1 with u % stride == 0
                mcm_row(dflat[rb - w : rb], dflat[rb : rb + w], dflat[rb + w : rb + 2 * w], prm, u0, stride, gq, vr, cc)
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
                xn = ray_x(Kf, xt, i, u, yn, skew0)
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
                        s0 = _sigma(z, na, nb, nz0)
                        v0[t] = s0 * s0
                for kk in range(nbr_n[i]):
                    votes(dflat, Kf, M_rel, xt, yt, skew0, i, vn[i, kk], h, w, nc, cx_, cy_, cz_, v0, prm,
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
                    out_pr[base] = om / _sigma(z, na, nb, nz0)
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
                        out_w[base] = -om  # a run's first point (exact: fine_pass takes abs)
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
