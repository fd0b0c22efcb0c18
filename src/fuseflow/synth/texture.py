"""Procedural colour textures rich enough for SIFT matching between cameras.

Each texture is a square RGB image covering ``TEXTURE_METRES`` of surface. It layers
multi-octave value noise (colour blotches from 2 m down to 1 cm) with random discs, rectangles,
lines and ellipses of random colour and log-uniform size (1 cm to 30 cm), so that every
neighbourhood is distinctive at the scales a VGA camera at 1-5 m resolves (2-10 mm per pixel).
"""

from __future__ import annotations

import functools
import math
import os

import numpy as np

__all__ = ["TEXTURE_PX", "TEXTURE_METRES", "make_textures", "sample_texture", "sample_texture_ref",
           "layer2_uv", "surface_albedo_ref"]  # fmt: skip

TEXTURE_PX = 1024
TEXTURE_METRES = 2.0  # one texture tile spans 2 m: 1.95 mm per texel

# A surface's albedo blends two tiles: its own texture at uv, and the next texture at uv rotated by
# 37 deg and scaled by 1 / 1.37 (period 2.74 m along rotated axes). The two periods are
# incommensurate, so the pattern never repeats on a surface (a single 2 m tile repeated on the 9 m
# studio floor gave SIFT grids of wrong but epipolar-consistent matches, one period apart).
LAYER2_ROT_DEG = 37.0
LAYER2_SCALE = 1.37
LAYER2_SHIFT = (0.37, 0.71)  # metres
CONTRAST = 1.3  # the blend of two independent tiles has 1/sqrt(2) of their contrast; restore most


def layer2_uv(uv_m: np.ndarray) -> np.ndarray:
    """(M, 2) surface coordinates (metres) of the second texture layer."""
    a = math.radians(LAYER2_ROT_DEG)
    c, s = math.cos(a), math.sin(a)
    u, v = uv_m[:, 0], uv_m[:, 1]
    return np.stack(
        [(c * u - s * v) / LAYER2_SCALE + LAYER2_SHIFT[0], (s * u + c * v) / LAYER2_SCALE + LAYER2_SHIFT[1]], 1
    )


def surface_albedo_ref(textures: np.ndarray, tex_id: np.ndarray, uv_m: np.ndarray) -> np.ndarray:
    """(M, 3) float32 albedo in [0, 1] of surface points: the two-layer blend (numpy reference of
    the shading kernel's lookup)."""
    a = sample_texture_ref(textures, tex_id, uv_m)
    b = sample_texture_ref(textures, (tex_id + 1) % len(textures), layer2_uv(uv_m).astype(np.float32))
    return np.clip(0.5 + CONTRAST * (0.5 * (a + b) - 0.5), 0.0, 1.0).astype(np.float32)


def _value_noise(rng: np.random.Generator, size: int) -> np.ndarray:
    import cv2

    out = np.zeros((size, size, 3), np.float32)
    amp = 1.0
    for cells in (2, 5, 13, 34, 89, 233):
        g = rng.uniform(-1, 1, (cells + 1, cells + 1, 3)).astype(np.float32)
        out += amp * cv2.resize(g, (size, size), interpolation=cv2.INTER_CUBIC)
        amp *= 0.7
    out -= out.min()
    out /= max(float(out.max()), 1e-6)
    return out


