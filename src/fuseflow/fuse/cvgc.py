"""CVGC, Cross-View Geometric Consistency (paper III-C-2, eq. 19-21), PyTorch reference.

For a point P_i(x) of camera i and each neighbour j in N_i (|N_i| <= K_max, neighbours.py):

x_ij = pi(K_j E_j E_i^-1 P_i)                                                  (19)
r_ij = |z_ij - D_j(x_ij)| / (z_ij + eps)                                        (20)
omega_geo = (1 / |V_i|) sum_{j in V_i} 1[r_ij < tau], or c(x) when V_i is empty  (21)

The projection, depth lookup and vote of eq. (19)-(20) are shared with GMAC and the pipeline:
they live in :mod:`fuseflow.geometry.agreement` (``project_votes``, with its conventions:
nearest pixel, no depth = no vote, ``cvgc.visibility_aware``). This module counts those votes per
point and turns them into omega_geo (eq. 21).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from fuseflow.fuse.mcm import noise_sigma_of
from fuseflow.geometry.agreement import project_to_pixel, project_votes
from fuseflow.geometry.camera import pixel_rays, relative_transforms
from fuseflow.geometry.overlap import NeighbourGraph

if TYPE_CHECKING:
    import torch

__all__ = ["cvgc_counts", "cvgc_votes", "omega_geo", "multiview_mean"]


def cvgc_counts(
    X: torch.Tensor,
    cam: torch.Tensor,
    depth: torch.Tensor,
    K: torch.Tensor,
    T_cam_world: torch.Tensor,
    graph: NeighbourGraph,
    present: torch.Tensor,
    tau: float = 0.05,
    visibility_aware: bool = True,
    eps: float = 1e-6,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Agreeing and total votes of eq. (21) for a set of points.

    Args:
        X: (M, 3) float32 points, each in the frame of its own camera ``cam`` (metres).
        cam: (M,) int64 index (into depth / K / T, camera axis) of each point's camera.
        depth: (N, H, W) float32 metres gated to the valid range. K: (N, 3, 3) float32.
        T_cam_world: (N, 4, 4) camera-from-world. graph: neighbours, indices into the same N.
        present: (N,) bool; absent views cast no vote.

    Returns:
        agree (M,) int32 and votes (M,) int32.
    """
    import torch

    dev = X.device
    M_all = relative_transforms(T_cam_world)
    index = graph.index.tolist()
    pres = present.detach().cpu().tolist()
    agree = torch.zeros(X.shape[0], dtype=torch.int32, device=dev)
    votes = torch.zeros(X.shape[0], dtype=torch.int32, device=dev)
    n = depth.shape[0]
    for i in range(n):
        sel = torch.nonzero(cam == i).squeeze(1)
        if sel.numel() == 0:
            continue
        Xi = X[sel]
        for j in index[i]:
            if j < 0 or not pres[j]:
                continue
            a, v = project_votes(Xi, M_all[i, j], K[j], depth[j], tau, visibility_aware, eps)
            agree.index_add_(0, sel, a.to(torch.int32))
            votes.index_add_(0, sel, v.to(torch.int32))
    return agree, votes


