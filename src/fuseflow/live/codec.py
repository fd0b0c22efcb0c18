"""The compact frame formats of the live stream (``--codec compact``): positions on a grid coded
as an octree, colour as quantised luma / chroma residuals. Version 3 range-codes both with
adaptive context models; version 4 is a delta: the same, coded against the previous frame of the
stream (``InterEncoder`` writes both, ``CompactDecoder`` reads a stream in order); versions 5
and 6 (the deltas written by default) are 3 and 4 with chroma blocks that split; version 2
deflates byte streams; version 7 (the key frames written by default) is version 5 with the
octree coded as one symbol a node, its occupancy byte, from adaptive frequency tables. ``decode_compact`` reads
versions 2, 3, 5 and 7.
docs/live.md has them byte by byte with the decoding steps.

Version 3, little-endian::

    offset  size  type        field
    0       4     char[4]     magic "FFLV"
    4       2     uint16      version (3)
    6       2     uint16      header size H in bytes (60): the streams start here
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
    48      4     uint32      CRC-32 (zlib's) of everything after the header
    52      4     uint32      stream 1 size: geometry (range coded)
    56      4     uint32      stream 2 size: colour (range coded)
    60      ...               the two streams, one after the other

Positions: every point is snapped to the cell ``i = floor((p - origin) / s)`` of a grid of
``2^L`` cells per axis and decoded at the cell's centre ``origin + (i + 0.5) s``: at most s / 2
off per axis. Points that fall in one cell are merged into one (their mean colour). The occupied
cells form an octree, coded depth by depth from the root, nodes in Morton order (children in
increasing ``k = 4 x_bit + 2 y_bit + z_bit``); points come out in Morton order.

The range coder is LZMA's binary one: 32-bit range, 11-bit probabilities that start at one half
and adapt after every decision (``p += (2048 - p) >> 5`` after a 0, ``p -= p >> 5`` after a 1);
stream byte 0 is always 0. Geometry: for every node of depths 0..L-1, a single-child flag, then
either that child's index k as 3 bits of a binary tree or the 8 child bits k = 0..7 (bit 7 implied
when bits 0-6 hold at most one child), in contexts of the node's face neighbours (found from the
parents' without a search; ``codec_kernels.child_neighbours``), k and the siblings coded so far
(``codec_kernels.geo_contexts``).

Colour: ``Y = (R + 2G + B) / 4`` per point, ``Co = R - B`` and ``Cg = G - (R + B) / 2`` as means
over blocks of ``chroma block`` consecutive points, each rounded to a multiple of its step and
sent as the difference to the previous point's (block's) value: a nonzero flag, the sign, the
magnitude in unary up to 14, then an Exp-Golomb code of ``magnitude - 14``, all in contexts of
the size (0, 1, more) of the previous residual of the channel (and of this point's luma or Co
residual for Co and Cg). Versions 5 and 6: each block starts with a split flag (in a context of
the previous block's flag); the points of a split block each send their own Co, Cg (after their
luma), predicted from the previous point's. The encoder splits a block when a point's Co or Cg is
more than ``CompactParams.split`` chroma steps off the block's mean. Decoding: ``R = Y + Co/2 - Cg/2``, ``G = Y + Cg/2``,
``B = Y - Co/2 - Cg/2``, rounded half to even and clamped to 0-255.

Version 7: version 5's header (version 7) and colour stream; the geometry stream holds, for every
node in version 3's order, one symbol: its occupancy byte in the canonical frame of its face
neighbour pattern (the cube's 48 symmetries take the 64 patterns to 10 classes; the byte's
children move with the pattern), numbered by its number of children, from an adaptive frequency
table per class and last depth or not, multi-symbol range coded
(``codec_kernels.symmetry_tables``, ``symbol_code``).

Version 2 (deflated byte streams; read, and written with ``CompactParams(version=2)``)::

    offset  size  type        field
    0-47                      as version 3 (version 2, header size 64)
    48      4     uint32      occupancy bytes (decompressed size of stream 1)
    52      4     uint32      stream 1 size (zlib): octree occupancy, one byte per node
    56      4     uint32      stream 2 size (zlib): luma residuals, M bytes
    60      4     uint32      stream 3 size (zlib): chroma residuals, 2 ceil(M / block) bytes
    64      ...               the three zlib streams, one after the other

The occupancy bytes are breadth first from the root, bit ``k`` set when child ``k`` is occupied;
``Y = (77 R + 150 G + 29 B + 128) >> 8``, ``Cb = B - Y``, ``Cr = R - Y``; the luma
``round(Y / luma_step)`` per point and the chroma ``round(mean(Cb) / chroma_step)``,
``round(mean(Cr) / chroma_step)`` per block, each the difference to the previous value (mod 256).
"""

