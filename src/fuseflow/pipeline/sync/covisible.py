"""Camera-sync scores on co-visible moving surface (the 30-fps sync check).

Per camera pair (i, j) and shift s: camera i's *moving* pixels at frame t (depth closer than
that pixel's median over the loaded frames by more than ``motion_m``), restricted to surface
that camera j sees as well (the surface normal, from i's depth, faces j's centre by more than
``min_cos``), are projected into camera j's depth at frame t + s; the score is the mean of
exp(-r^2 / 2 tau^2) over the points that land on j's valid depth, r the depth residual along j's
ray. Points j sees something in front of count as misses, like points in front of j's surface:
skipping them biases the peak towards shifts where the body moves towards j.

Why co-visible only: the cameras of a ring see different sides of a moving body, and a shift of
a frame or two moves one side's points onto the other's (the walker covers ~3 cm a frame at
30 fps, less than a body's thickness), which biased the all-pixel scorer by a frame. What bias
is left differs with the direction (i against j, or j against i); ``offsets.pair_lags``
keeps a pair only when both directions agree.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from scipy import ndimage

from fuseflow.io.recording import Recording
from fuseflow.types import Rig

__all__ = ["covisible_curves", "load_depths", "moving_masks"]


def load_depths(rec: Recording, sel: list[int], frames: list[int], stride: int) -> tuple[np.ndarray, np.ndarray]:
    """(T, N, H', W') float32 metres (0 = none) of the selected views at positions ``frames``,
    subsampled by ``stride``, and (T, N) bool present."""
    depth, present = [], []
    for t in frames:
        f = rec[t].subset(sel)
        depth.append(f.depth.numpy()[:, ::stride, ::stride])
        present.append(f.present.numpy())
    return np.stack(depth).astype(np.float32), np.stack(present)


def moving_masks(depth: np.ndarray, motion_m: float) -> np.ndarray:
    """(T, N, H, W) bool: valid depth closer than the pixel's median over T by > ``motion_m``
    (something moved in front of the background), kept within 2 pixels of its 3x3 opening. A
    static scene has none."""
    d = np.where(depth > 0, depth, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN pixels: never valid
        bg = np.nanmedian(d, axis=0)
    raw = (depth > 0) & (depth < np.nan_to_num(bg, nan=0.0)[None] - motion_m)
    # an opening (3x3, per image) removes depth noise and the flicker of static depth edges,
    # which are lines a pixel wide: a static studio has ~900 such pixels per 200x150 view and
    # none after it. A moving body keeps its blob, and its silhouette (where most of the motion
    # shows) is taken back from the raw mask within 2 pixels of the blob.
    st = np.zeros((1, 1, 3, 3), dtype=bool)
    st[0, 0] = True
    blob = ndimage.binary_opening(raw, structure=st)
    return ndimage.binary_dilation(blob, structure=st, iterations=2) & raw


def _surface(depth: np.ndarray, mask: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray):
    """World points and unit normals (facing the camera) of the masked pixels of one depth map
    that have all four neighbours valid."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    X = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], -1)
    nrm = np.cross(X[1:-1, 2:] - X[1:-1, :-2], X[2:, 1:-1] - X[:-2, 1:-1])
    ok = mask[1:-1, 1:-1] & (depth[2:, 1:-1] > 0) & (depth[:-2, 1:-1] > 0)
    ok &= (depth[1:-1, 2:] > 0) & (depth[1:-1, :-2] > 0)
    Xc, Nc = X[1:-1, 1:-1][ok], nrm[ok]
    Nc /= np.linalg.norm(Nc, axis=1, keepdims=True) + 1e-12
    Nc *= -np.sign((Nc * Xc).sum(1, keepdims=True))
    R, c = T_world_cam[:3, :3], T_world_cam[:3, 3]
    return Xc @ R.T + c, Nc @ R.T


def _score(
    Xw: np.ndarray,
    Nw: np.ndarray,
    K: np.ndarray,
    T_cam_world: np.ndarray,
    depth: np.ndarray,
    tau: float,
    min_cos: float,
) -> float:
    """Mean Gaussian agreement of points (with normals) that face camera (K, T_cam_world) with its depth."""
    centre = -T_cam_world[:3, :3].T @ T_cam_world[:3, 3]
    to_cam = centre - Xw
    to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True) + 1e-12
    X = Xw[(Nw * to_cam).sum(1) > min_cos] @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    X = X[X[:, 2] > 1e-3]
    h, w = depth.shape
    u = np.round(K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2]).astype(np.int64)
    v = np.round(K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = np.zeros(len(X))
    d[inside] = depth[v[inside], u[inside]]
    ok = inside & (d > 0)
    if ok.sum() < 30:
        return float("nan")
    r = d[ok] - X[ok, 2]
    return float(np.exp(-0.5 * (r / tau) ** 2).mean())


def _scaled_K(K: np.ndarray, stride: int) -> np.ndarray:
    S = np.diag([1.0 / stride, 1.0 / stride, 1.0])
    out = S @ K
    out[0, 2] = (K[0, 2] + 0.5) / stride - 0.5
    out[1, 2] = (K[1, 2] + 0.5) / stride - 0.5
    return out


def covisible_curves(
    rec: Recording,
    rig: Rig,
    sel: list[int],
    positions: list[int],
    shifts: list[int],
    tau: float = 0.03,
    min_cos: float = 0.3,
    motion_m: float = 0.05,
    max_width: int = 320,
) -> tuple[np.ndarray, np.ndarray]:
    """Directed score curves: ``curves[i, j, k]`` is the mean over sampled positions t of camera
    i's co-visible moving surface at t against camera j's depth at t + shifts[k] (NaN where
    never measured); also the (N, N, F, S) per-position scores. Depth maps wider than
    ``max_width`` are subsampled. Cost: (N^2 - N) x F x S projections of the moving pixels."""
    m, n = len(rec), len(rig)
    need = sorted({t + s for t in positions for s in shifts if 0 <= t + s < m} | set(positions))
    at = {t: k for k, t in enumerate(need)}
    stride = max(1, math.ceil(rig.resolution[0] / max_width))
    depth, present = load_depths(rec, sel, need, stride)
    mov = moving_masks(depth, motion_m)
    Ks = [_scaled_K(c.K, stride) for c in rig.cameras]
    Tcw = [np.asarray(c.T_cam_world, dtype=np.float64) for c in rig.cameras]
    per = np.full((n, n, len(positions), len(shifts)), np.nan)
    for f, t in enumerate(positions):
        for i in range(n):
            if not present[at[t], i] or mov[at[t], i].sum() < 30:
                continue
            Xw, Nw = _surface(depth[at[t], i].astype(np.float64), mov[at[t], i], Ks[i], np.linalg.inv(Tcw[i]))
            for j in range(n):
                for k, s in enumerate(shifts):
                    if j != i and t + s in at and present[at[t + s], j]:
                        per[i, j, f, k] = _score(Xw, Nw, Ks[j], Tcw[j], depth[at[t + s], j], tau, min_cos)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pairs never measured stay NaN
        curves = np.nanmean(per, axis=2)
    return curves, per
