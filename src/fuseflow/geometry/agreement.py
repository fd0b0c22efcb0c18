"""Depth agreement between views: projection into another camera, depth lookup, the vote.

The one implementation of "does camera j's depth confirm this point of camera i?" (the
projection and residual of the paper's eq. 19-20). FUSE's CVGC counts these votes per point
(``fuseflow.fuse.cvgc``, eq. 21); GMAC checks a calibration with them
(``depth_agreement``); the pipeline's health monitor watches them per camera pair
(``pair_agreement``). Conventions: x_ij is rounded to the nearest pixel (pixel centres at
integer coordinates); j votes only when x_ij is inside its image, in front of it, and
D_j(x_ij) > 0 (no depth = no vote). ``visibility_aware`` (beyond the paper): a point merely
occluded in j (D_j < z_ij by more than tau) casts no vote; only agreement and free-space
violations (D_j > z_ij) vote.

Every product is written element by element, in the order the compiled CPU kernel
(fuse/kernels/) uses, so both paths give the same float32 numbers.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

import numpy as np

from fuseflow.geometry.camera import pixel_rays, relative_transforms
from fuseflow.geometry.overlap import neighbour_graph
from fuseflow.types import Frame, Rig

if TYPE_CHECKING:
    import torch

__all__ = [
    "one_torch_thread",
    "project_to_pixel",
    "project_votes",
    "pair_agreement",
    "camera_agreement",
    "depth_agreement",
    "subsample_stride",
]


def project_to_pixel(
    X: torch.Tensor, m: list, Kj: list, depth_j: torch.Tensor, eps: float = 1e-6
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Eq. (19): points of camera i projected into camera j, and j's depth at the nearest pixel.

    Args:
        X: (M, 3) float32 points in camera i's frame (metres).
        m: [R_ji | t_ji] as nested lists of python floats holding float32 values (3 x 4), Kj:
            K_j likewise (3 x 3): torch rounds them back to the same float32, so the arithmetic
            is the compiled kernels' (kernels.pixels).
        depth_j: (H, W) float32 metres (0 = no depth).

    Returns:
        z_ij (M,) depth in j, u_ij and v_ij (M,) the nearest pixel (float32 integers), D_j (M,)
        j's depth there (0 where j has none, x_ij is outside the image or X is behind j).
    """
    import torch

    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    xj = m[0][0] * x + m[0][1] * y + m[0][2] * z + m[0][3]
    yj = m[1][0] * x + m[1][1] * y + m[1][2] * z + m[1][3]
    zj = m[2][0] * x + m[2][1] * y + m[2][2] * z + m[2][3]
    h, w = depth_j.shape
    front = zj > eps
    zs = torch.where(front, zj, torch.ones_like(zj))
    xn = xj / zs
    yn = yj / zs
    u = Kj[0][0] * xn + Kj[0][1] * yn + Kj[0][2]
    v = Kj[1][1] * yn + Kj[1][2]
    ui = torch.floor(u + 0.5)
    vi = torch.floor(v + 0.5)
    inside = front & (ui >= 0) & (ui <= w - 1) & (vi >= 0) & (vi <= h - 1)
    flat = (vi.clamp(0, h - 1).to(torch.int64) * w + ui.clamp(0, w - 1).to(torch.int64)).clamp(0, h * w - 1)
    d = torch.where(inside, depth_j.reshape(-1)[flat], torch.zeros_like(zj))
    return zj, ui, vi, d


