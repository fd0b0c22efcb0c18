"""ASH, Adaptive Spatial Hashing (paper III-C-3, eq. 23-25), PyTorch reference.

rho(C)   = |{P in C}| / s_c^3                                   coarse cell density  (23)
s_f(C)   = clip(s_0 / sqrt(rho(C) + eps), s_min, s_max)          fine cell size       (24)
h_f(P)   = floor((P - o(C)) / s_f(C)),  o(C) = s_c h_c(P)         fine index           (25)

The (coarse, fine) pair is packed into one int64: 14 bits per coarse axis (offset 8192, so
|P| < 8192 s_c; points beyond are dropped and counted) and 7 bits per fine axis (s_c / s_min
<= 127 is checked by FuseConfig). The structure is built from the frame's points and thrown
away: nothing is kept between frames.

The "w/o ASH" ablation (Table VII) replaces this by one fixed grid (21 bits per axis).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch


__all__ = [
    "CellIndex",
    "adaptive_hash",
    "fixed_hash",
    "COARSE_BITS",
    "COARSE_OFFSET",
    "FINE_BITS",
    "FIXED_BITS",
    "FIXED_OFFSET",
]

COARSE_BITS = 14
COARSE_OFFSET = 1 << (COARSE_BITS - 1)
FINE_BITS = 7
FIXED_BITS = 21
FIXED_OFFSET = 1 << (FIXED_BITS - 1)


@dataclass(frozen=True)
class CellIndex:
    """Per-point cell assignment.

    Attributes:
        keep: (M,) bool, False for points outside the addressable range (dropped).
        key: (M,) int64 packed (coarse, fine) cell key (meaningless where keep is False).
        cell_size: (M,) float32 s_f of the point's coarse cell (or the fixed size).
    """

    keep: torch.Tensor
    key: torch.Tensor
    cell_size: torch.Tensor


def _coarse_coords(P: torch.Tensor, s_c: float) -> tuple[torch.Tensor, torch.Tensor]:
    import torch

    q = torch.floor(P / s_c)
    keep = (q.abs() < COARSE_OFFSET - 1).all(dim=1)
    return q.to(torch.int64), keep


def adaptive_hash(P: torch.Tensor, s_c: float, s0: float, s_min: float, s_max: float, eps: float = 1e-6) -> CellIndex:
    """Eq. (23)-(25) for points P (M, 3) float32 world metres."""
    import torch

    q, keep = _coarse_coords(P, s_c)
    qo = q + COARSE_OFFSET
    ckey = (qo[:, 0] << (2 * COARSE_BITS)) | (qo[:, 1] << COARSE_BITS) | qo[:, 2]
    ckey = torch.where(keep, ckey, torch.full_like(ckey, -1))
    _, inv, counts = torch.unique(ckey, return_inverse=True, return_counts=True)
    count = counts[inv].to(torch.float32)
    rho = count / (s_c**3)  # eq. (23)
    s_f = torch.clamp(s0 / torch.sqrt(rho + eps), s_min, s_max)  # eq. (24)
    origin = q.to(torch.float32) * s_c
    f = torch.floor((P - origin) / s_f[:, None]).to(torch.int64).clamp(0, (1 << FINE_BITS) - 1)  # eq. (25)
    fkey = (f[:, 0] << (2 * FINE_BITS)) | (f[:, 1] << FINE_BITS) | f[:, 2]
    key = (ckey << (3 * FINE_BITS)) | fkey
    return CellIndex(keep, key, s_f)


def fixed_hash(P: torch.Tensor, size: float) -> CellIndex:
    """One fixed grid of cell ``size`` (the "w/o ASH" ablation)."""
    import torch

    q = torch.floor(P / size)
    keep = (q.abs() < FIXED_OFFSET - 1).all(dim=1)
    qo = q.to(torch.int64) + FIXED_OFFSET
    key = (qo[:, 0] << (2 * FIXED_BITS)) | (qo[:, 1] << FIXED_BITS) | qo[:, 2]
    return CellIndex(keep, key, torch.full((P.shape[0],), size, dtype=torch.float32, device=P.device))
