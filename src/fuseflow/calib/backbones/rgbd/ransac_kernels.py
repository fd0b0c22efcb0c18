"""Compiled residuals of the rgbd backbone's RANSAC (``backbones.rgbd.candidates``).

A RANSAC round scores up to ``RGBDConfig.ransac_iterations`` (2000) models against every match
of a pair: as a (H, K) residual table of ``numpy.einsum`` and ``numpy.linalg.norm`` that was
about a quarter of a calibration's time (10 cameras x 10 frames). Here one loop over models and
matches counts the inliers without building the table (the single refitted model's residuals
stay numpy's).

The arithmetic is the einsum form's, in its order, so the distances are bit-identical to it with
numpy 2 on x86-64 and the counts equal (``tests/calib/test_ransac_kernels.py`` compares them):

- rigid 3-D: q_i = ((R_i0 x + R_i2 z) + R_i1 y) + t_i (numpy's einsum sums a length-3 contraction
  in that order), distance sqrt((d_0^2 + d_1^2) + d_2^2);
- planar (floor frame): q_i = (R_i0 x + R_i1 y) + t_i, distance sqrt(d_0^2 + d_1^2), then the
  larger of it and the height difference |h_a - h_b| (NaN if either is NaN, as numpy.maximum).

numba is imported here only; ``import fuseflow.calib`` does not load it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__)  # before any @njit(cache=True) below

__all__ = ["rigid_counts", "planar_counts"]


@njit(cache=True, error_model="numpy", inline="always")
def _rigid_d(M: np.ndarray, h: int, x: float, y: float, z: float, X: float, Y: float, Z: float) -> float:
    d0 = ((M[h, 0, 0] * x + M[h, 0, 2] * z) + M[h, 0, 1] * y + M[h, 0, 3]) - X
    d1 = ((M[h, 1, 0] * x + M[h, 1, 2] * z) + M[h, 1, 1] * y + M[h, 1, 3]) - Y
    d2 = ((M[h, 2, 0] * x + M[h, 2, 2] * z) + M[h, 2, 1] * y + M[h, 2, 3]) - Z
    return np.sqrt((d0 * d0 + d1 * d1) + d2 * d2)


@njit(cache=True, error_model="numpy", inline="always")
def _planar_d(M: np.ndarray, h: int, x: float, y: float, X: float, Y: float, dh: float) -> float:
    d0 = (M[h, 0, 0] * x + M[h, 0, 1] * y + M[h, 0, 3]) - X
    d1 = (M[h, 1, 0] * x + M[h, 1, 1] * y + M[h, 1, 3]) - Y
    r = np.sqrt(d0 * d0 + d1 * d1)
    if np.isnan(dh) or dh > r:
        return dh
    return r


@njit(cache=True, error_model="numpy")
def rigid_counts(models: np.ndarray, A: np.ndarray, B: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """(H,) number of matches k with |R_h A_k + t_h - B_k| < thr[k]: models (H, 4, 4), matches
    A, B (K, 3)."""
    out = np.zeros(models.shape[0], dtype=np.int64)
    for h in range(models.shape[0]):
        c = 0
        for k in range(A.shape[0]):
            if _rigid_d(models, h, A[k, 0], A[k, 1], A[k, 2], B[k, 0], B[k, 1], B[k, 2]) < thr[k]:
                c += 1
        out[h] = c
    return out


@njit(cache=True, error_model="numpy")
def planar_counts(models: np.ndarray, pa: np.ndarray, pb: np.ndarray, dh: np.ndarray, thr: np.ndarray) -> np.ndarray:
    """(H,) number of matches k with max(|R_h pa_k + t_h - pb_k|, dh_k) < thr[k]: floor-frame
    models (H, 4, 4; the 2-D part), floor points pa, pb (K, 2), height differences dh (K,)."""
    out = np.zeros(models.shape[0], dtype=np.int64)
    for h in range(models.shape[0]):
        c = 0
        for k in range(pa.shape[0]):
            if _planar_d(models, h, pa[k, 0], pa[k, 1], pb[k, 0], pb[k, 1], dh[k]) < thr[k]:
                c += 1
        out[h] = c
    return out