def _one_texture(rng: np.random.Generator, size: int) -> np.ndarray:
    import cv2

    base = rng.uniform(0.2, 0.8, 3).astype(np.float32)
    tex = (0.45 * base + 0.55 * _value_noise(rng, size)).astype(np.float32)
    px_per_m = size / TEXTURE_METRES
    img = np.ascontiguousarray(tex * 255).astype(np.uint8)
    n_shapes = 1400
    for _ in range(n_shapes):
        col = tuple(int(c) for c in rng.integers(0, 256, 3))
        r = int(math.exp(rng.uniform(math.log(0.006), math.log(0.09))) * px_per_m)
        x, y = (int(v) for v in rng.integers(0, size, 2))
        kind = rng.integers(5)
        if kind == 0:
            cv2.circle(img, (x, y), max(r, 2), col, -1, cv2.LINE_AA)
        elif kind == 1:
            w, h = (int(v) for v in rng.integers(2, max(3, 2 * r), 2))
            cv2.rectangle(img, (x, y), (x + w, y + h), col, -1)
        elif kind == 2:
            ang = rng.uniform(0, 2 * math.pi)
            cv2.line(img, (x, y), (int(x + 2 * r * math.cos(ang)), int(y + 2 * r * math.sin(ang))), col,
                     int(rng.integers(2, 6)), cv2.LINE_AA)  # fmt: skip
        elif kind == 3:
            axes = (max(r, 2), max(int(r * rng.uniform(0.2, 1.0)), 1))
            cv2.ellipse(img, (x, y), axes, float(rng.uniform(0, 180)), 0, 360, col, -1, cv2.LINE_AA)
        else:
            pts = rng.integers(-r - 2, r + 3, (int(rng.integers(3, 6)), 2)) + np.array([x, y])
            cv2.fillPoly(img, [pts.astype(np.int32)], col, cv2.LINE_AA)
    img = cv2.GaussianBlur(img, (3, 3), 0.7)
    # a multiplicative grain on top, so that the inside of large shapes is not flat either
    grain = _value_noise(rng, size)[..., :1]
    out = img.astype(np.float32) / 255.0 * (0.7 + 0.6 * grain)
    return np.clip(out, 0.0, 1.0)


@functools.lru_cache(maxsize=4)
def make_textures(seed: int, count: int = 6, size: int = TEXTURE_PX) -> np.ndarray:
    """(count, size, size, 3) uint8 RGB textures, deterministic for ``seed`` (cached, read-only)."""
    from concurrent.futures import ThreadPoolExecutor

    def one(k: int) -> np.ndarray:
        # own generator per texture: the same textures whatever the thread count (OpenCV's
        # drawing and resizing release the GIL, so two threads use both cores)
        return np.rint(_one_texture(np.random.default_rng([seed, 0x7E87, k]), size) * 255).astype(np.uint8)

    with ThreadPoolExecutor(max_workers=min(count, os.cpu_count() or 1)) as pool:
        out = np.stack(list(pool.map(one, range(count))))
    out.setflags(write=False)
    return out


def sample_texture(textures: np.ndarray, tex_id: np.ndarray, uv_m: np.ndarray) -> np.ndarray:
    """Bilinear lookup with wrap-around (numba kernel; ``sample_texture_ref`` is the numpy twin).

    Args:
        textures: (K, S, S, 3) uint8.
        tex_id: (M,) int texture index per sample.
        uv_m: (M, 2) float32 surface coordinates in metres.
    Returns: (M, 3) float32 RGB in [0, 1].
    """
    from fuseflow.synth.numba_kernels import sample_texture_nb

    S = textures.shape[1]
    uv_px = np.ascontiguousarray(uv_m * (S / TEXTURE_METRES), dtype=np.float32)
    return sample_texture_nb(textures, np.ascontiguousarray(tex_id, dtype=np.int64), uv_px)


def sample_texture_ref(textures: np.ndarray, tex_id: np.ndarray, uv_m: np.ndarray) -> np.ndarray:
    """Plain numpy bilinear lookup, the reference of ``sample_texture``."""
    S = textures.shape[1]
    flat = textures.reshape(-1, 3).astype(np.float32) / 255.0
    p = uv_m * (S / TEXTURE_METRES) - 0.5
    p0 = np.floor(p)
    f = (p - p0).astype(np.float32)
    x0 = p0[:, 0].astype(np.int64) % S
    y0 = p0[:, 1].astype(np.int64) % S
    x1 = (x0 + 1) % S
    y1 = (y0 + 1) % S
    base = tex_id.astype(np.int64) * (S * S)
    fx, fy = f[:, :1], f[:, 1:]
    c00 = flat[base + y0 * S + x0]
    c01 = flat[base + y0 * S + x1]
    c10 = flat[base + y1 * S + x0]
    c11 = flat[base + y1 * S + x1]
    return (c00 * (1 - fx) + c01 * fx) * (1 - fy) + (c10 * (1 - fx) + c11 * fx) * fy