from __future__ import annotations

import os
import struct
import zlib
from dataclasses import dataclass

import numpy as np

from fuseflow.errors import FormatError, ValidationError

__all__ = [
    "CompactParams",
    "CompactDecoder",
    "InterEncoder",
    "COMPACT_VERSION",
    "COMPACT_VERSIONS",
    "COMPACT_HEADER",
    "encode_compact",
    "decode_compact",
    "MAX_LEVELS",
    "MAX_POINTS",
]

COMPACT_VERSION = 7
"""``CompactParams.version`` by default: the range-coded format with the octree as one symbol a
node (key frames of version 7, deltas of version 6; with ``split=0``: versions 3 and 4)."""
COMPACT_VERSIONS = (2, 3, 4, 5, 6, 7)
"""The compact versions ``decode_compact`` reads."""
_HEAD = struct.Struct("<4sHHIII3ffffBBBBIIII")  # version 2
_HEAD3 = struct.Struct("<4sHHIII3ffffBBBBIII")
_HEAD4 = struct.Struct("<4sHHIII3ffffBBBBIIII")  # version 3's fields, then the reference's number
_KEY, _DELTA = {False: 3, True: 5}, {False: 4, True: 6}
"""Message versions of a key frame and a delta, without and with split chroma blocks."""
COMPACT_HEADER = _HEAD3.size
"""Header size in bytes of version 3 (60; version 2: 64)."""
MAX_POINTS = 1 << 26
"""Most points a compact frame may hold (a decoder refuses more before allocating for them)."""
MAX_LEVELS = 21
"""Octree depth limit: 2^21 cells per axis (4 km at 2 mm)."""


@dataclass(frozen=True)
class CompactParams:
    """How coarse the compact format is (docs/live.md, "Bandwidth", has the trade-off)."""

    step_mm: float = 3.0
    """Grid step: positions are at most step / 2 off per axis. 3 mm is about the spacing of a
    200 k-point ``--preset live`` cloud of an 8-camera rig (docs/live.md, "Bandwidth")."""
    luma_step: int = 12
    """Luma quantisation step (1 = lossless 8-bit luma); the luma error is at most step / 2. 12
    keeps the colour error's 95th percentile at 12 levels or less on the clouds of docs/live.md,
    "Bandwidth" (0.4-0.5 bits a point fewer than 8, at a median error of 4 levels instead of 3)."""
    chroma_step: int = 16
    """Chroma quantisation step (2 or more)."""
    chroma_block: int = 4
    """Consecutive points (in Morton order: neighbours) that share one chroma pair."""
    version: int = COMPACT_VERSION
    """Format version written: 7 (range coded, the octree's nodes as one symbol each in key
    frames: messages of version 7, deltas of version 6; with ``split=0`` versions 3 and 4), 3
    (range coded, the octree's nodes as bits: with ``split`` versions 5 and 6, else 3 and 4) or 2
    (deflated; its rows in docs/live.md use luma step 4, chroma step 8)."""
    split: float = 1.5
    """A chroma block where a point's Co or Cg is more than this many chroma steps off the
    block's mean sends every point's own (versions 5 and 6); 0: never (versions 3 and 4)."""

    def check(self) -> CompactParams:
        if not (0.01 <= self.step_mm <= 1000.0):
            raise ValidationError(f"--grid-mm must be between 0.01 and 1000 mm, got {self.step_mm}")
        if not (1 <= self.luma_step <= 64 and 2 <= self.chroma_step <= 64 and 1 <= self.chroma_block <= 64):
            raise ValidationError(
                f"compact colour: luma step 1-64, chroma step 2-64, chroma block 1-64; got "
                f"{self.luma_step}, {self.chroma_step}, {self.chroma_block}"
            )
        if not (0.0 <= self.split <= 64.0):
            raise ValidationError(f"compact chroma split must be between 0 and 64 chroma steps, got {self.split}")
        if self.version not in (2, 3, 7):
            raise ValidationError(f"compact version must be 2, 3 or 7, got {self.version}")
        return self


