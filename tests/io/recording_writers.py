"""Test helpers: write RealSense .bag files and Azure Kinect .mkv files in the layouts the vendor
tools write, from arrays (simulator frames), so the converters can be tested without hardware.

RealSense: the topics, message types and serialisation of librealsense's ``ros_writer.cpp``
(``write_file_version``, ``write_vendor_info``, ``write_sensor_option``, ``write_stream_info``,
``write_streaming_info``, ``write_video_frame``, ``write_frame_metadata``, ``write_extrinsics``),
written with ``rosbags`` (the same library the reader uses).

Azure Kinect: the Matroska layout of the SDK's ``k4a_record_create`` / ``k4a_record_write_capture``
(tracks "COLOR" and "DEPTH" with codec "V_MS/VFW/FOURCC" and a BITMAPINFOHEADER, depth as
big-endian 16-bit "b16g", 1 us timecode scale, block times relative to K4A_START_OFFSET_NS,
"calibration.json" attached, K4A_* tags). FFmpeg's matroska muxer (PyAV) cannot write
VFW-mode tracks (it writes raw video as V_UNCOMPRESSED), so a small EBML writer does it here;
the reader under test demuxes it with PyAV.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

# ----------------------------------------------------------------------------- RealSense .bag


def _rotation_to_quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    # librealsense rot2quat (valid for rotations far from 180 degrees, as depth-to-colour ones are)
    w = np.sqrt(1 + R[0, 0] + R[1, 1] + R[2, 2]) / 2
    return (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w


def write_realsense_bag(
    path: Path,
    serial: str,
    color: np.ndarray,
    depth_raw: np.ndarray,
    stamps_s: np.ndarray,
    K_color: np.ndarray,
    depth_units: float = 0.001,
    K_depth: np.ndarray | None = None,
    T_color_depth: np.ndarray | None = None,
    depth_units_trailer: bool = True,
    color_stamps_s: np.ndarray | None = None,
    color_encoding: str = "rgb8",
    write_depth: bool = True,
    compress: bool = False,
) -> Path:
    """One RealSense device's recording.

    color: (T, H, W, 3) uint8 RGB; depth_raw: (T, h, w) uint16 depth units; stamps_s: (T,)
    device timestamps (seconds); K_depth / T_color_depth (colour-from-depth) default to a depth
    stream already registered to colour. depth_units_trailer: the float32 that recent
    librealsense appends to every Image message.
    """
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg("uint32 fps\nstring encoding\nbool is_recommended", "realsense_msgs/msg/StreamInfo"))
    T = len(stamps_s)
    K_depth = K_color if K_depth is None else K_depth
    T_cd = np.eye(4) if T_color_depth is None else T_color_depth
    color_stamps_s = stamps_s if color_stamps_s is None else color_stamps_s
    fps = int(round(1.0 / float(np.median(np.diff(stamps_s))))) if T > 1 else 30
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    KeyValue = ts.types["diagnostic_msgs/msg/KeyValue"]

    def stamp(t: float):
        sec = int(np.floor(t))
        return Time(sec=sec, nanosec=int(round((t - sec) * 1e9)))

    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    w = Writer(path)
    if compress:
        w.set_compression(Writer.CompressionFormat.LZ4)  # rs-record's compressed mode
    with w:
        conns: dict[str, object] = {}

        def put(topic: str, msgtype: str, msg: object, t_ns: int, trailer: bytes = b"") -> None:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], t_ns, bytes(ts.serialize_ros1(msg, msgtype)) + trailer)

        put("/file_version", "std_msgs/msg/UInt32", ts.types["std_msgs/msg/UInt32"](data=3), 0)
        for k, v in (("Name", "Intel RealSense D435"), ("Serial Number", serial), ("Firmware Version", "5.13.0.50")):
            put("/device_0/info", "diagnostic_msgs/msg/KeyValue", KeyValue(key=k, value=v), 0)
        put("/device_0/sensor_0/info", "diagnostic_msgs/msg/KeyValue", KeyValue(key="Name", value="Stereo Module"), 0)
        put("/device_0/sensor_1/info", "diagnostic_msgs/msg/KeyValue", KeyValue(key="Name", value="RGB Camera"), 0)
        put("/device_0/sensor_0/option/Depth Units/value", "std_msgs/msg/Float32",
            ts.types["std_msgs/msg/Float32"](data=depth_units), 0)  # fmt: skip
        put("/device_0/sensor_0/option/Depth Units/description", "std_msgs/msg/String",
            ts.types["std_msgs/msg/String"](data="Number of meters represented by a single depth unit"), 0)  # fmt: skip
        streams = [("/device_0/sensor_0/Depth_0", "mono16", K_depth, depth_raw.shape[1:], np.eye(4)),
                   ("/device_0/sensor_1/Color_0", color_encoding, K_color, color.shape[1:3], T_cd)]  # fmt: skip
        for prefix, enc, K, (h, wd), T_s_ref in streams:
            if prefix.endswith("Depth_0") and not write_depth:
                continue
            put(prefix + "/info", "realsense_msgs/msg/StreamInfo",
                ts.types["realsense_msgs/msg/StreamInfo"](fps=fps, encoding=enc, is_recommended=True), 0)  # fmt: skip
            ci = ts.types["sensor_msgs/msg/CameraInfo"](
                header=Header(seq=0, stamp=stamp(0.0), frame_id=""), height=h, width=wd,
                distortion_model="Brown Conrady", D=np.zeros(5), K=np.asarray(K, dtype=np.float64).reshape(9),
                R=np.zeros(9), P=np.zeros(12), binning_x=0, binning_y=0,
                roi=ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
            )  # fmt: skip
            put(prefix + "/info/camera_info", "sensor_msgs/msg/CameraInfo", ci, 0)
            q = _rotation_to_quaternion(T_s_ref[:3, :3])
            tf = ts.types["geometry_msgs/msg/Transform"](
                translation=ts.types["geometry_msgs/msg/Vector3"](x=T_s_ref[0, 3], y=T_s_ref[1, 3], z=T_s_ref[2, 3]),
                rotation=ts.types["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            put(prefix + "/tf/0", "geometry_msgs/msg/Transform", tf, 0)
        t0 = min(float(stamps_s[0]), float(color_stamps_s[0]))
        events = [(float(s), 0, k) for k, s in enumerate(stamps_s) if write_depth]
        events += [(float(s), 1, k) for k, s in enumerate(color_stamps_s)]
        for s, which, k in sorted(events):
            if which == 0:
                prefix, img, enc, units = "/device_0/sensor_0/Depth_0", depth_raw[k], "mono16", depth_units
                data, step = np.ascontiguousarray(img).astype("<u2").tobytes(), img.shape[1] * 2
            else:
                prefix, img, enc, units = "/device_0/sensor_1/Color_0", color[k], color_encoding, 0.0
                px = img if color_encoding == "rgb8" else img[..., ::-1]
                data, step = np.ascontiguousarray(px).tobytes(), img.shape[1] * 3
            msg = ts.types["sensor_msgs/msg/Image"](
                header=Header(seq=k + 1, stamp=stamp(s), frame_id=""), height=img.shape[0], width=img.shape[1],
                encoding=enc, is_bigendian=0, step=step, data=np.frombuffer(data, dtype=np.uint8),
            )  # fmt: skip
            t_ns = int(round((s - t0) * 1e9)) + 1
            put(prefix + "/image/data", "sensor_msgs/msg/Image", msg, t_ns,
                struct.pack("<f", units) if depth_units_trailer else b"")  # fmt: skip
            for key, val in (("system_time", f"{s * 1000:.6f}"), ("timestamp_domain", "Global Time"),
                             ("Frame Counter", str(k + 1))):  # fmt: skip
                put(prefix + "/image/metadata", "diagnostic_msgs/msg/KeyValue", KeyValue(key=key, value=val), t_ns)
    return path


# ----------------------------------------------------------------------------- Azure Kinect .mkv


def _vint_size(n: int) -> bytes:
    for length in range(1, 9):
        if n < (1 << (7 * length)) - 1:
            return (n | (1 << (7 * length))).to_bytes(length, "big")
    raise ValueError("EBML size too large")


def _el(eid: int, payload: bytes) -> bytes:
    return eid.to_bytes((eid.bit_length() + 7) // 8, "big") + _vint_size(len(payload)) + payload


def _uint(eid: int, v: int) -> bytes:
    return _el(eid, v.to_bytes(max(1, (v.bit_length() + 7) // 8), "big"))


def _str(eid: int, s: str) -> bytes:
    return _el(eid, s.encode("utf-8"))


def _bitmapinfoheader(width: int, height: int, bitcount: int, fourcc: int, size_image: int) -> bytes:
    return struct.pack("<IiiHHIIiiII", 40, width, height, 1, bitcount, fourcc, size_image, 0, 0, 0, 0)


def k4a_calibration_json(
    depth_params: list[float], color_params: list[float], R_color: np.ndarray, t_color_m: np.ndarray
) -> dict:
    """A device calibration.json: the depth camera at the identity, colour at [R | t] (metres).
    *_params: the 15 normalised ModelParameters (cx, cy, fx, fy, k1..k6, codx, cody, p2, p1, metric_radius)."""

    def cam(loc: str, purpose: str, params: list[float], w: int, h: int, R: np.ndarray, t: np.ndarray) -> dict:
        return {"Intrinsics": {"ModelParameterCount": 14, "ModelParameters": list(params),
                               "ModelType": "CALIBRATION_LensDistortionModelBrownConrady"},
                "Location": loc, "Purpose": purpose, "MetricRadius": 1.7, "SensorHeight": h, "SensorWidth": w,
                "Rt": {"Rotation": [float(x) for x in np.asarray(R).reshape(9)],
                       "Translation": [float(x) for x in np.asarray(t).reshape(3)]},
                "Shutter": "CALIBRATION_ShutterTypeUndefined", "ThermalAdjustmentParams": {"Params": [0.0] * 12}}  # fmt: skip

    return {"CalibrationInformation": {
        "Cameras": [cam("CALIBRATION_CameraLocationD0", "CALIBRATION_CameraPurposeDepth", depth_params, 1024, 1024,
                        np.eye(3), np.zeros(3)),
                    cam("CALIBRATION_CameraLocationPV0", "CALIBRATION_CameraPurposePhotoVideo", color_params, 4096, 3072,
                        R_color, t_color_m)],
        "InertialSensors": [], "Metadata": {"SerialId": "", "FactoryCalDate": "", "Version": {"Major": 1, "Minor": 2}}}}  # fmt: skip


def write_k4a_mkv(
    path: Path,
    color_bgra: np.ndarray,
    depth_mm: np.ndarray,
    stamps_us: np.ndarray,
    color_mode: str,
    depth_mode: str,
    calibration: dict | None,
    serial: str | None = "000123456789",
    start_offset_ns: int = 200_000,
) -> Path:
    """One Azure Kinect recording: COLOR (BGRA32, 'BGRA' fourcc) and DEPTH ('b16g') tracks, in
    k4arecorder's layout. color_bgra: (T, H, W, 4) uint8; depth_mm: (T, h, w) uint16;
    stamps_us: (T,) device timestamps (microseconds); color_mode e.g. "BGRA_720P"; depth_mode
    e.g. "NFOV_UNBINNED"; calibration: the calibration.json dict, or None to leave it out."""
    T, H, W = color_bgra.shape[:3]
    h, w = depth_mm.shape[1:]
    ebml_header = _el(0x1A45DFA3, _uint(0x4286, 1) + _uint(0x42F7, 1) + _uint(0x42F2, 4) + _uint(0x42F3, 8)
                      + _str(0x4282, "matroska") + _uint(0x4287, 4) + _uint(0x4285, 2))  # fmt: skip
    info = _el(0x1549A966, _uint(0x2AD7B1, 1000) + _str(0x4D80, "libmatroska-1.4.9")
               + _str(0x5741, "k4arecord-1.4.1") + _str(0x7BA9, "Azure Kinect"))  # fmt: skip
    uid_c, uid_d, uid_a = 1111, 2222, 3333

    def track(num: int, uid: int, name: str, bih: bytes, tw: int, th: int) -> bytes:
        video = _el(0xE0, _uint(0xB0, tw) + _uint(0xBA, th))
        return _el(0xAE, _uint(0xD7, num) + _uint(0x73C5, uid) + _uint(0x83, 1) + _str(0x536E, name)
                   + _str(0x86, "V_MS/VFW/FOURCC") + _el(0x63A2, bih) + _uint(0x23E383, 33_333_333) + video)  # fmt: skip

    tracks = _el(0x1654AE6B,
                 track(1, uid_c, "COLOR", _bitmapinfoheader(W, H, 32, 0x41524742, W * H * 4), W, H)
                 + track(2, uid_d, "DEPTH", _bitmapinfoheader(w, h, 16, 0x67363162, w * h * 2), w, h))  # fmt: skip
    attachments = b""
    if calibration is not None:
        data = json.dumps(calibration).encode()
        attachments = _el(0x1941A469, _el(0x61A7, _str(0x466E, "calibration.json") + _str(0x4660, "application/octet-stream")
                                                  + _el(0x465C, data) + _uint(0x46AE, uid_a)))  # fmt: skip

    def tag(name: str, value: str, target: bytes = b"") -> bytes:
        return _el(0x7373, _el(0x63C0, target) + _el(0x67C8, _str(0x45A3, name) + _str(0x4487, value)))

    trk = lambda uid: _uint(0x68CA, 30) + _uint(0x63C5, uid)  # noqa: E731
    tags_payload = (tag("K4A_COLOR_TRACK", str(uid_c), trk(uid_c)) + tag("K4A_COLOR_MODE", color_mode, trk(uid_c))
                    + tag("K4A_DEPTH_TRACK", str(uid_d), trk(uid_d)) + tag("K4A_DEPTH_MODE", depth_mode, trk(uid_d))
                    + tag("K4A_DEPTH_DELAY_NS", "0") + tag("K4A_WIRED_SYNC_MODE", "STANDALONE")
                    + tag("K4A_START_OFFSET_NS", str(start_offset_ns)))  # fmt: skip
    if serial is not None:
        tags_payload += tag("K4A_DEVICE_SERIAL_NUMBER", serial)
    if calibration is not None:
        tags_payload += tag("K4A_CALIBRATION_FILE", "calibration.json", _uint(0x68CA, 30) + _uint(0x63C6, uid_a))
    tags = _el(0x1254C367, tags_payload)
    clusters = b""
    for k in range(T):
        t_us = int(stamps_us[k]) - start_offset_ns // 1000
        color_bytes = np.ascontiguousarray(color_bgra[k]).tobytes()
        depth_bytes = np.ascontiguousarray(depth_mm[k]).astype(">u2").tobytes()  # b16g: big-endian
        blocks = b"".join(_el(0xA3, bytes([0x80 | tn]) + struct.pack(">hB", 0, 0x80) + data)
                          for tn, data in ((1, color_bytes), (2, depth_bytes)))  # fmt: skip
        clusters += _el(0x1F43B675, _uint(0xE7, t_us) + blocks)
    segment = _el(0x18538067, info + tracks + attachments + tags + clusters)
    path.write_bytes(ebml_header + segment)
    return path
