"""RPS, Representative Point Selection (paper III-C-3, eq. 26-28), PyTorch reference.

k(C_f) = clip(ceil(k_0 rho(C_f) / rho_bar * r), 1, k_max)                      (26)
S      = {P : c(P) > r_c}  (the caller filters; see rps.min_weight)             (27)
score  = d(P, S_sel) * omega(P)   confidence-weighted farthest point sampling   (28)

rho(C_f) = |{P in C_f}| / s_f^3 and rho_bar is its mean over the occupied fine cells of the
frame. The first pick of a cell is its highest-omega point; each further pick maximises (28).
Points are selected, never averaged. Vectorised over all cells at once: one pass per round,
k_max rounds (no per-cell Python loop).

With ``FuseConfig.rps.range_priority`` the ranking value of eq. (28) (first pick and FPS score)
is omega / sigma(z) (``selection_priority``) instead of omega; the output weight stays omega.

Tie-break (shared with the compiled kernel): equal omega or equal score -> the point that
comes first in input order (camera, then row-major pixel).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from fuseflow.fuse.ash import FINE_BITS
from fuseflow.geometry.noise import sigma_torch

if TYPE_CHECKING:
    import torch

__all__ = ["cell_counts", "select_representatives", "selection_priority", "consensus"]


def cell_counts(
    key: torch.Tensor,
    cell_size: torch.Tensor,
    k0: float,
    ratio: float,
    k_max: int,
    density_adaptive: bool,
    k_fixed: int,
    lone_cell_mean: float = 0.0,
    kept: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Group points by key and apply eq. (26).

    Args:
        key: (M,) int64 cell keys. cell_size: (M,) float32 s_f of each point's cell.
        density_adaptive: True = eq. (26) with the fine-cell density; False with ``rps.k_fixed``
            (the "w/o RPS" ablation) or, when k_fixed is None-like (0), with rho_bar (w/o ASH).
        lone_cell_mean: FuseConfig.rps.lone_cell_mean (adaptive keys only): k = 0 for a one-point fine
            cell whose coarse cell averages at least this many points per occupied fine cell.
        kept: (M,) bool or None: points the lone-cell rule spares (FuseConfig.rps.lone_cell_keep).

    Returns:
        inverse (M,) int64 cell index of each point, counts (C,) int64, k (C,) int64.
    """
    import torch

    uniq, inv, counts = torch.unique(key, return_inverse=True, return_counts=True)
    if not density_adaptive:
        k = torch.full_like(counts, int(k_fixed))
        return inv, counts, k
    size = torch.zeros(uniq.shape[0], dtype=torch.float32, device=key.device).scatter_(0, inv, cell_size)
    rho = counts.to(torch.float32) / size**3
    rho_bar = rho.mean()
    k = torch.ceil(k0 * (rho / rho_bar) * ratio).clamp(1, k_max).to(torch.int64)
    if lone_cell_mean > 0 and counts.numel():
        # coarse cell of each fine cell (the key's high bits, ash.py): candidates per occupied fine cell
        _, cinv = torch.unique(uniq >> (3 * FINE_BITS), return_inverse=True)
        csum = torch.zeros(int(cinv.max()) + 1, dtype=torch.float64, device=key.device).scatter_add_(
            0, cinv, counts.to(torch.float64)
        )
        cnf = torch.bincount(cinv).to(torch.float64)
        lone = (counts == 1) & (csum[cinv] >= lone_cell_mean * cnf[cinv])
        if kept is not None:  # a lone cell's flag is its one point's
            spared = torch.zeros(counts.shape[0], dtype=torch.bool, device=key.device).scatter_(0, inv, kept)
            lone = lone & ~spared
        k = torch.where(lone, torch.zeros_like(k), k)
    return inv, counts, k