def _deflate(data: bytes) -> bytes:
    """zlib (RFC 1950) with Huffman coding only: these streams have no long repeats to match,
    and it is several times faster than the default at the same size."""
    c = zlib.compressobj(6, zlib.DEFLATED, 15, 9, zlib.Z_HUFFMAN_ONLY)
    return c.compress(data) + c.flush()


_POOL: dict = {}
"""The geometry worker of this process (by pid: a forked child starts its own)."""
_NO_REF = (np.zeros(0, np.uint8), np.zeros(0, np.int64), np.zeros((0, 3), np.int64))


def _pool():
    from concurrent.futures import ThreadPoolExecutor

    pool = _POOL.get(os.getpid())
    if pool is None:
        pool = _POOL[os.getpid()] = ThreadPoolExecutor(1, thread_name_prefix="fuseflow-codec")
    return pool


@dataclass
class _Reference:
    """A decoded frame as the next one may refer to it: its grid and colour steps, its depth, its
    leaves' quantised Y, Co, Cg, and its leaf keys (encoder) or octree bytes (decoder); ``octree``
    makes the breadth-first bytes and ``ref_first`` of them only when a delta refers to it."""

    number: int
    grid: bytes
    levels: int
    q: np.ndarray
    leaves: np.ndarray | None = None
    occ: np.ndarray | None = None
    first: np.ndarray | None = None

    def octree(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(breadth-first occupancy bytes, ``ref_first`` of them, quantised colour)."""
        from fuseflow.live.codec_kernels import occupancy, ref_first

        if self.occ is None:
            self.occ = occupancy(self.leaves, self.levels)
        if self.first is None:
            self.first = ref_first(self.occ, self.levels)[0]
        return self.occ, self.first, self.q


def _streams(leaves, mean, levels, p: CompactParams, ref: _Reference | None, rleaf) -> tuple[bytes, bytes, np.ndarray]:
    """(geometry stream, colour stream, quantised colour) of a frame's leaves, against ``ref``
    (None: a key frame, its geometry as one symbol a node when ``p.version`` is 7); the geometry
    is coded in a worker thread (the kernels release the GIL)."""
    from fuseflow.live.codec_kernels import colour_stream, geometry_stream, geometry_symbols_stream, symmetry_tables

    rocc, rfirst, rq = _NO_REF if ref is None else ref.octree()
    if ref is None and _key_version(p) == 7:
        cls, fwd, _ = symmetry_tables()
        geo = _pool().submit(lambda: (geometry_symbols_stream(leaves, levels, cls, fwd),))
    else:
        geo = _pool().submit(geometry_stream, leaves, levels, rocc, rfirst)
    col, q = colour_stream(mean, p.luma_step, p.chroma_step, p.chroma_block, rleaf, rq, float(p.split))
    return geo.result()[0].tobytes(), col.tobytes(), q


def _key_version(p: CompactParams) -> int:
    """The message version of a key frame written with ``p``."""
    return 2 if p.version == 2 else 7 if p.version == 7 and p.split > 0 else _KEY[p.split > 0]


def _streams_v3(cells: np.ndarray, levels: int, rgb: np.ndarray, p: CompactParams) -> tuple[bytes, bytes, int]:
    """(geometry stream, colour stream, points sent) of a key frame."""
    from fuseflow.live.codec_kernels import leaves_v3

    leaves, mean = leaves_v3(cells, levels, rgb)
    geo, col, _ = _streams(leaves, mean, levels, p, None, np.full(len(leaves), -1, np.int64))
    return geo, col, len(leaves)


def _finite(xyz: np.ndarray, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(finite points as contiguous float32, their uint8 colours, per-axis minimum): points with a
    NaN or infinite coordinate are not sent."""
    from fuseflow.live.codec_kernels import finite_min

    xyz = np.ascontiguousarray(xyz, np.float32)
    lo, bad = finite_min(xyz)
    if bad:
        keep = np.isfinite(xyz).all(1)
        xyz, rgb = np.ascontiguousarray(xyz[keep]), rgb[keep]
    if len(xyz) > MAX_POINTS:
        raise ValidationError(f"compact frame: {len(xyz)} points, over the format's {MAX_POINTS}")
    return xyz, np.ascontiguousarray(rgb, np.uint8), lo


def _levels(top: int, step_mm: float) -> int:
    levels = max(1, int(top).bit_length())
    if levels > MAX_LEVELS:
        raise ValidationError(
            f"compact frame: the cloud spans {top * step_mm / 1000:.1f} m, over 2^{MAX_LEVELS} cells of {step_mm:g} mm; "
            "use a larger --grid-mm or --crop"
        )
    return levels


def encode_compact(
    xyz: np.ndarray, rgb: np.ndarray, number: int, latency_ms: float, fuse_ms: float, params: CompactParams
) -> bytes:
    """The compact message (``params.version`` 7: version 7; 3: version 5; either with
    ``split=0``: version 3; or 2) for (M, 3) float32 positions and (M, 3) uint8 colours."""
    from fuseflow.live.codec_kernels import compact_streams, grid_cells

    params.check()
    step = params.step_mm / 1000.0
    xyz, rgb, lo = _finite(xyz, rgb)
    n_in = len(xyz)
    origin = lo.astype(np.float32) if n_in else np.zeros(3, np.float32)
    cells, top = grid_cells(xyz, origin.astype(np.float64), 1.0 / step)
    levels = _levels(top, params.step_mm)
    p = params
    version = _key_version(p)
    fixed = (b"FFLV", version, _HEAD.size if p.version == 2 else COMPACT_HEADER, number & 0xFFFFFFFF)
    tail = (*origin.tolist(), step, latency_ms, fuse_ms, levels, p.luma_step, p.chroma_step, p.chroma_block)
    if p.version != 2:
        geo, col, m = _streams_v3(cells, levels, rgb, p) if n_in else (b"", b"", 0)
        body = geo + col
        return _HEAD3.pack(*fixed, int(m), n_in, *tail, zlib.crc32(body), len(geo), len(col)) + body
    if n_in:
        occ, luma, chroma, m = compact_streams(cells, levels, rgb, p.luma_step, p.chroma_step, p.chroma_block)
    else:
        occ = luma = chroma = np.zeros(0, np.uint8)
        m = 0
    streams = [_deflate(occ.tobytes()), _deflate(luma.tobytes()), _deflate(chroma.tobytes())]
    head = _HEAD.pack(*fixed, int(m), n_in, *tail, len(occ), *(len(s) for s in streams))
    return b"".join([head, *streams])


class InterEncoder:
    """The compact frames of one stream: each frame as a key frame (version 7 by default, 5 with
    ``CompactParams(version=3)``, 3 with ``split=0``; decodes alone) and / or as a delta (version 6 or 4: coded against the previous frame this encoder coded, which
    the receiver must hold; ``CompactDecoder``). Frames share one grid (origin and depth, with a
    margin of a quarter of the extent, at least 32 cells, around the cloud that opened it) until a
    cloud leaves it; the first frame on a new grid has no delta. Geometry and colour decode exactly
    as from a key frame of the same grid: a delta changes the bytes, not the picture."""

    def __init__(self, params: CompactParams = CompactParams()):
        if params.check().version == 2:
            raise ValidationError("inter-frame coding needs the range-coded compact format (version 3 or 7, not 2)")
        self.params = params
        self._grid: tuple[np.ndarray, int] | None = None
        self._ref: _Reference | None = None

    @property
    def reference(self) -> int | None:
        """The frame number the next delta refers to (None: the next frame has no delta)."""
        return None if self._ref is None else self._ref.number

    def _place(self, xyz: np.ndarray, lo: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """(cells, origin, levels): on the current grid when the cloud fits it, else on a new one."""
        from fuseflow.live.codec_kernels import bounds, grid_cells

        inv = 1000.0 / self.params.step_mm
        if self._grid is not None and np.all(lo >= self._grid[0]):
            cells, top = grid_cells(xyz, self._grid[0].astype(np.float64), inv)
            if top < (1 << self._grid[1]):
                return cells, *self._grid
        extent = int(np.ceil(float((bounds(xyz)[1] - lo).max()) * inv))
        pad = max(32, extent // 4)
        origin = (lo - pad / inv).astype(np.float32)
        cells, top = grid_cells(xyz, origin.astype(np.float64), inv)
        self._grid, self._ref = (origin, _levels(max(int(top), extent + 2 * pad), self.params.step_mm)), None
        return cells, *self._grid

    def encode(self, xyz: np.ndarray, rgb: np.ndarray, number: int, latency_ms: float = 0.0, fuse_ms: float = 0.0,
               key: bool = True, delta: bool = True) -> tuple[bytes | None, bytes | None]:  # fmt: skip
        """(key frame, delta) of a cloud: the key frame when ``key`` is set or no delta can be made,
        the delta when ``delta`` is set and the previous frame is on this one's grid. This frame
        becomes the reference of the next delta."""
        from fuseflow.live.codec_kernels import leaves_v3, match_leaves

        xyz, rgb, lo = _finite(xyz, rgb)
        if not len(xyz):
            self._grid = self._ref = None
            return encode_compact(xyz, rgb, number, latency_ms, fuse_ms, self.params), None
        cells, origin, levels = self._place(xyz, lo)
        leaves, mean = leaves_v3(cells, levels, rgb)
        p, ref = self.params, self._ref
        head = (
            *origin.tolist(),
            p.step_mm / 1000.0,
            latency_ms,
            fuse_ms,
            levels,
            p.luma_step,
            p.chroma_step,
            p.chroma_block,
        )
        counts = (number & 0xFFFFFFFF, len(leaves), len(xyz))
        out: list[bytes | None] = [None, None]
        q = None
        if delta and ref is not None:
            geo, col, q = _streams(leaves, mean, levels, p, ref, match_leaves(leaves, ref.leaves))
            out[1] = _HEAD4.pack(b"FFLV", _DELTA[p.split > 0], _HEAD4.size, *counts, *head, zlib.crc32(geo + col), len(geo), len(col),
                                 ref.number & 0xFFFFFFFF) + geo + col  # fmt: skip
        if key or out[1] is None:
            geo, col, q = _streams(leaves, mean, levels, p, None, np.full(len(leaves), -1, np.int64))
            out[0] = _HEAD3.pack(
                b"FFLV", _key_version(p), COMPACT_HEADER, *counts, *head, zlib.crc32(geo + col), len(geo), len(col)
            )
            out[0] += geo + col
        self._ref = _Reference(number & 0xFFFFFFFF, _grid_of(out[0] or out[1]), levels, q, leaves)
        return out[0], out[1]


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
    """Version 2: the decompressed size of the occupancy stream; versions 3-6: the CRC-32."""
    sizes: tuple[int, ...]
    """Byte sizes of the streams (version 2: occupancy, luma, chroma; 3-6: geometry, colour)."""
    version: int = COMPACT_VERSION
    reference: int | None = None
    """Versions 4 and 6: the number of the frame this one is coded against."""


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
    version = struct.unpack_from("<H", data, 4)[0] if len(data) >= 6 else 0
    if version not in COMPACT_VERSIONS:
        raise FormatError(f"live frame: compact version {version}, expected one of {COMPACT_VERSIONS}")
    head = {2: _HEAD, 3: _HEAD3, 4: _HEAD4, 5: _HEAD3, 6: _HEAD4, 7: _HEAD3}[version]
    if len(data) < head.size:
        raise FormatError(f"live frame: {len(data)} bytes, shorter than the {head.size}-byte header")
    f = head.unpack_from(data)
    sizes, ref = (tuple(f[17:19]), f[19]) if version in (4, 6) else (tuple(f[17:]), None)
    h = CompactHeader(f[3], f[4], f[5], np.array(f[6:9], np.float32), *f[9:17], sizes, version, ref)
    if f[2] != head.size or not (1 <= h.levels <= MAX_LEVELS) or not (h.step > 0) or h.points > h.points_in:
        raise FormatError(f"live frame: bad compact header (size {f[2]}, levels {h.levels}, step {h.step})")
    if min(h.luma_step, h.chroma_step, h.chroma_block) < 1 or h.points_in > MAX_POINTS:
        raise FormatError(f"live frame: bad compact header (a zero colour step or block, or {h.points_in} points)")
    if len(data) != head.size + sum(h.sizes):
        raise FormatError(f"live frame: {len(data)} bytes, expected {head.size + sum(h.sizes)} from its header")
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


def _grid_of(data: bytes) -> bytes:
    """A message's grid and colour steps (origin, step; depth, luma and chroma steps, block): a
    delta decodes only against a reference with the same."""
    return bytes(data[20:36]) + bytes(data[44:48])


def _decode_v3(
    data: bytes, h: CompactHeader, ref: _Reference | None = None
) -> tuple[np.ndarray, np.ndarray, _Reference]:
    """(positions, colours, the frame as a reference) of a version 3 or 5 message, or of a
    version 4 or 6 message against ``ref``."""
    from fuseflow.live.codec_kernels import (
        decode_colour,
        decode_geometry,
        decode_geometry_symbols,
        morton_cells,
        symmetry_tables,
    )

    hsize = _HEAD4.size if h.version in (4, 6) else COMPACT_HEADER
    if zlib.crc32(memoryview(data)[hsize:]) != h.occupancy_bytes:
        raise FormatError("live frame: the checksum does not match (corrupt or altered streams)")
    m = h.points
    rocc, rfirst, rq = _NO_REF if ref is None else ref.octree()
    if m == 0:
        if sum(h.sizes):
            raise FormatError("live frame: streams given for a frame of no points")
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), None
    raw = np.frombuffer(data, np.uint8, offset=hsize)
    geo, col = raw[: h.sizes[0]], raw[h.sizes[0] :]
    if h.version == 7:
        cls, _, inv = symmetry_tables()
        keys, used, err, rleaf, occ = decode_geometry_symbols(geo, h.levels, m, cls, inv)
    else:
        keys, used, err, rleaf, occ = decode_geometry(geo, h.levels, m, rocc, rfirst)
    if err or len(keys) != m or used > len(geo):
        raise FormatError(f"live frame: the geometry stream gives {len(keys)} points, the header says {m}")
    rgb, used, err, q = decode_colour(col, m, h.luma_step, h.chroma_step, h.chroma_block, rleaf, rq, h.version >= 5)
    if err or used > len(col):
        raise FormatError("live frame: the colour stream is corrupt or ends early")
    xyz = (h.origin.astype(np.float64) + (morton_cells(keys) + 0.5) * h.step).astype(np.float32)
    return xyz, rgb, _Reference(h.number, _grid_of(data), h.levels, q, occ=occ)


class CompactDecoder:
    """Decodes the compact messages of one stream in the order they came, holding the last
    decoded frame for a delta (version 4 or 6) that refers to it; ``decode`` as ``decode_compact``."""

    def __init__(self) -> None:
        self._ref: _Reference | None = None

    def decode(self, data: bytes) -> tuple[CompactHeader, np.ndarray, np.ndarray]:
        h = _read_header(data)
        if h.version == 2:
            self._ref = None
            return decode_compact(data)
        ref = None
        if h.version in (4, 6):
            ref = self._ref
            if ref is None or ref.number != h.reference or ref.grid != _grid_of(data):
                held = "no frame" if ref is None else f"frame {ref.number}"
                raise FormatError(f"live frame: a delta against frame {h.reference}, but this decoder holds {held}")
        self._ref = None  # a frame that fails to decode leaves nothing to refer to
        xyz, rgb, self._ref = _decode_v3(data, h, ref)
        return h, xyz, rgb


def decode_compact(data: bytes) -> tuple[CompactHeader, np.ndarray, np.ndarray]:
    """(header, (M, 3) float32 cell-centre positions, (M, 3) uint8 colours) of a version 5, 3 or
    2 message; FormatError for anything truncated, corrupt or inconsistent."""
    h = _read_header(data)
    if h.version in (4, 6):
        raise FormatError(f"live frame: a delta against frame {h.reference}: decode the stream with CompactDecoder")
    if h.version in (3, 5, 7):
        return (h, *_decode_v3(data, h)[:2])
    a = _HEAD.size
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
