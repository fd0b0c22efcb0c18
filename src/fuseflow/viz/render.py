"""A small headless point-cloud renderer: z-buffered square splats through a pinhole camera.

No display, OpenGL or EGL is needed (CI and servers have none), so the demo and
``fuseflow view --save-png`` work everywhere. It is for looking, not for measuring.

``view_camera(xyz, rig, volume)`` chooses the view ``view --save-png`` uses: the points inside
the capture volume (``geometry.volume``), seen from above the ring for a rig that surrounds the
scene, and from behind the cameras, looking where they look, for a rig on one side (a room seen
from the side it was filmed from, not the backs of its walls). ``annotate`` draws the rig's
cameras (frusta, 0.15 m deep, with their ids), a world-axes gizmo (x red, y green, z blue), a
label and, for weights, a colour bar.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import FusedCloud

__all__ = ["orbit_camera", "render_cloud", "save_cloud_png", "weight_colors", "view_camera", "annotate"]


def orbit_camera(
    xyz: np.ndarray,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 30.0,
    up: tuple[float, float, float] = (0.0, -1.0, 0.0),
    width: int = 960,
    height: int = 720,
    fov_deg: float = 50.0,
    direction: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """A camera (K, T_cam_world) that frames the bulk of ``xyz`` (2nd-98th percentile box).

    ``up`` is the world's up direction; the default (0, -1, 0) suits OpenCV-style worlds where
    the first camera's -y is up (ICL, simulator rigs). The camera orbits the box centre at
    ``azimuth_deg`` around ``up`` and ``elevation_deg`` above the horizontal plane, or, with
    ``direction`` (a vector from the centre towards the eye), looks back along it.
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
    if direction is None:
        direction = np.cos(el) * (np.cos(az) * a + np.sin(az) * b) + np.sin(el) * up_v
    direction = np.asarray(direction, np.float64) / np.linalg.norm(direction)
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    half_fov = np.arctan(0.5 * min(width, height) / f)  # the narrower of the two image axes
    dist = radius / np.sin(half_fov) * 1.05
    eye = centre + dist * direction
    z = centre - eye
    z /= np.linalg.norm(z)
    x = np.cross(-up_v, z)
    if np.linalg.norm(x) < 1e-6:  # looking straight along up
        x = np.cross(-a, z)
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
    rig=None,
    volume=None,
    label: str = "",
) -> Path:
    """Render ``cloud`` headless to a PNG; ``color_by`` is 'rgb' or 'weight' (TURBO colormap over
    the 2nd-98th percentile of the frame's weights, ``weight_range``, with a colour bar and a
    caption saying what the colours mean).

    Without K / T_cam_world, ``view_camera`` frames the cloud (inside ``volume``, a
    ``geometry.volume.CaptureVolume``, when given: points outside it are not drawn). With
    ``rig``, its cameras are drawn; ``label`` is written top left; an axes gizmo bottom left.
    """
    import cv2

    if color_by not in ("rgb", "weight"):
        raise ValidationError(f"color_by must be 'rgb' or 'weight', got {color_by!r}")
    c = cloud.to("cpu")
    xyz = c.xyz.numpy()
    span = weight_range(c.weight.numpy()) if color_by == "weight" else (0.0, 1.0)
    if color_by == "rgb":
        colors = c.rgb.numpy()
    else:
        colors = weight_colors((c.weight.numpy() - span[0]) / (span[1] - span[0]))
    shown = volume.contains(xyz) if volume is not None and len(xyz) else np.ones(len(xyz), bool)
    if K is None or T_cam_world is None:
        if len(xyz) == 0:
            K, T_cam_world = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1]]), np.eye(4)
        else:
            K, T_cam_world, shown = view_camera(xyz, rig, volume, width, height)
    if not shown.any():
        shown = np.ones(len(xyz), bool)
    img = render_cloud(xyz[shown], colors[shown], K, T_cam_world, width, height, point_size, BACKGROUND)
    size = 0.15
    if shown.sum() > 10:  # frusta a twentieth of the shown scene's size
        lo, hi = np.percentile(xyz[shown], 2, axis=0), np.percentile(xyz[shown], 98, axis=0)
        size = float(np.clip(np.linalg.norm(hi - lo) / 20, 0.02, 0.3))
    if label and volume is not None and len(xyz):
        label = f"{label}; {int(shown.sum()):,} in the capture volume"
    annotate(img, K, T_cam_world, rig, label, color_by == "weight", size, span)
    if color_by == "weight":
        _caption(img, weight_caption(span))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path


