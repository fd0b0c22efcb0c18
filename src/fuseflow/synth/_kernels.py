"""Numba kernels of the simulator's two per-pixel / per-sample loops (compiled on first use,
cached on disk). Each has a plain numpy twin in the calling module's docstring terms; tests
compare them."""

from __future__ import annotations

import warnings

import numba
import numpy as np

# numba warns once per process that the installed TBB is too old and falls back to another
# threading layer; that is not the user's concern.
warnings.filterwarnings("ignore", message="The TBB threading layer requires", category=numba.NumbaWarning)


@numba.njit(parallel=True, cache=True, fastmath=False)
def sample_texture_nb(textures, tex_id, uv_px):  # pragma: no cover - compiled
    """Bilinear, wrap-around: textures (K, S, S, 3) uint8; uv_px (M, 2) float32 texel coords."""
    M = uv_px.shape[0]
    S = textures.shape[1]
    out = np.empty((M, 3), np.float32)
    for m in numba.prange(M):
        px = uv_px[m, 0] - 0.5
        py = uv_px[m, 1] - 0.5
        fx0 = np.floor(px)
        fy0 = np.floor(py)
        fx = px - fx0
        fy = py - fy0
        x0 = int(fx0) % S
        y0 = int(fy0) % S
        x1 = (x0 + 1) % S
        y1 = (y0 + 1) % S
        k = tex_id[m]
        for c in range(3):
            a = textures[k, y0, x0, c] * (1 - fx) + textures[k, y0, x1, c] * fx
            b = textures[k, y1, x0, c] * (1 - fx) + textures[k, y1, x1, c] * fx
            out[m, c] = (a * (1 - fy) + b * fy) / 255.0
    return out


@numba.njit(parallel=True, cache=True)
def visible_nb(points, normals, T_cam_world, K, centres, depth_gt, tol_m, tol_rel):  # pragma: no cover
    """(S,) bool: seen by a camera whose depth agrees within tol_m + tol_rel z (see visible_mask)."""
    S = points.shape[0]
    N, H, W = depth_gt.shape
    out = np.zeros(S, np.bool_)
    for s in numba.prange(S):
        px, py, pz = points[s, 0], points[s, 1], points[s, 2]
        for i in range(N):
            if (centres[i, 0] - px) * normals[s, 0] + (centres[i, 1] - py) * normals[s, 1] + (
                centres[i, 2] - pz
            ) * normals[s, 2] <= 0:
                continue
            T = T_cam_world[i]
            x = T[0, 0] * px + T[0, 1] * py + T[0, 2] * pz + T[0, 3]
            y = T[1, 0] * px + T[1, 1] * py + T[1, 2] * pz + T[1, 3]
            z = T[2, 0] * px + T[2, 1] * py + T[2, 2] * pz + T[2, 3]
            if z <= 1e-6:
                continue
            u = np.rint((K[i, 0, 0] * x + K[i, 0, 1] * y) / z + K[i, 0, 2])
            v = np.rint(K[i, 1, 1] * y / z + K[i, 1, 2])
            if u < 0 or u >= W or v < 0 or v >= H:
                continue
            d = depth_gt[i, int(v), int(u)]
            if d > 0 and abs(d - z) < tol_m + tol_rel * z:
                out[s] = True
                break
    return out
