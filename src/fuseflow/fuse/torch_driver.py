"""The PyTorch path of FUSE (the readable reference, any device), beside the compiled CPU path
of fuse/kernels/driver.py; ``fuse/api.py`` prepares the frame and dispatches to one of them.

Stages, each in its own module: MCM (mcm.py, eq. 16-18) -> back-projection -> CVGC over the
neighbour graph (cvgc.py, eq. 19-21) -> joint weight (weights.py, eq. 22) -> ASH (ash.py,
eq. 23-25) -> RPS (rps.py, eq. 26-28). ``fuse_torch`` has the contract of
``kernels.fuse_numba``: the prepared inputs of api.py in, (cloud, valid pixels, candidates,
out-of-range) out.
"""

from __future__ import annotations

import numpy as np
import torch

from fuseflow.fuse.config import FuseConfig
from fuseflow.fuse.mcm import valid_depth
from fuseflow.types import FusedCloud

__all__ = ["fuse_torch", "gate_depth"]


def gate_depth(
    depth: torch.Tensor, lo: np.ndarray, hi: np.ndarray, present: torch.Tensor
) -> tuple[torch.Tensor, tuple[int, ...]]:
    """(gated depth (N, H, W) float32 metres, valid pixels per view): depth outside each view's
    [lo, hi] and every pixel of an absent view set to 0 (kernels.gate_depth's torch twin)."""
    dev = depth.device
    depth = valid_depth(depth, torch.from_numpy(lo).to(dev), torch.from_numpy(hi).to(dev))
    depth = torch.where(present[:, None, None], depth, torch.zeros_like(depth)).contiguous()
    return depth, tuple((depth > 0).flatten(1).sum(dim=1).tolist())


def fuse_torch(p, cfg: FuseConfig) -> tuple[FusedCloud, int, int, int]:
    """FUSE over api's prepared inputs (torch tensors on one device): (cloud, valid pixels,
    candidates, out-of-range). With ``target_points``, s0 is searched with density.fit_s0 over
    whole passes (this path is not split into stages the search could reuse)."""
    if cfg.target_points is None:
        return _fuse_once(p, cfg)
    from fuseflow.fuse.density import fit_s0, with_s0

    first = _fuse_once(p, with_s0(cfg, cfg.ash.s0))
    fit = fit_s0(cfg, lambda s: len(_fuse_once(p, with_s0(cfg, s))[0]), len(first[0]), whole_passes=True)
    return first if fit.ash.s0 == cfg.ash.s0 else _fuse_once(p, fit)


def _to_world(X: torch.Tensor, cam: torch.Tensor, T_wc: torch.Tensor) -> torch.Tensor:
    """X (M, 3) camera-frame points of cameras ``cam`` -> world, elementwise (kernel order)."""
    m = T_wc[cam]  # (M, 3, 4)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    cols = [m[:, a, 0] * x + m[:, a, 1] * y + m[:, a, 2] * z + m[:, a, 3] for a in range(3)]
    return torch.stack(cols, dim=1)


