"""Intel RealSense recordings (.bag, ROS1 bag format) as written by RealSense Viewer, ``rs-record``
and ``rs2::recorder``, read with the pure-Python ``rosbags`` library (no librealsense).

Topics read (librealsense ``src/media/ros/ros_file_format.h``, ``ros_topic``; docs/formats.md
says what a user gets)::

    /file_version                                    std_msgs/UInt32   (2 or 3)
    /device_0/info                                   diagnostic_msgs/KeyValue  ("Serial Number", "Name", ...)
    /device_0/sensor_S/option/Depth Units/value      std_msgs/Float32  metres per depth unit (file v3)
    /device_0/sensor_S/property                      diagnostic_msgs/KeyValue  ("Depth Units", file v2)
    /device_0/sensor_S/Depth_0/info/camera_info      sensor_msgs/CameraInfo  (K row-major, width, height)
    /device_0/sensor_S/Color_0/info/camera_info      sensor_msgs/CameraInfo
    /device_0/sensor_S/<Stream>_0/tf/<ref>           geometry_msgs/Transform  extrinsics reference -> stream
    /device_0/sensor_S/Depth_0/image/data            sensor_msgs/Image  "mono16" (Z16), header.stamp = device ms
    /device_0/sensor_S/Color_0/image/data            sensor_msgs/Image  "rgb8" / "bgr8" / "rgba8" / "bgra8" / "yuv422" / "YUYV"

Conventions at the boundary: the extrinsics message maps the group's reference stream into
the stream (``device::get_extrinsics`` fetches pin stream -> stream; ``quat2rot`` is the usual
Hamilton rotation), so T_color_depth = T_color_ref inv(T_depth_ref). ``Image.header.stamp`` is
the frame timestamp (milliseconds in the device's timestamp domain, stored as ROS time) and
``header.seq`` the frame counter. Recent librealsense appends a float32 ``depth_units`` after
``data`` in each Image (its ``header.version == "1"`` serializer); both layouts are read.
Depth registered to colour in the file (same intrinsics, identity extrinsics) is copied
bit-exactly; otherwise it is aligned to colour (``align_depth_to_color``). Colour distortion
is not modelled (D400 colour coefficients are near zero).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FormatError, RecordingError
from fuseflow.io.multicam import align_depth_to_color, wanted_messages

__all__ = ["RealSenseBag", "read_image_message", "EXTRA_HINT"]

EXTRA_HINT = "pip install 'fuseflow[recordings]'"

_STREAM_RE = re.compile(r"^/device_(\d+)/sensor_(\d+)/(Depth|Color)_(\d+)/(image/data|info/camera_info|tf/(\d+))$")
_UNITS_RE = re.compile(r"^/device_\d+/sensor_\d+/option/Depth Units/value$")
_PROPERTY_RE = re.compile(r"^/device_\d+/sensor_\d+/property$")
_DEVICE_INFO_RE = re.compile(r"^/device_\d+/info$")


def _rosbag1():
    try:
        from rosbags import rosbag1
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise RecordingError(f"reading RealSense .bag files needs the 'rosbags' package: {EXTRA_HINT}") from None
    return rosbag1, get_typestore(Stores.ROS1_NOETIC)


@dataclass(frozen=True)
class ImageMessage:
    """A decoded sensor_msgs/Image: header fields, geometry, encoding and the raw bytes."""

    seq: int
    stamp_s: float
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: memoryview
    depth_units: float | None


def read_image_message(raw: bytes | memoryview, where: str) -> ImageMessage:
    """Parse a ROS1-serialised sensor_msgs/Image (with librealsense's optional trailing float32
    ``depth_units``). Errors name ``where`` (file and topic)."""
    mv = memoryview(raw)
    try:
        seq, sec, nsec, n = struct.unpack_from("<IIII", mv, 0)
        pos = 16 + n
        height, width, n = struct.unpack_from("<III", mv, pos)
        pos += 12
        encoding = bytes(mv[pos : pos + n]).decode("ascii", "replace")
        pos += n
        is_be, step, n = struct.unpack_from("<BII", mv, pos)
        pos += 9
        data = mv[pos : pos + n]
        if len(data) != n:
            raise struct.error("data shorter than declared")
        pos += n
        units = struct.unpack_from("<f", mv, pos)[0] if len(mv) - pos >= 4 else None
    except struct.error as exc:
        raise FormatError(f"{where}: not a sensor_msgs/Image message ({exc})") from None
    if step * height != n:
        raise FormatError(f"{where}: image step {step} x height {height} != {n} data bytes")
    return ImageMessage(seq, sec + nsec * 1e-9, height, width, encoding, is_be, step, data, units)


def _decode_color(img: ImageMessage, where: str) -> np.ndarray:
    import cv2

    enc = img.encoding.lower()
    buf = np.frombuffer(img.data, dtype=np.uint8).reshape(img.height, img.step)
    ch = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "8uc1": 1, "yuv422": 2, "uyvy": 2, "yuyv": 2}
    if enc not in ch:
        raise FormatError(
            f"{where}: colour encoding {img.encoding!r} is not supported (rgb8, bgr8, rgba8, bgra8, mono8, yuv422, YUYV)"
        )
    px = buf[:, : img.width * ch[enc]].reshape(img.height, img.width, ch[enc])
    if enc == "rgb8":
        return px.copy()
    if enc == "bgr8":
        return px[..., ::-1].copy()
    if enc == "rgba8":
        return px[..., :3].copy()
    if enc == "bgra8":
        return px[..., 2::-1].copy()
    if enc in ("mono8", "8uc1"):
        return np.repeat(px, 3, axis=2)
    code = cv2.COLOR_YUV2RGB_YUYV if enc == "yuyv" else cv2.COLOR_YUV2RGB_UYVY
    return cv2.cvtColor(np.ascontiguousarray(px), code)


def _decode_depth(img: ImageMessage, where: str) -> np.ndarray:
    if img.encoding.lower() not in ("mono16", "16uc1", "z16"):
        raise FormatError(f"{where}: depth encoding {img.encoding!r} is not Z16 (mono16 / 16UC1)")
    dt = ">u2" if img.is_bigendian else "<u2"
    buf = np.frombuffer(img.data, dtype=np.uint8).reshape(img.height, img.step)[:, : img.width * 2]
    return np.ascontiguousarray(buf).view(dt).reshape(img.height, img.width).astype(np.uint16)


def _quat_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = np.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


@dataclass
class _Stream:
    topic: str
    K: np.ndarray | None = None
    size: tuple[int, int] | None = None
    tf: dict[int, np.ndarray] | None = None
    seq: list[int] | None = None
    stamp: list[float] | None = None


class RealSenseBag:
    """One RealSense .bag file as a ``CameraStream`` (see ``fuseflow.io.multicam``).

    Opening reads every message once (camera info, options, image headers); ``views`` reads the
    images again and yields them decoded, depth registered to colour as uint16 depth units.

    Attributes (beyond CameraStream): serial (or None), file_version, depth_units (metres per
    unit), K_depth, depth_size, T_color_depth (4, 4) colour-from-depth, aligned_in_file (depth
    already registered to colour), fps (median rate of the depth stream).
    """

    def __init__(self, path: str | Path, depth_range: tuple[float, float] = (0.2, 6.0), camera_id: str | None = None):
        self.source = Path(path)
        self.depth_range = depth_range
        rosbag1, self._ts = _rosbag1()
        self._rosbag1 = rosbag1
        if not self.source.is_file():
            raise RecordingError(f"{self.source}: no such file")
        streams: dict[str, _Stream] = {}
        self.serial: str | None = None
        self.file_version: int | None = None
        self.depth_units: float | None = None
        try:
            with rosbag1.Reader(self.source) as reader:
                for conn, _, raw in reader.messages():
                    self._scan(conn.topic, conn.msgtype, raw, streams)
        except rosbag1.ReaderError as exc:
            raise FormatError(f"{self.source}: not a readable ROS1 bag ({exc})") from None
        except (struct.error, ValueError, IndexError, KeyError) as exc:
            raise FormatError(f"{self.source}: corrupt bag ({type(exc).__name__}: {exc})") from None
        depth = self._pick(streams, "Depth")
        color = self._pick(streams, "Color")
        self._depth, self._color = depth, color
        for s, what in ((depth, "depth"), (color, "colour")):
            if s.K is None or s.size is None:
                raise FormatError(
                    f"{self.source}: {s.topic.rsplit('/image', 1)[0]}/info/camera_info missing: no {what} intrinsics"
                )
            if not s.stamp:
                raise FormatError(f"{self.source}: {s.topic}: no {what} frames")
        if self.depth_units is None:
            raise FormatError(f"{self.source}: no depth units (expected /device_0/sensor_N/option/Depth Units/value)")
        self.id = camera_id or self.serial or self.source.stem
        self.width, self.height = color.size
        self.K = color.K
        self.K_depth, self.depth_size = depth.K, depth.size
        self.T_color_depth = self._extrinsics(depth, color)
        self.aligned_in_file = (
            depth.size == color.size
            and np.allclose(depth.K, color.K, rtol=0, atol=1e-9)
            and np.allclose(self.T_color_depth, np.eye(4), rtol=0, atol=1e-9)
        )
        inv = 1.0 / self.depth_units
        self.depth_scale = float(round(inv, 3)) if abs(inv - round(inv, 3)) < 1e-6 * inv else inv
        self._pair_color(depth, color)

    # ---- pass 1

    def _scan(self, topic: str, msgtype: str, raw: memoryview, streams: dict[str, _Stream]) -> None:
        where = f"{self.source}: {topic}"
        if topic == "/file_version":
            self.file_version = int(self._ts.deserialize_ros1(raw, "std_msgs/msg/UInt32").data)
            return
        if _DEVICE_INFO_RE.match(topic):
            kv = self._ts.deserialize_ros1(raw, "diagnostic_msgs/msg/KeyValue")
            if kv.key == "Serial Number" and kv.value:
                self.serial = kv.value
            return
        if _UNITS_RE.match(topic):
            self.depth_units = float(self._ts.deserialize_ros1(raw, "std_msgs/msg/Float32").data)
            return
        if _PROPERTY_RE.match(topic):
            kv = self._ts.deserialize_ros1(raw, "diagnostic_msgs/msg/KeyValue")
            if kv.key == "Depth Units":
                self.depth_units = float(kv.value)
            return
        m = _STREAM_RE.match(topic)
        if not m:
            return
        prefix = topic.split("/image/")[0].split("/info/")[0].split("/tf/")[0]
        s = streams.setdefault(prefix, _Stream(prefix + "/image/data", tf={}, seq=[], stamp=[]))
        kind = m.group(5)
        if kind == "image/data":
            img = read_image_message(raw, where)
            s.seq.append(img.seq)
            s.stamp.append(img.stamp_s)
            if s.size is None:
                s.size = (img.width, img.height)
            if img.depth_units and self.depth_units is None and m.group(3) == "Depth":
                self.depth_units = float(img.depth_units)
        elif kind == "info/camera_info":
            ci = self._ts.deserialize_ros1(raw, "sensor_msgs/msg/CameraInfo")
            s.K = np.asarray(ci.K, dtype=np.float64).reshape(3, 3)
            s.size = (int(ci.width), int(ci.height))
        else:
            tf = self._ts.deserialize_ros1(raw, "geometry_msgs/msg/Transform")
            T = np.eye(4)
            q = tf.rotation
            T[:3, :3] = _quat_to_matrix(q.x, q.y, q.z, q.w)
            T[:3, 3] = [tf.translation.x, tf.translation.y, tf.translation.z]
            s.tf[int(m.group(6))] = T

    def _pick(self, streams: dict[str, _Stream], kind: str) -> _Stream:
        found = sorted(p for p in streams if re.search(rf"/{kind}_\d+$", p) and streams[p].stamp)
        if not found:
            name = "depth" if kind == "Depth" else "colour"
            raise FormatError(
                f"{self.source}: no {name} stream (expected a topic like /device_0/sensor_N/{kind}_0/image/data)"
            )
        return streams[found[0]]

    def _extrinsics(self, depth: _Stream, color: _Stream) -> np.ndarray:
        common = sorted(set(depth.tf) & set(color.tf))
        if common:
            ref = common[0]
            return color.tf[ref] @ np.linalg.inv(depth.tf[ref])
        if depth.size == color.size and np.allclose(depth.K, color.K):
            return np.eye(4)  # registered in the file already
        raise FormatError(
            f"{self.source}: no depth-to-colour extrinsics (expected {depth.topic.rsplit('/image', 1)[0]}/tf/0 "
            f"and {color.topic.rsplit('/image', 1)[0]}/tf/0)"
        )

    def _pair_color(self, depth: _Stream, color: _Stream) -> None:
        from fuseflow.io.timesync import nominal_period

        ds = np.asarray(depth.stamp, dtype=np.float64)
        cs = np.asarray(color.stamp, dtype=np.float64)
        order_ok = np.all(np.diff(ds) > 0)
        if not order_ok:
            raise FormatError(f"{self.source}: {depth.topic}: depth timestamps do not increase")
        period = nominal_period([ds, cs])
        tol = period / 2 if period > 0 else 0.0
        k = np.clip(np.searchsorted(cs, ds), 1, max(len(cs) - 1, 1)) if len(cs) > 1 else np.zeros(len(ds), int)
        lo = np.maximum(k - 1, 0)
        ci = np.where(np.abs(cs[lo] - ds) <= np.abs(cs[k] - ds), lo, k)
        ok = np.abs(cs[ci] - ds) <= tol
        self._view_depth = np.flatnonzero(ok)
        self._view_color = ci[ok]
        self.timestamps = ds[ok]
        self.device_frames = np.asarray(depth.seq, dtype=np.int64)[ok]
        self.fps = 1.0 / float(np.median(np.diff(ds))) if len(ds) > 1 else 0.0

    # ---- pass 2

    def views(self, wanted: set[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        want_d, want_c = wanted_messages(self._view_depth, self._view_color, wanted)
        got_d: dict[int, np.ndarray] = {}
        got_c: dict[int, np.ndarray] = {}
        nd = nc = 0
        try:
            with self._rosbag1.Reader(self.source) as reader:
                conns = [c for c in reader.connections if c.topic in (self._depth.topic, self._color.topic)]
                for conn, _, raw in reader.messages(connections=conns):
                    where = f"{self.source}: {conn.topic}"
                    if conn.topic == self._depth.topic:
                        if nd in want_d:
                            got_d[want_d[nd]] = self._depth_raw(read_image_message(raw, where), where)
                        nd += 1
                    else:
                        if nc in want_c:
                            rgb = _decode_color(read_image_message(raw, where), where)
                            for k in want_c[nc]:
                                got_c[k] = rgb
                        nc += 1
                    for k in [k for k in got_d if k in got_c]:
                        yield k, got_c.pop(k), got_d.pop(k)
        except self._rosbag1.ReaderError as exc:
            raise FormatError(f"{self.source}: not a readable ROS1 bag ({exc})") from None

    def _depth_raw(self, img: ImageMessage, where: str) -> np.ndarray:
        raw = _decode_depth(img, where)
        if self.aligned_in_file:
            return raw
        depth_m = raw.astype(np.float32) * np.float32(self.depth_units)
        al = align_depth_to_color(depth_m, self.K_depth, self.K, self.T_color_depth, (self.width, self.height))
        return np.clip(np.rint(al / np.float32(self.depth_units)), 0, 65535).astype(np.uint16)

    def describe(self) -> dict[str, Any]:
        """Facts about the file for messages and ``fuseflow info``."""
        return {"file": str(self.source), "serial": self.serial, "file_version": self.file_version,
                "depth_topic": self._depth.topic, "color_topic": self._color.topic, "fps": self.fps,
                "aligned_in_file": self.aligned_in_file}  # fmt: skip
