"""The binary frame formats of the live stream (``/ws``), one WebSocket binary message per fused
frame, little-endian (docs/live.md has them byte by byte). Two codecs (``CODECS``): ``compact``
(``fuseflow.live.codec``: key frames version 7, deltas version 6; 5, 3, 4 and 2 when asked for;
0.9-1.8 bytes a point, docs/live.md) and ``raw`` (version 1, below: 9 bytes a point, no
decompression). ``encode_frame`` writes either; ``decode_frame`` reads raw and every compact key
frame (deltas need the stream's ``codec.CompactDecoder``).

Version 1 (``raw``)::

    offset  size  type        field
    0       4     char[4]     magic "FFLV"
    4       2     uint16      version (1)
    6       2     uint16      header size in bytes (48): positions start here
    8       4     uint32      frame number (source sequence number)
    12      4     uint32      M, the number of points
    16      12    float32[3]  box minimum (x, y, z), metres, world frame
    28      12    float32[3]  box maximum (x, y, z)
    40      4     float32     latency: capture to encoding, milliseconds
    44      4     float32     FUSE time of the frame, milliseconds
    48      6 M   int16[M,3]  positions, quantised in the box (below)
    48+6M   3 M   uint8[M,3]  colours, RGB

Position decoding: ``p = min + (q + 32768) / 65535 * (max - min)`` per axis (a step of 1/65535
of the box: 0.06 mm for a 4 m box). A frame with no points has M = 0 and a zero box. The message
is 48 + 9 M bytes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from fuseflow.errors import FormatError, ValidationError
from fuseflow.live.codec import COMPACT_VERSIONS, CompactParams, decode_compact, encode_compact
from fuseflow.types import FusedCloud

__all__ = ["MAGIC", "VERSION", "HEADER", "CODECS", "encode_frame", "decode_frame", "DecodedFrame",
           "encode_attributes", "decode_attributes"]  # fmt: skip

MAGIC = b"FFLV"
VERSION = 1
_HEAD = struct.Struct("<4sHHII3f3fff")
HEADER = _HEAD.size
"""Header size in bytes (48)."""
CODECS = ("compact", "raw")
"""Frame codecs, the default first."""


@dataclass
class DecodedFrame:
    """A frame read back from its bytes (tests and Python clients)."""

    number: int
    xyz: np.ndarray
    """(M, 3) float32 metres: within one quantisation step of the sent positions (raw), or the
    centres of the occupied grid cells (compact: at most half a step off per axis)."""
    rgb: np.ndarray
    """(M, 3) uint8."""
    box: tuple[np.ndarray, np.ndarray]
    latency_ms: float
    fuse_ms: float
    version: int = VERSION
    points_in: int = -1
    """Points of the fused cloud before cells were merged (compact); M for raw."""
    step: float = 0.0
    """Grid step in metres (compact); 0 for raw."""


def encode_frame(
    cloud: FusedCloud,
    number: int,
    latency_ms: float,
    fuse_ms: float,
    codec: str = "raw",
    params: CompactParams = CompactParams(),
) -> bytes:
    """The message for one fused cloud in ``codec`` (module docstring)."""
    xyz = cloud.xyz.detach().cpu().numpy().astype(np.float32, copy=False)
    rgb = cloud.rgb.detach().cpu().numpy().astype(np.uint8, copy=False)
    if codec == "compact":
        return encode_compact(xyz, rgb, number, latency_ms, fuse_ms, params)
    if codec != "raw":
        raise ValidationError(f"unknown frame codec {codec!r}; codecs are {', '.join(CODECS)}")
    m = len(xyz)
    if m:
        from fuseflow.live.codec_kernels import bounds

        lo, hi = bounds(np.ascontiguousarray(xyz))
        scale = (np.float32(65535.0) / np.maximum(hi - lo, np.float32(1e-6))).astype(np.float32)
        q = np.subtract(xyz, lo, dtype=np.float32)  # in place from here: one float32 buffer
        np.multiply(q, scale, out=q)
        np.rint(q, out=q)
        np.subtract(q, np.float32(32768.0), out=q)
        np.clip(q, -32768.0, 32767.0, out=q)
        pos = q.astype("<i2")
    else:
        lo = hi = np.zeros(3, np.float32)
        pos = np.zeros((0, 3), "<i2")
    head = _HEAD.pack(MAGIC, VERSION, HEADER, number & 0xFFFFFFFF, m, *lo.tolist(), *hi.tolist(), latency_ms, fuse_ms)
    return b"".join((head, pos.tobytes(), np.ascontiguousarray(rgb).tobytes()))


def decode_frame(data: bytes) -> DecodedFrame:
    """Read a message written by ``encode_frame`` (either codec); FormatError when it is not one
    (truncated, corrupt, inconsistent or of an unknown version)."""
    data = bytes(data)
    if len(data) < 8:
        raise FormatError(f"live frame: {len(data)} bytes, too short for a header")
    magic, version = struct.unpack_from("<4sH", data)
    if magic == MAGIC and version in COMPACT_VERSIONS:
        h, xyz, rgb = decode_compact(data)
        box = (xyz.min(0), xyz.max(0)) if len(xyz) else (np.zeros(3, np.float32), np.zeros(3, np.float32))
        return DecodedFrame(h.number, xyz, rgb, box, h.latency_ms, h.fuse_ms, version, h.points_in, h.step)
    if magic != MAGIC or version != VERSION:
        raise FormatError(
            f"live frame: magic {magic!r} version {version}, expected {MAGIC!r} version {VERSION} "
            f"or {' or '.join(map(str, COMPACT_VERSIONS))}"
        )
    if len(data) < HEADER:
        raise FormatError(f"live frame: {len(data)} bytes, shorter than the {HEADER}-byte header")
    magic, version, head, number, m, *rest = _HEAD.unpack_from(data)
    if len(data) != head + 9 * m:
        raise FormatError(f"live frame: {len(data)} bytes, expected {head + 9 * m} for {m} points")
    lo, hi = np.array(rest[0:3], np.float32), np.array(rest[3:6], np.float32)
    q = np.frombuffer(data, "<i2", 3 * m, head).reshape(m, 3).astype(np.float32)
    xyz = lo + (q + 32768.0) / 65535.0 * np.maximum(hi - lo, np.float32(1e-6))
    rgb = np.frombuffer(data, np.uint8, 3 * m, head + 6 * m).reshape(m, 3)
    return DecodedFrame(
        number, xyz.astype(np.float32), rgb.copy(), (lo, hi), float(rest[6]), float(rest[7]), VERSION, m
    )


ATTR_MAGIC = b"FFLA"
_ATTR_HEAD = struct.Struct("<4sII")


def encode_attributes(cloud: FusedCloud, number: int) -> bytes:
    """Each point's camera and weight, in the order of its ``raw`` frame: magic "FFLA", uint32
    frame number, uint32 M, then M uint8 camera indices (the source's camera order; 255: none or
    over 254) and M uint8 weights (the point's weight over the frame's largest, times 255)."""
    cam = cloud.camera.detach().cpu().numpy().astype(np.int64)
    cam = np.where((cam >= 0) & (cam < 255), cam, 255).astype(np.uint8)
    w = cloud.weight.detach().cpu().numpy().astype(np.float32)
    top = float(w.max()) if len(w) else 0.0
    wq = np.rint(np.clip(w / top, 0.0, 1.0) * 255.0).astype(np.uint8) if top > 0 else np.zeros(len(w), np.uint8)
    return b"".join((_ATTR_HEAD.pack(ATTR_MAGIC, number & 0xFFFFFFFF, len(cam)), cam.tobytes(), wq.tobytes()))


def decode_attributes(data: bytes) -> tuple[int, np.ndarray, np.ndarray]:
    """(frame number, camera indices, weights 0-255) of an ``encode_attributes`` message."""
    data = bytes(data)
    if len(data) < _ATTR_HEAD.size:
        raise FormatError(f"attributes message: {len(data)} bytes, too short for a header")
    magic, number, m = _ATTR_HEAD.unpack_from(data)
    if magic != ATTR_MAGIC or len(data) != _ATTR_HEAD.size + 2 * m:
        raise FormatError(f"attributes message: magic {magic!r}, {len(data)} bytes for {m} points")
    body = np.frombuffer(data, np.uint8, 2 * m, _ATTR_HEAD.size)
    return number, body[:m].copy(), body[m:].copy()
