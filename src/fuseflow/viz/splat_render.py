"""A small headless Gaussian-splat renderer for the splat files of ``--format splat``
(``io.splat``): isotropic Gaussians through a pinhole camera, alpha-composited front to back.

Each splat covers the pixels within 3 of its projected standard deviations (``sigma * f / z``,
at least half a pixel, at most ``MAX_RADIUS_PX``); at a pixel at distance d from its centre it
has alpha = opacity * exp(-d^2 / (2 sigma_px^2)). The fragments of every pixel are sorted by depth
and composited: C = sum_i alpha_i T_i c_i with T_i = prod_{j<i} (1 - alpha_j), over a white
background. Numpy only: no display, OpenGL or GPU. For looking, not for measuring (the
reference 3DGS rasteriser also uses anisotropic covariances and view-dependent colour, which
these files do not have).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["render_splats", "save_splat_png", "MAX_RADIUS_PX"]

MAX_RADIUS_PX = 12
"""Largest footprint radius of a splat, pixels (near splats are cut there)."""


def _fragments(uv, sigma_px, z, alpha, width, height):
    """(pixel index, depth, alpha) of every covered pixel of every splat, grouped by footprint."""
    radius = np.clip(np.ceil(3 * sigma_px), 1, MAX_RADIUS_PX).astype(np.int64)
    pix, depth, a, src = [], [], [], []
    for r in np.unique(radius):
        sel = np.nonzero(radius == r)[0]
        dy, dx = np.mgrid[-r : r + 1, -r : r + 1]
        dx, dy = dx.ravel(), dy.ravel()
        cu = np.rint(uv[sel, 0]).astype(np.int64)[:, None] + dx
        cv = np.rint(uv[sel, 1]).astype(np.int64)[:, None] + dy
        d2 = (cu - uv[sel, 0][:, None]) ** 2 + (cv - uv[sel, 1][:, None]) ** 2
        w = alpha[sel][:, None] * np.exp(-0.5 * d2 / sigma_px[sel][:, None] ** 2)
        ok = (cu >= 0) & (cu < width) & (cv >= 0) & (cv < height) & (w > 1.0 / 255)
        pix.append((cv * width + cu)[ok])
        depth.append(np.broadcast_to(z[sel][:, None], ok.shape)[ok])
        a.append(np.minimum(w[ok], 0.99))
        src.append(np.broadcast_to(sel[:, None], ok.shape)[ok])
    return np.concatenate(pix), np.concatenate(depth), np.concatenate(a), np.concatenate(src)


def render_splats(
    xyz: np.ndarray, rgb: np.ndarray, sigma: np.ndarray, opacity: np.ndarray, K: np.ndarray, T_cam_world: np.ndarray,
    width: int, height: int,
) -> np.ndarray:  # fmt: skip
    """(height, width, 3) uint8 RGB picture of isotropic Gaussians (world centres ``xyz`` (M, 3),
    colours ``rgb`` (M, 3) 0-255, standard deviations ``sigma`` (M,) metres, opacities (M,) in
    [0, 1]) seen by the camera (K, T_cam_world) (module docstring)."""
    X = np.asarray(xyz, np.float64) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    front = X[:, 2] > 1e-3
    X, rgb, sigma, opacity = X[front], np.asarray(rgb, np.float64)[front], sigma[front], opacity[front]
    uv = (X @ K.T)[:, :2] / X[:, 2:3]
    sigma_px = np.maximum(sigma * K[0, 0] / X[:, 2], 0.5)
    image = np.ones((height * width, 3))
    if len(X) == 0:
        return (image.reshape(height, width, 3) * 255).astype(np.uint8)
    pix, depth, a, src = _fragments(uv, sigma_px, X[:, 2], np.asarray(opacity, np.float64), width, height)
    order = np.lexsort((depth, pix))
    pix, a, src = pix[order], a[order], src[order]
    la = np.log1p(-a)
    cs = np.cumsum(la)
    start = np.ones(len(pix), bool)
    start[1:] = pix[1:] != pix[:-1]
    first = np.maximum.accumulate(np.where(start, np.arange(len(pix)), 0))
    before = cs[first] - la[first]  # the cumulative sum up to this pixel's first fragment
    weight = a * np.exp(cs - la - before)  # alpha times the transmittance in front of it
    colour = np.zeros((height * width, 3))
    for c in range(3):
        colour[:, c] = np.bincount(pix, weight * rgb[src, c] / 255.0, height * width)
    left = np.ones(height * width)
    ends = np.nonzero(np.append(start[1:], True))[0]
    left[pix[ends]] = np.exp(cs[ends] - before[ends])
    image = colour + left[:, None]
    return (np.clip(image, 0, 1).reshape(height, width, 3) * 255).round().astype(np.uint8)


def save_splat_png(
    splat_ply: str | Path, png: str | Path, width: int = 960, height: int = 720, azimuth_deg: float = 35.0,
    elevation_deg: float = 25.0, up: tuple[float, float, float] = (0.0, 0.0, 1.0),
) -> Path:  # fmt: skip
    """Render a splat file (``io.splat``) from an orbit camera around its bulk
    (``viz.render.orbit_camera``, ``up`` the file's up axis: +z for the floor frame) to ``png``."""
    import cv2

    from fuseflow.io.ply import read_ply_columns
    from fuseflow.io.splat import SH_C0
    from fuseflow.viz.render import orbit_camera

    cols = read_ply_columns(splat_ply)
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1).astype(np.float64)
    rgb = np.clip(np.stack([cols[f"f_dc_{a}"] for a in range(3)], axis=1) * SH_C0 + 0.5, 0, 1) * 255
    sigma = np.exp(np.asarray(cols["scale_0"], np.float64))
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(cols["opacity"], np.float64)))
    K, T = orbit_camera(xyz, azimuth_deg, elevation_deg, up, width, height)
    img = render_splats(xyz, rgb, sigma, opacity, K, T, width, height)
    Path(png).parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(png), img[:, :, ::-1])
    return Path(png)
