"""``BackboneResult``: what every backbone returns (its own module, so that the backbones and
the registry in ``__init__`` do not import each other)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fuseflow.calib.errors import CalibrationError

__all__ = ["BackboneResult"]


@dataclass(frozen=True)
class BackboneResult:
    """Output of a backbone for an N-camera frame (rig order).

    Attributes:
        T_cam_world: (N, 4, 4) float64 camera-from-world poses in backbone units (arbitrary
            scale); rows of unregistered cameras are the identity and must be ignored.
        registered: (N,) bool, cameras the backbone placed.
        features: (N, D) float64 per-camera features F_i for eq. (8), or None.
        overlap: (N, N) float64 in [0, 1] pairwise overlap, or None (then RC measures it).
        matches: {(i, j), i < j: (uv_i (K, 2), uv_j (K, 2)) float64 pixels} verified keypoint
            matches, or None.
        points: {i: (uv (M, 2) pixels, z (M,) backbone-unit depth in camera i)} the backbone's
            own depth at some pixels (for the naive median-depth-ratio baseline), or None.
        name: backbone name. info: timings, counts, notes (JSON-serialisable).
        metric: True when the translations are already in metres (scale 1 by construction,
            e.g. the ``rgbd`` backbone); GMAC's scale s* is then a check, not an estimate.
        tracks: metric keypoint correspondences behind the poses, for the depth-aware joint
            refinement (:mod:`fuseflow.calib.joint_refine`): tuples (camera id a, camera id b,
            X_a (m, 3), X_b (m, 3) the same points in each camera's frame in metres, sigma (m,)
            metres). Empty for scale-free backbones. Not written to calib.json.
    """

    T_cam_world: np.ndarray
    registered: np.ndarray
    features: np.ndarray | None = None
    overlap: np.ndarray | None = None
    matches: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] | None = None
    points: dict[int, tuple[np.ndarray, np.ndarray]] | None = None
    name: str = ""
    info: dict[str, Any] = field(default_factory=dict)
    metric: bool = False
    tracks: tuple = ()

    def __post_init__(self) -> None:
        T = np.asarray(self.T_cam_world, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4):
            raise CalibrationError(f"backbone {self.name!r}: poses must be (N, 4, 4), got {T.shape}")
        reg = np.asarray(self.registered, dtype=bool)
        if reg.shape != (T.shape[0],):
            raise CalibrationError(f"backbone {self.name!r}: registered must be ({T.shape[0]},), got {reg.shape}")
        if not np.all(np.isfinite(T[reg])):
            raise CalibrationError(f"backbone {self.name!r}: non-finite poses for registered cameras")
        object.__setattr__(self, "T_cam_world", T)
        object.__setattr__(self, "registered", reg)
        n = T.shape[0]
        if self.features is not None:
            F = np.asarray(self.features, dtype=np.float64)
            if F.ndim != 2 or F.shape[0] != n:
                raise CalibrationError(f"backbone {self.name!r}: features must be (N={n}, D), got {F.shape}")
            object.__setattr__(self, "features", F)
        if self.overlap is not None:
            ov = np.asarray(self.overlap, dtype=np.float64)
            if ov.shape != (n, n):
                raise CalibrationError(f"backbone {self.name!r}: overlap must be ({n}, {n}), got {ov.shape}")
            object.__setattr__(self, "overlap", np.clip(ov, 0.0, 1.0))
