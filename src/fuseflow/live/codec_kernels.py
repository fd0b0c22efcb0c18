"""Compiled kernels of the compact frame codec (``fuseflow.live.codec``): grid cells and Morton
keys, a radix sort, the octree's occupancy bytes and the colour residuals, in a few linear passes
that release the GIL (the encoder runs in a thread of its own, beside fusion).

numba is imported here only; ``import fuseflow.live`` does not load it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fuseflow.io.numba_cache import use_usable_cache

use_usable_cache(__file__)  # before any @njit(cache=True) below

__all__ = [
    "bounds",
    "finite_min",
    "grid_cells",
    "compact_streams",
    "leaves_v3",
    "geometry_stream",
    "colour_stream",
    "colour_code",
    "occupancy",
    "ref_first",
    "match_leaves",
    "decode_geometry",
    "decode_colour",
    "morton_cells",
    "symmetry_tables",
    "symbol_decisions",
    "symbol_code",
    "geometry_symbols_stream",
    "decode_geometry_symbols",
]


@njit(cache=True, nogil=True)
def bounds(xyz):  # pragma: no cover - compiled
    """Per-axis (minimum, maximum) of (M, 3) points (one pass; numpy's axis-0 reductions over
    (M, 3) are several times slower)."""
    lo = np.full(3, np.inf, np.float32)
    hi = np.full(3, -np.inf, np.float32)
    for i in range(xyz.shape[0]):
        for a in range(3):
            v = xyz[i, a]
            if v < lo[a]:
                lo[a] = v
            if v > hi[a]:
                hi[a] = v
    return lo, hi


@njit(cache=True, nogil=True)
def finite_min(xyz):  # pragma: no cover - compiled
    """(per-axis minimum over the finite points, number of points with a non-finite coordinate)."""
    lo = np.full(3, np.inf)
    bad = 0
    for i in range(xyz.shape[0]):
        x, y, z = np.float64(xyz[i, 0]), np.float64(xyz[i, 1]), np.float64(xyz[i, 2])
        if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
            bad += 1
            continue
        lo[0], lo[1], lo[2] = min(lo[0], x), min(lo[1], y), min(lo[2], z)
    return lo, bad


@njit(cache=True, nogil=True)
def grid_cells(xyz, origin, inv_step):  # pragma: no cover - compiled
    """(M, 3) int64 cells ``floor((p - origin) * inv_step)`` and the largest coordinate."""
    n = xyz.shape[0]
    cells = np.empty((n, 3), np.int64)
    top = 0
    for i in range(n):
        for a in range(3):
            c = np.int64(np.floor((np.float64(xyz[i, a]) - origin[a]) * inv_step))
            c = max(c, 0)
            cells[i, a] = c
            top = max(top, c)
    return cells, top


@njit(cache=True, nogil=True, inline="always")
def _part1by2(x):  # pragma: no cover - compiled
    x = np.uint64(x) & np.uint64(0x1FFFFF)
    x = (x | (x << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    x = (x | (x << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    x = (x | (x << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    x = (x | (x << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    x = (x | (x << np.uint64(2))) & np.uint64(0x1249249249249249)
    return x


@njit(cache=True, nogil=True)
def _sorted_keys(cells, bits):  # pragma: no cover - compiled
    """Morton keys (x high, z low within each 3-bit group) sorted by an LSD radix sort of
    ``bits`` bits, and the permutation that sorts them."""
    n = cells.shape[0]
    key = np.empty(n, np.uint64)
    for i in range(n):
        key[i] = (
            (_part1by2(cells[i, 0]) << np.uint64(2)) | (_part1by2(cells[i, 1]) << np.uint64(1)) | _part1by2(cells[i, 2])
        )
    order = np.arange(n)
    key2 = np.empty(n, np.uint64)
    order2 = np.empty(n, np.int64)
    passes = max(1, (bits + 15) // 16)  # as few scatter passes as 16-bit digits allow
    digit = (bits + passes - 1) // passes
    mask = np.uint64((1 << digit) - 1)
    count = np.empty(1 << digit, np.int64)
    for p in range(passes):
        shift = np.uint64(p * digit)
        count[:] = 0
        for i in range(n):
            count[(key[i] >> shift) & mask] += 1
        total = 0
        for d in range(count.shape[0]):
            c = count[d]
            count[d] = total
            total += c
        for i in range(n):
            d = (key[i] >> shift) & mask
            j = count[d]
            count[d] = j + 1
            key2[j] = key[i]
            order2[j] = order[i]
        key, key2 = key2, key
        order, order2 = order2, order
    return key, order


@njit(cache=True, nogil=True)
def _leaves(key, order, rgb):  # pragma: no cover - compiled
    """Unique sorted keys and the mean colour (float64) of the points in each."""
    n = key.shape[0]
    uniq = np.empty(n, np.uint64)
    mean = np.zeros((n, 3), np.float64)
    m = 0
    i = 0
    while i < n:
        j = i
        s0 = s1 = s2 = 0.0
        while j < n and key[j] == key[i]:
            p = order[j]
            s0 += rgb[p, 0]
            s1 += rgb[p, 1]
            s2 += rgb[p, 2]
            j += 1
        c = j - i
        uniq[m] = key[i]
        mean[m, 0], mean[m, 1], mean[m, 2] = s0 / c, s1 / c, s2 / c
        m += 1
        i = j
    return uniq[:m], mean[:m]


@njit(cache=True, nogil=True)
def _occupancy(leaves, levels):  # pragma: no cover - compiled
    """Breadth-first occupancy bytes (root first) of sorted unique keys of depth ``levels``."""
    cur = leaves.copy()
    n = cur.shape[0]
    buf = np.empty(max(2 * n, 64), np.uint8)
    starts = np.empty(levels + 1, np.int64)
    used = 0
    for lev in range(levels):  # leaves up: level ``lev`` holds the parents of the current nodes
        starts[lev] = used
        m = 0
        i = 0
        while i < n:
            parent = cur[i] >> np.uint64(3)
            byte = 0
            while i < n and (cur[i] >> np.uint64(3)) == parent:
                byte |= 1 << np.int64(cur[i] & np.uint64(7))
                i += 1
            if used == buf.shape[0]:
                bigger = np.empty(2 * used, np.uint8)
                bigger[:used] = buf
                buf = bigger
            buf[used] = byte
            used += 1
            cur[m] = parent
            m += 1
        n = m
    starts[levels] = used
    out = np.empty(used, np.uint8)
    k = 0
    for lev in range(levels - 1, -1, -1):
        for t in range(starts[lev], starts[lev + 1]):
            out[k] = buf[t]
            k += 1
    return out


@njit(cache=True, nogil=True)
def _colour_residuals(mean, luma_step, chroma_step, block):  # pragma: no cover - compiled
    """Luma residuals (one byte a point) and chroma residuals (Cb blocks, then Cr blocks), mod 256."""
    m = mean.shape[0]
    nb = (m + block - 1) // block
    luma = np.empty(m, np.uint8)
    chroma = np.empty(2 * nb, np.uint8)
    prev = 0
    pcb = 0
    pcr = 0
    for b in range(nb):
        scb = scr = 0.0
        for t in range(block):
            i = min(b * block + t, m - 1)  # the last block repeats its last point
            r, g, bl = mean[i, 0], mean[i, 1], mean[i, 2]
            y = np.floor((77.0 * r + 150.0 * g + 29.0 * bl + 128.0) / 256.0)
            scb += bl - y
            scr += r - y
            if b * block + t < m:
                q = np.int64(np.rint(y / luma_step))
                luma[i] = (q - prev) & 255
                prev = q
        qb = np.int64(np.rint(scb / block / chroma_step))
        qr = np.int64(np.rint(scr / block / chroma_step))
        chroma[b] = (qb - pcb) & 255
        chroma[nb + b] = (qr - pcr) & 255
        pcb, pcr = qb, qr
    return luma, chroma


@njit(cache=True, nogil=True)
def compact_streams(cells, levels, rgb, luma_step, chroma_step, block):  # pragma: no cover - compiled
    """(occupancy bytes, luma residuals, chroma residuals, points sent) of a frame's cells."""
    key, order = _sorted_keys(cells, 3 * levels)
    leaves, mean = _leaves(key, order, rgb)
    occ = _occupancy(leaves, levels)
    luma, chroma = _colour_residuals(mean, luma_step, chroma_step, block)
    return occ, luma, chroma, leaves.shape[0]


