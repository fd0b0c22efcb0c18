"""Density control (beyond the paper): the s_0 of eq. (24) that gives a frame about N points.

The number of output points falls with s_0 (fine cells grow as s_f ~ s_0 / sqrt(rho), eq. 24),
roughly as a power law M ~ s_0^-p, but p is not the 2 of an ideal surface: k per cell (eq. 26),
sparse cells and the s_min / s_max clips bend it (p ~ 1.1-1.3 measured on simulated rigs). So
s_0 is searched by the secant method in log-log space from the configured s_0 (first step with
p = 1.2), each step costing only the fine hash of eq. (23)-(25) and the k of eq. (26) per
fine cell on the candidates that MCM and CVGC already produced (the compiled path counts
min(k, n) per fine cell, which is what the FPS of eq. (28) selects unless points coincide; the
final pass at the chosen s_0 selects exactly).

A small budget also picks a coarser pixel grid (FuseConfig.budget_stride, ``budget_stride``):
every stage before the hash costs per candidate, and at an equal point count the candidates of
a coarser grid, selected with a finer s_0, scored better than every pixel selected with a
coarser s_0 (docs/fuse.md, Presets, "Point budget").
"""

from __future__ import annotations

import math
from collections.abc import Callable

__all__ = [
    "search_s0",
    "fit_s0",
    "with_s0",
    "budget_stride",
    "grid_spacing",
    "BUDGET_FILL",
    "BUDGET_MAX_STRIDE",
    "BUDGET_SHORT",
    "COUNT_EVALS",
    "PASS_EVALS",
]

#: budget_stride takes a grid of stride s only for a budget of at most this many points per
#: valid pixel on it (target <= BUDGET_FILL V / s^2). The most a grid gives (every candidate
#: kept, s_0 -> 0) measured 0.87-0.98 V / s^2 on ICL, hocap-8rs and the simulated ring; 0.75
#: leaves the search a 15 % margin below the least of them. At 0.76 V / 4 the stride-2 grid still
#: met the budget (-2 %) and beat every pixel on the simulated ring; at 1.07 V / 4 it ended
#: 12-16 % short (docs/fuse.md, Presets, "Point budget").
BUDGET_FILL = 0.75
#: Most evaluations of the s_0 search when each is a count pass (hash and eq. 26 only, the
#: compiled path): with multiview_mean the count falls more steeply with s_0 on small frames
#: (4-camera 160x120: -20 % for +2.5 % s_0) and 6 left it 11 % off.
COUNT_EVALS = 8
#: Most evaluations of the s_0 search when each is a whole FUSE pass (the PyTorch reference).
PASS_EVALS = 6
#: The coarsest grid budget_stride picks (stride 3 was the coarsest measured for quality).
BUDGET_MAX_STRIDE = 3
#: A coarser grid whose cloud ends this far below the budget is replaced by pixel_stride's.
BUDGET_SHORT = 0.10


def with_s0(cfg, s0: float):
    """``cfg`` (a FuseConfig) with s_0 = ``s0``, target_points cleared, and the clips of eq. (24)
    scaled along (s_max up to the coarse cell when s_0 grows, s_min down to coarse / 127 when it
    shrinks): with fixed clips the count stops following s_0 (an 8-camera studio frame never
    went below ~18 k points with s_max = 5 cm)."""
    ash = cfg.ash
    f = s0 / ash.s0
    s_max = min(ash.coarse_size, ash.s_max * max(1.0, f))
    s_min = max(ash.coarse_size / 127.0, ash.s_min * min(1.0, f))
    return cfg.replace(ash={"s0": s0, "s_min": min(s_min, s_max), "s_max": s_max}, target_points=None)


