"""MCM, Measurement Confidence Modelling (paper III-C-1, eq. 16-18), PyTorch reference.

c(x) = exp(-alpha g(x) - beta v(x)) * 1[z > delta] * 1[z < z_max]            (18)
g(x) = ||grad D(x)||_2 / (z + eps), central differences                       (16)
v(x) = Var_{r x r window} D / (z^2 + eps)                                      (17)

A pixel whose gradient stencil or variance window touches a pixel with no depth (0, outside
the valid range, or outside the image) is an edge pixel: c = 0 (docs/design.md 2.1: it must not
look smooth). The defaults of alpha and beta (``config.MCM_ALPHA`` / ``MCM_BETA``) are derived
at the end of this docstring.

Noise-aware MCM (``FuseConfig.mcm.noise_aware``, beyond the paper): the sensor's expected axial
noise sigma(z) = a + b (z - z0)^2 (``FuseConfig.noise_sigma``) is taken out of both measures
before they are divided by z, so that range noise alone does not read as roughness:

g_n(x) = sqrt(max(gx^2 + gy^2 - sigma^2, 0)) / (z + eps)     (E[gx^2 + gy^2] = sigma^2 for noise)
v_n(x) = max(Var - sigma^2, 0) / (z^2 + eps)                  (E[Var] = (8/9) sigma^2 for 3x3)

A slope or an edge keeps its geometric part (it is many sigma), a smooth surface far away
(Kinect sigma / z = 0.6 % at 4 m) no longer loses c to its noise (derivation below).

Gap-tolerant window (``FuseConfig.mcm.max_missing`` = m > 0, beyond the paper and docs/design.md's
"a neighbour with no depth makes the pixel an edge pixel"): a 3x3 window with at most m of its
8 neighbours missing is measured on the pixels it has: mean and variance over the valid pixels
(in row-major order), each central difference replaced by the one-sided difference with the
centre when one side is missing (0 when both are). Isolated dropouts and the range cut no
longer erase far surfaces (docs/fuse.md, Quality); pixels on the image border keep c = 0.

The defaults (Kinect-class structured-light noise: sigma(z) = 1.2 mm + 1.9 mm * (z - 0.4)^2,
z in metres, a relative noise sigma/z of about 0.3 % at 1.5-2.5 m, f ~ 525 px at 640x480).

Smooth surface at 45 degrees, depth z: neighbouring pixels differ by ~ z / f (ray spacing
z / f, slope tan 45 = 1), so the central-difference gradient gives g ~ 1 / f = 0.0019, plus
noise sqrt(2) * 0.003 / 2 per axis -> g ~ 0.004-0.005 in total. The 3x3 variance of a plane
at 45 degrees is (2/3) (z/f)^2 -> v = 2.4e-6, plus the noise (0.003)^2 = 9e-6 -> v ~ 1.2e-5.
Requirement "c > 0.8":  alpha * 0.005 + beta * 1.2e-5 < -ln 0.8 = 0.223.

Depth edge with a 5 % jump: central difference across it gives g = 0.05 / 2 = 0.025; a 3x3
window holding 3 (or 6) pixels of the far side has variance (1/3)(2/3)(0.05 z)^2, so
v = 5.6e-4. Requirement "c < 0.05": alpha * 0.025 + beta * 5.6e-4 > -ln 0.05 = 3.0.

The variance term separates the two cases 47x, the gradient term only 5x, so beta carries
the edge test: beta = 6000 gives 3.36 on the edge alone and 0.072 on the smooth surface;
alpha = 20 adds 0.5 on the edge and 0.1 on the smooth surface. Check: smooth c = exp(-0.17)
= 0.84 > 0.8, edge c = exp(-3.86) = 0.021 < 0.05; both numbers are checked on synthetic depth
maps (tests/fuse/test_components.py::test_mcm_defaults_meet_the_design_targets).

Noise-aware MCM (MCMConfig.noise_aware, beyond the paper). The numbers above hold at 1.5-2.5 m
only: Kinect noise is 0.47 % of depth at 3 m and 0.65 % at 4 m, so a smooth surface there gets
v ~ (0.0065)^2 = 4.2e-5 and g ~ 0.006 from noise alone -> c = exp(-0.25 - 0.12) = 0.69 < 0.8
(measured: median c 0.74 at 4 m, 0.70 at 4.45 m on the 45-degree test plane). With noise_aware
the expected noise is removed before dividing by z: gx^2 + gy^2 - sigma(z)^2
(central differences: E = 2 (sigma^2 / 2)) and Var - sigma(z)^2 (3x3: E = (8/9) sigma^2, the
1/9 extra is margin). What is left of a smooth 45-degree surface is its geometry, g = 1 / f =
0.0019 and v = (2/3) / f^2 = 2.4e-6 at every range -> alpha g + beta v = 0.05, c ~ 0.95; a
5 % edge loses at most sigma^2 at the far end of the Kinect range (4.5 m: sigma / z = 0.73 %):
v = 5.6e-4 - 5.3e-5 = 5.1e-4 and g = sqrt(0.025^2 - 0.0073^2) = 0.024 -> 3.04 + 0.48 = 3.5,
c = 0.03 < 0.05. So alpha and beta stay. Measured on noisy synthetic maps at 0.5-4.45 m with
the Kinect sigma(z): smooth median c 0.97-1.00 (10th percentile >= 0.80), 5 % edge median
c <= 0.03 (tests/fuse/test_components.py::test_noise_aware_mcm_meets_the_targets_at_every_range);
without it the smooth median falls to 0.74 at 4 m. A grid over alpha in {20, 30, 40} and beta
in {6000, 8000, 10000} traded the smooth 10th percentile (0.82 -> 0.73) for the edge tail,
so the paper-range values were kept.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch.nn.functional as F

from fuseflow.geometry.noise import sigma_torch

if TYPE_CHECKING:
    import torch

__all__ = ["valid_depth", "confidence", "gradient_and_variance", "noise_sigma_of", "tolerant_gradient_and_variance"]


def valid_depth(depth: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Depth with every value outside (lo, hi) set to 0.

    depth: (N, H, W) float32 metres. lo, hi: (N,) float32 metres (per camera: the larger of
    delta and the camera's range minimum; the smaller of z_max and its maximum).
    """
    import torch

    ok = (depth > lo[:, None, None]) & (depth < hi[:, None, None])
    return torch.where(ok, depth, torch.zeros_like(depth))