def weight_range(weight: np.ndarray) -> tuple[float, float]:
    """The weights the colour scale spans: the 2nd to 98th percentile of ``weight`` (fusion weights
    crowd near 1, where a 0-1 scale paints nearly every point red), at least 0.01 wide, in [0, 1]."""
    w = np.asarray(weight, dtype=np.float64)
    w = w[np.isfinite(w)]
    if not w.size:
        return 0.0, 1.0
    lo, hi = (float(v) for v in np.percentile(w, [2, 98]))
    if hi - lo < 0.01:
        mid = (lo + hi) / 2
        lo, hi = mid - 0.005, mid + 0.005
    return max(0.0, lo), min(1.0, max(hi, lo + 0.01))


def weight_caption(span: tuple[float, float]) -> str:
    """What a weight picture shows, in one line."""
    return (
        f"colour: fusion weight of each point (eq. 22: measurement confidence x cross-view agreement); "
        f"blue {span[0]:.2f} or less, red {span[1]:.2f} or more (2nd-98th percentile)"
    )


def _caption(img: np.ndarray, text: str) -> None:
    """``text`` along the bottom edge, right of the axes gizmo, on the background colour."""
    import cv2

    h = img.shape[0]
    scale = 0.45
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    room = img.shape[1] - 110
    if tw > room:
        scale *= room / tw
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    cv2.rectangle(img, (96, h - 16 - th), (104 + tw, h - 6), BACKGROUND, -1)
    cv2.putText(img, text, (100, h - 10), cv2.FONT_HERSHEY_SIMPLEX, scale, INK, 1, cv2.LINE_AA)


def camera_labels(ids) -> dict[str, str]:
    """A label per camera id: the shortest tail of 6 or more characters that no two ids share
    (serial numbers differ at the end; two HO-Cap serials end in the same 6 digits)."""
    ids = [str(i) for i in ids]
    for k in range(6, max((len(i) for i in ids), default=6) + 1):
        tails = [i[-k:] for i in ids]
        if len(set(tails)) == len(tails):
            return dict(zip(ids, tails))
    return {i: i for i in ids}


def _up(rig) -> np.ndarray:
    """The mean of the cameras' up axes (-y in OpenCV axes), (0, -1, 0) without a rig."""
    if rig is None or not rig.is_calibrated:
        return np.array([0.0, -1.0, 0.0])
    up = np.mean([-c.T_cam_world[1, :3] for c in rig], axis=0)
    n = float(np.linalg.norm(up))
    return up / n if n > 1e-6 else np.array([0.0, -1.0, 0.0])


def view_camera(xyz: np.ndarray, rig=None, volume=None, width: int = 960, height: int = 720):
    """(K, T_cam_world, shown) for a picture of ``xyz``: ``shown`` (M,) bool are the points
    inside ``volume`` (all of them without one, or when none is inside), framed by
    ``orbit_camera``. A "ring" volume is seen from 35 degrees above its side; any other
    calibrated rig from behind and above its cameras, looking along their mean optical axis."""
    xyz = np.asarray(xyz, np.float64)
    shown = volume.contains(xyz) if volume is not None and len(xyz) else np.ones(len(xyz), bool)
    if not shown.any():
        shown = np.ones(len(xyz), bool)
    up = _up(rig)
    framed = width - 100  # the right margin keeps the colour bar off the points
    if volume is not None and volume.kind == "ring":
        K, T = orbit_camera(xyz[shown], 35.0, 35.0, tuple(up), framed, height)
        return K, T, shown
    direction = None
    if rig is not None and rig.is_calibrated:
        axis = np.mean([c.T_world_cam[:3, 2] for c in rig], axis=0)
        if np.linalg.norm(axis) > 1e-6:
            axis /= np.linalg.norm(axis)
            direction = -axis + 0.35 * up  # behind the cameras, a little above them
    K, T = orbit_camera(xyz[shown], up=tuple(up), width=framed, height=height, direction=direction)
    return K, T, shown