def search_s0(
    count_at: Callable[[float], int],
    s0: float,
    target: int,
    first_count: int | None = None,
    max_evals: int = 6,
    tol: float = 0.03,
    s0_range: tuple[float, float] = (0.05, 500.0),
) -> tuple[float, int]:
    """The s_0 whose point count ``count_at(s_0)`` is within ``tol`` of ``target`` (or the best
    of at most ``max_evals`` evaluations, besides ``first_count`` = count_at(s0) when given).
    Secant steps in log-log space; once two evaluations bracket the target, a step that would
    leave the bracket is replaced by its geometric midpoint (the count is a step function of
    s_0 on small frames: +7 % in s_0 moved a 4-camera 160x120 frame from 7062 to 5028 points,
    and the plain secant then oscillated around the target). Returns (s_0, its count).
    """
    if target < 1:
        raise ValueError(f"target must be >= 1, got {target}")
    m0 = count_at(s0) if first_count is None else first_count
    best = (abs(m0 - target), s0, m0)
    s_prev, m_prev, p = s0, m0, 1.2
    lo = hi = None  # s_0 with a count above / below the target (counts fall with s_0)
    if m0 > target:
        lo = s0
    elif m0 < target:
        hi = s0
    for _ in range(max_evals):
        if best[0] <= tol * target or m_prev <= 0:
            break
        s = min(max(s_prev * (m_prev / target) ** (1.0 / p), s0_range[0]), s0_range[1])
        if lo is not None and hi is not None and not min(lo, hi) < s < max(lo, hi):
            s = math.sqrt(lo * hi)
        if s == s_prev:
            break
        m = count_at(s)
        best = min(best, (abs(m - target), s, m))
        if m > target:
            lo = s if lo is None or s > lo else lo
        elif m < target:
            hi = s if hi is None or s < hi else hi
        if m > 0 and m != m_prev:
            p_new = math.log(m_prev / m) / math.log(s / s_prev)
            p = min(max(p_new, 0.3), 4.0) if math.isfinite(p_new) and p_new > 0 else p
        s_prev, m_prev = s, m
    return best[1], best[2]


def fit_s0(cfg, count_at: Callable[[float], int], first_count: int | None = None, whole_passes: bool = False):
    """The policy of FuseConfig.target_points, for every backend: ``cfg`` (a FuseConfig with
    target_points) at the s_0 of ``search_s0`` from cfg.ash.s0 (``with_s0``: clips scaled, target
    cleared). ``count_at(s_0)``: the frame's point count at s_0; ``first_count``: count_at(cfg.ash.s0)
    when already known; ``whole_passes``: each count is a whole FUSE pass (PASS_EVALS
    evaluations, else COUNT_EVALS)."""
    evals = PASS_EVALS if whole_passes else COUNT_EVALS
    s0, _ = search_s0(count_at, cfg.ash.s0, cfg.target_points, first_count, max_evals=evals)
    return with_s0(cfg, s0)


def budget_stride(stride: int, target: int, valid_pixels: int) -> int:
    """FuseConfig.budget_stride: the pixel grid for a budget of ``target`` points on a frame of
    ``valid_pixels`` valid depth pixels, the largest s in stride .. BUDGET_MAX_STRIDE with
    target <= BUDGET_FILL valid_pixels / s^2 (``stride``, the configured pixel_stride, when
    none is coarser)."""
    if target < 1:
        raise ValueError(f"target must be >= 1, got {target}")
    s = stride
    while s < BUDGET_MAX_STRIDE and target <= BUDGET_FILL * valid_pixels / (s + 1) ** 2:
        s += 1
    return s


def grid_spacing(depth, K, stride: int, quantile: float, step: int = 8) -> float:
    """How far apart, in metres, the candidates of a ``stride``-pixel grid lie on a surface
    facing the camera, ``stride`` z / f, at ``quantile`` of the frame's valid depth pixels (the
    value of rank floor(quantile (n - 1)) of the n counted), counted on every ``step``-th pixel
    of every ``step``-th row. ``depth``: (N, H, W) metres, 0 = none; ``K``: (N, 3, 3); numpy
    arrays, or tensors on any device; f = sqrt(fx fy) per view. 0.0 for a frame without depth."""
    import numpy as np

    sub = depth[:, ::step, ::step]
    if isinstance(sub, np.ndarray):
        f = np.sqrt(np.asarray(K[:, 0, 0], np.float32) * np.asarray(K[:, 1, 1], np.float32)).reshape(-1, 1, 1)
        v = (sub / f).ravel()
        v = v[v > 0]
        if v.size == 0:
            return 0.0
        k = int(quantile * (v.size - 1))
        return float(np.partition(v, k)[k]) * stride
    import torch  # a tensor: the rank on its device, one number back

    f = torch.sqrt(K[:, 0, 0] * K[:, 1, 1]).to(sub.dtype).view(-1, 1, 1)
    v = (sub / f).reshape(-1)
    v = v[v > 0]
    if v.numel() == 0:
        return 0.0
    k = int(quantile * (v.numel() - 1))
    return float(torch.kthvalue(v.float(), k + 1).values) * stride
