"""Reading and writing colour and depth images, with validation at the input boundary.

Every reader returns numpy arrays in the library's conventions: colour (H, W, 3) uint8 RGB,
depth (H, W) float32 metres with 0 = no measurement. Errors name the file.

Depth encodings (each reader states its units):

* ``uint16`` PNG with a depth scale in stored units per metre (1000 for ICL-NUIM / Redwood /
  RealSense / Azure Kinect millimetres, 5000 for TUM RGB-D).
* SUN RGB-D: uint16 whose 16 bits are rotated right by 3; metres = rot(d) / 1000.
* NYU Depth v2 raw: 16-bit Kinect disparity in a PGM whose bytes are actually little-endian
  although PGM says big-endian, so the NYU toolbox reads the PGM and then ``swapbytes``
  (Open3D's ``CreateFromNYUFormat`` does the same). metres = 351.3 / (1092.5 - d) (the toolbox's
  ``depth_rel2depth_abs``), with d = 0 or d >= 2047 meaning no measurement.
"""

from __future__ import annotations

import os
import re
import threading
from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError, RecordingError
from fuseflow.io.files import read_bytes

__all__ = [
    "read_color",
    "read_depth",
    "write_color",
    "write_depth",
    "decode_sun_depth",
    "decode_nyu_disparity",
    "read_pgm16",
    "clean_depth",
]


def _cv2():
    import cv2

    # Decoding failures are reported as FuseFlow errors naming the file; OpenCV's own
    # warnings on stderr would only duplicate them.
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    return cv2


def _read_bytes(path: Path) -> bytes:
    data = read_bytes(path)
    if not data:
        raise RecordingError(f"{path}: file is empty")
    return data


_JPEG_DAMAGE = (b"premature end of data segment", b"Huffman", b"Corrupt JPEG data: bad", b"before marker 0xd9")
"""libjpeg warnings that mean the picture itself is damaged (decoded with grey blocks: the
scan data ran out early, or bytes were left over before the end marker); others ("N extraneous
bytes before marker 0xc4", common from MJPEG cameras) leave the pixels intact."""

_STDERR_LOCK = threading.Lock()


def _imdecode_jpeg(cv2, data: bytes, flags: int, path: Path):
    """cv2.imdecode of a JPEG with libjpeg's warnings (written to file descriptor 2) caught:
    RecordingError when one says the entropy-coded data is damaged. Whatever else reached
    descriptor 2 meanwhile is written back. Without memfd (not Linux) the check is skipped."""
    buf = np.frombuffer(data, dtype=np.uint8)
    if not hasattr(os, "memfd_create"):  # pragma: no cover - Linux has it
        return cv2.imdecode(buf, flags)
    with _STDERR_LOCK:
        sink = os.memfd_create("fuseflow-jpeg")
        saved = os.dup(2)
        try:
            os.dup2(sink, 2)
            try:
                img = cv2.imdecode(buf, flags)
            finally:
                os.dup2(saved, 2)
            os.lseek(sink, 0, os.SEEK_SET)
            said = os.read(sink, 1 << 16)
        finally:
            os.close(saved)
            os.close(sink)
    damage = [line for line in said.splitlines() if any(k in line for k in _JPEG_DAMAGE)]
    rest = b"".join(line + b"\n" for line in said.splitlines() if line not in damage)
    if rest:
        os.write(2, rest)
    if damage and img is not None:
        raise RecordingError(
            f"{path}: corrupt JPEG data ({damage[0].decode(errors='replace').strip()}): it decodes with grey "
            "blocks; replace the file or drop the view"
        )
    return img


def _decode(path: Path, flags: int) -> np.ndarray:
    cv2 = _cv2()
    data = _read_bytes(path)
    if data[:2] == b"\xff\xd8":
        img = _imdecode_jpeg(cv2, data, flags, path)
    else:
        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    if img is None:
        raise RecordingError(f"{path}: not a readable image (corrupt, truncated or unsupported format)")
    if _looks_truncated(path, data):
        raise RecordingError(f"{path}: image file is truncated")
    return img


def _looks_truncated(path: Path, data: bytes) -> bool:
    # OpenCV decodes a truncated PNG or JPEG into a partially grey image with only a warning;
    # the end markers catch that: PNG ends with an IEND chunk, JPEG with EOI (FF D9).
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return b"IEND" not in data[-16:]
    if data[:2] == b"\xff\xd8":
        return b"\xff\xd9" not in data[-4:]
    return False


