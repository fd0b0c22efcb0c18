"""The kernels' parameters: one NamedTuple of scalars per stage, built from a FuseConfig in
one place (``kernel_params``, ``consensus_params``).

numba takes a NamedTuple of scalars as one argument and types each field by its Python value
(np.float32 -> float32, float -> float64, bool -> boolean, int -> int64). The field types below
are the ones the kernels compute with.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from fuseflow.fuse.ash import COARSE_BITS, COARSE_OFFSET, FIXED_BITS, FIXED_OFFSET
from fuseflow.fuse.config import FuseConfig

__all__ = [
    "PixelParams",
    "CellParams",
    "SelectParams",
    "KernelParams",
    "ConsensusParams",
    "kernel_params",
    "consensus_params",
]

_F = np.float32


class PixelParams(NamedTuple):
    """Scalars of stage 1 (``pixels``): MCM, eq. (27), CVGC, eq. (22), the coarse hash key."""

    alpha: np.float32
    """alpha of eq. (18)."""
    beta: np.float32
    """beta of eq. (18)."""
    eps: np.float32
    """epsilon of eq. (16), (17), (20), (22)."""
    r_c: np.float32
    """r_c of eq. (27): candidates need c(x) > r_c."""
    tau: np.float32
    """tau of eq. (21)."""
    min_weight: np.float32
    """rps.min_weight: candidates also need omega(x) >= this."""
    cell: np.float32
    """Cell size (m) of the first hash level: ash.coarse_size with ASH, ash.fixed_size without."""
    use_mcm: bool
    use_cvgc: bool
    visibility_aware: bool
    qlim: np.float32
    """Largest |cell index| the hash addresses (offset - 1); beyond it a point is out of range."""
    range_priority: bool
    """Also write the ranking value omega / sigma(z) (rps.selection_priority)."""
    noise_a: np.float32
    """a, b, z0 of sigma(z) = a + b (z - z0)^2 (FuseConfig.noise_sigma)."""
    noise_b: np.float32
    noise_z0: np.float32
    mcm_noise: bool
    """Noise-aware MCM (mcm.noise_aware): sigma(z)^2 taken out of g and v (mcm.py)."""
    mcm_max_missing: int
    """mcm.max_missing: gap-tolerant 3x3 window (mcm.py); 0 = any missing -> c = 0."""
    mv_mean: bool
    """Multi-view depth averaging (FuseConfig.cvgc.multiview_mean)."""
    mv_gate2: np.float32
    """cvgc.multiview_gate squared."""
    stride: int
    """FuseConfig.pixel_stride: candidates only at u % stride == 0 of rows v % stride == 0."""
    offset: int
    """Offset added to each cell index before packing (ash.COARSE_OFFSET or FIXED_OFFSET)."""
    bits: int
    """Bits per axis of the packed first-level key (14 with ASH, 21 without)."""


class CellParams(NamedTuple):
    """Scalars of ``fine_pass``: eq. (23)-(25)."""

    s_c: np.float32
    """Coarse cell size (m), or fixed_size without ASH."""
    s0: np.float32
    """s_0 of eq. (24)."""
    s_min: np.float32
    s_max: np.float32
    eps: np.float32
    adaptive: bool
    """ASH on: fine cells of eq. (24)-(25); off: one fine cell per (fixed) coarse cell."""
    fixed_size: np.float32
    s_c3: np.float32
    """s_c^3 (the coarse cell volume of eq. 23), rounded once to float32."""
    offset: int
    """As PixelParams.offset (to unpack a coarse key into the cell's origin)."""
    bits: int
    """As PixelParams.bits."""


class SelectParams(NamedTuple):
    """Scalars of ``select``: eq. (26) and the FPS of eq. (28)."""

    k0: np.float32
    """k_0 of eq. (26)."""
    ratio: np.float32
    """r of eq. (26)."""
    k_max: int
    """Most representatives per fine cell."""
    rho_bar: np.float32
    """Mean fine-cell density of eq. (26) (set after ``fine_pass``; 1 when unused)."""
    fixed_k: bool
    """True: k = k_const in every cell (w/o ASH or w/o RPS); False: eq. (26)."""
    k_const: int
    lone_cell_mean: float
    """rps.lone_cell_mean (0 = off)."""
    lone_keep: int
    """rps.lone_cell_keep: a lone point confirmed by at least this many neighbours is kept
    (0 = never; also 0 without the multi-view mean, which counts the confirmations)."""


class KernelParams(NamedTuple):
    """The three parameter structs of one FuseConfig (``kernel_params``)."""

    pixel: PixelParams
    cell: CellParams
    select: SelectParams


def kernel_params(cfg: FuseConfig) -> KernelParams:
    """The kernels' parameters from ``cfg``'s stage configs (``select.rho_bar`` is 1 until
    ``fine_pass`` ran): ``pixel`` from mcm, cvgc and rps's candidate filter (27), ``cell`` from
    ash, ``select`` from rps."""
    mcm, cvgc, ash, rps = cfg.mcm, cfg.cvgc, cfg.ash, cfg.rps
    adaptive = ash.enabled
    s_c = ash.coarse_size if adaptive else ash.fixed_size
    offset = COARSE_OFFSET if adaptive else FIXED_OFFSET
    bits = COARSE_BITS if adaptive else FIXED_BITS
    qlim = offset - 1
    a, b, z0 = cfg.noise_sigma
    mv_mean = bool(cvgc.multiview_mean and cvgc.enabled)
    pixel = PixelParams(
        alpha=_F(mcm.alpha), beta=_F(mcm.beta), eps=_F(cfg.eps), r_c=_F(rps.r_c), tau=_F(cvgc.tau),
        min_weight=_F(rps.min_weight), cell=_F(s_c), use_mcm=bool(mcm.enabled), use_cvgc=bool(cvgc.enabled),
        visibility_aware=bool(cvgc.visibility_aware), qlim=_F(qlim), range_priority=bool(rps.range_priority),
        noise_a=_F(a), noise_b=_F(b), noise_z0=_F(z0), mcm_noise=bool(mcm.noise_aware),
        mcm_max_missing=int(mcm.max_missing), mv_mean=mv_mean,
        mv_gate2=_F(cvgc.multiview_gate * cvgc.multiview_gate), stride=int(cfg.pixel_stride), offset=offset,
        bits=bits,
    )  # fmt: skip
    cell = CellParams(
        s_c=_F(s_c), s0=_F(ash.s0), s_min=_F(ash.s_min), s_max=_F(ash.s_max), eps=_F(cfg.eps),
        adaptive=bool(adaptive), fixed_size=_F(ash.fixed_size), s_c3=_F(s_c**3), offset=offset, bits=bits,
    )  # fmt: skip
    if rps.enabled and adaptive:
        fixed_k, k_const = False, 0
    elif rps.enabled:  # w/o ASH: rho_bar in place of rho(C_f) -> k = ceil(k0 r)
        fixed_k, k_const = True, int(min(max(np.ceil(rps.k0 * rps.ratio), 1), rps.k_max))
    else:  # w/o RPS
        fixed_k, k_const = True, int(rps.k_fixed)
    select = SelectParams(
        k0=_F(rps.k0), ratio=_F(rps.ratio), k_max=int(rps.k_max), rho_bar=_F(1.0), fixed_k=fixed_k,
        k_const=k_const, lone_cell_mean=float(rps.lone_cell_mean),
        lone_keep=int(rps.lone_cell_keep) if mv_mean else 0,
    )  # fmt: skip
    return KernelParams(pixel, cell, select)


class ConsensusParams(NamedTuple):
    """Scalars of the consensus step inside ``select`` (rps.consensus)."""

    on: bool
    gate: np.float32
    """Gate in sigma(z) (rps.consensus_gate)."""
    noise_a: np.float32
    noise_b: np.float32
    noise_z0: np.float32


def consensus_params(cfg: FuseConfig, on: bool | None = None) -> ConsensusParams:
    """ConsensusParams of ``cfg`` (``on`` overrides cfg.rps.consensus)."""
    a, b, z0 = cfg.noise_sigma
    on = bool(cfg.rps.consensus) if on is None else bool(on)
    return ConsensusParams(on, _F(cfg.rps.consensus_gate), _F(a), _F(b), _F(z0))
