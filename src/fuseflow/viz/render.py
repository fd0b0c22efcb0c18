"""A small headless point-cloud renderer: z-buffered square splats through a pinhole camera.

No display, OpenGL or EGL is needed (CI and servers have none), so the demo and
``fuseflow view --save-png`` work everywhere. It is for looking, not for measuring.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import FusedCloud

__all__ = ["orbit_camera", "render_cloud", "save_cloud_png", "weight_colors"]


def orbit_camera(
    xyz: np.ndarray,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 30.0,
    up: tuple[float, float, float] = (0.0, -1.0, 0.0),
    width: int = 960,
    height: int = 720,
    fov_deg: float = 50.0,
) -> tuple[np.ndarray, np.ndarray]:
    """A camera (K, T_cam_world) that frames the bulk of ``xyz`` (2nd-98th percentile box).

    ``up`` is the world's up direction; the default (0, -1, 0) suits OpenCV-style worlds where
    the first camera's -y is up (ICL, simulator rigs). The camera orbits the box centre at
    ``azimuth_deg`` around ``up`` and ``elevation_deg`` above the horizontal plane.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or len(xyz) == 0:
        raise ValidationError(f"orbit_camera: expected (M, 3) points with M > 0, got {xyz.shape}")
    lo, hi = np.percentile(xyz, 2, axis=0), np.percentile(xyz, 98, axis=0)
    centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-3)
    up_v = np.asarray(up, dtype=np.float64)
    up_v /= np.linalg.norm(up_v)
    # a horizontal basis (a, b) orthogonal to up
    a = np.cross(up_v, [1.0, 0.0, 0.0] if abs(up_v[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(up_v, a)
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    direction = np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * up_v
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    half_fov = np.arctan(0.5 * min(width, height) / f)  # the narrower of the two image axes
    dist = radius / np.sin(half_fov) * 1.05
    eye = centre + dist * direction
    z = centre - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up_v, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z])
    T[:3, 3] = -T[:3, :3] @ eye
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    return K, T


def weight_colors(weight: np.ndarray) -> np.ndarray:
    """Map weights in [0, 1] to RGB uint8 with OpenCV's TURBO colormap (blue low, red high)."""
    import cv2

    w = np.clip(np.nan_to_num(np.asarray(weight, dtype=np.float32)), 0.0, 1.0)
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0, ::-1]
    return lut[np.round(w * 255).astype(np.int64)]


def render_cloud(
    xyz: np.ndarray,
    rgb: np.ndarray,
    K: np.ndarray,
    T_cam_world: np.ndarray,
    width: int = 960,
    height: int = 720,
    point_size: int = 2,
    background: tuple[int, int, int] = (255, 255, 255),
) -> np.ndarray:
    """Render points (M, 3) world metres with colours (M, 3) uint8 to an (H, W, 3) uint8 image.

    Each point is a ``point_size`` x ``point_size`` square; the nearest point wins per pixel.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    rgb = np.asarray(rgb, dtype=np.uint8)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape:
        raise ValidationError(f"render_cloud: expected xyz (M, 3) and rgb (M, 3), got {xyz.shape} and {rgb.shape}")
    img = np.empty((height, width, 3), np.uint8)
    img[:] = background
    if len(xyz) == 0:
        return img
    Xc = xyz @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    front = Xc[:, 2] > 1e-6
    Xc, rgb = Xc[front], rgb[front]
    u = np.floor(K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2] + 0.5).astype(np.int64)
    v = np.floor(K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2] + 0.5).astype(np.int64)
    z = Xc[:, 2]
    lin, zs, idx = [], [], []
    for du in range(point_size):
        for dv in range(point_size):
            uu, vv = u + du - point_size // 2, v + dv - point_size // 2
            ok = (uu >= 0) & (uu < width) & (vv >= 0) & (vv < height)
            lin.append(vv[ok] * width + uu[ok])
            zs.append(z[ok])
            idx.append(np.nonzero(ok)[0])
    lin_a, z_a, idx_a = np.concatenate(lin), np.concatenate(zs), np.concatenate(idx)
    order = np.lexsort((z_a, lin_a))  # by pixel, then nearest first
    lin_s = lin_a[order]
    first = np.ones(len(lin_s), bool)
    first[1:] = lin_s[1:] != lin_s[:-1]
    img.reshape(-1, 3)[lin_s[first]] = rgb[idx_a[order][first]]
    return img


def save_cloud_png(
    path: str | Path,
    cloud: FusedCloud,
    color_by: str = "rgb",
    K: np.ndarray | None = None,
    T_cam_world: np.ndarray | None = None,
    width: int = 960,
    height: int = 720,
    point_size: int = 2,
) -> Path:
    """Render ``cloud`` headless to a PNG; ``color_by`` is 'rgb' or 'weight' (TURBO colormap).

    Without K / T_cam_world, ``orbit_camera`` frames the cloud.
    """
    import cv2

    if color_by not in ("rgb", "weight"):
        raise ValidationError(f"color_by must be 'rgb' or 'weight', got {color_by!r}")
    c = cloud.to("cpu")
    xyz = c.xyz.numpy()
    colors = c.rgb.numpy() if color_by == "rgb" else weight_colors(c.weight.numpy())
    if K is None or T_cam_world is None:
        if len(xyz) == 0:
            K, T_cam_world = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]]), np.eye(4)
        else:
            K, T_cam_world = orbit_camera(xyz, width=width, height=height)
    img = render_cloud(xyz, colors, K, T_cam_world, width, height, point_size)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path