def _fuse_once(p, cfg: FuseConfig) -> tuple[FusedCloud, int, int, int]:
    """One pass of the stages at ``cfg``: (cloud, valid pixels, candidates, out-of-range)."""
    from fuseflow.fuse.ash import adaptive_hash, fixed_hash
    from fuseflow.fuse.cvgc import cvgc_counts, multiview_mean, omega_geo
    from fuseflow.fuse.mcm import confidence
    from fuseflow.fuse.rps import cell_counts, consensus, select_representatives, selection_priority
    from fuseflow.fuse.weights import joint_weight
    from fuseflow.geometry.camera import pixel_rays

    depth = p.depth
    dev = depth.device
    n, h, w = depth.shape
    mcm, cvgc, ash, rps = cfg.mcm, cfg.cvgc, cfg.ash, cfg.rps
    ns = cfg.noise_sigma if mcm.noise_aware else None
    c = confidence(depth, mcm.alpha, mcm.beta, mcm.window, cfg.eps, mcm.enabled, ns, mcm.max_missing)  # (16)-(18)
    valid_pixels = int((depth > 0).sum())
    cand = (c > rps.r_c) & (depth > 0)  # eq. (27), applied before CVGC: exact, it only needs c
    if cfg.pixel_stride > 1:  # every s-th pixel of every s-th row (FuseConfig.pixel_stride)
        s = cfg.pixel_stride
        on_grid = torch.zeros((h, w), dtype=torch.bool, device=dev)
        on_grid[::s, ::s] = True
        cand = cand & on_grid
    xn, yn = pixel_rays(p.K, h, w)
    z = depth[cand]
    X = torch.stack([xn[cand] * z, yn[cand] * z, z], dim=1)
    nz = torch.nonzero(cand)
    cam, pix = nz[:, 0], nz[:, 1] * w + nz[:, 2]
    c_m = c[cand]
    if cvgc.enabled:
        agree, votes = cvgc_counts(
            X, cam, depth, p.K, p.T_cam_world, p.graph, p.present, cvgc.tau, cvgc.visibility_aware, cfg.eps
        )
        w_geo = omega_geo(agree, votes, c_m)  # eq. (21)
    else:
        w_geo = c_m  # "w/o CVGC": eq. (21)'s no-vote case for every point
    omega = joint_weight(c_m, w_geo, cfg.eps)  # eq. (22)
    keep = omega >= rps.min_weight
    X, cam, pix, omega = X[keep], cam[keep], pix[keep], omega[keep]
    z_s = X[:, 2]  # the pixel's own depth ranks it (range_priority), before any averaging
    kept = None  # points the lone-cell rule spares (rps.lone_cell_keep)
    if cvgc.multiview_mean and cvgc.enabled:
        X, support = multiview_mean(X, cam, depth, p.K, p.T_cam_world, p.graph, p.present, cvgc.multiview_gate,
                                    cfg.noise_sigma, cfg.eps, with_support=True)  # fmt: skip
        if rps.lone_cell_keep > 0:
            kept = support >= rps.lone_cell_keep
    P = _to_world(X, cam, p.T_world_cam)
    if ash.enabled:
        cells = adaptive_hash(P, ash.coarse_size, ash.s0, ash.s_min, ash.s_max, cfg.eps)  # eq. (23)-(25)
    else:
        cells = fixed_hash(P, ash.fixed_size)
    candidates = int(P.shape[0])
    out_of_range = int((~cells.keep).sum())
    if out_of_range:
        P, cam, pix, omega, z_s = P[cells.keep], cam[cells.keep], pix[cells.keep], omega[cells.keep], z_s[cells.keep]
        kept = None if kept is None else kept[cells.keep]
        key, size = cells.key[cells.keep], cells.cell_size[cells.keep]
    else:
        key, size = cells.key, cells.cell_size
    if rps.enabled and ash.enabled:
        inv, _, k = cell_counts(key, size, rps.k0, rps.ratio, rps.k_max, True, 0, rps.lone_cell_mean, kept)  # eq. (26)
    elif rps.enabled:  # w/o ASH: rho_bar in place of rho(C_f) -> k = ceil(k0 r)
        k_const = int(min(max(np.ceil(rps.k0 * rps.ratio), 1), rps.k_max))
        inv, _, k = cell_counts(key, size, rps.k0, rps.ratio, rps.k_max, False, k_const)
    else:  # w/o RPS: fixed k
        inv, _, k = cell_counts(key, size, rps.k0, rps.ratio, rps.k_max, False, rps.k_fixed)
    rank = selection_priority(omega, z_s, cfg.noise_sigma) if rps.range_priority else omega
    sel = select_representatives(P, rank, inv, k, rps.k_max)  # eq. (28)
    cam_s = cam[sel]
    rgb = p.color.reshape(n, h * w, 3)[cam_s, pix[sel]]
    if rps.consensus:
        xyz, support = consensus(
            P, omega, cam, p.T_world_cam, p.T_cam_world, inv, sel, rps.consensus_gate, cfg.noise_sigma
        )
    else:
        xyz, support = P[sel].contiguous(), None
    cloud = FusedCloud(xyz, rgb.contiguous(), omega[sel].contiguous(), p.rig_index[cam_s].to(torch.int16), support)
    return cloud, valid_pixels, candidates, out_of_range