# Version 3: an adaptive binary range coder (LZMA's: 11-bit probabilities, a 32-bit range, carries
# through a one-byte cache) over the octree's occupancy bits, in contexts of the node's face
# neighbours, and over colour residuals, in contexts of the previous residuals' sizes. The encoder
# first lists every (context, bit) decision, then codes them in one tight loop; the decoders (below,
# and static/decode.js) make the same decisions in the same order.

GEO_CONTEXTS = 2 * 8 * 4 * 8 * 4 * 2 + 128 + 1024
"""Occupancy contexts: of a child bit (last level or not x the 3 face neighbours next to the
child x how many of the 3 others exist x child index x adjacent siblings already occupied (0-3) x
any sibling occupied so far: 4096), of the single-child flag (SINGLE + last level x neighbour
bits: 128) and of the single child's index, 3 bits as a binary tree (TREE + (last level x
neighbour bits) x tree node: 1024)."""
SINGLE = 4096
TREE = 4096 + 128
P_CHILD = GEO_CONTEXTS
"""Contexts of a frame coded against a reference (version 4) where the reference has the node:
a child bit as above x whether the reference has that child (8192); the single-child flag x
whether the reference node has one child (256); the single child's index bits x (the
reference's bit is 0, is 1, the bits so far differ from it) (3072). Without the node: as above."""
P_SINGLE = P_CHILD + 8192
P_TREE = P_SINGLE + 256
INTER_GEO_CONTEXTS = P_TREE + 3072
RES = 32
"""Contexts of one residual: nonzero, sign, 13 unary magnitude bits, 9 Exp-Golomb prefix bits,
8 suffix bit positions."""
SPLIT = 30 * RES
COL_CONTEXTS = SPLIT + 2
"""Colour residual context groups: luma (3: previous luma residual's size), Co (9: previous Co
size x this point's luma size), Cg (9: previous Cg size x this block's Co size); against a
reference point (version 4): luma (3), Co (3: the previous referenced block's larger chroma
size), Cg (3: this block's Co size); then a block's split flag (versions 5 and 6: 2, the
previous block's flag)."""
ESCAPE = 14
"""Residual magnitudes from this on continue as an Exp-Golomb code of ``magnitude - ESCAPE``."""
MAX_PREFIX = 16
"""Longest Exp-Golomb prefix a decoder accepts (a valid stream stays under 10)."""