def noise_sigma_of(z: torch.Tensor, noise_sigma: tuple[float, float, float]) -> torch.Tensor:
    """sigma(z) = a + b (z - z0)^2 (metres) for depth z (metres, any shape, float32); the same
    float32 operations as the compiled kernel."""
    return sigma_torch(z, noise_sigma)


def gradient_and_variance(
    depth: torch.Tensor,
    window: int = 3,
    eps: float = 1e-6,
    noise_sigma: tuple[float, float, float] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """g (eq. 16), v (eq. 17) and the "whole neighbourhood has depth" mask.

    depth: (N, H, W) float32 metres, 0 = no depth. noise_sigma: (a, b, z0) of the sensor's
    axial noise (FuseConfig.noise_sigma) for the noise-aware measures g_n, v_n (module
    docstring); None = eq. (16)-(17) as written. Returns g, v (N, H, W) float32 and
    full (N, H, W) bool: True where the pixel and every pixel of its window has depth.
    """
    import torch

    n, h, w = depth.shape
    r = window // 2
    k = window * window
    # (N, k, H, W) window samples; zero padding: outside the image = no depth
    patches = F.unfold(depth[:, None], window, padding=r).reshape(n, k, h, w)
    centre = k // 2
    gx = (patches[:, centre + 1] - patches[:, centre - 1]) * 0.5
    gy = (patches[:, centre + window] - patches[:, centre - window]) * 0.5
    z = depth
    gsq = gx * gx + gy * gy
    full = (patches > 0).all(dim=1)
    # two-pass variance (mean first), float32: exact enough for beta ~ 1e4 and matched by the
    # compiled kernel, unlike E[x^2] - E[x]^2
    mean = patches.mean(dim=1, keepdim=True)
    var = ((patches - mean) ** 2).mean(dim=1)
    if noise_sigma is not None:
        s = noise_sigma_of(z, noise_sigma)
        s2 = s * s
        gsq = torch.clamp(gsq - s2, min=0.0)
        var = torch.clamp(var - s2, min=0.0)
    g = torch.sqrt(gsq) / (z + eps)
    v = var / (z * z + eps)
    return g, v, full


def tolerant_gradient_and_variance(
    depth: torch.Tensor, eps: float = 1e-6, noise_sigma: tuple[float, float, float] | None = None
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """g, v of the gap-tolerant 3x3 window (module docstring) and the number of missing
    neighbours (N, H, W) int64 (9 at the image border). Float32 operations in the order of the
    compiled kernel (kernels.pixels)."""
    import torch

    n, h, w = depth.shape
    P = F.unfold(depth[:, None], 3, padding=1).reshape(n, 9, h, w)
    ok = P > 0
    zero = torch.zeros_like(depth)
    cnt = ok.sum(dim=1)
    s = zero
    for k in range(9):  # sequential, row-major: the kernel's order
        s = s + torch.where(ok[:, k], P[:, k], zero)
    mean = s / cnt.clamp(min=1).to(torch.float32)
    var = zero
    for k in range(9):
        e = P[:, k] - mean
        var = var + torch.where(ok[:, k], e * e, zero)
    var = var / cnt.clamp(min=1).to(torch.float32)
    half = torch.tensor(0.5, dtype=torch.float32)

    def diff(a: int, b: int) -> torch.Tensor:
        import torch

        pa, pb = P[:, a], P[:, b]
        va, vb = ok[:, a], ok[:, b]
        return torch.where(va & vb, (pb - pa) * half, torch.where(vb, pb - depth, torch.where(va, depth - pa, zero)))

    gx, gy = diff(3, 5), diff(1, 7)
    gsq = gx * gx + gy * gy
    if noise_sigma is not None:
        sg = noise_sigma_of(depth, noise_sigma)
        s2 = sg * sg
        gsq = torch.clamp(gsq - s2, min=0.0)
        var = torch.clamp(var - s2, min=0.0)
    g = torch.sqrt(gsq) / (depth + eps)
    v = var / (depth * depth + eps)
    missing = 9 - cnt
    border = torch.zeros((h, w), dtype=torch.bool, device=depth.device)
    border[0, :] = border[-1, :] = True
    border[:, 0] = border[:, -1] = True
    return g, v, torch.where(border[None], torch.full_like(missing, 9), missing)


def confidence(
    depth: torch.Tensor,
    alpha: float,
    beta: float,
    window: int = 3,
    eps: float = 1e-6,
    use_mcm: bool = True,
    noise_sigma: tuple[float, float, float] | None = None,
    max_missing: int = 0,
) -> torch.Tensor:
    """c(x) of eq. (18) for every pixel.

    Args:
        depth: (N, H, W) float32 metres, already gated to the valid range (``valid_depth``),
            0 = no depth (the 1[z > delta] 1[z < z_max] factors of eq. 18).
        alpha, beta: eq. (18) weights. window: r of eq. (17). eps: eq. (16)-(17).
        use_mcm: False = "w/o MCM" (Table VII): c = 1 wherever there is depth.
        noise_sigma: (a, b, z0) for the noise-aware g_n, v_n (FuseConfig.mcm.noise_aware); None = off.
        max_missing: FuseConfig.mcm.max_missing (gap-tolerant 3x3 window, module docstring);
            0 = docs/design.md's rule (any missing neighbour: c = 0). > 0 needs window = 3.

    Returns:
        (N, H, W) float32 in [0, 1]; 0 where there is no depth or the window is incomplete.
    """
    import torch

    valid = depth > 0
    if not use_mcm:
        return valid.to(torch.float32)
    if max_missing > 0:
        g, v, missing = tolerant_gradient_and_variance(depth, eps, noise_sigma)
        c = torch.exp(-alpha * g - beta * v)
        return torch.where(valid & (missing <= max_missing), c, torch.zeros_like(c))
    g, v, full = gradient_and_variance(depth, window, eps, noise_sigma)
    c = torch.exp(-alpha * g - beta * v)
    return torch.where(valid & full, c, torch.zeros_like(c))