def _project(K: np.ndarray, T: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    Xc = np.asarray(X, np.float64) @ T[:3, :3].T + T[:3, 3]
    z = Xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (Xc @ K.T)[:, :2] / z[:, None]
    return uv, z > 1e-3


INK = (235, 235, 235)
"""Colour of the drawn cameras, labels and ticks (on the dark ``BACKGROUND``)."""
BACKGROUND = (46, 50, 58)
"""Background of saved PNGs: dark, so that white walls and light clouds stand out."""


def _draw_cameras(img: np.ndarray, K: np.ndarray, T: np.ndarray, rig, size: float) -> None:
    import cv2

    labels = camera_labels(rig.ids)
    for cam in rig:
        if not cam.is_calibrated:
            continue
        d = size
        w, h = cam.width, cam.height
        corners = np.array([[0, 0, 1], [w, 0, 1], [w, h, 1], [0, h, 1]], np.float64) @ np.linalg.inv(cam.K).T * d
        pose = cam.T_world_cam
        pts = np.vstack([[0, 0, 0], corners]) @ pose[:3, :3].T + pose[:3, 3]
        uv, ok = _project(K, T, pts)
        if not ok.all():
            continue
        p = np.round(uv).astype(int)
        for i, j in ((0, 1), (0, 2), (0, 3), (0, 4), (1, 2), (2, 3), (3, 4), (4, 1)):
            cv2.line(img, tuple(map(int, p[i])), tuple(map(int, p[j])), INK, 1, cv2.LINE_AA)
        cv2.putText(img, labels[cam.id], tuple(map(int, p[0] + [4, -4])), cv2.FONT_HERSHEY_SIMPLEX, 0.4, INK, 1,
                    cv2.LINE_AA)  # fmt: skip


def _draw_axes(img: np.ndarray, T: np.ndarray) -> None:
    """A world-axes gizmo in the bottom-left corner: x red, y green, z blue (rotation only)."""
    import cv2

    h = img.shape[0]
    o = np.array([45.0, h - 45.0])
    for k, colour in enumerate(((240, 70, 70), (80, 210, 80), (90, 140, 255))):
        d = T[:3, :3][:, k]  # world axis k in the view camera's frame
        tip = o + 32 * np.array([d[0], d[1]])
        cv2.arrowedLine(img, tuple(map(int, o)), tuple(map(int, tip)), colour, 2, cv2.LINE_AA, tipLength=0.25)
        cv2.putText(img, "xyz"[k], tuple(map(int, tip + [3, 3])), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1,
                    cv2.LINE_AA)  # fmt: skip


def _draw_colour_bar(img: np.ndarray, span: tuple[float, float] = (0.0, 1.0)) -> None:
    """A vertical TURBO bar on the right: weight ``span[1]`` at the top, ``span[0]`` at the
    bottom, with ticks."""
    import cv2

    h, w = img.shape[:2]
    top, bottom, x0, x1 = int(0.15 * h), int(0.85 * h), w - 60, w - 40
    ramp = weight_colors(np.linspace(1, 0, bottom - top))
    img[top:bottom, x0:x1] = ramp[:, None, :]
    cv2.rectangle(img, (x0, top), (x1, bottom), INK, 1)
    for val in (0.0, 0.25, 0.5, 0.75, 1.0):
        y = int(bottom - val * (bottom - top))
        cv2.line(img, (x0 - 4, y), (x0, y), INK, 1)
        value = span[0] + val * (span[1] - span[0])
        cv2.putText(img, f"{value:.2f}", (x0 - 42, y + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, INK, 1, cv2.LINE_AA)
    cv2.putText(img, "weight", (x0 - 20, top - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.45, INK, 1, cv2.LINE_AA)


def annotate(
    img: np.ndarray,
    K: np.ndarray,
    T: np.ndarray,
    rig=None,
    label: str = "",
    colour_bar: bool = False,
    camera_size: float = 0.15,
    span: tuple[float, float] = (0.0, 1.0),
):
    """Draw the rig's cameras (frusta ``camera_size`` metres deep), the axes gizmo, ``label``
    (top left) and, with ``colour_bar``, the weight colour bar over the weights ``span`` onto
    ``img`` (H, W, 3) RGB uint8, in place; returns it."""
    import cv2

    if rig is not None:
        _draw_cameras(img, K, T, rig, camera_size)
    _draw_axes(img, T)
    if label:
        (tw, th), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
        cv2.rectangle(img, (6, 8), (18 + tw, 34), BACKGROUND, -1)  # over frusta that reach the top
        cv2.putText(img, label, (12, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.6, INK, 1, cv2.LINE_AA)
    if colour_bar:
        _draw_colour_bar(img, span)
    return img