def read_color(path: str | Path) -> np.ndarray:
    """Read an 8-bit colour image (PNG, JPEG, PPM ...) as (H, W, 3) uint8 RGB."""
    cv2 = _cv2()
    path = Path(path)
    img = _decode(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        raise FormatError(f"{path}: colour image must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    elif img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    else:
        raise FormatError(f"{path}: colour image has {img.shape[2]} channels, expected 1, 3 or 4")
    return np.ascontiguousarray(img)


def read_depth_raw(path: str | Path) -> np.ndarray:
    """Read a single-channel 16-bit depth PNG as (H, W) uint16, without scaling."""
    cv2 = _cv2()
    path = Path(path)
    img = _decode(path, cv2.IMREAD_UNCHANGED)  # never folds 3 channels into one grey (x 0.30)
    if img.ndim != 2:
        raise FormatError(
            f"{path}: depth image must have one channel, got {img.shape[2]} ({img.dtype}): a colour "
            "image is not depth; write depth as a single-channel 16-bit PNG"
        )
    if img.dtype != np.uint16:
        raise FormatError(f"{path}: depth image must be 16-bit unsigned, got {img.dtype}")
    return img


def clean_depth(depth_m: np.ndarray) -> tuple[np.ndarray, int]:
    """Zero NaN, inf and negative depth (the input boundary rule); return (depth, count zeroed)."""
    depth_m = np.asarray(depth_m, dtype=np.float32)
    bad = ~np.isfinite(depth_m) | (depth_m < 0)
    n_bad = int(bad.sum())
    if n_bad:
        depth_m = depth_m.copy()
        depth_m[bad] = 0.0
    return depth_m, n_bad


def read_depth(path: str | Path, depth_scale: float) -> np.ndarray:
    """Read a uint16 depth PNG and convert to (H, W) float32 metres (value / depth_scale)."""
    raw = read_depth_raw(path)
    return raw.astype(np.float32) / np.float32(depth_scale)


def write_color(path: str | Path, rgb: np.ndarray) -> None:
    """Write (H, W, 3) uint8 RGB as PNG or JPEG (by extension)."""
    cv2 = _cv2()
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise FormatError(f"{path}: colour must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise RecordingError(f"{path}: could not write image")


def write_depth(path: str | Path, depth_m: np.ndarray, depth_scale: float) -> None:
    """Write (H, W) float32 metres as a uint16 PNG of round(depth * depth_scale).

    Depth that does not fit in uint16 at this scale is written as 0 (no measurement) rather than
    wrapped, so an over-range value can never come back as a wrong, small depth.
    """
    cv2 = _cv2()
    depth_m, _ = clean_depth(depth_m)
    if depth_m.ndim != 2:
        raise FormatError(f"{path}: depth must be (H, W), got {depth_m.shape}")
    q = np.rint(depth_m.astype(np.float64) * depth_scale)
    q[q > 65535] = 0
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), q.astype(np.uint16)):
        raise RecordingError(f"{path}: could not write depth image")


def decode_sun_depth(raw: np.ndarray) -> np.ndarray:
    """SUN RGB-D depth: uint16 with bits rotated by 3 -> float32 metres."""
    d = raw.astype(np.uint32)
    mm = ((d >> 3) | (d << 13)) & 0xFFFF
    return (mm.astype(np.float32) / 1000.0).astype(np.float32)


def read_pgm16(path: str | Path) -> np.ndarray:
    """Read a binary 16-bit PGM (P5, maxval > 255) as (H, W) uint16; PGM stores it big-endian."""
    path = Path(path)
    data = _read_bytes(path)
    m = re.match(rb"P5\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s+(?:#[^\n]*\n\s*)*(\d+)\s", data)
    if m is None:
        raise FormatError(f"{path}: not a binary PGM (P5) file")
    w, h, maxval = (int(g) for g in m.groups())
    if maxval < 256:
        raise FormatError(f"{path}: PGM is 8-bit (maxval {maxval}), expected 16-bit depth")
    need = w * h * 2
    body = data[m.end() :]
    if len(body) < need:
        raise RecordingError(f"{path}: PGM is truncated ({len(body)} of {need} bytes of pixel data)")
    return np.frombuffer(body[:need], dtype=">u2").reshape(h, w).astype(np.uint16)


def decode_nyu_disparity(raw: np.ndarray) -> np.ndarray:
    """NYU Depth v2 raw PGM values (as read per the PGM spec) -> float32 metres.

    Applies the toolbox's byte swap first, then metres = 351.3 / (1092.5 - d); 0 where d = 0
    or d >= 2047 (the Kinect's "no disparity" code).
    """
    d = raw.astype(np.uint16).byteswap().astype(np.float64)
    valid = (d > 0) & (d < 2047)
    out = np.zeros(d.shape, dtype=np.float64)
    out[valid] = 351.3 / (1092.5 - d[valid])
    out[(out < 0) | ~np.isfinite(out)] = 0.0
    return out.astype(np.float32)
