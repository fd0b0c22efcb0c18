"""CVGC, Cross-View Geometric Consistency (paper III-C-2, eq. 19-21), PyTorch reference.

For a point P_i(x) of camera i and each neighbour j in N_i (|N_i| <= K_max, neighbours.py):

x_ij = pi(K_j E_j E_i^-1 P_i)                                                  (19)
r_ij = |z_ij - D_j(x_ij)| / (z_ij + eps)                                        (20)
omega_geo = (1 / |V_i|) sum_{j in V_i} 1[r_ij < tau], or c(x) when V_i is empty  (21)

Conventions (DESIGN.md 2.3): x_ij is rounded to the nearest pixel (pixel centres at integer
coordinates, as everywhere in the package); j votes only when x_ij is inside its image, j's
view is present and D_j(x_ij) > 0 (no depth = no vote). ``visibility_aware`` (beyond the
paper): when D_j(x_ij) < z_ij by more than tau the point is merely occluded in j and j casts
no vote; only agreement (r < tau) and free-space violations (D_j > z_ij) vote.

Every product below is written element by element, in the order the compiled CPU kernel
(numba_kernels.py) uses, so both paths give the same float32 numbers.
"""

from __future__ import annotations

import numpy as np
import torch

from fuseflow.fuse.neighbours import NeighbourGraph

__all__ = ["relative_transforms", "project_votes", "cvgc_counts", "cvgc_votes", "omega_geo"]


def relative_transforms(T_cam_world: torch.Tensor) -> torch.Tensor:
    """(N, N, 3, 4) float32 [R_ji | t_ji] = E_j E_i^-1 (camera i to camera j), from (N, 4, 4).

    Composed in float64, then rounded once to float32.
    """
    T = T_cam_world.detach().to("cpu", torch.float64)
    R, t = T[:, :3, :3], T[:, :3, 3]
    R_ji = torch.einsum("jab,icb->jiac", R, R)  # R_j R_i^T
    t_ji = t[:, None, :] - torch.einsum("jiab,ib->jia", R_ji, t)
    out = torch.cat([R_ji, t_ji[..., None]], dim=-1).transpose(0, 1)  # index [i, j]
    return out.to(torch.float32).to(T_cam_world.device).contiguous()


def project_votes(
    X: torch.Tensor,
    M_ji: torch.Tensor,
    K_j: torch.Tensor,
    depth_j: torch.Tensor,
    tau: float,
    visibility_aware: bool,
    eps: float = 1e-6,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. (19)-(20) for points of camera i against one neighbour j.

    Args:
        X: (M, 3) float32 points in camera i's frame (metres).
        M_ji: (3, 4) float32 [R_ji | t_ji]. K_j: (3, 3) float32. depth_j: (H, W) float32 metres
            gated to the valid range (0 = no depth).

    Returns:
        agree (M,) bool (r_ij < tau) and vote (M,) bool (j counts in V_i(x)).
    """
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    # python floats holding float32 values: torch rounds them back to the same float32
    m = M_ji.tolist()
    Kj = K_j.tolist()
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
    has = d > 0
    r = torch.abs(zj - d) / (zj + eps)
    agree = has & (r < tau)
    if visibility_aware:
        vote = agree | (has & (d > zj))
    else:
        vote = has
    return agree, vote


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


def _pixel_rays(K: torch.Tensor, h: int, w: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Normalised ray coordinates (xn, yn), each (N, H, W) float32, of every pixel centre."""
    dev = K.device
    v = torch.arange(h, device=dev, dtype=torch.float32)[None, :, None]
    u = torch.arange(w, device=dev, dtype=torch.float32)[None, None, :]
    fx, fy, s = K[:, 0, 0, None, None], K[:, 1, 1, None, None], K[:, 0, 1, None, None]
    cx, cy = K[:, 0, 2, None, None], K[:, 1, 2, None, None]
    yn = (v - cy) / fy
    xn = (u - cx - s * yn) / fx
    return xn.expand(-1, h, w), yn.expand(-1, h, w)


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

    A health measure (pipeline.camera_agreement): a camera whose share agree / votes drops has
    likely moved. depth (N, H, W) float32 metres (0 = none), K (N, 3, 3), T_cam_world (N, 4, 4).
    Returns two (N,) int64 numpy arrays.
    """
    n = depth.shape[0]
    if present is None:
        present = torch.ones(n, dtype=torch.bool, device=depth.device)
    depth = torch.where(present[:, None, None], depth, torch.zeros_like(depth))
    xn, yn = _pixel_rays(K.to(torch.float32), depth.shape[1], depth.shape[2])
    valid = depth > 0
    z = depth[valid]
    X = torch.stack([xn[valid] * z, yn[valid] * z, z], dim=1)
    cam = torch.nonzero(valid)[:, 0]
    agree, votes = cvgc_counts(X, cam, depth, K.to(torch.float32), T_cam_world, graph, present, tau, visibility_aware)
    a = torch.zeros(n, dtype=torch.int64).index_add_(0, cam.cpu(), agree.cpu().to(torch.int64))
    v = torch.zeros(n, dtype=torch.int64).index_add_(0, cam.cpu(), votes.cpu().to(torch.int64))
    return a.numpy(), v.numpy()
