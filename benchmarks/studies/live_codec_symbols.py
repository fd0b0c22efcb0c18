"""Would the compact codec's octree cost fewer bits, or fewer decisions, coded as one symbol per
node's occupancy byte and with a direct mode for isolated nodes (as MPEG G-PCC and Draco do)?
Per fused cloud, the geometry's cost under each alternative model, against version 5's coded
geometry stream of the same cells (3 mm grid, ``CompactParams()``):

- **v5**: version 5's decisions and contexts (``codec_kernels.geometry_decisions``);
- **byte, binary**: the occupancy byte as one symbol of an adaptive 256-ary model per context,
  binarised as the 255-node tree of its bits (bit k in a context of the bits below it: the chain
  rule, so the same model as a 256-ary one adapting per tree node), contexts the node's 6 face
  neighbour bits x last depth (128) or its number of face neighbours x last depth (14);
- **hybrid**: version 5's single-child flag and index; a node with two or more children sends its
  byte as the binary tree above (bits that the two-child minimum implies not sent);
- **byte, frequency counts**: one 256-ary symbol per node from an adaptive frequency table per
  context (every count starts at 1, the coded byte's count grows by ``inc``, all halve when the
  total passes ``limit``), the cost of a multi-symbol range coder: one decoded symbol per node;
- **v7** (version 7's coded stream, ``codec_kernels.geometry_symbols_stream``): as the row above
  with the neighbour pattern taken up to the cube's symmetries (10 classes, the byte in the
  class's canonical frame) x last depth, counts starting at max(1, 16 >> (children - 1));
- **direct mode** on top of v5's or the hybrid's contexts: a node with no face neighbour (and,
  G-PCC's rule, no sibling; or any) whose subtree holds one leaf sends a flag (context: the
  depths left, whether it has siblings) and then the leaf's remaining 3 bits a depth unmodelled
  (1 bit each); a node with no face neighbour whose subtree holds more sends the flag and goes on
  as before.

Bits a point are the ideal cost (-log2 p of every decision under its adaptive model; LZMA's
11-bit probabilities adapting by 1/32) over the fused cloud's points; for v5 it matches the coded
stream (``coded_geometry_bits_per_point``) to a few bytes, which checks the harness. Decisions
(or symbols) a point count the range decoder's work. ``spacing_bound`` is the estimate of what any
coder of the occupied cells needs when which cells of a surface hold a point is random: per
occupied cell, the fraction f of the surface's cells occupied near it (its 16 nearest occupied
cells' density over the cells a plane of its local normal crosses, ``|nx| + |ny| + |nz|`` per
cell area), and H(f) / f bits for it, summed over the cells and divided by the fused points.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from numba import njit

from fuseflow.live import codec_kernels as K

__all__ = [
    "VARIANTS",
    "variant_decisions",
    "ideal_bits",
    "symbol_bits",
    "spacing_bound",
    "symbol_rows",
    "run_codec_symbols",
]

DIRECT = K.TREE + 1024
"""Contexts of the direct-mode flag (16: depths left, up to 7, x whether the node has siblings)."""
BYTE = DIRECT + 16
"""Contexts of the binarised occupancy byte: row x 256 tree nodes."""
N_CONTEXTS = BYTE + 128 * 256
VARIANTS = [
    ("v5", 0, 0),
    ("v5 + direct (no neighbour, no sibling, 2+ depths left)", 0, 1),
    ("v5 + direct (no neighbour, 1+ depths left)", 0, 2),
    ("byte, binary, 6 neighbour bits", 1, 0),
    ("byte, binary, 6 neighbour bits + direct (1+ depths)", 1, 2),
    ("byte, binary, neighbour count", 3, 0),
    ("hybrid: v5 single child, byte otherwise", 2, 0),
    ("hybrid + direct (1+ depths)", 2, 2),
]
"""(label, byte model: 0 v5's, 1 the binary tree per 6 neighbour bits, 2 hybrid, 3 the binary
tree per neighbour count; direct mode: 0 none, 1 G-PCC's rule, 2 any node without a neighbour)."""
SYMBOL_MODELS = [("6 neighbour bits", 0, 32, 1 << 16), ("6 neighbour bits", 0, 24, 1 << 13),
                 ("6 neighbour bits", 0, 32, 1 << 12), ("neighbour count", 1, 32, 1 << 16)]  # fmt: skip
"""(context, mode, inc, limit) of the frequency-count rows."""


@njit(cache=True, inline="always")
def _byte_tree(ctx, bits, t, base, byte, floor):  # pragma: no cover - compiled
    """List the bits of ``byte`` in increasing k as the nodes of a 255-node tree from ``base``;
    bits implied by the byte holding at least ``floor`` children are not listed."""
    node = 1
    for k in range(8):
        seen = K._popcount(byte & ((1 << k) - 1))
        if seen + (8 - k) <= floor:  # every bit from k on must be set
            break
        bit = (byte >> k) & 1
        ctx[t], bits[t] = base + node, bit
        t += 1
        node = 2 * node + bit
    return t


@njit(cache=True, inline="always")
def _v5_node(ctx, bits, t, base, extra, row, byte):  # pragma: no cover - compiled
    """List version 5's decisions of a node (``geometry_decisions`` without a reference)."""
    single = 1 if (byte & (byte - 1)) == 0 else 0
    ctx[t], bits[t] = K.SINGLE + row, single
    t += 1
    if single:
        node = 1
        for b in range(2, -1, -1):
            bit = (K._popcount(byte - 1) >> b) & 1
            ctx[t], bits[t] = K.TREE + row * 8 + node, bit
            t += 1
            node = 2 * node + bit
        return t
    for k in range(8):
        below = byte & ((1 << k) - 1)
        if k == 7 and K._popcount(below) <= 1:
            break
        ctx[t], bits[t] = base[row * 8 + k] + extra[k * 128 + below], (byte >> k) & 1
        t += 1
    return t


@njit(cache=True)
def variant_decisions(leaves, levels, byte_model, direct):  # pragma: no cover - compiled
    """(contexts, bits, direct-coded nodes) of the octree of sorted unique Morton keys under one
    of ``VARIANTS``; context -1: an unmodelled bit (direct mode's leaf bits)."""
    keys, start = K._node_levels(leaves, levels)
    base, extra = K.geo_contexts()
    size = 9 * start[levels] + 3 * levels * leaves.shape[0] + 8
    ctx = np.empty(size, np.int32)
    bits = np.empty(size, np.uint8)
    t = 0
    n_direct = 0
    pbyte = np.ones(1, np.int64)
    pstart = np.zeros(1, np.int64)
    pup = np.full((3, 1), -1, np.int64)
    known = np.zeros(1, np.uint8)  # inside a direct-coded subtree: nothing to send
    only = np.ones(1, np.uint8)  # the node has no sibling
    for d in range(levels):
        lo, hi = start[d], start[d + 1]
        nbs, up = K.child_neighbours(pbyte, pstart, pup, hi - lo)
        last = 1 if d == levels - 1 else 0
        byte_d = np.zeros(hi - lo, np.int64)
        cstart = np.zeros(hi - lo, np.int64)
        nknown = np.zeros(start[d + 2] - hi, np.uint8)
        nonly = np.zeros(start[d + 2] - hi, np.uint8)
        j = hi
        for i in range(hi - lo):
            cstart[i] = j - hi
            j0, byte = j, 0
            while j < start[d + 2] and (keys[j] >> np.uint64(3)) == keys[lo + i]:
                byte |= 1 << np.int64(keys[j] & np.uint64(7))
                j += 1
            byte_d[i] = byte
            nknown[j0 - hi : j - hi] = known[i]
            nonly[j0 - hi : j - hi] = 1 if (byte & (byte - 1)) == 0 else 0
            if known[i]:
                continue
            left = levels - d
            row = last * 64 + np.int64(nbs[i])
            if direct and d > 0 and nbs[i] == 0 and (direct == 2 or (only[i] and left >= 2)):
                shift = np.uint64(3 * left)
                a = np.searchsorted(leaves, keys[lo + i] << shift)
                b = np.searchsorted(leaves, (keys[lo + i] + np.uint64(1)) << shift)
                one = 1 if b - a == 1 else 0
                ctx[t], bits[t] = DIRECT + min(left, 7) + 8 * np.int64(only[i]), one
                t += 1
                if one:
                    n_direct += 1
                    for s in range(3 * left - 1, -1, -1):
                        ctx[t], bits[t] = -1, np.uint8((leaves[a] >> np.uint64(s)) & np.uint64(1))
                        t += 1
                    nknown[j0 - hi : j - hi] = 1
                    continue
            if byte_model == 0 or (byte_model == 2 and (byte & (byte - 1)) == 0):
                t = _v5_node(ctx, bits, t, base, extra, row, byte)
            elif byte_model == 2:
                ctx[t], bits[t] = K.SINGLE + row, 0
                t = _byte_tree(ctx, bits, t + 1, BYTE + row * 256, byte, 2)
            else:
                r = row if byte_model == 1 else last * 64 + K._popcount(np.int64(nbs[i]))
                t = _byte_tree(ctx, bits, t, BYTE + r * 256, byte, 1)
        pbyte, pstart, pup, known, only = byte_d, cstart, up, nknown, nonly
    return ctx[:t], bits[:t], n_direct


@njit(cache=True)
def ideal_bits(ctx, bits, n_contexts):  # pragma: no cover - compiled
    """Sum of -log2 p of decisions under LZMA's adaptive binary model (context -1: 1 bit)."""
    probs = np.full(n_contexts, 1024, np.int64)
    total = 0.0
    for i in range(ctx.shape[0]):
        c = ctx[i]
        if c < 0:
            total += 1.0
            continue
        p = probs[c]
        if bits[i] == 0:
            total -= np.log2(p / 2048.0)
            probs[c] = p + ((2048 - p) >> 5)
        else:
            total -= np.log2(1.0 - p / 2048.0)
            probs[c] = p - (p >> 5)
    return total


@njit(cache=True)
def symbol_bits(leaves, levels, mode, inc, limit):  # pragma: no cover - compiled
    """(ideal bits, nodes) of every node's occupancy byte as one symbol of an adaptive frequency
    table per context (mode 0: last depth x 6 neighbour bits; 1: x neighbour count)."""
    keys, start = K._node_levels(leaves, levels)
    freq = np.ones((128, 256), np.int64)
    freq[:, 0] = 0  # a node holds at least one child
    total = np.full(128, 255, np.int64)
    pbyte = np.ones(1, np.int64)
    pstart = np.zeros(1, np.int64)
    pup = np.full((3, 1), -1, np.int64)
    cost = 0.0
    for d in range(levels):
        lo, hi = start[d], start[d + 1]
        nbs, up = K.child_neighbours(pbyte, pstart, pup, hi - lo)
        last = 1 if d == levels - 1 else 0
        byte_d = np.zeros(hi - lo, np.int64)
        cstart = np.zeros(hi - lo, np.int64)
        j = hi
        for i in range(hi - lo):
            cstart[i] = j - hi
            byte = 0
            while j < start[d + 2] and (keys[j] >> np.uint64(3)) == keys[lo + i]:
                byte |= 1 << np.int64(keys[j] & np.uint64(7))
                j += 1
            byte_d[i] = byte
            r = last * 64 + (np.int64(nbs[i]) if mode == 0 else K._popcount(np.int64(nbs[i])))
            cost -= np.log2(freq[r, byte] / total[r])
            freq[r, byte] += inc
            total[r] += inc
            if total[r] > limit:
                total[r] = 0
                for s in range(1, 256):
                    freq[r, s] = (freq[r, s] + 1) // 2
                    total[r] += freq[r, s]
        pbyte, pstart, pup = byte_d, cstart, up
    return cost, start[levels]


def _entropy(f: np.ndarray) -> np.ndarray:
    f = np.clip(f, 1e-9, 1 - 1e-9)
    return -(f * np.log2(f) + (1 - f) * np.log2(1 - f))


def spacing_bound(cells: np.ndarray, step: float, points: int, k: int = 16) -> dict:
    """The random-occupancy estimate (module docstring) for (M, 3) occupied integer cells."""
    from scipy.spatial import cKDTree

    c = (cells + 0.5) * step
    dist, idx = cKDTree(c).query(c, k + 1)
    centred = c[idx] - c[idx].mean(1, keepdims=True)
    normal = np.linalg.eigh(np.einsum("mki,mkj->mij", centred, centred))[1][:, :, 0]
    f = np.clip(k / (np.pi * dist[:, k] ** 2) * step * step / np.abs(normal).sum(1), 0.0, 1.0)
    return {"spacing_bound_bits_per_point": round(float((_entropy(f) / np.maximum(f, 1e-9)).sum() / points), 3),
            "occupied_fraction_median": round(float(np.median(f)), 3),
            "cell_spacing_median_mm": round(float(np.median(dist[:, 1])) * 1e3, 2)}  # fmt: skip


def symbol_rows(name: str, xyz: np.ndarray, rgb: np.ndarray, step_mm: float = 3.0) -> list[dict]:
    """One row per VARIANTS and SYMBOL_MODELS entry for a cloud, each with version 5's coded
    geometry bits, and the spacing bound."""
    xyz = np.ascontiguousarray(xyz, np.float32)
    origin = xyz.min(0).astype(np.float64)
    cells, top = K.grid_cells(xyz, origin, 1000.0 / step_mm)
    levels = max(1, int(top).bit_length())
    leaves, _ = K.leaves_v3(cells, levels, np.ascontiguousarray(rgb, np.uint8))
    n = len(xyz)
    empty = (np.zeros(0, np.uint8), np.zeros(0, np.int64))
    coded = len(K.geometry_stream(leaves, levels, *empty)[0]) * 8 / n
    common = {"cloud": name, "points": n, "cells": len(leaves), "levels": levels,
              "coded_geometry_bits_per_point": round(coded, 3)}  # fmt: skip
    bound = spacing_bound(K.morton_cells(leaves), step_mm / 1000.0, n)
    rows = []
    for label, byte_model, direct in VARIANTS:
        ctx, bits, n_direct = variant_decisions(leaves, levels, byte_model, direct)
        cost = ideal_bits(ctx, bits, N_CONTEXTS)
        rows.append({**common, "model": label, "geometry_bits_per_point": round(cost / n, 3),
                     "vs_coded": round(cost / n / coded - 1.0, 4), "decisions_per_point": round(len(ctx) / n, 3),
                     "direct_nodes": int(n_direct), **bound})  # fmt: skip
    cls, fwd, _ = K.symmetry_tables()
    v7 = len(K.geometry_symbols_stream(leaves, levels, cls, fwd)) * 8 / n
    rows.append({**common, "model": "v7: byte, frequency counts, symmetry classes x last depth, fewer-children prior (coded)",
                 "geometry_bits_per_point": round(v7, 3), "vs_coded": round(v7 / coded - 1.0, 4),
                 "decisions_per_point": round(int(K._node_levels(leaves, levels)[1][levels]) / n, 3), "direct_nodes": 0,
                 **bound})  # fmt: skip
    for label, mode, inc, limit in SYMBOL_MODELS:
        cost, nodes = symbol_bits(leaves, levels, mode, inc, limit)
        rows.append({**common, "model": f"byte, frequency counts, {label}, +{inc}, halved over {limit}",
                     "geometry_bits_per_point": round(cost / n, 3), "vs_coded": round(cost / n / coded - 1.0, 4),
                     "decisions_per_point": round(nodes / n, 3), "direct_nodes": 0, **bound})  # fmt: skip
    return rows


def _kinect3_frame(data_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """kinect3-room's first frame fused at 200 k points with its reference extrinsics (a real
    3-camera rig, sparse at 3 mm)."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording, read_calibration

    rec = open_recording(data_dir / "kinect3-room")
    rig = rec.rig.with_extrinsics(read_calibration(data_dir / "kinect3-room" / "reference_calib.json").T_cam_world)
    c = fuse(rec[0], rig, preset_config("live", 200_000))
    return c.xyz.numpy().astype(np.float32), c.rgb.numpy().astype(np.uint8)


def run_codec_symbols(data_dir: Path, log=print) -> dict:
    """Rows for the hocap8, sim8 and polyroom8 200 k-point clouds (``live_codec_versions``) and
    kinect3-room's first frame."""
    from benchmarks.studies.live_codec_versions import fused_clouds

    rows = []
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-") as tmp:
        clouds = fused_clouds(Path(data_dir), Path(tmp))
    clouds["kinect3-room-frame0"] = _kinect3_frame(Path(data_dir))
    for name, (xyz, rgb) in clouds.items():
        rows += symbol_rows(name, xyz, rgb)
        for r in rows[-len(VARIANTS) - len(SYMBOL_MODELS) - 1 :]:
            log(f"{name}: {r['model']}: {r['geometry_bits_per_point']} bits a point ({r['vs_coded']:+.1%} against "
                f"v5's {r['coded_geometry_bits_per_point']}), {r['decisions_per_point']} decisions a point")  # fmt: skip
    load.append(os.getloadavg()[0])
    return {"rows": rows, "meta": {"step_mm": 3.0, "load_1min_start_end": [round(x, 1) for x in load]}}
