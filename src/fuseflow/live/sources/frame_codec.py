"""How a capture node ships its views to the fusing host: raw (the arrays as they are, for a node
on the fusing host's own Ray node, where Ray's object store is shared memory), or coded: colour as
JPEG (``quality``, lossy, full-resolution chroma), PNG (lossless) or raw bytes; depth always
lossless, as the 16-bit integers of the camera's depth units (``Camera.depth_scale``: metres x
depth_scale, the uint16 a depth camera delivers) compressed with LZ4 (``lz4`` package, about
0.6 ms a 640x480 view) or PNG (OpenCV, about 11 ms a view at level 1, a fifth smaller).

Raw: colour uint8 and depth float32 metres travel unchanged; decoded they are the node's arrays
bit for bit (3 bytes + 4 bytes a pixel: 2.15 MB a 640x480 view). ``raw16`` (``depth_units``):
colour raw and depth as the uint16 arrays of depth units, uncoded (3 + 2 bytes a pixel). ``lz4``
colour raw and depth LZ4. Both bit for bit as well.

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
DEPTH_CODECS = ("lz4", "png")


@dataclass(frozen=True)
class ViewCodec:
    """Colour and depth coders and JPEG quality of a node's views."""

    color: str = "jpeg"
    """jpeg (lossy, ``quality``, full-resolution chroma: 4:4:4), png (lossless) or raw (no coding:
    the arrays themselves, colour and depth, unless ``depth_raw`` is False)."""
    quality: int = 90
    """JPEG quality, 1..100."""
    png_level: int = 1
    """PNG compression level 0..9 of depth (and png colour): 1 is fast and within a few percent
    of the smallest."""
    depth: str = "lz4"
    """Lossless depth coder: lz4 (fast) or png (a fifth smaller, about 17x slower to encode)."""
    depth_raw: bool = True
    """With colour raw: depth as float32 arrays too (False: colour raw bytes, depth coded)."""
    depth_units: bool = False
    """With colour and depth raw: depth as the uint16 arrays of depth units (lossless, half the
    bytes of float32, no coding)."""

    @property
    def arrays(self) -> bool:
        """Colour and depth travel as the arrays themselves."""
        return self.color == "raw" and self.depth_raw

    @property
    def name(self) -> str:
        """The wire format in reports: raw, lz4 (raw colour, LZ4 depth) or COLOUR+DEPTH."""
        if self.color == "raw":
            return ("raw16" if self.depth_units else "raw") if self.depth_raw else f"raw+{self.depth}"
        return f"{self.color}+{self.depth}"

    def check(self) -> ViewCodec:
        if self.color not in COLOR_CODECS:
            raise ValidationError(f"colour codec must be one of {', '.join(COLOR_CODECS)}, got {self.color!r}")
        if self.depth not in DEPTH_CODECS:
            raise ValidationError(f"depth codec must be one of {', '.join(DEPTH_CODECS)}, got {self.depth!r}")
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


def _lz4():
    from fuseflow.errors import require

    return require("lz4.block", "ray", "LZ4 depth of capture nodes", "lz4")


def _depth_bytes(units: np.ndarray, codec: ViewCodec) -> bytes:
    if codec.depth == "lz4":
        return _lz4().compress(units.tobytes(), store_size=False)
    cv2 = _cv2()
    ok, d = cv2.imencode(".png", units, [cv2.IMWRITE_PNG_COMPRESSION, codec.png_level])
    if not ok:
        raise ValidationError("OpenCV could not encode a depth view")
    return d.tobytes()


def _color_bytes(rgb: np.ndarray, codec: ViewCodec) -> bytes:
    if codec.color == "raw":
        return np.ascontiguousarray(rgb, np.uint8).tobytes()
    cv2 = _cv2()
    flags = ([cv2.IMWRITE_JPEG_QUALITY, int(codec.quality), cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
              cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444] if codec.color == "jpeg"
             else [cv2.IMWRITE_PNG_COMPRESSION, codec.png_level])  # fmt: skip
    ok, c = cv2.imencode(".jpg" if codec.color == "jpeg" else ".png", np.ascontiguousarray(rgb[..., ::-1]), flags)
    if not ok:
        raise ValidationError("OpenCV could not encode a colour view")
    return c.tobytes()


