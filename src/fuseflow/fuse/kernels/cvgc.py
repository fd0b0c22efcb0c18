"""CVGC (eq. 19-21) and the multi-view mean (cvgc.multiview_mean) compiled: the votes of one
neighbour camera for the candidates of a row (``votes``); per point the float32 operations of
fuse/cvgc.py and geometry/agreement.py."""

from __future__ import annotations

import numpy as np
from numba import njit

from fuseflow.fuse.kernels.common import ray_x
from fuseflow.fuse.kernels.common import sigma as _sigma
from fuseflow.geometry import noise
from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__, package=True, depends=(noise.__file__,))  # before any @njit(cache=True)

__all__ = ["votes"]

_F = np.float32


@njit(cache=True, fastmath=False, error_model="numpy", inline="always")
def votes(dflat, Kf, M_rel, xt, yt, skew0, i, j, h, w, nc, X, Y, Z, v0, prm, zjs, idx, ius, ivs, dv, xq, yq,
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
            xq[t] = ray_x(Kf, xt, j, iu, yq[t], skew0)
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
            szj = _sigma(zj, na, nb, nz0)
            sd = _sigma(d, na, nb, nz0)
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
