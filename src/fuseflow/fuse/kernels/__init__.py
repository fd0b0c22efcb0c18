"""The compiled CPU path of FUSE: the arithmetic of mcm / cvgc / weights / ash / rps fused into a
few numba loops (docs/design.md 2), one module per stage.

Same float32 operations in the same order as the PyTorch reference, so results agree up to float
rounding of exp / sqrt and float32 reductions (tests/fuse/test_numba.py states the tolerance;
tests/fuse/test_kernels.py tests each stage's kernel against a small numpy reference).

1. ``pixels`` (parallel over blocks of camera rows): MCM (eq. 16-18, ``mcm.mcm_row``), the
   candidate test of eq. (27) *before* any projection (exact: omega <= 2c), back-projection,
   CVGC over <= K_max neighbours (eq. 19-21, ``cvgc.votes``) with the multi-view mean, the joint
   weight (22), the minimum-weight filter, the world point and its coarse cell.
2. ``ash.cells`` / ``ash.scatter``: coarse cells hashed once per run of same-cell candidates of
   a row, then the candidates' pixel indices and points written in coarse-cell order.
3. ``ash.fine_pass`` (parallel over chunks of coarse cells): eq. (24)-(25) fine keys, a stable
   local counting sort, fine-cell densities for rho_bar.
4. ``rps.select``: eq. (26), the weighted FPS of eq. (28) inside every fine cell and the
   consensus (rps.consensus); ``rps.emit`` builds the cloud per coarse cell.

``driver`` runs them over a frame (``fuse_numba``); ``params`` builds their parameters from a
FuseConfig; ``workspace`` holds the per-thread buffers; ``common`` the shared helpers. The
kernels import nothing of fuse but its config, density and ash's key layout (import-linter
contract in pyproject.toml). numba is imported here only; ``import fuseflow`` does not load it.
"""

from fuseflow.fuse.kernels.driver import fuse_numba, gate_depth
from fuseflow.fuse.kernels.params import (
    CellParams,
    ConsensusParams,
    KernelParams,
    PixelParams,
    SelectParams,
    consensus_params,
    kernel_params,
)
from fuseflow.fuse.kernels.workspace import release_workspace

__all__ = [
    "fuse_numba",
    "gate_depth",
    "release_workspace",
    "PixelParams",
    "CellParams",
    "SelectParams",
    "KernelParams",
    "ConsensusParams",
    "kernel_params",
    "consensus_params",
]
