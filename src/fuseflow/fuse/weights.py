"""The joint fusion weight (paper III-C-2, eq. 22): harmonic mean of c and omega_geo.

omega(x) = 2 c(x) omega_geo(x) / (c(x) + omega_geo(x) + eps)                    (22)

Dual gate: omega is high only when both terms are; omega <= 2 min(c, omega_geo), which lets
the kernels skip CVGC for pixels whose c already rules them out.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch


__all__ = ["joint_weight"]


def joint_weight(c: torch.Tensor, w_geo: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Eq. (22), elementwise. c, w_geo: same shape, float32 in [0, 1]. Returns float32."""
    return 2.0 * c * w_geo / (c + w_geo + eps)