def project_votes(
    X: torch.Tensor,
    M_ji: torch.Tensor,
    K_j: torch.Tensor,
    depth_j: torch.Tensor,
    tau: float,
    visibility_aware: bool,
    eps: float = 1e-6,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. (19)-(20) for points of camera i against one other camera j.

    Args:
        X: (M, 3) float32 points in camera i's frame (metres).
        M_ji: (3, 4) float32 [R_ji | t_ji] (``relative_transforms``). K_j: (3, 3) float32.
        depth_j: (H, W) float32 metres gated to the valid range (0 = no depth).
        tau: relative residual |z_ij - D_j| / z_ij under which j agrees.

    Returns:
        agree (M,) bool (r_ij < tau) and vote (M,) bool (j counts in V_i(x)).
    """
    import torch

    # python floats holding float32 values: torch rounds them back to the same float32
    zj, _, _, d = project_to_pixel(X, M_ji.tolist(), K_j.tolist(), depth_j, eps)
    has = d > 0
    r = torch.abs(zj - d) / (zj + eps)
    agree = has & (r < tau)
    if visibility_aware:
        vote = agree | (has & (d > zj))
    else:
        vote = has
    return agree, vote


def subsample_stride(height: int, width: int, samples: int) -> int:
    """Pixel stride that leaves about ``samples`` pixels per view (>= 1)."""
    return max(1, int(np.sqrt(height * width / max(samples, 1))))


@contextlib.contextmanager
def one_torch_thread():
    """Run torch's CPU ops on one thread. The agreement measure works on a few thousand samples
    per view: with torch's thread pool beside numba's (the pipeline fuses with numba), each tiny
    op paid for waking and spinning threads. Measured on a 4-camera 320x240 frame, 2 cores: 7-8 ms
    per frame on one thread, 194-509 ms on two while other processes loaded the cores
    (``benchmarks/investigations/run_throughput.py`` measures ``run`` against FUSE alone)."""
    import torch

    n = torch.get_num_threads()
    if n == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(n)


def pair_agreement(
    frame: Frame, rig: Rig, samples: int = 5000, tau: float = 0.05, k_max: int = 4, only: int | None = None
) -> np.ndarray:
    """How well each pair of neighbouring cameras agree on the geometry they both see.

    For camera i, every valid pixel of a subsampled grid (about ``samples`` per view) is
    back-projected and projected into each of its <= ``k_max`` most-overlapping cameras
    (``neighbour_graph``), visibility-aware. j agrees when the relative residual is below
    ``tau``. Both directions of a pair are pooled.

    Args:
        frame: the views, in ``rig`` order (depth (N, H, W) float32 metres). rig: calibrated.

    Returns:
        (N, N) float64, symmetric: S[i, j] = agreeing / voting samples of the pair (i, j) in
        [0, 1]; NaN where the pair cast no vote (not neighbours, a missing view, no depth).
        With ``only = i``, just the pairs of camera i are computed (the others are NaN).
    """
    if frame.depth.device.type != "cpu":
        return _pair_agreement(frame, rig, samples, tau, k_max, only)
    with one_torch_thread():
        return _pair_agreement(frame, rig, samples, tau, k_max, only)


def _pair_agreement(frame: Frame, rig: Rig, samples: int, tau: float, k_max: int, only: int | None) -> np.ndarray:
    import torch

    n, h, w = frame.depth.shape
    stride = subsample_stride(h, w, samples)
    depth = frame.depth[:, ::stride, ::stride]
    depth = torch.where(torch.isfinite(depth) & (depth > 0), depth, torch.zeros_like(depth))
    depth = torch.where(frame.present[:, None, None], depth, torch.zeros_like(depth))
    K = rig.K(device=frame.device).clone()
    K[:, :2, :] /= stride  # pixel centres at integer coordinates: u_sub = u / stride
    M = relative_transforms(rig.T_cam_world(device=frame.device))
    xn, yn = pixel_rays(K, depth.shape[1], depth.shape[2])
    graph = neighbour_graph(rig, k_max=k_max)
    agree = np.zeros((n, n))
    votes = np.zeros((n, n))
    for i in range(n):
        m = depth[i] > 0
        if not bool(m.any()):
            continue
        z = depth[i][m]
        X = torch.stack([xn[i][m] * z, yn[i][m] * z, z], dim=1)
        for j in graph.index[i].tolist():
            if j < 0 or not bool(frame.present[j]) or (only is not None and only not in (i, j)):
                continue
            a, v = project_votes(X, M[i, j], K[j], depth[j], tau, True)
            agree[i, j] += float(a.sum())
            votes[i, j] += float(v.sum())
    agree, votes = agree + agree.T, votes + votes.T
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(votes > 0, agree / votes, np.nan)


def camera_agreement(pairs: np.ndarray) -> np.ndarray:
    """Per camera, the mean agreement of its pairs (``pair_agreement``); NaN with no pair. (N,)"""
    out = np.full(pairs.shape[0], np.nan)
    for i in range(pairs.shape[0]):
        row = pairs[i][np.isfinite(pairs[i])]
        if row.size:
            out[i] = float(row.mean())
    return out


def depth_agreement(frame: Frame, rig: Rig, T_cam_world: dict[str, np.ndarray]) -> dict[str, float | None]:
    """Per placed camera, the mean share of its depth its neighbours confirm under the
    extrinsics ``T_cam_world`` (``pair_agreement``, tau = 5 %); None for a camera with no
    neighbour vote. Cameras of ``frame`` absent from ``T_cam_world`` are left out."""
    placed = [c for c in frame.camera_ids if c in T_cam_world]
    if len(placed) < 2:
        return dict.fromkeys(placed)
    sub = frame.subset([frame.camera_ids.index(c) for c in placed])
    placed_rig = Rig(tuple(rig[c].with_extrinsics(T_cam_world[c]) for c in placed))
    a = camera_agreement(pair_agreement(sub, placed_rig))
    return {c: (float(v) if np.isfinite(v) else None) for c, v in zip(placed, a)}