@njit(cache=True, nogil=True)
def range_code(ctx, bits, n_contexts):  # pragma: no cover - compiled
    """The range-coded bytes of decisions ``bits[i]`` (0/1) each with the adaptive probability
    of its context ``ctx[i]`` (all starting at one half; p += (2048 - p) >> 5 after a 0, p -= p >> 5
    after a 1)."""
    n = bits.shape[0]
    buf = np.empty(n + n // 2 + 64, np.uint8)  # a decision costs at most 6.1 bits
    probs = np.full(n_contexts, 1024, np.int64)
    low = np.int64(0)
    rng = np.int64(0xFFFFFFFF)
    cache = np.int64(0)
    csize = np.int64(1)
    pos = 0
    for i in range(n + 5):
        if i < n:
            c = ctx[i]
            p = probs[c]
            bound = (rng >> 11) * p
            if bits[i] == 0:
                rng = bound
                probs[c] = p + ((2048 - p) >> 5)
            else:
                low += bound
                rng -= bound
                probs[c] = p - (p >> 5)
            if rng >= (1 << 24):
                continue
        while True:  # shift a byte out (at the end: five times, the flush)
            if low < 0xFF000000 or low >= (1 << 32):
                carry = low >> 32
                temp = cache
                while True:
                    buf[pos] = (temp + carry) & 0xFF
                    pos += 1
                    temp = 0xFF
                    csize -= 1
                    if csize == 0:
                        break
                cache = (low >> 24) & 0xFF
            csize += 1
            low = (low & 0x00FFFFFF) << 8
            if i >= n:
                break
            rng <<= 8
            if rng >= (1 << 24):
                break
    return buf[:pos].copy()


@njit(cache=True, nogil=True, inline="always")
def _put(es, buf, probs, c, bit):  # pragma: no cover - compiled
    """Code one decision as ``range_code`` does, directly into ``buf``: es = (low, range, cache,
    cache size, bytes written) in, the new state out (a tuple: it stays in registers)."""
    low, rng, cache, csize, pos = es
    p = probs[c]
    bound = (rng >> 11) * p
    if bit == 0:
        rng = bound
        probs[c] = p + ((2048 - p) >> 5)
    else:
        low += bound
        rng -= bound
        probs[c] = p - (p >> 5)
    while rng < (1 << 24):
        rng <<= 8
        if low < 0xFF000000 or low >= (1 << 32):
            carry = low >> 32
            temp = cache
            while True:
                buf[pos] = (temp + carry) & 0xFF
                pos += 1
                temp = 0xFF
                csize -= 1
                if csize == 0:
                    break
            cache = (low >> 24) & 0xFF
        csize += 1
        low = (low & 0x00FFFFFF) << 8
    return low, rng, cache, csize, pos


@njit(cache=True, nogil=True, inline="always")
def _put_residual(es, buf, probs, base, r):  # pragma: no cover - compiled
    """Code residual r as ``_residual`` lists its decisions; the new state."""
    a = abs(r)
    es = _put(es, buf, probs, base, 1 if a else 0)
    if a == 0:
        return es
    es = _put(es, buf, probs, base + 1, 1 if r < 0 else 0)
    for j in range(1, ESCAPE):
        es = _put(es, buf, probs, base + 1 + j, 1 if a > j else 0)
        if a <= j:
            return es
    e = a - ESCAPE + 1
    n = 0
    while (e >> (n + 1)) != 0:
        n += 1
    for i in range(n + 1):
        es = _put(es, buf, probs, base + 15 + min(i, 8), 1 if i < n else 0)
    for i in range(n - 1, -1, -1):
        es = _put(es, buf, probs, base + 24 + min(i, 7), (e >> i) & 1)
    return es


@njit(cache=True, nogil=True, inline="always")
def _get(st, data, probs, c):  # pragma: no cover - compiled
    """Decode one decision with ``probs[c]``; st = (range, code, bytes read)."""
    p = probs[c]
    bound = (st[0] >> 11) * p
    if st[1] < bound:
        st[0] = bound
        probs[c] = p + ((2048 - p) >> 5)
        bit = 0
    else:
        st[1] -= bound
        st[0] -= bound
        probs[c] = p - (p >> 5)
        bit = 1
    while st[0] < (1 << 24):
        st[0] <<= 8
        b = data[st[2]] if st[2] < data.shape[0] else 0
        st[2] += 1
        st[1] = ((st[1] << 8) | b) & 0xFFFFFFFF
    return bit


@njit(cache=True, nogil=True)
def _reader(data):  # pragma: no cover - compiled
    st = np.zeros(3, np.int64)
    st[0] = 0xFFFFFFFF
    for i in range(1, 5):  # byte 0 is the encoder's empty cache
        st[1] = (st[1] << 8) | (data[i] if i < data.shape[0] else 0)
    st[2] = 5
    return st


@njit(cache=True, nogil=True)
def _node_levels(leaves, levels):  # pragma: no cover - compiled
    """Sorted unique Morton keys of every depth 0..levels, concatenated root first, and where
    each depth starts (``start[levels + 1]`` is the total)."""
    parts = [leaves]
    for _ in range(levels):
        cur = parts[-1]
        nxt = np.empty(cur.shape[0], np.uint64)
        m = 0
        for i in range(cur.shape[0]):
            p = cur[i] >> np.uint64(3)
            if m == 0 or nxt[m - 1] != p:
                nxt[m] = p
                m += 1
        parts.append(nxt[:m])
    start = np.zeros(levels + 2, np.int64)
    for d in range(levels + 1):
        start[d + 1] = start[d] + parts[levels - d].shape[0]
    keys = np.empty(start[levels + 1], np.uint64)
    for d in range(levels + 1):
        keys[start[d] : start[d + 1]] = parts[levels - d]
    return keys, start


@njit(cache=True, nogil=True)
def child_neighbours(pbyte, pstart, pup, n):  # pragma: no cover - compiled
    """Face neighbours of the n nodes one depth below parents with occupancy bytes ``pbyte``,
    first children at ``pstart`` and upper neighbours ``pup`` (3, parents; -1: none), all in
    Morton order: (nb, up) with nb bit 2a set when a node's lower neighbour along axis a
    (x, y, z) exists and bit 2a + 1 for its upper one, and up (3, n) the upper neighbours' indices.
    A child's upper neighbour along a is its sibling when its own bit a is 0, else a child of the
    parent's upper neighbour: no search."""
    nb = np.zeros(n, np.uint8)
    up = np.full((3, n), -1, np.int64)
    q = 0
    for p in range(pbyte.shape[0]):
        byte = pbyte[p]
        for k in range(8):
            if not (byte >> k) & 1:
                continue
            for a in range(3):
                bp = 2 - a
                if (k >> bp) & 1:
                    kk, par = k & ~(1 << bp), pup[a, p]
                else:
                    kk, par = k | (1 << bp), p
                if par >= 0 and (pbyte[par] >> kk) & 1:
                    below = pbyte[par] & ((1 << kk) - 1)
                    j = pstart[par]
                    while below:
                        j += 1
                        below &= below - 1
                    up[a, q] = j
                    nb[q] |= 1 << (2 * a + 1)
                    nb[j] |= 1 << (2 * a)
            q += 1
    return nb, up


@njit(cache=True, nogil=True)
def geo_contexts():  # pragma: no cover - compiled
    """(base, extra) tables of the occupancy contexts: child bit k of a node with neighbour
    bits nb at the last depth (last = 1) or above has context ``base[(last * 64 + nb) * 8 + k]
    + extra[k * 128 + below]``, ``below`` being its bits under k."""
    base = np.empty(2 * 64 * 8, np.int32)
    for last in range(2):
        for nb in range(64):
            for k in range(8):
                bx, by, bz = k >> 2, (k >> 1) & 1, k & 1
                adj = (((nb >> bx) & 1) << 2) | (((nb >> (2 + by)) & 1) << 1) | ((nb >> (4 + bz)) & 1)
                far = ((nb >> (1 - bx)) & 1) + ((nb >> (3 - by)) & 1) + ((nb >> (5 - bz)) & 1)
                base[(last * 64 + nb) * 8 + k] = (((last * 8 + adj) * 4 + far) * 8 + k) * 8
    extra = np.zeros(8 * 128, np.int32)
    for k in range(8):
        for below in range(1 << k):
            sib = ((below >> (k ^ 4)) & 1) + ((below >> (k ^ 2)) & 1) + ((below >> (k ^ 1)) & 1)
            extra[k * 128 + below] = sib * 2 + (1 if below else 0)
    return base, extra


@njit(cache=True, nogil=True, inline="always")
def _popcount(b):  # pragma: no cover - compiled
    n = 0
    while b:
        b &= b - 1
        n += 1
    return n


@njit(cache=True, nogil=True)
def ref_first(rocc, levels):  # pragma: no cover - compiled
    """(first, ok) of a reference octree's breadth-first occupancy bytes (root first): first[g]
    is where node g's first child is (the next depth's position in ``rocc``, or at the last
    depth the leaf index); ok 0 when the bytes do not make an octree of ``levels`` depths."""
    first = np.zeros(rocc.shape[0], np.int64)
    pos = 0
    n = 1
    for d in range(levels):
        if pos + n > rocc.shape[0]:
            return first, 0
        cnt = 0
        for g in range(pos, pos + n):
            first[g] = (pos + n + cnt) if d < levels - 1 else cnt
            cnt += _popcount(np.int64(rocc[g]))
        pos += n
        n = cnt
    return first, 1 if pos == rocc.shape[0] else 0


@njit(cache=True, nogil=True, inline="always")
def _ref_child(rocc, rfirst, g, k):  # pragma: no cover - compiled
    """The reference's child k of its node g (-1: none, or g is -1)."""
    if g < 0:
        return -1
    rb = np.int64(rocc[g])
    if not (rb >> k) & 1:
        return -1
    return rfirst[g] + _popcount(rb & ((1 << k) - 1))


@njit(cache=True, nogil=True, inline="always")
def _single_ctx(row, g, rb):  # pragma: no cover - compiled
    """Context of the single-child flag: as version 3 without a reference node, else by whether
    the reference node has one child or more."""
    if g < 0:
        return SINGLE + row
    return P_SINGLE + (0 if (rb & (rb - 1)) == 0 else 128) + row


@njit(cache=True, nogil=True, inline="always")
def _tree_ctx(row, node, cls):  # pragma: no cover - compiled
    return TREE + row * 8 + node if cls == 0 else P_TREE + ((cls - 1) * 128 + row) * 8 + node


@njit(cache=True, nogil=True, inline="always")
def _tree_cls(g, rb, depth_bit, match):  # pragma: no cover - compiled
    """Class of a single child's index bit: 0 without a single-child reference node, else 1 + the
    reference child's bit while the bits so far agree with it, 3 once they do not."""
    if g < 0 or (rb & (rb - 1)) != 0:
        return 0
    if not match:
        return 3
    return 1 + ((_popcount(rb - 1) >> depth_bit) & 1)


@njit(cache=True, nogil=True)
def geometry_decisions(leaves, levels, rocc, rfirst):  # pragma: no cover - compiled
    """(contexts, bits, ref) of the octree of sorted unique Morton keys of depth ``levels``: every
    node from the root down, depth by depth in Morton order: whether it has a single child; if
    so that child's index k = 4 x + 2 y + z as 3 bits (x, y, z) of a binary tree, else its 8
    child bits in increasing k (bit 7 not when bits 0-6 hold at most one child). With a reference
    octree (``rocc``, its breadth-first bytes, and ``ref_first`` of them; empty: none), a node
    that the reference also has codes in contexts of the reference's children; ``ref`` is each
    leaf's index in the reference (-1: new)."""
    keys, start = _node_levels(leaves, levels)
    base, extra = geo_contexts()
    ctx = np.empty(9 * start[levels] + 8, np.int32)  # a node: at most 1 + 8 decisions
    bits = np.empty(9 * start[levels] + 8, np.uint8)
    t = 0
    pbyte = np.ones(1, np.int64)  # a virtual parent of the root: child 0
    pstart = np.zeros(1, np.int64)
    pup = np.full((3, 1), -1, np.int64)
    rref = np.full(1, 0 if rocc.shape[0] else -1, np.int64)
    for d in range(levels):
        lo, hi = start[d], start[d + 1]
        nbs, up = child_neighbours(pbyte, pstart, pup, hi - lo)
        last = 1 if d == levels - 1 else 0
        byte_d = np.zeros(hi - lo, np.int64)
        cstart = np.zeros(hi - lo, np.int64)
        rnext = np.empty(start[d + 2] - hi, np.int64)
        j = hi  # the first child of this depth's first node
        for i in range(hi - lo):
            parent = keys[lo + i]
            cstart[i] = j - hi
            byte = 0
            while j < start[d + 2] and (keys[j] >> np.uint64(3)) == parent:
                k = np.int64(keys[j] & np.uint64(7))
                byte |= 1 << k
                rnext[j - hi] = _ref_child(rocc, rfirst, rref[i], k)
                j += 1
            byte_d[i] = byte
            g = rref[i]
            rb = np.int64(rocc[g]) if g >= 0 else 0
            row = last * 64 + np.int64(nbs[i])
            single = 1 if (byte & (byte - 1)) == 0 else 0
            ctx[t], bits[t] = _single_ctx(row, g, rb), single
            t += 1
            if single:
                node = 1
                match = True
                for b in range(2, -1, -1):
                    bit = (_popcount(byte - 1) >> b) & 1  # the child's index, bit b
                    ctx[t], bits[t] = _tree_ctx(row, node, _tree_cls(g, rb, b, match)), bit
                    t += 1
                    node = 2 * node + bit
                    match = match and ((_popcount(rb - 1) >> b) & 1) == bit
                continue
            for k in range(8):
                below = byte & ((1 << k) - 1)
                if k == 7 and _popcount(below) <= 1:
                    break
                c = base[row * 8 + k] + extra[k * 128 + below]
                ctx[t] = c if g < 0 else c + P_CHILD + ((rb >> k) & 1) * 4096
                bits[t] = (byte >> k) & 1
                t += 1
        pbyte, pstart, pup, rref = byte_d, cstart, up, rnext
    return ctx[:t], bits[:t], rref


@njit(cache=True, nogil=True)
def decode_geometry(data, levels, points, rocc, rfirst):  # pragma: no cover - compiled
    """(sorted Morton keys of the leaves, bytes read, error, each leaf's index in the reference
    (-1: new), the breadth-first occupancy bytes): error 1 when a depth would hold more nodes
    than ``points`` (not a valid stream). ``rocc``, ``rfirst``: as ``geometry_decisions``."""
    st = _reader(data)
    probs = np.full(INTER_GEO_CONTEXTS, 1024, np.int64)
    base, extra = geo_contexts()
    keys = np.zeros(1, np.uint64)
    pbyte = np.ones(1, np.int64)
    pstart = np.zeros(1, np.int64)
    pup = np.full((3, 1), -1, np.int64)
    rref = np.full(1, 0 if rocc.shape[0] else -1, np.int64)
    occ = np.empty(0, np.uint8)
    for d in range(levels):
        n = keys.shape[0]
        nbs, up = child_neighbours(pbyte, pstart, pup, n)
        last = 1 if d == levels - 1 else 0
        nxt = np.empty(min(8 * n, points + 8), np.uint64)
        rnext = np.empty(min(8 * n, points + 8), np.int64)
        byte_d = np.zeros(n, np.int64)
        cstart = np.zeros(n, np.int64)
        m = 0
        for i in range(n):
            cstart[i] = m
            g = rref[i]
            rb = np.int64(rocc[g]) if g >= 0 else 0
            row = last * 64 + np.int64(nbs[i])
            byte = 0
            if _get(st, data, probs, _single_ctx(row, g, rb)):
                node = 1
                match = True
                for b in range(2, -1, -1):
                    bit = _get(st, data, probs, _tree_ctx(row, node, _tree_cls(g, rb, b, match)))
                    node = 2 * node + bit
                    match = match and ((_popcount(rb - 1) >> b) & 1) == bit
                byte = 1 << (node - 8)
            else:
                for k in range(8):
                    if k == 7 and _popcount(byte) <= 1:
                        byte |= 128
                        continue
                    c = base[row * 8 + k] + extra[k * 128 + byte]
                    if _get(st, data, probs, c if g < 0 else c + P_CHILD + ((rb >> k) & 1) * 4096):
                        byte |= 1 << k
            for k in range(8):
                if (byte >> k) & 1:
                    if m >= points:
                        return keys[:0], st[2], 1, rref[:0], occ
                    nxt[m] = (keys[i] << np.uint64(3)) | np.uint64(k)
                    rnext[m] = _ref_child(rocc, rfirst, g, k)
                    m += 1
            byte_d[i] = byte
        keys = nxt[:m]
        grown = np.empty(occ.shape[0] + n, np.uint8)
        grown[: occ.shape[0]] = occ
        grown[occ.shape[0] :] = byte_d
        occ = grown
        pbyte, pstart, pup, rref = byte_d, cstart, up, rnext[:m]
    return keys, st[2], 0, rref, occ


@njit(cache=True, nogil=True)
def colour_values(mean, luma_step, chroma_step, block, split):  # pragma: no cover - compiled
    """Quantised colour of (M, 3) float RGB in point order: (M,) Y = (R + 2G + B) / 4, (M, 2)
    Co = R - B, Cg = G - (R + B) / 2 (the mean over each block of ``block`` points) each rounded
    to a multiple of its step, and (ceil(M / block),) split flags. With ``split`` > 0, a block
    where a point's Co or Cg is more than ``split`` chroma steps off the block's mean is split:
    each of its points has its own Co, Cg (``split`` <= 0: no block is split)."""
    m = mean.shape[0]
    nb = (m + block - 1) // block
    qy = np.empty(m, np.int64)
    qc = np.empty((m, 2), np.int64)
    flags = np.zeros(nb, np.uint8)
    for b in range(nb):
        co = cg = 0.0
        n = 0
        end = min(m, (b + 1) * block)
        for i in range(b * block, end):
            r, g, bl = mean[i, 0], mean[i, 1], mean[i, 2]
            qy[i] = np.int64(np.rint((r + 2.0 * g + bl) / 4.0 / luma_step))
            co += r - bl
            cg += g - 0.5 * (r + bl)
            n += 1
        co /= n
        cg /= n
        cut = split * chroma_step
        for i in range(b * block, end):
            r, g, bl = mean[i, 0], mean[i, 1], mean[i, 2]
            if split > 0 and (abs(r - bl - co) > cut or abs(g - 0.5 * (r + bl) - cg) > cut):
                flags[b] = 1
        for i in range(b * block, end):
            if flags[b]:
                r, g, bl = mean[i, 0], mean[i, 1], mean[i, 2]
                qc[i, 0] = np.int64(np.rint((r - bl) / chroma_step))
                qc[i, 1] = np.int64(np.rint((g - 0.5 * (r + bl)) / chroma_step))
            else:
                qc[i, 0] = np.int64(np.rint(co / chroma_step))
                qc[i, 1] = np.int64(np.rint(cg / chroma_step))
    return qy, qc, flags


@njit(cache=True, nogil=True, inline="always")
def _size(r):  # pragma: no cover - compiled
    a = abs(r)
    return 0 if a == 0 else (1 if a == 1 else 2)


@njit(cache=True, nogil=True, inline="always")
def _residual(ctx, bits, t, base, r):  # pragma: no cover - compiled
    """List the decisions of residual r from context ``base`` on: nonzero, sign, magnitude in
    unary up to ESCAPE, then an Exp-Golomb code of magnitude - ESCAPE (prefix, suffix)."""
    a = abs(r)
    ctx[t], bits[t] = base, 1 if a else 0
    t += 1
    if a == 0:
        return t
    ctx[t], bits[t] = base + 1, 1 if r < 0 else 0
    t += 1
    for j in range(1, ESCAPE):
        ctx[t], bits[t] = base + 1 + j, 1 if a > j else 0
        t += 1
        if a <= j:
            return t
    e = a - ESCAPE + 1
    n = 0
    while (e >> (n + 1)) != 0:
        n += 1
    for i in range(n + 1):
        ctx[t], bits[t] = base + 15 + min(i, 8), 1 if i < n else 0
        t += 1
    for i in range(n - 1, -1, -1):
        ctx[t], bits[t] = base + 24 + min(i, 7), (e >> i) & 1
        t += 1
    return t


@njit(cache=True, nogil=True)
def colour_decisions(qy, qc, block, rleaf, rq, flags, adaptive):  # pragma: no cover - compiled
    """(contexts, bits) of the colour: per point its luma residual, and at the first point of each
    block (of every point of a split block) the Co and Cg residuals; with ``adaptive`` (versions 5
    and 6) each block starts with its split flag (``flags``), in contexts of the previous block's.
    A point with a reference (``rleaf[i]`` >= 0, an index into the reference's per-point quantised
    (Y, Co, Cg) ``rq``) predicts them from it, in contexts of their own; any other from the
    previous point's luma and the previous chroma sent (with no reference at all: version 3)."""
    m = qy.shape[0]
    ctx = np.empty(8 * m + 256, np.int32)
    bits = np.empty(8 * m + 256, np.uint8)
    t = 0
    py = pco = pcg = 0
    sy = sco = scg = sry = src = 0
    split = 0
    for i in range(m):
        if t + 120 > ctx.shape[0]:  # a flag and three residuals take at most 1 + 3 x 37 decisions
            ctx2 = np.empty(2 * ctx.shape[0], np.int32)
            bits2 = np.empty(2 * ctx.shape[0], np.uint8)
            ctx2[:t], bits2[:t] = ctx[:t], bits[:t]
            ctx, bits = ctx2, bits2
        j = rleaf[i]
        if j >= 0:
            r = qy[i] - rq[j, 0]
            t = _residual(ctx, bits, t, (21 + sry) * RES, r)
            sry = _size(r)
        else:
            r = qy[i] - py
            t = _residual(ctx, bits, t, sy * RES, r)
            sy = _size(r)
        py = qy[i]
        first = i % block == 0
        if first and adaptive:
            ctx[t], bits[t] = SPLIT + split, flags[i // block]
            split = np.int64(flags[i // block])
            t += 1
        if first or split:
            if j >= 0:
                r1, r2 = qc[i, 0] - rq[j, 1], qc[i, 1] - rq[j, 2]
                t = _residual(ctx, bits, t, (24 + src) * RES, r1)
                s1 = _size(r1)
                t = _residual(ctx, bits, t, (27 + s1) * RES, r2)
                src = max(s1, _size(r2))
            else:
                r1, r2 = qc[i, 0] - pco, qc[i, 1] - pcg
                t = _residual(ctx, bits, t, (3 + sco * 3 + sy) * RES, r1)
                s1 = _size(r1)
                t = _residual(ctx, bits, t, (12 + scg * 3 + s1) * RES, r2)
                sco, scg = s1, _size(r2)
            pco, pcg = qc[i, 0], qc[i, 1]
    return ctx[:t], bits[:t]


@njit(cache=True, nogil=True)
def colour_code(qy, qc, block, rleaf, rq, flags, adaptive):  # pragma: no cover - compiled
    """The range-coded bytes of ``colour_decisions(qy, qc, block, rleaf, rq, flags, adaptive)``,
    coded as they are made (the same bytes as ``range_code`` of the listed decisions)."""
    m = qy.shape[0]
    buf = np.empty(m + 256, np.uint8)
    probs = np.full(COL_CONTEXTS, 1024, np.int64)
    # the coder's state: low, range, cache, cache size, bytes written
    es = (np.int64(0), np.int64(0xFFFFFFFF), np.int64(0), np.int64(1), np.int64(0))
    py = pco = pcg = 0
    sy = sco = scg = sry = src = 0
    split = 0
    for i in range(m):
        if es[4] + 128 > buf.shape[0]:  # a point: at most 1 + 3 x 37 decisions of at most 6.1 bits
            bigger = np.empty(2 * buf.shape[0], np.uint8)
            bigger[: es[4]] = buf[: es[4]]
            buf = bigger
        j = rleaf[i]
        if j >= 0:
            r = qy[i] - rq[j, 0]
            es = _put_residual(es, buf, probs, (21 + sry) * RES, r)
            sry = _size(r)
        else:
            r = qy[i] - py
            es = _put_residual(es, buf, probs, sy * RES, r)
            sy = _size(r)
        py = qy[i]
        first = i % block == 0
        if first and adaptive:
            es = _put(es, buf, probs, SPLIT + split, np.int64(flags[i // block]))
            split = np.int64(flags[i // block])
        if first or split:
            if j >= 0:
                r1, r2 = qc[i, 0] - rq[j, 1], qc[i, 1] - rq[j, 2]
                es = _put_residual(es, buf, probs, (24 + src) * RES, r1)
                s1 = _size(r1)
                es = _put_residual(es, buf, probs, (27 + s1) * RES, r2)
                src = max(s1, _size(r2))
            else:
                r1, r2 = qc[i, 0] - pco, qc[i, 1] - pcg
                es = _put_residual(es, buf, probs, (3 + sco * 3 + sy) * RES, r1)
                s1 = _size(r1)
                es = _put_residual(es, buf, probs, (12 + scg * 3 + s1) * RES, r2)
                sco, scg = s1, _size(r2)
            pco, pcg = qc[i, 0], qc[i, 1]
    if es[4] + 16 > buf.shape[0]:
        bigger = np.empty(buf.shape[0] + 16, np.uint8)
        bigger[: es[4]] = buf[: es[4]]
        buf = bigger
    low, rng, cache, csize, pos = es
    for _ in range(5):  # the flush
        if low < 0xFF000000 or low >= (1 << 32):
            carry = low >> 32
            temp = cache
            while True:
                buf[pos] = (temp + carry) & 0xFF
                pos += 1
                temp = 0xFF
                csize -= 1
                if csize == 0:
                    break
            cache = (low >> 24) & 0xFF
        csize += 1
        low = (low & 0x00FFFFFF) << 8
    return buf[:pos].copy()


@njit(cache=True, nogil=True, inline="always")
def _get_residual(st, data, probs, base):  # pragma: no cover - compiled
    """(residual, error) read as ``_residual`` lists it; error 1 for an over-long prefix."""
    if _get(st, data, probs, base) == 0:
        return 0, 0
    neg = _get(st, data, probs, base + 1)
    a = 1
    while a < ESCAPE and _get(st, data, probs, base + 1 + a) == 1:
        a += 1
    if a == ESCAPE:
        n = 0
        while _get(st, data, probs, base + 15 + min(n, 8)) == 1:
            n += 1
            if n > MAX_PREFIX:
                return 0, 1
        e = 1
        for i in range(n - 1, -1, -1):
            e = (e << 1) | _get(st, data, probs, base + 24 + min(i, 7))
        a = e + ESCAPE - 1
    return (-a if neg else a), 0


@njit(cache=True, nogil=True)
def decode_colour(data, m, luma_step, chroma_step, block, rleaf, rq, adaptive):  # pragma: no cover - compiled
    """((M, 3) uint8 RGB, bytes read, error, (M, 3) quantised Y, Co, Cg of every point) of a
    colour stream (``colour_decisions``; ``rleaf``, ``rq``, ``adaptive`` as there)."""
    st = _reader(data)
    probs = np.full(COL_CONTEXTS, 1024, np.int64)
    rgb = np.empty((m, 3), np.uint8)
    q = np.empty((m, 3), np.int64)
    py = pco = pcg = 0
    sy = sco = scg = sry = src = 0
    split = 0
    for i in range(m):
        j = rleaf[i]
        if j >= 0:
            r, err = _get_residual(st, data, probs, (21 + sry) * RES)
            sry = _size(r)
            py = rq[j, 0] + r
        else:
            r, err = _get_residual(st, data, probs, sy * RES)
            sy = _size(r)
            py += r
        first = i % block == 0
        if first and adaptive:
            split = _get(st, data, probs, SPLIT + split)
        if first or split:
            if j >= 0:
                r1, e1 = _get_residual(st, data, probs, (24 + src) * RES)
                s1 = _size(r1)
                r2, e2 = _get_residual(st, data, probs, (27 + s1) * RES)
                src = max(s1, _size(r2))
                pco, pcg = rq[j, 1] + r1, rq[j, 2] + r2
            else:
                r1, e1 = _get_residual(st, data, probs, (3 + sco * 3 + sy) * RES)
                s1 = _size(r1)
                r2, e2 = _get_residual(st, data, probs, (12 + scg * 3 + s1) * RES)
                sco, scg = s1, _size(r2)
                pco += r1
                pcg += r2
            err |= e1 | e2
        if err:
            return rgb[:0], st[2], 1, q[:0]
        q[i, 0], q[i, 1], q[i, 2] = py, pco, pcg
        y, co, cg = float(py * luma_step), float(pco * chroma_step), float(pcg * chroma_step)
        for c, v in enumerate(((y + co * 0.5) - cg * 0.5, y + cg * 0.5, (y - co * 0.5) - cg * 0.5)):
            rgb[i, c] = np.uint8(min(max(np.rint(v), 0.0), 255.0))
    return rgb, st[2], 0, q


@njit(cache=True, nogil=True)
def leaves_v3(cells, levels, rgb):  # pragma: no cover - compiled
    """Sorted unique Morton keys of the occupied cells and each one's mean colour (float64)."""
    key, order = _sorted_keys(cells, 3 * levels)
    return _leaves(key, order, rgb)


@njit(cache=True, nogil=True)
def geometry_stream(leaves, levels, rocc, rfirst):  # pragma: no cover - compiled
    """(the range-coded geometry stream of sorted unique leaf keys, each leaf's index in the
    reference or -1); ``rocc``, ``rfirst``: the reference (``geometry_decisions``)."""
    ctx, bits, rleaf = geometry_decisions(leaves, levels, rocc, rfirst)
    return range_code(ctx, bits, INTER_GEO_CONTEXTS), rleaf


@njit(cache=True, nogil=True)
def colour_stream(mean, luma_step, chroma_step, block, rleaf, rq, split):  # pragma: no cover - compiled
    """(the range-coded colour stream of (M, 3) mean colours in Morton order, (M, 3) quantised
    Y, Co, Cg of every point); ``rleaf``, ``rq``: the reference (``colour_decisions``); ``split``
    > 0: adaptive chroma blocks (``colour_values``)."""
    qy, qc, flags = colour_values(mean, luma_step, chroma_step, block, split)
    m = qy.shape[0]
    q = np.empty((m, 3), np.int64)
    for i in range(m):
        q[i, 0], q[i, 1], q[i, 2] = qy[i], qc[i, 0], qc[i, 1]
    return colour_code(qy, qc, block, rleaf, rq, flags, split > 0), q


@njit(cache=True, nogil=True)
def match_leaves(leaves, ref):  # pragma: no cover - compiled
    """Each sorted key's index in the sorted keys ``ref`` (-1: not there)."""
    out = np.full(leaves.shape[0], -1, np.int64)
    j = 0
    for i in range(leaves.shape[0]):
        while j < ref.shape[0] and ref[j] < leaves[i]:
            j += 1
        if j < ref.shape[0] and ref[j] == leaves[i]:
            out[i] = j
    return out


@njit(cache=True, nogil=True)
def occupancy(leaves, levels):  # pragma: no cover - compiled
    """Breadth-first occupancy bytes (root first) of sorted unique keys: a reference octree."""
    return _occupancy(leaves, levels)


@njit(cache=True, nogil=True)
def morton_cells(keys):  # pragma: no cover - compiled
    """(M, 3) int64 cells of Morton keys (x high, z low within each 3-bit group)."""
    n = keys.shape[0]
    out = np.zeros((n, 3), np.int64)
    for i in range(n):
        k = keys[i]
        x = y = z = np.int64(0)
        b = 0
        while k != 0:
            z |= np.int64(k & np.uint64(1)) << b
            y |= np.int64((k >> np.uint64(1)) & np.uint64(1)) << b
            x |= np.int64((k >> np.uint64(2)) & np.uint64(1)) << b
            k >>= np.uint64(3)
            b += 1
        out[i, 0], out[i, 1], out[i, 2] = x, y, z
    return out


# Version 7: the geometry as one symbol per node, its occupancy byte, from an adaptive frequency
# table per context, multi-symbol range coded (same range, carry and flush as above). The context
# is the node's face-neighbour pattern up to the cube's 48 symmetries (10 classes) x last depth;
# the byte is coded in the pattern's canonical frame (its children permuted by the symmetry that
# takes the pattern to its class's representative), so the 6 mirror images of a flat surface's
# pattern share one table.

SYM_CLASSES = 10
"""Face-neighbour patterns up to the cube's symmetries."""
SYM_CONTEXTS = 2 * SYM_CLASSES
"""Symbol contexts: last depth or not x neighbour class."""
SYM_INC = 32
"""A coded byte's count grows by this."""
SYM_LIMIT = 1 << 16
"""When a table's total passes this, every count halves (rounding up; the empty byte stays 0)."""
SYM_LAST = (8, 36, 92, 162, 218, 246, 254, 255)
"""The last symbol of the bytes of 1, 2, ... 8 children (symbols number bytes by their children)."""
_SYM_TABLES: list = []


def _perms3() -> list[tuple[int, int, int]]:
    return [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]


def symmetry_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cls, fwd, inv): ``cls[nb]`` the class (0-9) of face-neighbour bits nb; ``fwd[nb, byte]``
    the symbol of an occupancy byte: the byte in the class's canonical frame, numbered 1-255 in
    order of its number of children, then its value (the likeliest bytes first, where the
    decoder's search starts); ``inv`` its inverse. The 48 symmetries are
    tried in order (axis permutation p lexicographic, then flips f = 0..7, f's bit 2 - a flipping
    axis a); the first that gives the smallest pattern maps nb to its canonical pattern (axis a's
    neighbour bit 2a + side goes to 2 p[a] + (side ^ flip a); child bit a, k's bit 2 - a, to
    p[a]'s, flipped); classes number the canonical patterns in increasing order."""
    if _SYM_TABLES:
        return _SYM_TABLES[0]
    moves = [(p, [(f >> (2 - a)) & 1 for a in range(3)]) for p in _perms3() for f in range(8)]

    def move_nb(nb: int, p, f) -> int:
        return sum(1 << (2 * p[a] + (side ^ f[a])) for a in range(3) for side in range(2) if nb >> (2 * a + side) & 1)

    def move_k(k: int, p, f) -> int:
        return sum((((k >> (2 - a)) & 1) ^ f[a]) << (2 - p[a]) for a in range(3))

    best = [min(moves, key=lambda m, nb=nb: move_nb(nb, *m)) for nb in range(64)]
    canon = [move_nb(nb, *best[nb]) for nb in range(64)]
    reps = sorted(set(canon))
    cls = np.array([reps.index(c) for c in canon], np.int64)
    rank = np.zeros(256, np.int64)  # symbols number the bytes by their children, then value
    rank[sorted(range(1, 256), key=lambda b: (bin(b).count("1"), b))] = np.arange(1, 256)
    fwd = np.zeros((64, 256), np.int64)
    inv = np.zeros((64, 256), np.int64)
    for nb in range(64):
        kmap = [move_k(k, *best[nb]) for k in range(8)]
        for b in range(256):
            s = rank[sum(1 << kmap[k] for k in range(8) if b >> k & 1)]
            fwd[nb, b], inv[nb, s] = s, b
    _SYM_TABLES.append((cls, fwd, inv))
    return cls, fwd, inv


@njit(cache=True, nogil=True)
def symbol_decisions(leaves, levels, cls, fwd):  # pragma: no cover - compiled
    """(contexts, symbols) of the octree of sorted unique Morton keys of depth ``levels``: every
    node from the root down, depth by depth in Morton order, its occupancy byte in its canonical
    frame (``symmetry_tables``), in context ``last * SYM_CLASSES + cls[nb]``."""
    occ = _occupancy(leaves, levels)
    ctx = np.empty(occ.shape[0], np.int32)
    sym = np.empty(occ.shape[0], np.int32)
    pbyte = np.ones(1, np.int64)
    pstart = np.zeros(1, np.int64)
    pup = np.full((3, 1), -1, np.int64)
    lo, n = 0, 1
    for d in range(levels):
        nbs, up = child_neighbours(pbyte, pstart, pup, n)
        last = SYM_CLASSES if d == levels - 1 else 0
        byte_d = np.empty(n, np.int64)
        cstart = np.empty(n, np.int64)
        children = 0
        for i in range(n):
            byte = np.int64(occ[lo + i])
            byte_d[i] = byte
            cstart[i] = children
            children += _popcount(byte)
            nb = np.int64(nbs[i])
            ctx[lo + i] = last + cls[nb]
            sym[lo + i] = fwd[nb, byte]
        pbyte, pstart, pup = byte_d, cstart, up
        lo += n
        n = children
    return ctx, sym


@njit(cache=True, nogil=True)
def _sym_tables():  # pragma: no cover - compiled
    """(counts, block sums of 16, totals) of every context at the start: the symbol of a byte of c
    children counts max(1, 16 >> (c - 1)) (fewer children are likelier), the empty byte 0."""
    freq = np.zeros((SYM_CONTEXTS, 256), np.int64)
    blk = np.zeros((SYM_CONTEXTS, 16), np.int64)
    total = np.zeros(SYM_CONTEXTS, np.int64)
    children = 1
    for s in range(1, 256):
        while s > SYM_LAST[children - 1]:
            children += 1
        for c in range(SYM_CONTEXTS):
            freq[c, s] = max(1, 16 >> (children - 1))
            blk[c, s >> 4] += freq[c, s]
            total[c] += freq[c, s]
    return freq, blk, total


@njit(cache=True, nogil=True, inline="always")
def _sym_update(freq, blk, total, c, s):  # pragma: no cover - compiled
    freq[c, s] += SYM_INC
    blk[c, s >> 4] += SYM_INC
    total[c] += SYM_INC
    if total[c] > SYM_LIMIT:
        total[c] = 0
        for b in range(16):
            blk[c, b] = 0
        for q in range(1, 256):
            freq[c, q] = (freq[c, q] + 1) >> 1
            blk[c, q >> 4] += freq[c, q]
            total[c] += freq[c, q]


@njit(cache=True, nogil=True)
def symbol_code(ctx, sym):  # pragma: no cover - compiled
    """The range-coded bytes of symbols ``sym[i]`` (1-255) each with the adaptive frequency table
    of its context ``ctx[i]``: a symbol of count f after counts summing to cum in a table of total
    T takes r = range // T, low += r cum, range = r f."""
    n = sym.shape[0]
    buf = np.empty(2 * n + 64, np.uint8)  # a symbol costs at most 16 bits
    freq, blk, total = _sym_tables()
    low = np.int64(0)
    rng = np.int64(0xFFFFFFFF)
    cache = np.int64(0)
    csize = np.int64(1)
    pos = 0
    for i in range(n + 1):
        shifts = 5  # at the end: the flush
        if i < n:
            c, s = ctx[i], sym[i]
            cum = 0
            for b in range(s >> 4):
                cum += blk[c, b]
            for q in range((s >> 4) << 4, s):
                cum += freq[c, q]
            r = rng // total[c]
            low += r * cum
            rng = r * freq[c, s]
            _sym_update(freq, blk, total, c, s)
            shifts = 0
            while rng < (1 << 24):
                rng <<= 8
                shifts += 1
        for _ in range(shifts):
            if low < 0xFF000000 or low >= (1 << 32):
                carry = low >> 32
                temp = cache
                while True:
                    buf[pos] = (temp + carry) & 0xFF
                    pos += 1
                    temp = 0xFF
                    csize -= 1
                    if csize == 0:
                        break
                cache = (low >> 24) & 0xFF
            csize += 1
            low = (low & 0x00FFFFFF) << 8
    return buf[:pos].copy()


@njit(cache=True, nogil=True)
def geometry_symbols_stream(leaves, levels, cls, fwd):  # pragma: no cover - compiled
    """The version 7 geometry stream of sorted unique leaf keys (``symbol_decisions``)."""
    ctx, sym = symbol_decisions(leaves, levels, cls, fwd)
    return symbol_code(ctx, sym)


@njit(cache=True, nogil=True)
def decode_geometry_symbols(data, levels, points, cls, inv):  # pragma: no cover - compiled
    """As ``decode_geometry`` (no reference: every leaf's reference index is -1) for a version 7
    geometry stream; error 1 also for a value past a table's total or an empty byte."""
    st = _reader(data)
    freq, blk, total = _sym_tables()
    keys = np.zeros(1, np.uint64)
    pbyte = np.ones(1, np.int64)
    pstart = np.zeros(1, np.int64)
    pup = np.full((3, 1), -1, np.int64)
    occ = np.empty(0, np.uint8)
    for d in range(levels):
        n = keys.shape[0]
        nbs, up = child_neighbours(pbyte, pstart, pup, n)
        last = 1 if d == levels - 1 else 0
        nxt = np.empty(min(8 * n, points + 8), np.uint64)
        byte_d = np.zeros(n, np.int64)
        cstart = np.zeros(n, np.int64)
        m = 0
        for i in range(n):
            cstart[i] = m
            nb = np.int64(nbs[i])
            c = last * SYM_CLASSES + cls[nb]
            r = st[0] // total[c]
            v = st[1] // r
            if v >= total[c]:
                return keys[:0], st[2], 1, np.full(0, -1, np.int64), occ
            cum = 0
            b = 0
            while cum + blk[c, b] <= v:
                cum += blk[c, b]
                b += 1
            s = b << 4
            while cum + freq[c, s] <= v:
                cum += freq[c, s]
                s += 1
            st[1] -= r * cum
            st[0] = r * freq[c, s]
            _sym_update(freq, blk, total, c, s)
            while st[0] < (1 << 24):
                st[0] <<= 8
                byte_in = data[st[2]] if st[2] < data.shape[0] else 0
                st[2] += 1
                st[1] = ((st[1] << 8) | byte_in) & 0xFFFFFFFF
            byte = inv[nb, s]
            for k in range(8):
                if (byte >> k) & 1:
                    if m >= points:
                        return keys[:0], st[2], 1, np.full(0, -1, np.int64), occ
                    nxt[m] = (keys[i] << np.uint64(3)) | np.uint64(k)
                    m += 1
            byte_d[i] = byte
        keys = nxt[:m]
        grown = np.empty(occ.shape[0] + n, np.uint8)
        grown[: occ.shape[0]] = occ
        grown[occ.shape[0] :] = byte_d
        occ = grown
        pbyte, pstart, pup = byte_d, cstart, up
    return keys, st[2], 0, np.full(keys.shape[0], -1, np.int64), occ
