"""The compact frame format of the live stream (version 2, ``--codec compact``): positions on a
grid coded as an octree, colour as quantised luma / chroma residuals, each stream deflated.

A message, little-endian (docs/live.md has it byte by byte with the decoding steps)::

    offset  size  type        field
    0       4     char[4]     magic "FFLV"
    4       2     uint16      version (2)
    6       2     uint16      header size H in bytes (64): the streams start here
    8       4     uint32      frame number
    12      4     uint32      M, the number of points sent (occupied grid cells)
    16      4     uint32      points before merging (the fused cloud's size)
    20      12    float32[3]  grid origin (x, y, z), metres, world frame
    32      4     float32     grid step s, metres
    36      4     float32     latency: capture to encoding, milliseconds
    40      4     float32     FUSE time of the frame, milliseconds
    44      1     uint8       L, octree depth (levels)
    45      1     uint8       luma step
    46      1     uint8       chroma step
    47      1     uint8       chroma block (points sharing one chroma pair)
    48      4     uint32      occupancy bytes (decompressed size of stream 1)
    52      4     uint32      stream 1 size (zlib): octree occupancy, one byte per node
    56      4     uint32      stream 2 size (zlib): luma residuals, M bytes
    60      4     uint32      stream 3 size (zlib): chroma residuals, 2 ceil(M / block) bytes
    64      ...               the three zlib streams, one after the other

Positions: every point is snapped to the cell ``i = floor((p - origin) / s)`` of a grid of
``2^L`` cells per axis and decoded at the cell's centre ``origin + (i + 0.5) s``: at most s / 2
off per axis. Points that fall in one cell are merged into one (their mean colour). The occupied
cells are coded as an octree, breadth first from the root: one byte per node, bit ``k`` set when
child ``k`` is occupied, with ``k = 4 x_bit + 2 y_bit + z_bit``; children in increasing ``k``.
Points come out in that order (Morton order), which the colour streams follow.

Colour: ``Y = (77 R + 150 G + 29 B + 128) >> 8``, ``Cb = B - Y``, ``Cr = R - Y``; the luma
``round(Y / luma_step)`` per point and the chroma ``round(mean(Cb) / chroma_step)``,
``round(mean(Cr) / chroma_step)`` per block of ``chroma_block`` consecutive points, each sent as
the difference to the previous value (mod 256).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from fuseflow.errors import FormatError, ValidationError

__all__ = ["CompactParams", "COMPACT_VERSION", "COMPACT_HEADER", "encode_compact", "decode_compact", "MAX_LEVELS"]

COMPACT_VERSION = 2
_HEAD = struct.Struct("<4sHHIII3ffffBBBBIIII")
COMPACT_HEADER = _HEAD.size
"""Header size in bytes (64)."""
MAX_LEVELS = 21
"""Octree depth limit: 2^21 cells per axis (4 km at 2 mm)."""


@dataclass(frozen=True)
class CompactParams:
    """How coarse the compact format is (docs/live.md, "Bandwidth", has the trade-off)."""

    step_mm: float = 3.0
    """Grid step: positions are at most step / 2 off per axis. 3 mm is about the spacing of a
    200 k-point ``--preset live`` cloud of an 8-camera rig (docs/live.md, "Bandwidth")."""
    luma_step: int = 4
    """Luma quantisation step (1 = lossless 8-bit luma); the luma error is at most step / 2."""
    chroma_step: int = 8
    """Chroma quantisation step (2 or more)."""
    chroma_block: int = 4
    """Consecutive points (in Morton order: neighbours) that share one chroma pair."""

    def check(self) -> CompactParams:
        if not (0.01 <= self.step_mm <= 1000.0):
            raise ValidationError(f"--grid-mm must be between 0.01 and 1000 mm, got {self.step_mm}")
        if not (1 <= self.luma_step <= 64 and 2 <= self.chroma_step <= 64 and 1 <= self.chroma_block <= 64):
            raise ValidationError(
                f"compact colour: luma step 1-64, chroma step 2-64, chroma block 1-64; got "
                f"{self.luma_step}, {self.chroma_step}, {self.chroma_block}"
            )
        return self


def _deflate(data: bytes) -> bytes:
    """zlib (RFC 1950) with Huffman coding only: these streams have no long repeats to match,
    and it is several times faster than the default at the same size."""
    c = zlib.compressobj(6, zlib.DEFLATED, 15, 9, zlib.Z_HUFFMAN_ONLY)
    return c.compress(data) + c.flush()


def encode_compact(
    xyz: np.ndarray, rgb: np.ndarray, number: int, latency_ms: float, fuse_ms: float, params: CompactParams
) -> bytes:
    """The version-2 message for (M, 3) float32 positions and (M, 3) uint8 colours."""
    from fuseflow.live.codec_kernels import compact_streams, finite_min, grid_cells

    step = params.step_mm / 1000.0
    xyz = np.ascontiguousarray(xyz, np.float32)
    lo, bad = finite_min(xyz)
    if bad:  # points with a NaN or infinite coordinate are not sent
        keep = np.isfinite(xyz).all(1)
        xyz, rgb = np.ascontiguousarray(xyz[keep]), rgb[keep]
    n_in = len(xyz)
    origin = lo.astype(np.float32) if n_in else np.zeros(3, np.float32)
    cells, top = grid_cells(xyz, origin.astype(np.float64), 1.0 / step)
    levels = max(1, int(top).bit_length())
    if levels > MAX_LEVELS:
        raise ValidationError(
            f"compact frame: the cloud spans {top * step:.1f} m, over 2^{MAX_LEVELS} cells of {params.step_mm:g} mm; "
            "use a larger --grid-mm or --crop"
        )
    if n_in:
        occ, luma, chroma, m = compact_streams(cells, levels, np.ascontiguousarray(rgb), params.luma_step,
                                               params.chroma_step, params.chroma_block)  # fmt: skip
    else:
        occ = luma = chroma = np.zeros(0, np.uint8)
        m = 0
    streams = [_deflate(occ.tobytes()), _deflate(luma.tobytes()), _deflate(chroma.tobytes())]
    head = _HEAD.pack(
        b"FFLV", COMPACT_VERSION, COMPACT_HEADER, number & 0xFFFFFFFF, int(m), n_in, *origin.tolist(),
        step, latency_ms, fuse_ms, levels, params.luma_step, params.chroma_step, params.chroma_block,
        len(occ), *(len(s) for s in streams),
    )  # fmt: skip
    return b"".join([head, *streams])


@dataclass
class CompactHeader:
    number: int
    points: int
    points_in: int
    origin: np.ndarray
    step: float
    latency_ms: float
    fuse_ms: float
    levels: int
    luma_step: int
    chroma_step: int
    chroma_block: int
    occupancy_bytes: int
    sizes: tuple[int, int, int]


def _inflate(data: bytes, expected: int, what: str) -> bytes:
    try:
        d = zlib.decompressobj()
        out = d.decompress(data, expected + 1)
        if not d.eof or d.unused_data:
            raise FormatError(f"live frame: the {what} stream is truncated or has trailing bytes")
    except zlib.error as exc:
        raise FormatError(f"live frame: the {what} stream is corrupt ({exc})") from None
    if len(out) != expected:
        raise FormatError(f"live frame: the {what} stream holds {len(out)} bytes, expected {expected}")
    return out


def _read_header(data: bytes) -> CompactHeader:
    if len(data) < COMPACT_HEADER:
        raise FormatError(f"live frame: {len(data)} bytes, shorter than the {COMPACT_HEADER}-byte header")
    f = _HEAD.unpack_from(data)
    h = CompactHeader(f[3], f[4], f[5], np.array(f[6:9], np.float32), *f[9:17], tuple(f[17:20]))
    if f[2] != COMPACT_HEADER or not (1 <= h.levels <= MAX_LEVELS) or not (h.step > 0) or h.points > h.points_in:
        raise FormatError(f"live frame: bad compact header (size {f[2]}, levels {h.levels}, step {h.step})")
    if min(h.luma_step, h.chroma_step, h.chroma_block) < 1:
        raise FormatError("live frame: bad compact header (zero colour step or block)")
    if len(data) != COMPACT_HEADER + sum(h.sizes):
        raise FormatError(f"live frame: {len(data)} bytes, expected {COMPACT_HEADER + sum(h.sizes)} from its header")
    return h


def _cells(occ: bytes, levels: int, points: int) -> np.ndarray:
    """(M, 3) integer cells from breadth-first occupancy bytes, in Morton order."""
    occ_a = np.frombuffer(occ, np.uint8)
    cells = np.zeros((1, 3), np.int64)
    offsets = np.array([[k >> 2, (k >> 1) & 1, k & 1] for k in range(8)], np.int64)
    pos = 0
    for _ in range(levels):
        n = len(cells)
        if pos + n > len(occ_a):
            raise FormatError("live frame: the occupancy stream ends before the octree does")
        mask = np.unpackbits(occ_a[pos : pos + n, None], axis=1, bitorder="little").astype(bool)
        parent, child = np.nonzero(mask)
        cells = cells[parent] * 2 + offsets[child]
        pos += n
    if pos != len(occ_a) or len(cells) != points:
        raise FormatError(f"live frame: the octree gives {len(cells)} points and uses {pos} of {len(occ_a)} bytes; "
                          f"the header says {points} points")  # fmt: skip
    return cells


def _colours(luma: bytes, chroma: bytes, h: CompactHeader) -> np.ndarray:
    m, k = h.points, h.chroma_block
    nb = -(-m // k)
    y = np.cumsum(np.frombuffer(luma, np.uint8), dtype=np.int64) % 256 * h.luma_step
    c = np.frombuffer(chroma, np.uint8).reshape(2, nb)
    cb, cr = (np.repeat((np.cumsum(c[i], dtype=np.int64) % 256).astype(np.uint8).view(np.int8), k)[:m]
              .astype(np.float64) * h.chroma_step for i in range(2))  # fmt: skip
    r, b = y + cr, y + cb
    g = (256.0 * y - 77.0 * r - 29.0 * b) / 150.0
    return np.clip(np.rint(np.stack([r, g, b], 1)), 0, 255).astype(np.uint8)


def decode_compact(data: bytes) -> tuple[CompactHeader, np.ndarray, np.ndarray]:
    """(header, (M, 3) float32 cell-centre positions, (M, 3) uint8 colours) of a version-2
    message; FormatError for anything truncated, corrupt or inconsistent."""
    h = _read_header(data)
    a = COMPACT_HEADER
    b, c = a + h.sizes[0], a + h.sizes[0] + h.sizes[1]
    m = h.points
    occ = _inflate(data[a:b], h.occupancy_bytes, "occupancy")
    luma = _inflate(data[b:c], m, "luma")
    chroma = _inflate(data[c:], 2 * (-(-m // h.chroma_block)), "chroma")
    if m == 0:
        return h, np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    cells = _cells(occ, h.levels, m)
    xyz = (h.origin.astype(np.float64) + (cells + 0.5) * h.step).astype(np.float32)
    return h, xyz, _colours(luma, chroma, h)