def selection_priority(omega: torch.Tensor, z: torch.Tensor, noise_sigma: tuple[float, float, float]) -> torch.Tensor:
    """omega / sigma(z), sigma(z) = a + b (z - z0)^2: the range-aware ranking value of eq. (28).

    Args:
        omega: (M,) float32 joint weights (eq. 22). z: (M,) float32 depth of each point in its
            source camera (m). noise_sigma: (a, b, z0) of FuseConfig.noise_sigma.

    Returns:
        (M,) float32; same float32 operations as the compiled kernel (kernels.pixels).
    """
    return omega / sigma_torch(z, noise_sigma)


def select_representatives(
    P: torch.Tensor, omega: torch.Tensor, inv: torch.Tensor, k: torch.Tensor, k_max: int
) -> torch.Tensor:
    """Confidence-weighted FPS (eq. 28) inside every cell, all cells at once.

    Args:
        P: (M, 3) float32 candidate points (world metres). omega: (M,) float32 ranking value,
            eq. (22)'s omega or ``selection_priority`` (only compared, never output).
        inv: (M,) int64 cell of each point. k: (C,) int64 points to keep per cell.

    Returns:
        (S,) int64 indices into P of the selected points, ordered by cell then pick round.
    """
    import torch

    m = P.shape[0]
    dev = P.device
    n_cells = int(k.shape[0])
    if m == 0:
        return torch.zeros(0, dtype=torch.int64, device=dev)
    idx = torch.arange(m, device=dev)
    # order: cell, then omega descending, then input order (stable sorts)
    o1 = torch.argsort(-omega, stable=True)
    o2 = torch.argsort(inv[o1], stable=True)
    order = o1[o2]
    first = torch.ones(m, dtype=torch.bool, device=dev)
    cell_sorted = inv[order]
    first[1:] = cell_sorted[1:] != cell_sorted[:-1]
    first &= k[cell_sorted] >= 1  # k = 0 (lone_cell_mean): the cell keeps nothing
    pick = [order[first]]  # round 1: highest omega per cell (cells in ascending order)
    picked_cell = [cell_sorted[first]]
    d2 = torch.full((m,), math.inf, dtype=torch.float32, device=dev)
    sel_pt = P[pick[0]]
    sel_cell = picked_cell[0]
    cell_point = torch.zeros((n_cells, 3), dtype=torch.float32, device=dev)
    done = torch.zeros(m, dtype=torch.bool, device=dev)
    done[pick[0]] = True
    for rnd in range(2, int(k_max) + 1):
        if not bool((k >= rnd).any()):
            break
        cell_point[sel_cell] = sel_pt
        diff = P - cell_point[inv]
        d2 = torch.minimum(d2, (diff * diff).sum(dim=1))
        score = torch.sqrt(d2) * omega  # eq. (28)
        score = torch.where(done | (k[inv] < rnd), torch.zeros_like(score), score)
        best = torch.zeros(n_cells, dtype=torch.float32, device=dev).scatter_reduce(0, inv, score, "amax")
        hit = (score == best[inv]) & (score > 0)
        if not bool(hit.any()):
            break
        big = torch.full((n_cells,), m, dtype=torch.int64, device=dev)
        winner = big.scatter_reduce(0, inv[hit], idx[hit], "amin")
        cells = torch.nonzero(winner < m).squeeze(1)
        chosen = winner[cells]
        done[chosen] = True
        pick.append(chosen)
        picked_cell.append(cells)
        # cells that picked nothing keep their last point: re-applying it to d2 is a no-op
        sel_pt, sel_cell = P[chosen], cells
    all_pick = torch.cat(pick)
    all_cell = torch.cat(picked_cell)
    rank = torch.cat([torch.full_like(p, r) for r, p in enumerate(pick)])
    o = torch.argsort(all_cell * (k_max + 1) + rank, stable=True)
    return all_pick[o]


