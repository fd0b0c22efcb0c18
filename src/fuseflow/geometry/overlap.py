"""Field-of-view overlap and the neighbour graph of CVGC (paper III-C-2, N_i with |N_i| <= K_max;
docs/design.md 2.2).

For camera i, overlap(i, j) = share of i's frustum samples (a pixel grid times depths spread
over i's depth range) that land inside camera j's image, in front of j. The neighbours of i
are the <= K_max cameras with the largest overlap above ``min_overlap``. The graph depends on
the calibration only (intrinsics, resolution, depth ranges, extrinsics), so it is computed once
per calibration and cached; nothing about the scene enters it.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from fuseflow.errors import ValidationError
from fuseflow.types import Rig

__all__ = ["NeighbourGraph", "neighbour_graph", "fov_overlap"]

_GRID = (16, 12)  # frustum samples across the image (u, v)
_DEPTHS = 8  # samples along each ray
_FAR_CAP = 8.0  # metres: the far end of the sampled range (depth_range max of 10 m is noise)


@dataclass(frozen=True)
class NeighbourGraph:
    """Bounded neighbour sets of a rig.

    Attributes:
        index: (N, K) int64 rig indices of each camera's neighbours, best first, -1 = none.
        overlap: (N, K) float32 overlap share of each neighbour, 0 where index is -1.
    """

    index: torch.Tensor
    overlap: torch.Tensor

    @property
    def k(self) -> int:
        return int(self.index.shape[1])

    def to(self, device: torch.device | str) -> NeighbourGraph:
        return NeighbourGraph(self.index.to(device), self.overlap.to(device))


def fov_overlap(rig: Rig) -> np.ndarray:
    """(N, N) float64 overlap share overlap[i, j] (0 on the diagonal). Needs extrinsics."""
    n = len(rig)
    T = np.stack([c.T_cam_world for c in rig.cameras]) if rig.is_calibrated else None
    if T is None:
        missing = [c.id for c in rig.cameras if c.T_cam_world is None]
        raise ValidationError(f"the neighbour graph needs extrinsics; cameras without: {missing}")
    out = np.zeros((n, n))
    for i, ci in enumerate(rig.cameras):
        us = (np.arange(_GRID[0]) + 0.5) * ci.width / _GRID[0]
        vs = (np.arange(_GRID[1]) + 0.5) * ci.height / _GRID[1]
        lo = max(ci.depth_range[0], 0.1)
        hi = max(min(ci.depth_range[1], _FAR_CAP), lo * 1.01)
        zs = np.geomspace(lo, hi, _DEPTHS)
        uu, vv, zz = np.meshgrid(us, vs, zs, indexing="ij")
        pix = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)])
        X_cam = np.linalg.inv(ci.K) @ pix * zz.ravel()
        T_wi = np.linalg.inv(T[i])
        X_w = T_wi[:3, :3] @ X_cam + T_wi[:3, 3:4]
        for j, cj in enumerate(rig.cameras):
            if j == i:
                continue
            X_j = T[j][:3, :3] @ X_w + T[j][:3, 3:4]
            z = X_j[2]
            front = z > 1e-6
            uvw = cj.K @ X_j
            with np.errstate(divide="ignore", invalid="ignore"):
                u = uvw[0] / z
                v = uvw[1] / z
            inside = front & (u >= -0.5) & (u < cj.width - 0.5) & (v >= -0.5) & (v < cj.height - 0.5)
            out[i, j] = float(inside.mean())
    return out


@functools.lru_cache(maxsize=32)
def _graph_cached(key: bytes, ref: _RigRef, k_max: int, min_overlap: float) -> tuple[np.ndarray, np.ndarray]:
    rig = ref.rig
    ov = fov_overlap(rig)
    n = len(rig)
    k = max(1, min(k_max, n - 1)) if n > 1 else 1
    index = np.full((n, k), -1, dtype=np.int64)
    share = np.zeros((n, k), dtype=np.float32)
    for i in range(n):
        order = sorted((-ov[i, j], j) for j in range(n) if j != i and ov[i, j] > min_overlap)[:k]
        for slot, (neg, j) in enumerate(order):
            index[i, slot] = j
            share[i, slot] = -neg
    return index, share


def _calibration_key(rig: Rig) -> bytes:
    parts = []
    for c in rig.cameras:
        parts += [c.K.tobytes(), np.float64(c.width).tobytes(), np.float64(c.height).tobytes()]
        parts += [np.asarray(c.depth_range).tobytes(), c.T_cam_world.tobytes()]
    return b"".join(parts)


def neighbour_graph(rig: Rig, k_max: int = 4, min_overlap: float = 0.05) -> NeighbourGraph:
    """The <= ``k_max`` most-overlapping cameras of each camera (docs/design.md 2.2), cached.

    The cache key is the calibration itself (intrinsics, resolution, depth ranges, extrinsics),
    so a new calibration gives a new graph and the same one is never computed twice.
    Cameras with no neighbour above ``min_overlap`` get an all -1 row (CVGC then falls back to
    c(x), eq. 21). Returns a CPU NeighbourGraph.
    """
    if not isinstance(rig, Rig):
        raise ValidationError(f"rig must be a fuseflow.Rig, got {type(rig).__name__}")
    if not rig.is_calibrated:
        missing = [c.id for c in rig.cameras if c.T_cam_world is None]
        raise ValidationError(f"the neighbour graph needs extrinsics; cameras without: {missing}")
    index, share = _graph_cached(_calibration_key(rig), _RigRef(rig), int(k_max), float(min_overlap))
    return NeighbourGraph(torch.from_numpy(index.copy()), torch.from_numpy(share.copy()))


class _RigRef:
    """Carries the rig into the lru cache without taking part in the key (Rig is unhashable)."""

    __slots__ = ("rig",)

    def __init__(self, rig: Rig) -> None:
        self.rig = rig

    def __hash__(self) -> int:
        return 0

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _RigRef)