def encode_views(color: np.ndarray, depth: np.ndarray, present: np.ndarray, scales: list[float],
                 codec: ViewCodec = ViewCodec()) -> EncodedViews:  # fmt: skip
    """(N, H, W, 3) uint8 RGB, (N, H, W) float32 metres, (N,) bool -> ``EncodedViews``."""
    if codec.arrays and not codec.depth_units:
        raw = (
            np.ascontiguousarray(color, np.uint8),
            np.ascontiguousarray(depth, np.float32),
            np.asarray(present, bool),
        )
        return EncodedViews([], [], codec, 0.0, 0, raw=raw)
    if codec.arrays:
        t0 = time.perf_counter()
        units, clipped = _units(depth, scales)
        raw = (np.ascontiguousarray(color, np.uint8), units, np.asarray(present, bool))
        return EncodedViews([], [], codec, (time.perf_counter() - t0) * 1e3, clipped, raw=raw)
    t0 = time.perf_counter()
    out_c: list[bytes | None] = []
    out_d: list[bytes | None] = []
    clipped = 0
    for i in range(len(present)):
        if not bool(present[i]):
            out_c.append(None)
            out_d.append(None)
            continue
        units, over = _units(depth[i : i + 1], scales[i : i + 1])
        clipped += over
        out_d.append(_depth_bytes(units[0], codec))
        out_c.append(_color_bytes(color[i], codec))
    return EncodedViews(out_c, out_d, codec, (time.perf_counter() - t0) * 1e3, clipped)


def _units(depth: np.ndarray, scales: list[float]) -> tuple[np.ndarray, int]:
    """(N, H, W) float32 metres -> (N, H, W) uint16 depth units (``round(depth x scale)``, 0
    beyond 65535) and the count of those clipped."""
    out = np.empty(depth.shape, np.uint16)
    clipped = 0
    for i in range(len(depth)):
        # float32 like the depth itself (depth units / scale): the same integers as float64 after
        # rounding, at a fifteenth of the time
        units = np.rint(np.asarray(depth[i], dtype=np.float32) * np.float32(scales[i]))
        over = units > 65535
        clipped += int(over.sum())
        units[over] = 0
        out[i] = units
    return out, clipped


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
        if depth.dtype == np.uint16:  # raw16: depth units
            metres = np.empty(depth.shape, np.float32)
            for i in range(len(depth)):
                np.divide(depth[i], np.float32(scales[i]), out=metres[i], dtype=np.float32)
            depth = metres
        return color, depth, present
    n = len(views.depth)
    color = np.zeros((n, h, w, 3), np.uint8)
    depth = np.zeros((n, h, w), np.float32)
    present = np.zeros(n, bool)
    for i in range(n):
        if views.depth[i] is None:
            continue
        d = _decode_depth(views.depth[i], views.codec, (h, w))
        c = _decode_color(views.color[i], views.codec, (h, w))
        if d is None or c is None or d.shape != (h, w) or c.shape[:2] != (h, w):
            raise ValidationError(f"view {i}: the node sent an image that does not decode to {w}x{h}")
        depth[i] = d.astype(np.float32) / np.float32(scales[i])
        color[i] = c
        present[i] = True
    return color, depth, present


def _decode_depth(data: bytes, codec: ViewCodec, shape: tuple[int, int]) -> np.ndarray | None:
    if codec.depth == "lz4":
        size = shape[0] * shape[1] * 2
        try:
            out = _lz4().decompress(data, uncompressed_size=size)
        except Exception:  # noqa: BLE001 - lz4.block.LZ4BlockError: corrupt or not this size
            return None
        return np.frombuffer(out, np.uint16).reshape(shape) if len(out) == size else None
    return _cv2().imdecode(np.frombuffer(data, np.uint8), _cv2().IMREAD_UNCHANGED)


def _decode_color(data: bytes, codec: ViewCodec, shape: tuple[int, int]) -> np.ndarray | None:
    if codec.color == "raw":
        size = shape[0] * shape[1] * 3
        return np.frombuffer(data, np.uint8).reshape(*shape, 3) if len(data) == size else None
    c = _cv2().imdecode(np.frombuffer(data, np.uint8), _cv2().IMREAD_COLOR)
    return None if c is None else c[..., ::-1]
