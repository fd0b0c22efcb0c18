"""Noise-aware depth smoothing (fuse/smooth.py): the compiled and torch forms agree, noise
shrinks on a flat surface, edges and missing pixels are kept."""

from __future__ import annotations

import numpy as np
import torch

from fuseflow.fuse.config import FuseConfig
from fuseflow.fuse.smooth import smooth_depth, smooth_depth_numpy, smooth_depth_torch

MODEL = FuseConfig().noise_sigma


def _scene(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Two views: a wall at 3 m with a box at 1.5 m in front, Kinect-like noise, some holes."""
    rng = np.random.default_rng(seed)
    truth = np.full((2, 40, 50), 3.0, np.float32)
    truth[:, 10:25, 15:30] = 1.5
    sig = 0.0012 + 0.0019 * (truth - 0.4) ** 2
    depth = (truth + sig * rng.standard_normal(truth.shape)).astype(np.float32)
    depth[rng.random(truth.shape) < 0.05] = 0.0
    return truth, depth


def test_numpy_and_torch_forms_agree():
    _, depth = _scene()
    for r in (1, 2):
        a = smooth_depth_numpy(depth, r, 2.5, MODEL)
        b = smooth_depth_torch(torch.from_numpy(depth), r, 2.5, MODEL).numpy()
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    a = smooth_depth_numpy(depth, 1, 2.5, MODEL, stride=2)
    b = smooth_depth_torch(torch.from_numpy(depth), 1, 2.5, MODEL, stride=2).numpy()
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6)
    assert (a[:, 1::2] == depth[:, 1::2]).all() and (a[:, :, 1::2] == depth[:, :, 1::2]).all()
    assert isinstance(smooth_depth(torch.from_numpy(depth), 1, 2.5, MODEL), torch.Tensor)
    assert smooth_depth(depth, 0, 2.5, MODEL) is depth


def test_noise_shrinks_and_edges_and_holes_stay():
    truth, depth = _scene(1)
    out = smooth_depth_numpy(depth, 1, 2.5, MODEL)
    assert ((out > 0) == (depth > 0)).all()  # missing stays missing, nothing filled
    inner = np.zeros_like(truth, bool)
    inner[:, 2:-2, 2:-2] = True
    edge = np.zeros_like(truth, bool)
    edge[:, 9:11, 14:31] = edge[:, 24:26, 14:31] = True  # rows along the box's top and bottom edges
    wall = inner & ~edge & (truth == 3.0) & (depth > 0)
    raw = np.abs(depth - truth)[wall].std()
    assert np.abs(out - truth)[wall].std() < 0.55 * raw  # up to 9 samples averaged: ~1/3 expected
    # no pixel mixes the box (1.5 m) and the wall (3 m): every output stays within 10 cm of its truth
    ok = depth > 0
    assert np.abs(out - truth)[ok].max() < 0.1


def _pixel_by_pixel(depth: np.ndarray, r: int, gate: float, stride: int) -> np.ndarray:
    """The filter's definition, one pixel and one window offset at a time, in float32."""
    a, b, z0 = (np.float32(v) for v in MODEL)
    g = np.float32(gate)
    out = depth.copy()
    n_views, h, w = depth.shape
    for i in range(n_views):
        for y in range(0, h, stride):
            for x in range(0, w, stride):
                z = depth[i, y, x]
                if z <= 0:
                    continue
                lim = g * (a + b * ((z - z0) * (z - z0)))
                s = np.float32(0.0)
                n = np.float32(0.0)
                for yy in range(max(y - r, 0), min(y + r, h - 1) + 1):
                    for xx in range(max(x - r, 0), min(x + r, w - 1) + 1):
                        zn = depth[i, yy, xx]
                        if zn > 0 and abs(zn - z) < lim:
                            s = np.float32(s + zn)
                            n = np.float32(n + np.float32(1.0))
                out[i, y, x] = s / n
    return out


def test_compiled_kernel_is_the_definition_bit_for_bit():
    """Borders, holes, every radius and grid: the vectorised kernel sums what the definition sums."""
    _, depth = _scene(2)
    depth = depth[:, 3:20, 11:30].copy()  # 17 x 19: odd sizes, a box edge inside
    for r in (1, 2, 3):
        for stride in (1, 2, 3):
            got = smooth_depth_numpy(depth, r, 2.5, MODEL, stride)
            assert np.array_equal(got, _pixel_by_pixel(depth, r, 2.5, stride)), (r, stride)
