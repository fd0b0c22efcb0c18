"""The floor as a calibration target: plane fit in one camera's depth, metric top-down image.

Every camera of a capture rig sees the floor. Fitted in each camera's own depth, the floor plane
fixes that camera's roll, pitch and height above it; re-rendered as an orthographic top-down
image at a fixed metric resolution, the floor looks the same from every camera up to a 2-D
rotation and shift, so plain SIFT matches it across baselines of 90-180 deg where image-plane
matching fails (measured: ``shared/notes/wide-baseline-calibration.md``). The remaining 4 DoF
(yaw and the shift on the floor) come from those matches.

Frames: the *floor frame* of a camera has its origin at the foot of the camera centre on the
plane, z up (the plane normal towards the camera), x along the optical axis projected onto the
floor, y = z x x. Top-down pixel (u, v) is the floor point (x0 + u * res, y0 + v * res, 0).
Units: metres; camera frame with OpenCV axes (x right, y down, z forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FloorPlane", "TopDown", "fit_floor_plane", "render_topdown", "floor_mask"]


@dataclass(frozen=True)
class FloorPlane:
    """A floor plane in one camera's frame: ``normal . X + height = 0`` for floor points X.

    Attributes:
        normal: (3,) float64 unit normal, camera frame, pointing from the floor to the camera
            (up). height: metres, the camera centre's height above the plane (> 0).
        inliers: number of depth points within the inlier band. rms: their RMS distance, metres.
    """

    normal: np.ndarray
    height: float
    inliers: int
    rms: float

    def T_cam_floor(self) -> np.ndarray:
        """(4, 4) float64 camera-from-floor transform (floor frame: see the module docstring)."""
        z = self.normal / np.linalg.norm(self.normal)
        fwd = np.array([0.0, 0.0, 1.0]) - z[2] * z  # optical axis projected onto the floor
        if np.linalg.norm(fwd) < 1e-6:  # looking straight down: use the image's up direction
            fwd = np.array([0.0, -1.0, 0.0]) - z[1] * z
        x = fwd / np.linalg.norm(fwd)
        y = np.cross(z, x)
        T = np.eye(4)
        T[:3, :3] = np.stack([x, y, z], axis=1)  # columns: floor axes in camera coordinates
        T[:3, 3] = -self.height * z  # the foot of the camera centre on the plane
        return T

    def distance(self, X: np.ndarray) -> np.ndarray:
        """(M,) signed height above the plane of camera-frame points X (M, 3), metres."""
        return X @ self.normal + self.height


@dataclass(frozen=True)
class TopDown:
    """A metric orthographic image of the floor seen by one camera.

    Attributes:
        image: (h, w) uint8 grey. mask: (h, w) bool, pixels where the camera sees the floor.
        origin: (2,) float64 floor coordinates (x0, y0) of pixel (0, 0), metres.
        res: metres per pixel.
    """

    image: np.ndarray
    mask: np.ndarray
    origin: np.ndarray
    res: float

    def to_floor(self, uv: np.ndarray) -> np.ndarray:
        """(M, 2) floor coordinates (x, y) in metres of top-down pixels uv (M, 2)."""
        return self.origin[None, :] + np.asarray(uv, dtype=np.float64) * self.res


def fit_floor_plane(
    X: np.ndarray,
    band: float = 0.02,
    max_tilt_deg: float = 60.0,
    min_height: float = 0.2,
    iterations: int = 400,
    seed: int = 0,
) -> FloorPlane | None:
    """RANSAC fit of the floor in one camera's points.

    The floor is taken as the lowest large plane roughly perpendicular to the image's up
    direction: candidate planes must have a normal within ``max_tilt_deg`` of the camera's -y
    axis and lie at least ``min_height`` below the camera; of the best-supported plane and a
    parallel one below it with at least a quarter of its support (a table top over the floor),
    the lower one wins. Refined by least squares on its inliers.

    Args:
        X: (M, 3) float64/float32 camera-frame points, metres (valid depth only).
        band: inlier distance, metres. seed: RANSAC seed (deterministic).

    Returns:
        The plane, or None when no such plane has at least 500 inliers (or 5 % of the points).
    """
    X = np.asarray(X, dtype=np.float64)
    if X.shape[0] < 500:
        return None
    rng = np.random.default_rng(seed)
    if X.shape[0] > 20000:  # the fit needs no more; subsample deterministically
        X = X[rng.choice(X.shape[0], 20000, replace=False)]
    min_support = max(500 * X.shape[0] // 20000, int(0.05 * X.shape[0]), 100)
    best = _ransac_plane(X, band, max_tilt_deg, min_height, iterations, rng)
    if best is None or best[2] < min_support:
        return None
    n, h, support = best
    # a lower parallel plane with enough support is the floor (the best one was a table top)
    below = X[n @ X.T + h < -3 * band]
    if below.shape[0] >= support // 4:
        low = _ransac_plane(below, band, max_tilt_deg, min_height, iterations, rng)
        if low is not None and low[2] >= max(support // 4, min_support // 2) and float(low[0] @ n) > 0.97:
            n, h, support = low
    return _refine_plane(X, n, h, band)


def _ransac_plane(X, band, max_tilt_deg, min_height, iterations, rng):
    up = np.array([0.0, -1.0, 0.0])
    idx = rng.integers(0, X.shape[0], size=(iterations, 3))
    a, b, c = X[idx[:, 0]], X[idx[:, 1]], X[idx[:, 2]]
    n = np.cross(b - a, c - a)
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 1e-9
    n = n[ok] / norm[ok, None]
    a = a[ok]
    n *= np.where(n @ up < 0, -1.0, 1.0)[:, None]  # orient up
    h = -np.einsum("ij,ij->i", n, a)
    ok = (n @ up > np.cos(np.radians(max_tilt_deg))) & (h > min_height)
    if not ok.any():
        return None
    n, h = n[ok], h[ok]
    support = np.zeros(len(n), dtype=np.int64)
    for k in range(0, len(n), 64):  # bounded memory: 64 x M distances at a time
        d = np.abs(n[k : k + 64] @ X.T + h[k : k + 64, None])
        support[k : k + 64] = (d < band).sum(axis=1)
    k = int(np.argmax(support))
    return n[k], float(h[k]), int(support[k])


def _refine_plane(X, n, h, band) -> FloorPlane | None:
    for _ in range(3):
        inl = X[np.abs(X @ n + h) < band]
        if inl.shape[0] < 3:
            return None
        c = inl.mean(axis=0)
        _, _, vt = np.linalg.svd(inl - c, full_matrices=False)
        m = vt[2] * (1.0 if vt[2] @ n > 0 else -1.0)
        n, h = m, float(-m @ c)
    d = X @ n + h
    inl = np.abs(d) < band
    return FloorPlane(normal=n, height=h, inliers=int(inl.sum()), rms=float(np.sqrt(np.mean(d[inl] ** 2))))


def floor_mask(depth: np.ndarray, K: np.ndarray, plane: FloorPlane, band: float) -> np.ndarray:
    """(H, W) bool: pixels whose depth point lies within ``band`` metres of the plane."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    xn = (u - K[0, 2]) / K[0, 0]
    yn = (v - K[1, 2]) / K[1, 1]
    d = depth * (xn * plane.normal[0] + yn * plane.normal[1] + plane.normal[2]) + plane.height
    return (depth > 0) & (np.abs(d) < band)


