"""How a capture node ships its views to the fusing host: raw (the arrays as they are, for a node
on the fusing host's machine, where Ray's object store is memory), or compressed for a network:
colour as JPEG (``quality``, lossy) or PNG (lossless), depth always lossless as a 16-bit PNG of
the camera's depth units (``Camera.depth_scale``: metres x depth_scale, the uint16 a depth
camera delivers), through OpenCV's coders.

Raw: colour uint8 and depth float32 metres travel unchanged; decoded they are the node's arrays
bit for bit (3 bytes + 4 bytes a pixel: 2.15 MB a 640x480 view).

Depth round trip: ``encode_views`` writes ``round(depth x depth_scale)``, ``decode_views`` gives
``uint16 / depth_scale`` as float32, exactly what ``io`` reads from a recording's depth PNGs and
what the device sources compute from the sensor's uint16: the decoded depth equals the node's
bit for bit. Depth beyond 65535 depth units (65.5 m at depth_scale 1000) is written as 0 (no
measurement) and counted.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fuseflow.errors import ValidationError

__all__ = ["ViewCodec", "EncodedViews", "encode_views", "decode_views"]

COLOR_CODECS = ("jpeg", "png", "raw")


@dataclass(frozen=True)
class ViewCodec:
    """Colour coder and JPEG quality of a node's views (depth is lossless PNG, or raw with raw)."""

    color: str = "jpeg"
    """jpeg (lossy, ``quality``, full-resolution chroma: 4:4:4), png (lossless) or raw (no coding:
    the arrays themselves, colour and depth)."""
    quality: int = 90
    """JPEG quality, 1..100."""
    png_level: int = 1
    """PNG compression level 0..9 of depth (and png colour): 1 is fast and within a few percent
    of the smallest."""

    def check(self) -> ViewCodec:
        if self.color not in COLOR_CODECS:
            raise ValidationError(f"colour codec must be one of {', '.join(COLOR_CODECS)}, got {self.color!r}")
        if not 1 <= int(self.quality) <= 100:
            raise ValidationError(f"JPEG quality must be 1..100, got {self.quality}")
        if not 0 <= int(self.png_level) <= 9:
            raise ValidationError(f"PNG level must be 0..9, got {self.png_level}")
        return self


@dataclass
class EncodedViews:
    """One frame of a node's cameras, encoded; a view the camera did not deliver is None."""

    color: list[bytes | None]
    depth: list[bytes | None]
    codec: ViewCodec
    encode_ms: float = 0.0
    clipped: int = 0
    """Depth pixels beyond 65535 depth units, written as no measurement."""
    meta: dict = field(default_factory=dict)
    raw: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    """The raw codec's (colour, depth, present) arrays (``color`` and ``depth`` are then empty)."""

    @property
    def nbytes(self) -> int:
        if self.raw is not None:
            color, depth, present = self.raw
            return int(color[present].nbytes + depth[present].nbytes)
        return sum(len(b) for b in (*self.color, *self.depth) if b is not None)


def _cv2():
    import cv2

    return cv2


def encode_views(color: np.ndarray, depth: np.ndarray, present: np.ndarray, scales: list[float],
                 codec: ViewCodec = ViewCodec()) -> EncodedViews:  # fmt: skip
    """(N, H, W, 3) uint8 RGB, (N, H, W) float32 metres, (N,) bool -> ``EncodedViews``."""
    if codec.color == "raw":
        raw = (
            np.ascontiguousarray(color, np.uint8),
            np.ascontiguousarray(depth, np.float32),
            np.asarray(present, bool),
        )
        return EncodedViews([], [], codec, 0.0, 0, raw=raw)
    cv2 = _cv2()
    t0 = time.perf_counter()
    out_c: list[bytes | None] = []
    out_d: list[bytes | None] = []
    clipped = 0
    cflags = ([cv2.IMWRITE_JPEG_QUALITY, int(codec.quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
               cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444] if codec.color == "jpeg"
              else [cv2.IMWRITE_PNG_COMPRESSION, codec.png_level])  # fmt: skip
    ext = ".jpg" if codec.color == "jpeg" else ".png"
    for i in range(len(present)):
        if not bool(present[i]):
            out_c.append(None)
            out_d.append(None)
            continue
        # float32 like the depth itself (depth units / scale): the same integers as float64 after
        # rounding, at a fifteenth of the time
        units = np.rint(np.asarray(depth[i], dtype=np.float32) * np.float32(scales[i]))
        over = units > 65535
        clipped += int(over.sum())
        units[over] = 0
        ok_d, d = cv2.imencode(".png", units.astype(np.uint16), [cv2.IMWRITE_PNG_COMPRESSION, codec.png_level])
        ok_c, c = cv2.imencode(ext, np.ascontiguousarray(color[i][..., ::-1]), cflags)
        if not (ok_d and ok_c):
            raise ValidationError(f"view {i}: OpenCV could not encode it")
        out_c.append(c.tobytes())
        out_d.append(d.tobytes())
    return EncodedViews(out_c, out_d, codec, (time.perf_counter() - t0) * 1e3, clipped)


def decode_views(
    views: EncodedViews, scales: list[float], shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``EncodedViews`` -> (N, H, W, 3) uint8, (N, H, W) float32 metres, (N,) bool present;
    ``shape`` is (H, W) of a view."""
    h, w = shape
    if views.raw is not None:
        color, depth, present = views.raw
        if color.shape[1:] != (h, w, 3) or depth.shape[1:] != (h, w) or not len(color) == len(depth) == len(present):
            raise ValidationError(f"the node sent raw views that are not {w}x{h}")
        return color, depth, present
    cv2 = _cv2()
    n = len(views.depth)
    color = np.zeros((n, h, w, 3), np.uint8)
    depth = np.zeros((n, h, w), np.float32)
    present = np.zeros(n, bool)
    for i in range(n):
        if views.depth[i] is None:
            continue
        d = cv2.imdecode(np.frombuffer(views.depth[i], np.uint8), cv2.IMREAD_UNCHANGED)
        c = cv2.imdecode(np.frombuffer(views.color[i], np.uint8), cv2.IMREAD_COLOR)
        if d is None or c is None or d.shape != (h, w) or c.shape[:2] != (h, w):
            raise ValidationError(f"view {i}: the node sent an image that does not decode to {w}x{h}")
        depth[i] = d.astype(np.float32) / np.float32(scales[i])
        color[i] = c[..., ::-1]
        present[i] = True
    return color, depth, present