def _neighbour_points(
    X: torch.Tensor, M_ji: list, M_ij: list, Kj: list, depth_j: torch.Tensor, eps: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Project X (camera i) into j (eq. 19, ``project_to_pixel``), read D_j at the nearest pixel
    and back-project that pixel at D_j into camera i.

    Returns z_ij (M,), D_j (M,) (0 = no depth / outside / behind), Q (M, 3) in camera i."""
    import torch

    zj, ui, vi, d = project_to_pixel(X, M_ji, Kj, depth_j, eps)
    ynp = (vi - Kj[1][2]) / Kj[1][1]  # pixel_rays' formula for the pixel x_ij
    xnp = ((ui - Kj[0][2]) - Kj[0][1] * ynp) / Kj[0][0]
    qx, qy = xnp * d, ynp * d
    n = M_ij
    Q = [n[r][0] * qx + n[r][1] * qy + n[r][2] * d + n[r][3] for r in range(3)]
    return zj, d, torch.stack(Q, dim=1)


def multiview_mean(
    X: torch.Tensor,
    cam: torch.Tensor,
    depth: torch.Tensor,
    K: torch.Tensor,
    T_cam_world: torch.Tensor,
    graph: NeighbourGraph,
    present: torch.Tensor,
    gate: float,
    noise_sigma: tuple[float, float, float],
    eps: float = 1e-6,
    with_support: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Multi-view depth averaging (beyond the paper, ``FuseConfig.cvgc.multiview_mean``).

    Each point X of camera i becomes X + sum_j r_j (Q_j - X) / (1 + sum_j r_j) over its present
    neighbours j (graph order) whose depth D_j at x_ij (eq. 19) satisfies
    (z_ij - D_j)^2 < gate^2 (sigma(z_ij)^2 + sigma(D_j)^2); Q_j is j's pixel x_ij back-projected
    at D_j, in camera i's frame, and r_j = sigma(z)^2 / sigma(D_j)^2 its inverse-variance weight
    relative to X's own (z = X's depth). The inverse-variance 3D mean of X and the Q_j.

    Args: as ``cvgc_counts``; gate in units of the combined sigma; noise_sigma (a, b, z0).

    Returns:
        (M, 3) float32 averaged points in each point's own camera frame. Same float32
        operations in the same order as the compiled kernel (kernels.pixels). With
        ``with_support`` also (M,) int32 ``support``: how many neighbours passed the gate
        (FuseConfig.rps.lone_cell_keep).
    """
    import torch

    M_all = relative_transforms(T_cam_world).tolist()
    index = graph.index.tolist()
    pres = present.detach().cpu().tolist()
    Kl = K.tolist()
    out = X.clone()
    support = torch.zeros(X.shape[0], dtype=torch.int32, device=X.device)
    g2 = torch.tensor(gate * gate, dtype=torch.float32, device=X.device)
    one = torch.ones((), dtype=torch.float32, device=X.device)
    for i in range(depth.shape[0]):
        sel = torch.nonzero(cam == i).squeeze(1)
        if sel.numel() == 0:
            continue
        Xi = X[sel]
        s0 = noise_sigma_of(Xi[:, 2], noise_sigma)
        v0 = s0 * s0
        num = torch.zeros_like(Xi)
        den = one.expand(Xi.shape[0]).clone()
        for j in index[i]:
            if j < 0 or not pres[j]:
                continue
            zj, d, Q = _neighbour_points(Xi, M_all[i][j], M_all[j][i], Kl[j], depth[j], eps)
            sz, sd = noise_sigma_of(zj, noise_sigma), noise_sigma_of(d, noise_sigma)
            vd = sd * sd
            e = zj - d
            ok = (d > 0) & (e * e < g2 * (sz * sz + vd))
            r = torch.where(ok, v0 / vd, torch.zeros_like(vd))
            num = num + r[:, None] * (Q - Xi)
            den = den + r
            support.index_add_(0, sel, ok.to(torch.int32))
        out[sel] = Xi + num / den[:, None]
    return (out, support) if with_support else out


def omega_geo(agree: torch.Tensor, votes: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Eq. (21): share of agreeing votes, or c(x) where there is no vote. (M,) float32."""
    import torch

    share = agree.to(torch.float32) / votes.clamp_min(1).to(torch.float32)
    return torch.where(votes > 0, share, c)


def cvgc_votes(
    depth: torch.Tensor,
    K: torch.Tensor,
    T_cam_world: torch.Tensor,
    graph: NeighbourGraph,
    tau: float = 0.05,
    present: torch.Tensor | None = None,
    visibility_aware: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """Per camera, the total agreeing and total votes of eq. (21) over its valid pixels.

    A health measure: a camera whose share agree / votes drops has
    likely moved. depth (N, H, W) float32 metres (0 = none), K (N, 3, 3), T_cam_world (N, 4, 4).
    Returns two (N,) int64 numpy arrays.
    """
    import torch

    n = depth.shape[0]
    if present is None:
        present = torch.ones(n, dtype=torch.bool, device=depth.device)
    depth = torch.where(present[:, None, None], depth, torch.zeros_like(depth))
    xn, yn = pixel_rays(K.to(torch.float32), depth.shape[1], depth.shape[2])
    valid = depth > 0
    z = depth[valid]
    X = torch.stack([xn[valid] * z, yn[valid] * z, z], dim=1)
    cam = torch.nonzero(valid)[:, 0]
    agree, votes = cvgc_counts(X, cam, depth, K.to(torch.float32), T_cam_world, graph, present, tau, visibility_aware)
    a = torch.zeros(n, dtype=torch.int64).index_add_(0, cam.cpu(), agree.cpu().to(torch.int64))
    v = torch.zeros(n, dtype=torch.int64).index_add_(0, cam.cpu(), votes.cpu().to(torch.int64))
    return a.numpy(), v.numpy()
