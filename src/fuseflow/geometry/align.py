"""Rigid alignment of two sets of corresponding 3-D points (Kabsch): used to put two
calibrations of one rig into one world frame (pipeline recalibration, GMAC's ``auto`` backbone)."""

from __future__ import annotations

import numpy as np

from fuseflow.errors import ValidationError

__all__ = ["rigid_align"]


def rigid_align(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """4x4 rigid A minimising sum_k |A src_k - dst_k|^2 (Kabsch, no scale).

    Args:
        src, dst: (M, 3) float corresponding points (e.g. camera centres in two world frames),
            M >= 1; the rotation is determined only for M >= 3 non-collinear points.

    Returns:
        (4, 4) float64 dst-from-src rigid transform.
    """
    src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    if src.ndim != 2 or src.shape[1:] != (3,) or src.shape != dst.shape or len(src) < 1:
        raise ValidationError(f"rigid_align: src and dst must both be (M >= 1, 3), got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    H = (src - mu_s).T @ (dst - mu_d)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    A = np.eye(4)
    A[:3, :3] = R
    A[:3, 3] = mu_d - R @ mu_s
    return A
