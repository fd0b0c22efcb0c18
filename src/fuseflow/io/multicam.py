"""Several single-camera recordings (one file per device) into one FuseFlow recording.

A reader of a device format (``io.rosbag``, ``io.azure_kinect``) gives one ``CameraStream`` per
file: the camera's intrinsics in the colour image, its depth scale, every view's device
timestamp, and an iterator over views with depth already registered to colour. This module
pairs the cameras' views by timestamp (``io.timesync.pair_by_timestamp``), writes the frames
(colour PNG, depth uint16 PNG with the stream's own raw values: bit-exact), rig.json and
timestamps.json. Memory stays at a few views: each file is read in one pass in time order.

``align_depth_to_color`` registers a depth image to a colour camera (what librealsense's
``rs2::align`` and the Azure Kinect SDK's ``depth_image_to_color_camera`` do): each depth pixel's
footprint is back-projected, moved by the depth-to-colour extrinsics, projected, and kept where
it is the nearest surface (z-buffer).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from fuseflow.errors import RecordingError, ValidationError
from fuseflow.io.recording import frame_path, write_rig
from fuseflow.io.timesync import Pairing, pair_by_timestamp, write_timestamps
from fuseflow.types import Camera, Rig

__all__ = ["CameraStream", "ConversionResult", "convert_streams", "align_depth_to_color", "write_depth_raw"]


class CameraStream(Protocol):
    """One device's recording, as the converters need it.

    Attributes:
        id: camera id (the serial number where the file gives one). source: the file.
        width, height: colour image size; depth is registered to it.
        K: (3, 3) float64 colour intrinsics, pixels. depth_scale: raw depth units per metre.
        depth_range: trustworthy depth range, metres.
        timestamps: (M,) float64 seconds, device time of each view, increasing.
        device_frames: (M,) int64 device frame counters, or None.
    """

    id: str
    source: Path
    width: int
    height: int
    K: np.ndarray
    depth_scale: float
    depth_range: tuple[float, float]
    timestamps: np.ndarray
    device_frames: np.ndarray | None

    def views(self, wanted: set[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """Yield (k, colour (H, W, 3) uint8 RGB, depth (H, W) uint16 raw registered to colour)
        for every view index k in ``wanted``, in increasing k."""
        ...


def wanted_messages(
    view_depth: np.ndarray, view_color: np.ndarray, wanted: set[int]
) -> tuple[dict[int, int], dict[int, list[int]]]:
    """For the views ``wanted`` (indices into a camera's paired views), the depth message index ->
    view and the colour message index -> views (one colour frame can serve several views): what
    a reader's second pass decodes (``CameraStream.views`` of rosbag.py and azure_kinect.py)."""
    want_d = {int(view_depth[k]): k for k in wanted}
    want_c: dict[int, list[int]] = {}
    for k in wanted:
        want_c.setdefault(int(view_color[k]), []).append(k)
    return want_d, want_c


def write_depth_raw(path: Path, raw: np.ndarray) -> None:
    """Write (H, W) uint16 depth units as a 16-bit PNG, unchanged."""
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if raw.dtype != np.uint16 or raw.ndim != 2:
        raise ValidationError(f"{path}: raw depth must be (H, W) uint16, got {raw.shape} {raw.dtype}")
    if not cv2.imwrite(str(path), raw):
        raise RecordingError(f"{path}: could not write depth image")


def _write_color_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise RecordingError(f"{path}: could not write image")


@dataclass(frozen=True)
class ConversionResult:
    """What ``convert_streams`` wrote.

    Attributes:
        rig: the rig written to rig.json (uncalibrated unless extrinsics were given).
        pairing: how views were paired into frames (``Pairing``; index (F, N), -1 = dropped).
        sources: per camera, the file it came from. seconds: wall time of the conversion.
    """

    rig: Rig
    pairing: Pairing
    sources: tuple[Path, ...]
    seconds: float


def _check_streams(streams: Sequence[CameraStream]) -> None:
    if not streams:
        raise ValidationError("no cameras to convert")
    first = streams[0]
    for s in streams[1:]:
        if (s.width, s.height) != (first.width, first.height):
            raise RecordingError(
                f"{s.source}: colour stream is {s.width}x{s.height}, but {first.source} is "
                f"{first.width}x{first.height}; a rig needs one resolution (record all cameras at the same one)"
            )
    ids = [s.id for s in streams]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        files = [str(s.source) for s in streams if s.id in dup]
        raise RecordingError(f"camera id {dup[0]!r} appears in several files ({', '.join(files)}): one file per device")


def convert_streams(
    streams: Sequence[CameraStream],
    out: str | Path,
    tolerance: float | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ConversionResult:
    """Pair the cameras' views by timestamp and write one FuseFlow recording to ``out``.

    Args:
        streams: one per camera, all at one colour resolution (else RecordingError naming files).
        tolerance: pairing tolerance in seconds; default half the frame period.
        progress: called as progress(cameras done, cameras) after each camera.
    """
    t0 = time.perf_counter()
    _check_streams(streams)
    out = Path(out)
    names = [f"{s.source} (camera {s.id})" for s in streams]
    pairing = pair_by_timestamp([s.timestamps for s in streams], tolerance, names)
    F = len(pairing.index)
    view_t, dev_f = {}, {}
    for i, s in enumerate(streams):
        col = pairing.index[:, i]
        frame_of = {int(k): f for f, k in enumerate(col) if k >= 0}
        for k, rgb, raw in s.views(set(frame_of)):
            f = frame_of[k]
            if rgb.shape != (s.height, s.width, 3) or raw.shape != (s.height, s.width):
                raise RecordingError(
                    f"{s.source}: view {k} is colour {rgb.shape[1]}x{rgb.shape[0]}, depth {raw.shape[1]}x{raw.shape[0]}; "
                    f"the stream says {s.width}x{s.height}"
                )
            _write_color_png(frame_path(out, s.id, "color", f), rgb)
            write_depth_raw(frame_path(out, s.id, "depth", f), raw)
        view_t[s.id] = np.where(col >= 0, s.timestamps[np.maximum(col, 0)], np.nan)
        if s.device_frames is not None:
            dev_f[s.id] = np.where(col >= 0, np.asarray(s.device_frames, dtype=np.float64)[np.maximum(col, 0)], np.nan)
        if progress is not None:
            progress(i + 1, len(streams))
    rig = Rig(
        tuple(
            Camera(s.id, s.width, s.height, s.K, depth_scale=s.depth_scale, depth_range=s.depth_range) for s in streams
        )
    )
    write_rig(out, rig)
    write_timestamps(out, range(F), view_t, {s.id: s.timestamps for s in streams}, pairing.tolerance, dev_f)
    return ConversionResult(rig, pairing, tuple(s.source for s in streams), time.perf_counter() - t0)


def align_depth_to_color(
    depth_m: np.ndarray,
    K_depth: np.ndarray,
    K_color: np.ndarray,
    T_color_depth: np.ndarray,
    color_size: tuple[int, int],
    rays_depth: np.ndarray | None = None,
) -> np.ndarray:
    """Register a depth image to a colour camera.

    Every valid depth pixel's footprint (its corners at +-0.5 px) is back-projected at its depth,
    moved into the colour camera, projected, and written to the colour pixels it covers; where
    several surfaces land on one pixel the nearest is kept. Pixels nothing lands on are 0.

    Args:
        depth_m: (h, w) float32 metres in the depth camera, 0 = none.
        K_depth, K_color: (3, 3) pinhole intrinsics, pixels (pixel centres at integers).
        T_color_depth: (4, 4) colour-from-depth rigid transform, metres.
        color_size: (width, height) of the colour image.
        rays_depth: optional (h, w, 2) normalised image coordinates (x/z, y/z) of the depth
            pixel centres (undistorted rays of a camera with lens distortion); default pinhole.
    Returns:
        (height, width) float32 metres in the colour camera.
    """
    depth_m = np.asarray(depth_m, dtype=np.float32)
    h, w = depth_m.shape
    W, H = color_size
    v, u = np.nonzero(depth_m > 0)
    z = depth_m[v, u].astype(np.float64)
    out = np.full(H * W, np.inf)
    if z.size == 0:
        return np.zeros((H, W), np.float32)
    R, t = np.asarray(T_color_depth, dtype=np.float64)[:3, :3], np.asarray(T_color_depth, dtype=np.float64)[:3, 3]
    Kd, Kc = np.asarray(K_depth, dtype=np.float64), np.asarray(K_color, dtype=np.float64)

    def project(du: float, dv: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if rays_depth is None or (du, dv) != (0.0, 0.0):
            if rays_depth is None:
                xn = (u + du - Kd[0, 2]) / Kd[0, 0]
                yn = (v + dv - Kd[1, 2]) / Kd[1, 1]
            else:  # corner rays: the pixel-centre ray plus the local pinhole step
                xn = rays_depth[v, u, 0] + du / Kd[0, 0]
                yn = rays_depth[v, u, 1] + dv / Kd[1, 1]
        else:
            xn, yn = rays_depth[v, u, 0], rays_depth[v, u, 1]
        X = np.stack([xn * z, yn * z, z], axis=1) @ R.T + t
        zc = X[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uc = Kc[0, 0] * X[:, 0] / zc + Kc[0, 1] * X[:, 1] / zc + Kc[0, 2]
            vc = Kc[1, 1] * X[:, 1] / zc + Kc[1, 2]
        return uc, vc, zc

    u0, v0, z0 = project(-0.5, -0.5)
    u1, v1, z1 = project(0.5, 0.5)
    _, _, zc = project(0.0, 0.0)
    # the colour pixels whose centres the footprint covers: [ceil(u0 - .5), floor(u1 - .5)] ... as
    # rs2::align does, rounded so that a footprint always covers at least its centre pixel
    x0 = np.floor(np.minimum(u0, u1) + 0.5).astype(np.int64)
    x1 = np.floor(np.maximum(u0, u1) - 0.5 + 1e-9).astype(np.int64)
    y0 = np.floor(np.minimum(v0, v1) + 0.5).astype(np.int64)
    y1 = np.floor(np.maximum(v0, v1) - 0.5 + 1e-9).astype(np.int64)
    ok = (zc > 0) & (z0 > 0) & (z1 > 0) & np.isfinite(u0 + u1 + v0 + v1)
    x1, y1 = np.maximum(x1, x0), np.maximum(y1, y0)
    span_x = np.minimum(x1 - x0, 8)
    span_y = np.minimum(y1 - y0, 8)
    for dy in range(int(span_y[ok].max(initial=0)) + 1):
        for dx in range(int(span_x[ok].max(initial=0)) + 1):
            xx, yy = x0 + dx, y0 + dy
            m = ok & (dx <= span_x) & (dy <= span_y) & (xx >= 0) & (xx < W) & (yy >= 0) & (yy < H)
            np.minimum.at(out, yy[m] * W + xx[m], zc[m])
    out[~np.isfinite(out)] = 0.0
    return out.reshape(H, W).astype(np.float32)