def consensus(
    P: torch.Tensor,
    omega: torch.Tensor,
    cam: torch.Tensor,
    T_world_cam: torch.Tensor,
    T_cam_world: torch.Tensor,
    inv: torch.Tensor,
    sel: torch.Tensor,
    gate: float,
    noise_sigma: tuple[float, float, float],
) -> tuple[torch.Tensor, torch.Tensor]:
    """Multi-view consensus (beyond the paper, ``FuseConfig.rps.consensus``) for the selected points.

    Each representative s (source camera i, centre C_i, unit ray u = (P_s - C_i) / t_s with
    t_s = |P_s - C_i|) is moved along its ray to the omega-weighted mean of t_q = (P_q - C_i) . u
    over the candidates q of its fine cell with |t_q - t_s| < gate * sigma(z_s), z_s its depth
    in camera i (itself included, so the mean exists). Candidates that disagree (another
    surface, a noise tail, the other side of a depth edge) are ignored: no smoothing across
    edges, nothing kept between frames.

    Args:
        P: (M, 3) float32 candidates (world m). omega: (M,) float32 eq. (22) weights.
        cam: (M,) int64 source view (frame order). T_world_cam: (N, 3, 4), T_cam_world:
            (N, 4, 4) float32. inv: (M,) int64 fine cell of each candidate. sel: (S,) int64
            selected candidates. gate: agreement gate in sigma units. noise_sigma: (a, b, z0).

    Returns:
        xyz (S, 3) float32 moved points, support (S,) int16 number of distinct cameras among
        the agreeing candidates (>= 1). Same float32 / float64 arithmetic as the compiled kernel.
    """
    import torch

    dev = P.device
    ns = int(sel.shape[0])
    if ns == 0:
        return P[sel], torch.zeros(0, dtype=torch.int16, device=dev)
    n_cells = int(inv.max()) + 1
    order = torch.argsort(inv, stable=True)
    counts = torch.bincount(inv, minlength=n_cells)
    cstart = torch.cumsum(counts, 0) - counts
    cell_s = inv[sel]
    per = counts[cell_s]
    rep = torch.repeat_interleave(torch.arange(ns, device=dev), per)
    first = torch.cumsum(per, 0) - per
    off = torch.arange(int(rep.shape[0]), device=dev) - first[rep]
    q = order[cstart[cell_s][rep] + off]
    cs = cam[sel]
    C = T_world_cam[cs][:, :, 3]  # (S, 3) camera centres
    Ps = P[sel]
    d = Ps - C
    t_s = torch.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2])
    u = d / t_s[:, None]
    r2 = T_cam_world[cs][:, 2]  # (S, 4) depth row
    z_s = r2[:, 0] * Ps[:, 0] + r2[:, 1] * Ps[:, 1] + r2[:, 2] * Ps[:, 2] + r2[:, 3]
    lim = torch.tensor(gate, dtype=torch.float32, device=dev) * sigma_torch(z_s, noise_sigma)
    dq = P[q] - C[rep]
    ur = u[rep]
    t_q = dq[:, 0] * ur[:, 0] + dq[:, 1] * ur[:, 1] + dq[:, 2] * ur[:, 2]
    ok = torch.abs(t_q - t_s[rep]) < lim[rep]
    w = omega[q].to(torch.float64)
    num = torch.zeros(ns, dtype=torch.float64, device=dev).index_add_(0, rep[ok], (w * t_q.to(torch.float64))[ok])
    den = torch.zeros(ns, dtype=torch.float64, device=dev).index_add_(0, rep[ok], w[ok])
    t_new = torch.where(den > 0, num / torch.clamp(den, min=1e-300), t_s.to(torch.float64)).to(torch.float32)
    xyz = C + t_new[:, None] * u
    n_views = int(T_world_cam.shape[0])
    pair = torch.unique(rep[ok] * n_views + cam[q[ok]])
    support = torch.bincount(pair // n_views, minlength=ns).to(torch.int16)
    return xyz.contiguous(), support