def render_topdown(
    grey: np.ndarray,
    depth: np.ndarray,
    K: np.ndarray,
    plane: FloorPlane,
    res: float = 0.005,
    max_range: float = 6.0,
    max_pixels: int = 1600,
    band: float = 0.03,
) -> TopDown | None:
    """Re-render the floor seen by one camera as a metric top-down image.

    Each top-down pixel is a floor point; it is projected into the camera (bilinear colour
    lookup) and kept where the camera's depth at that pixel agrees with the plane (the floor is
    visible there, not occluded), within ``band`` + 2 % of the depth.

    Args:
        grey: (H, W) uint8 image. depth: (H, W) float32 metres (0 = none), gated to the range.
        K: (3, 3) intrinsics. plane: the camera's floor. res: metres per top-down pixel.
        max_range: floor farther than this from the camera is left out, metres.
        max_pixels: cap on each side of the image (the far part is cropped first).

    Returns:
        The TopDown, or None when the floor covers fewer than 1000 top-down pixels.
    """
    import cv2

    fm = floor_mask(depth, K, plane, band)
    if fm.sum() < 200:
        return None
    T = plane.T_cam_floor()
    hh, ww = depth.shape
    v, u = np.nonzero(fm)
    z = depth[v, u].astype(np.float64)
    Xc = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    P = (Xc - T[:3, 3]) @ T[:3, :3]  # floor coordinates
    keep = np.hypot(P[:, 0], P[:, 1]) < max_range
    if keep.sum() < 200:
        return None
    P = P[keep]
    lo = np.percentile(P[:, :2], 0.5, axis=0)
    hi = np.percentile(P[:, :2], 99.5, axis=0)
    span = max_pixels * res
    hi[0] = min(hi[0], lo[0] + span)  # keep the near floor (sharper) when cropping
    if hi[1] - lo[1] > span:
        mid = 0.5 * (lo[1] + hi[1])
        lo[1], hi[1] = mid - span / 2, mid + span / 2
    nx, ny = int(np.ceil((hi[0] - lo[0]) / res)) + 1, int(np.ceil((hi[1] - lo[1]) / res)) + 1
    gx = lo[0] + np.arange(nx) * res
    gy = lo[1] + np.arange(ny) * res
    fx, fy = np.meshgrid(gx, gy)  # (ny, nx): image row = y, column = x
    Pc = fx[..., None] * T[:3, 0] + fy[..., None] * T[:3, 1] + T[:3, 3]
    zc = Pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        pu = K[0, 0] * Pc[..., 0] / zc + K[0, 1] * Pc[..., 1] / zc + K[0, 2]
        pv = K[1, 1] * Pc[..., 1] / zc + K[1, 2]
    inside = (zc > 0.1) & (pu >= 0) & (pu <= ww - 1) & (pv >= 0) & (pv <= hh - 1)
    pu = np.where(inside, pu, -1).astype(np.float32)
    pv = np.where(inside, pv, -1).astype(np.float32)
    img = cv2.remap(grey, pu, pv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    ui = np.clip(np.rint(pu), 0, ww - 1).astype(np.int64)
    vi = np.clip(np.rint(pv), 0, hh - 1).astype(np.int64)
    d = depth[vi, ui]
    visible = inside & (d > 0) & (np.abs(d - zc) < band + 0.02 * zc)
    if visible.sum() < 1000:
        return None
    img = np.where(visible, img, 0).astype(np.uint8)
    return TopDown(image=img, mask=visible, origin=np.array([lo[0], lo[1]]), res=float(res))
