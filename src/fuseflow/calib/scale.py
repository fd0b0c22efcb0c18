"""Closed-form metric scale estimators (paper eq. 9-12, corrected by docs/design.md section 3).

The backbone's translations are known up to one factor s: T_ji(s) = [R_ji | s t_ji], where
t_ji is the backbone's (unit-scale) relative translation from camera i to camera j. Sensor
points are metric, so for a correspondence (X_i in camera i, Y_j its sensor point in camera j)
the model is Y_j = R_ji X_i + s t_ji + noise, linear in s. Two weighted least-squares minimisers:

* z-only, the corrected eq. (12): with a = (R_ji X_i)_z, b = (t_ji)_z, d = (Y_j)_z,
  ``s = sum w (d - a) b / sum w b^2``. Ill-conditioned when b ~ 0 (sideways baselines).
* full-3D: ``s = sum w t_ji . (Y_j - R_ji X_i) / sum w |t_ji|^2``.
* point-to-plane (default, beyond docs/design.md): the full-3D form in the metric n n^T of camera
  j's surface normal at Y_j, ``s = sum w (n.t)(n.(Y - RX)) / sum w (n.t)^2``. With reprojection
  correspondences Y_j slides with s along camera j's ray, and the point-to-point forms then
  barely move s (the map s -> s* is close to the identity: measured on the synthetic room,
  F(3.3) = 3.301 for a true 3.7); the distance to the tangent plane does not depend on that
  sliding, so the alternation converges in a few steps. Its denominator over sum w |t|^2 is the
  share of the baseline the scene's surfaces can see: small = ill-conditioned.

Functions here are pure numpy over correspondence sets; they know nothing of images.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fuseflow.calib.errors import CalibrationError

__all__ = [
    "Correspondences",
    "ScaleEstimate",
    "scale_terms",
    "closed_form_scale",
    "residuals",
    "huber_weights",
    "naive_median_scale",
]


@dataclass(frozen=True)
class Correspondences:
    """Correspondences of one directed edge i -> j (points of camera i, sensor points of j).

    Attributes:
        i, j: camera indices (rig order).
        RX: (M, 3) float64 metres, R_ji X_i: camera i's sensor points rotated into camera j.
        Y: (M, 3) float64 metres, camera j's sensor points at the corresponding pixels (camera j frame).
        t: (3,) float64, backbone translation t_ji at unit scale (camera j frame).
        w: (M,) float64 >= 0, eq. (8) weights.
        is_match: (M,) bool, True where the pixel in j came from a keypoint match rather than
            from reprojection.
        n: (M, 3) float64 unit surface normals of camera j at Y (camera j frame), zeros where
            unknown (such rows get no weight in the point-to-plane form).
    """

    i: int
    j: int
    RX: np.ndarray
    Y: np.ndarray
    t: np.ndarray
    w: np.ndarray
    is_match: np.ndarray
    n: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.n is None:
            object.__setattr__(self, "n", np.zeros_like(self.Y))

    def __len__(self) -> int:
        return int(self.w.shape[0])

    def subset(self, keep: np.ndarray) -> Correspondences:
        return Correspondences(
            self.i, self.j, self.RX[keep], self.Y[keep], self.t, self.w[keep], self.is_match[keep], self.n[keep]
        )

    def reweighted(self, w: np.ndarray) -> Correspondences:
        return Correspondences(self.i, self.j, self.RX, self.Y, self.t, w, self.is_match, self.n)


@dataclass(frozen=True)
class ScaleEstimate:
    """A closed-form scale and its diagnostics.

    Attributes:
        s: the minimiser (backbone units -> metres).
        numerator, denominator: the sums of the closed form (denominator = its Hessian / 2).
        std_error: sandwich standard error of s (same units as s).
        count: correspondences used (weight > 0).
    """

    s: float
    numerator: float
    denominator: float
    std_error: float
    count: int

    @property
    def relative_std_error(self) -> float:
        return self.std_error / abs(self.s) if self.s else float("inf")


def scale_terms(c: Correspondences, form: str) -> tuple[np.ndarray, np.ndarray]:
    """Per-correspondence (numerator, denominator) terms, unweighted, shape (M,) each."""
    if form == "zonly":
        b = c.t[2]
        return (c.Y[:, 2] - c.RX[:, 2]) * b, np.full(len(c), b * b)
    if form == "full3d":
        return (c.Y - c.RX) @ c.t, np.full(len(c), float(c.t @ c.t))
    if form == "plane":
        nt = c.n @ c.t
        return nt * np.einsum("ij,ij->i", c.n, c.Y - c.RX), nt * nt
    raise CalibrationError(f"unknown closed form {form!r}; expected 'plane', 'full3d' or 'zonly'")


def closed_form_scale(corrs: Sequence[Correspondences], form: str = "plane") -> ScaleEstimate:
    """The weighted least-squares scale over all given edges (eq. 12 corrected, full-3D, plane).

    Raises CalibrationError when no correspondence has weight, or the problem is degenerate
    (all denominators zero: e.g. z-only with purely sideways baselines).
    """
    nums, dens, ws = [], [], []
    for c in corrs:
        if len(c) == 0:
            continue
        n, d = scale_terms(c, form)
        nums.append(n)
        dens.append(d)
        ws.append(c.w)
    if not ws:
        raise CalibrationError("no correspondences to estimate the scale from")
    n, d, w = np.concatenate(nums), np.concatenate(dens), np.concatenate(ws)
    count = int(np.count_nonzero(w > 0))
    W_num, W_den = float(w @ n), float(w @ d)
    if count == 0:
        raise CalibrationError("all correspondence weights are zero; no scale can be estimated")
    scale_ref = float(w @ np.abs(d)) / max(float(w.sum()), 1e-300)
    if not W_den > 1e-12 * max(scale_ref, 1e-300) * w.sum() or W_den <= 0:
        raise CalibrationError(
            f"the {form} closed form is degenerate (sum w b^2 = {W_den:.3g}): the baselines have no "
            "component the estimator can see"
            + (" (z-only with sideways cameras: use full3d)" if form == "zonly" else "")
        )
    s = W_num / W_den
    e = w * (n - s * d)
    se = float(np.sqrt(e @ e)) / W_den
    return ScaleEstimate(s=float(s), numerator=W_num, denominator=W_den, std_error=se, count=count)


def residuals(c: Correspondences, s: float, form: str = "full3d") -> np.ndarray:
    """(M,) metres: the residual each closed form minimises, at scale s (|3-D|, |z| or |n . r|)."""
    r = c.Y - c.RX - s * c.t[None, :]
    if form == "zonly":
        return np.abs(r[:, 2])
    if form == "plane":
        return np.abs(np.einsum("ij,ij->i", c.n, r))
    return np.linalg.norm(r, axis=1)


def huber_weights(r: np.ndarray, delta: float) -> np.ndarray:
    """IRLS Huber weights: 1 for |r| <= delta, delta / |r| beyond."""
    r = np.abs(r)
    return np.where(r <= delta, 1.0, delta / np.maximum(r, 1e-300))


def naive_median_scale(sensor_depth: np.ndarray, backbone_depth: np.ndarray) -> float:
    """The naive baseline scale: median of sensor depth / backbone depth at the backbone's points.

    Args:
        sensor_depth, backbone_depth: (M,) metres and backbone units, same points.
    """
    sensor_depth = np.asarray(sensor_depth, dtype=np.float64)
    backbone_depth = np.asarray(backbone_depth, dtype=np.float64)
    ok = (sensor_depth > 0) & (backbone_depth > 0) & np.isfinite(sensor_depth) & np.isfinite(backbone_depth)
    if ok.sum() < 3:
        raise CalibrationError(
            f"naive median depth ratio needs >= 3 backbone points with sensor depth, got {int(ok.sum())}"
        )
    return float(np.median(sensor_depth[ok] / backbone_depth[ok]))
