"""CVGC, Cross-View Geometric Consistency (paper III-C-2, eq. 19-21), PyTorch reference.

For a point P_i(x) of camera i and each neighbour j in N_i (|N_i| <= K_max, neighbours.py):

x_ij = pi(K_j E_j E_i^-1 P_i)                                                  (19)
r_ij = |z_ij - D_j(x_ij)| / (z_ij + eps)                                        (20)
omega_geo = (1 / |V_i|) sum_{j in V_i} 1[r_ij < tau], or c(x) when V_i is empty  (21)

The projection, depth lookup and vote of eq. (19)-(20) are shared with GMAC and the pipeline:
they live in :mod:`fuseflow.geometry.agreement` (``project_votes``, with its conventions:
nearest pixel, no depth = no vote, ``visibility_aware``). This module counts those votes per
point and turns them into omega_geo (eq. 21).
"""

from __future__ import annotations

import numpy as np
import torch

from fuseflow.geometry.agreement import project_votes
from fuseflow.geometry.camera import pixel_rays, relative_transforms
from fuseflow.geometry.overlap import NeighbourGraph

__all__ = ["cvgc_counts", "cvgc_votes", "omega_geo"]


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


def omega_geo(agree: torch.Tensor, votes: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Eq. (21): share of agreeing votes, or c(x) where there is no vote. (M,) float32."""
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
