"""Azure Kinect recordings (.mkv, Matroska) as written by ``k4arecorder`` / ``k4a_record_*``, read
with PyAV (FFmpeg's demuxer; the Azure Kinect SDK is not needed).

Layout read (Azure-Kinect-Sensor-SDK ``src/record/sdk/record.cpp``, ``src/record/internal/
matroska_write.cpp``; docs/formats.md says what a user gets):

* track "COLOR": codec V_MS/VFW/FOURCC, BITMAPINFOHEADER fourcc MJPG, NV12, YUY2 or BGRA;
  track tag K4A_COLOR_MODE = "<FORMAT>_<height>P" (e.g. "MJPG_1080P", "BGRA_720P").
* track "DEPTH": V_MS/VFW/FOURCC, fourcc "b16g": 16-bit depth in millimetres, **big-endian**
  (the SDK byte-swaps on write); track tag K4A_DEPTH_MODE (e.g. "NFOV_UNBINNED").
* attachment "calibration.json": the device calibration, cameras "CALIBRATION_CameraLocationD0"
  (depth) and "CALIBRATION_CameraLocationPV0" (colour), each with normalised ModelParameters
  (cx, cy, fx, fy, k1..k6, codx, cody, p2, p1, metric radius; Brown-Conrady = OpenCV's rational
  model) and Rt = world -> camera (Rotation row-major, Translation metres).
* timecode scale 1 us; block time + tag K4A_START_OFFSET_NS = device timestamp;
  tag K4A_DEVICE_SERIAL_NUMBER.

Conventions at the boundary: the mode-specific intrinsics are computed as the SDK's
``transformation_get_mode_specific_camera_calibration`` does (binned calibration resolution,
crop offset, then pixel centres at integers: c - 0.5). T_color_depth = Rt_color inv(Rt_depth)
(``transformation_get_extrinsic_transformation``). Depth is transformed into the colour camera
(through the depth lens model); a colour image with non-zero distortion is undistorted to the
pinhole K written in rig.json.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FormatError, RecordingError
from fuseflow.io.multicam import align_depth_to_color, wanted_messages

__all__ = ["AzureKinectMkv", "mode_specific_intrinsics", "COLOR_MODES", "DEPTH_MODES"]

EXTRA_HINT = "pip install 'fuseflow[recordings]'"

#: colour height -> (calibration image binned resolution, crop offset, output resolution): SDK mode table.
COLOR_MODES = {
    720: ((1280, 960), (0, 120), (1280, 720)),
    1080: ((1920, 1440), (0, 180), (1920, 1080)),
    1440: ((2560, 1920), (0, 240), (2560, 1440)),
    1536: ((2048, 1536), (0, 0), (2048, 1536)),
    2160: ((3840, 2880), (0, 360), (3840, 2160)),
    3072: ((4096, 3072), (0, 0), (4096, 3072)),
}
#: depth mode -> (binned resolution, crop offset, output resolution, operating range metres (hardware spec)).
DEPTH_MODES = {
    "NFOV_2X2BINNED": ((512, 512), (96, 90), (320, 288), (0.5, 5.46)),
    "NFOV_UNBINNED": ((1024, 1024), (192, 180), (640, 576), (0.5, 3.86)),
    "WFOV_2X2BINNED": ((512, 512), (0, 0), (512, 512), (0.25, 2.88)),
    "WFOV_UNBINNED": ((1024, 1024), (0, 0), (1024, 1024), (0.25, 2.21)),
}


def _av():
    try:
        import av
    except ImportError:
        raise RecordingError(f"reading Azure Kinect .mkv files needs PyAV ('av'): {EXTRA_HINT}") from None
    return av


def mode_specific_intrinsics(params: list[float], binned: tuple[int, int], crop: tuple[int, int],
                             pixelized: bool = True) -> list[float]:  # fmt: skip
    """The SDK's mode-specific calibration: normalised (cx, cy, fx, fy, ...) -> pixels for one mode.

    ``pixelized`` puts pixel centres at integer coordinates (c - 0.5), the OpenCV convention;
    otherwise the result stays normalised by the output size (used for legacy 16:9 calibrations).
    Returns the parameter list with cx, cy, fx, fy replaced.
    """
    p = list(params)
    cx, cy = p[0] * binned[0] - crop[0], p[1] * binned[1] - crop[1]
    fx, fy = p[2] * binned[0], p[3] * binned[1]
    p[:4] = [cx - 0.5, cy - 0.5, fx, fy] if pixelized else [cx, cy, fx, fy]
    return p


def _camera(calib: dict, location: str, where: str) -> dict:
    try:
        for cam in calib["CalibrationInformation"]["Cameras"]:
            if cam.get("Location") == location:
                return cam
    except (KeyError, TypeError):
        pass
    raise FormatError(f"{where}: no camera with Location {location!r} in CalibrationInformation.Cameras")


def _rt(cam: dict, where: str) -> np.ndarray:
    try:
        T = np.eye(4)
        T[:3, :3] = np.asarray(cam["Rt"]["Rotation"], dtype=np.float64).reshape(3, 3)
        T[:3, 3] = np.asarray(cam["Rt"]["Translation"], dtype=np.float64).reshape(3)
    except (KeyError, TypeError, ValueError):
        raise FormatError(
            f"{where}: camera {cam.get('Location')!r}: Rt needs Rotation (9) and Translation (3)"
        ) from None
    return T


def _params(cam: dict, where: str) -> list[float]:
    try:
        p = [float(x) for x in cam["Intrinsics"]["ModelParameters"]]
    except (KeyError, TypeError, ValueError):
        raise FormatError(f"{where}: camera {cam.get('Location')!r}: Intrinsics.ModelParameters missing") from None
    if len(p) < 14:
        raise FormatError(f"{where}: camera {cam.get('Location')!r}: {len(p)} ModelParameters, expected 14 or 15")
    return p


def _K_dist(p: list[float]) -> tuple[np.ndarray, np.ndarray]:
    K = np.array([[p[2], 0.0, p[0]], [0.0, p[3], p[1]], [0.0, 0.0, 1.0]])
    # OpenCV rational order (k1, k2, p1, p2, k3, k4, k5, k6); the SDK stores p2 before p1
    dist = np.array([p[4], p[5], p[13], p[12], p[6], p[7], p[8], p[9]], dtype=np.float64)
    return K, dist


class AzureKinectMkv:
    """One Azure Kinect .mkv as a ``CameraStream`` (see ``fuseflow.io.multicam``).

    Attributes (beyond CameraStream): serial (or None), color_mode, depth_mode, K_depth,
    dist_depth, dist_color (OpenCV rational order), depth_size, T_color_depth (4, 4) metres,
    fps, color_fourcc.
    """

    def __init__(self, path: str | Path, camera_id: str | None = None):
        av = _av()
        self.source = Path(path)
        if not self.source.is_file():
            raise RecordingError(f"{self.source}: no such file")
        try:
            container = av.open(str(self.source))
        except av.error.FFmpegError as exc:
            raise FormatError(f"{self.source}: not a readable Matroska file ({exc})") from None
        with container:
            self._probe(container)
            self._scan(container)

    # ---- header: tracks, tags, calibration

    def _probe(self, container: Any) -> None:
        src = self.source
        tracks = {s.metadata.get("title", "").upper(): s for s in container.streams if s.type == "video"}
        if "DEPTH" not in tracks:
            raise FormatError(f"{src}: no DEPTH track (k4arecorder writes video tracks 'COLOR' and 'DEPTH')")
        if "COLOR" not in tracks:
            raise FormatError(f"{src}: no COLOR track (k4arecorder writes video tracks 'COLOR' and 'DEPTH')")
        self._depth_index, self._color_index = tracks["DEPTH"].index, tracks["COLOR"].index
        dmeta, cmeta = dict(tracks["DEPTH"].metadata), dict(tracks["COLOR"].metadata)
        gmeta = dict(container.metadata)
        self.depth_mode = dmeta.get("K4A_DEPTH_MODE") or gmeta.get("K4A_DEPTH_MODE")
        self.color_mode = cmeta.get("K4A_COLOR_MODE") or gmeta.get("K4A_COLOR_MODE")
        self.serial = gmeta.get("K4A_DEVICE_SERIAL_NUMBER") or None
        self.start_offset_ns = int(gmeta.get("K4A_START_OFFSET_NS", "0") or 0)
        if self.depth_mode not in DEPTH_MODES:
            raise FormatError(
                f"{src}: DEPTH track: K4A_DEPTH_MODE {self.depth_mode!r} is not one of {sorted(DEPTH_MODES)}"
            )
        try:
            fmt, res = str(self.color_mode).split("_")
            height = int(res.rstrip("Pp"))
            cbin, ccrop, cout = COLOR_MODES[height]
        except (ValueError, KeyError):
            raise FormatError(
                f"{src}: COLOR track: K4A_COLOR_MODE {self.color_mode!r} is not <FORMAT>_<720..3072>P"
            ) from None
        self.color_fourcc = fmt.upper()
        calib = None
        for s in container.streams:
            if s.type == "attachment" and (s.metadata.get("filename") or getattr(s, "name", "")) == "calibration.json":
                try:
                    calib = json.loads(bytes(s.data).decode("utf-8").rstrip("\0"))
                except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                    raise FormatError(f"{src}: attachment calibration.json is not JSON ({exc})") from None
        if calib is None:
            raise FormatError(f"{src}: no calibration.json attachment (k4arecorder attaches the device calibration; "
                              "recordings made without a device have none)")  # fmt: skip
        where = f"{src}: calibration.json"
        dcam, ccam = (
            _camera(calib, "CALIBRATION_CameraLocationD0", where),
            _camera(calib, "CALIBRATION_CameraLocationPV0", where),
        )
        dbin, dcrop, dout, self.depth_range = DEPTH_MODES[self.depth_mode]
        self.K_depth, self.dist_depth = _K_dist(mode_specific_intrinsics(_params(dcam, where), dbin, dcrop))
        cp = _params(ccam, where)
        sw, sh = int(ccam.get("SensorWidth", 4096)), int(ccam.get("SensorHeight", 3072))
        if sw * 9 // 16 == sh:  # legacy 16:9 calibration: to 4:3 first, still normalised
            cp = mode_specific_intrinsics(cp, (4096, 2304), (0, -384), pixelized=False)
            cp[:4] = [cp[0] / 4096, cp[1] / 3072, cp[2] / 4096, cp[3] / 3072]
        self.K, self.dist_color = _K_dist(mode_specific_intrinsics(cp, cbin, ccrop))
        self.width, self.height = cout
        self.depth_size = dout
        self.T_color_depth = _rt(ccam, where) @ np.linalg.inv(_rt(dcam, where))
        self.depth_scale = 1000.0
        self.id = self.serial or self.source.stem
        for s, want, name in ((tracks["DEPTH"], dout, "DEPTH"), (tracks["COLOR"], cout, "COLOR")):
            got = (s.codec_context.width, s.codec_context.height)
            if got != tuple(want):
                raise FormatError(f"{src}: {name} track is {got[0]}x{got[1]}, its mode says {want[0]}x{want[1]}")

    def _scan(self, container: Any) -> None:
        from fuseflow.io.timesync import nominal_period

        ds, cs = [], []
        streams = [container.streams[self._depth_index], container.streams[self._color_index]]
        try:
            for pkt in container.demux(streams):
                if pkt.pts is None or pkt.size == 0:
                    continue
                t = self._seconds(pkt)
                (ds if pkt.stream.index == self._depth_index else cs).append(t)
        except Exception as exc:  # PyAV raises its own FFmpegError subclasses (truncated files)
            raise FormatError(f"{self.source}: cannot demux ({type(exc).__name__}: {exc})") from None
        if not ds:
            raise FormatError(f"{self.source}: DEPTH track has no frames")
        if not cs:
            raise FormatError(f"{self.source}: COLOR track has no frames")
        ds_a, cs_a = np.asarray(ds), np.asarray(cs)
        period = nominal_period([ds_a, cs_a])
        tol = period / 2 if period > 0 else 0.0
        k = np.searchsorted(cs_a, ds_a)
        lo, hi = np.clip(k - 1, 0, len(cs_a) - 1), np.clip(k, 0, len(cs_a) - 1)
        ci = np.where(np.abs(cs_a[lo] - ds_a) <= np.abs(cs_a[hi] - ds_a), lo, hi)
        ok = np.abs(cs_a[ci] - ds_a) <= tol
        self._view_depth, self._view_color = np.flatnonzero(ok), ci[ok]
        self.timestamps = ds_a[ok]
        self.device_frames = None
        self.fps = 1.0 / float(np.median(np.diff(ds_a))) if len(ds_a) > 1 else 0.0

    def _seconds(self, pkt: Any) -> float:
        tb = pkt.time_base if pkt.time_base is not None else pkt.stream.time_base
        us = round(float(pkt.pts * tb) * 1e6)  # 1 us timecode scale: integer microseconds
        return (us + self.start_offset_ns // 1000) * 1e-6

    # ---- images

    def _color(self, data: bytes) -> np.ndarray:
        import cv2

        W, H = self.width, self.height
        fmt = self.color_fourcc
        if fmt == "MJPG":
            bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            if bgr is None:
                raise FormatError(f"{self.source}: COLOR track: undecodable JPEG frame")
            rgb = bgr[..., ::-1]
        elif fmt == "BGRA":
            rgb = np.frombuffer(data, np.uint8).reshape(H, W, 4)[..., 2::-1]
        elif fmt == "NV12":
            rgb = cv2.cvtColor(np.frombuffer(data, np.uint8).reshape(H * 3 // 2, W), cv2.COLOR_YUV2RGB_NV12)
        elif fmt == "YUY2":
            rgb = cv2.cvtColor(np.frombuffer(data, np.uint8).reshape(H, W, 2), cv2.COLOR_YUV2RGB_YUY2)
        else:
            raise FormatError(f"{self.source}: COLOR track: format {fmt!r} is not MJPG, BGRA, NV12 or YUY2")
        rgb = np.ascontiguousarray(rgb)
        if np.any(self.dist_color != 0):
            if not hasattr(self, "_cmap"):
                self._cmap = cv2.initUndistortRectifyMap(self.K, self.dist_color, None, self.K, (W, H), cv2.CV_32FC1)
            rgb = cv2.remap(rgb, self._cmap[0], self._cmap[1], cv2.INTER_LINEAR)
        return rgb

    def depth_raw(self, data: bytes) -> np.ndarray:
        """One DEPTH block -> (h, w) uint16 millimetres in the depth camera (b16g is big-endian)."""
        w, h = self.depth_size
        if len(data) != w * h * 2:
            raise FormatError(f"{self.source}: DEPTH track: block of {len(data)} bytes, expected {w}x{h}x2")
        return np.frombuffer(data, ">u2").reshape(h, w).astype(np.uint16)

    def _rays(self) -> np.ndarray | None:
        if not np.any(self.dist_depth != 0):
            return None
        if not hasattr(self, "_rays_cache"):
            import cv2

            w, h = self.depth_size
            uv = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(
                -1, 1, 2
            )
            xy = cv2.undistortPoints(uv, self.K_depth, self.dist_depth).reshape(h, w, 2)
            self._rays_cache = xy
        return self._rays_cache

    def views(self, wanted: set[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        av = _av()
        want_d, want_c = wanted_messages(self._view_depth, self._view_color, wanted)
        got_d: dict[int, np.ndarray] = {}
        got_c: dict[int, np.ndarray] = {}
        nd = nc = 0
        with av.open(str(self.source)) as container:
            streams = [container.streams[self._depth_index], container.streams[self._color_index]]
            for pkt in container.demux(streams):
                if pkt.pts is None or pkt.size == 0:
                    continue
                if pkt.stream.index == self._depth_index:
                    if nd in want_d:
                        mm = self.depth_raw(bytes(pkt))
                        al = align_depth_to_color(mm.astype(np.float32) / 1000.0, self.K_depth, self.K,
                                                  self.T_color_depth, (self.width, self.height), self._rays())  # fmt: skip
                        got_d[want_d[nd]] = np.clip(np.rint(al * 1000.0), 0, 65535).astype(np.uint16)
                    nd += 1
                else:
                    if nc in want_c:
                        rgb = self._color(bytes(pkt))
                        for k in want_c[nc]:
                            got_c[k] = rgb
                    nc += 1
                for k in [k for k in got_d if k in got_c]:
                    yield k, got_c.pop(k), got_d.pop(k)

    def describe(self) -> dict[str, Any]:
        return {"file": str(self.source), "serial": self.serial, "color_mode": self.color_mode,
                "depth_mode": self.depth_mode, "fps": self.fps}  # fmt: skip
