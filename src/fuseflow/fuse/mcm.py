"""MCM, Measurement Confidence Modelling (paper III-C-1, eq. 16-18), PyTorch reference.

c(x) = exp(-alpha g(x) - beta v(x)) * 1[z > delta] * 1[z < z_max]            (18)
g(x) = ||grad D(x)||_2 / (z + eps), central differences                       (16)
v(x) = Var_{r x r window} D / (z^2 + eps)                                      (17)

A pixel whose gradient stencil or variance window touches a pixel with no depth (0, outside
the valid range, or outside the image) is an edge pixel: c = 0 (DESIGN.md 2.1: it must not
look smooth). The parameter derivation is next to the defaults in config.py.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["valid_depth", "confidence", "gradient_and_variance"]


def valid_depth(depth: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Depth with every value outside (lo, hi) set to 0.

    depth: (N, H, W) float32 metres. lo, hi: (N,) float32 metres (per camera: the larger of
    delta and the camera's range minimum; the smaller of z_max and its maximum).
    """
    ok = (depth > lo[:, None, None]) & (depth < hi[:, None, None])
    return torch.where(ok, depth, torch.zeros_like(depth))


def gradient_and_variance(
    depth: torch.Tensor, window: int = 3, eps: float = 1e-6
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """g (eq. 16), v (eq. 17) and the "whole neighbourhood has depth" mask.

    depth: (N, H, W) float32 metres, 0 = no depth. Returns g, v (N, H, W) float32 and
    full (N, H, W) bool: True where the pixel and every pixel of its window has depth.
    """
    n, h, w = depth.shape
    r = window // 2
    k = window * window
    # (N, k, H, W) window samples; zero padding: outside the image = no depth
    patches = F.unfold(depth[:, None], window, padding=r).reshape(n, k, h, w)
    centre = k // 2
    gx = (patches[:, centre + 1] - patches[:, centre - 1]) * 0.5
    gy = (patches[:, centre + window] - patches[:, centre - window]) * 0.5
    z = depth
    g = torch.sqrt(gx * gx + gy * gy) / (z + eps)
    full = (patches > 0).all(dim=1)
    # two-pass variance (mean first), float32: exact enough for beta ~ 1e4 and matched by the
    # compiled kernel, unlike E[x^2] - E[x]^2
    mean = patches.mean(dim=1, keepdim=True)
    var = ((patches - mean) ** 2).mean(dim=1)
    v = var / (z * z + eps)
    return g, v, full


def confidence(
    depth: torch.Tensor,
    alpha: float,
    beta: float,
    window: int = 3,
    eps: float = 1e-6,
    use_mcm: bool = True,
) -> torch.Tensor:
    """c(x) of eq. (18) for every pixel.

    Args:
        depth: (N, H, W) float32 metres, already gated to the valid range (``valid_depth``),
            0 = no depth (the 1[z > delta] 1[z < z_max] factors of eq. 18).
        alpha, beta: eq. (18) weights. window: r of eq. (17). eps: eq. (16)-(17).
        use_mcm: False = "w/o MCM" (Table VII): c = 1 wherever there is depth.

    Returns:
        (N, H, W) float32 in [0, 1]; 0 where there is no depth or the window is incomplete.
    """
    valid = depth > 0
    if not use_mcm:
        return valid.to(torch.float32)
    g, v, full = gradient_and_variance(depth, window, eps)
    c = torch.exp(-alpha * g - beta * v)
    return torch.where(valid & full, c, torch.zeros_like(c))
