"""Where the compact codec's bits and time go (version 5, ``CompactParams(version=3)``), per fused cloud:
the bits a point of each kind of decision (the ideal cost, -log2 p, of every decision under the
coder's adaptive model, which the range coder's output matches to a few bytes): in the geometry,
the child bits, the single-child flags and a single child's index bits, each at the last depth
(the leaves' parents) and above; in the colour, luma, chroma and the blocks' split flags; then
the thread CPU of the geometry and the colour kernels, encoding (``geometry_stream``,
``colour_stream``) and decoding (``decode_geometry``, ``decode_colour``; and decode.js's
``geometry`` and ``colours`` in node), median of ``repeats``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.studies.live_codec import cpu_ms
from benchmarks.studies.live_codec_versions import DECODE_JS, fused_clouds
from fuseflow.live import codec_kernels as K
from fuseflow.live.codec import CompactParams

__all__ = ["decision_bits", "split_row", "node_split_ms", "run_codec_split"]

NODE_SPLIT = """
const fs = require("fs"); const D = require(process.argv[2]); const repeats = +process.argv[3];
const [m, levels, ls, cs, blk] = process.argv.slice(5).map(Number);
const b = fs.readFileSync(process.argv[4]), g = new Uint8Array(b.buffer, b.byteOffset, b.length);
const s1 = g[52] | (g[53] << 8) | (g[54] << 16) | (g[55] * 16777216), geo = g.subarray(60, 60 + s1), col = g.subarray(60 + s1);
const tg = [], tc = [], ms = (t0) => { const u = process.cpuUsage(t0); return (u.user + u.system) / 1e3; };
for (let r = 0; r <= repeats; r++) {
  let t0 = process.cpuUsage(); D.geometry(geo, levels, m, D.NO_REF); if (r) tg.push(ms(t0));
  t0 = process.cpuUsage(); D.colours(col, m, ls, cs, blk, null, D.NO_REF.q, true); if (r) tc.push(ms(t0));
}
const med = (a) => a.sort((x, y) => x - y)[a.length >> 1];
console.log(JSON.stringify([med(tg), med(tc)]));
"""


def decision_bits(ctx: np.ndarray, bits: np.ndarray, n_contexts: int) -> np.ndarray:
    """-log2 p of every decision under the coder's adaptive model (11-bit probabilities from one
    half, adapted by 1/32)."""
    from numba import njit

    @njit(cache=False)
    def run(ctx, bits, n):  # pragma: no cover - compiled
        probs = np.full(n, 1024, np.int64)
        out = np.empty(ctx.shape[0])
        for i in range(ctx.shape[0]):
            c = ctx[i]
            p = probs[c]
            if bits[i] == 0:
                out[i] = -np.log2(p / 2048.0)
                probs[c] = p + ((2048 - p) >> 5)
            else:
                out[i] = -np.log2(1.0 - p / 2048.0)
                probs[c] = p - (p >> 5)
        return out

    return run(ctx, bits, n_contexts)


def _geometry_parts(ctx: np.ndarray, cost: np.ndarray, n: int) -> dict:
    """Bits a point of child bits, single-child flags and index bits, at the last depth and above
    (the context ranges of ``codec_kernels.geo_contexts``: child bit contexts hold the last-depth
    flag at 2048, the flag's at 64 and the index bits' at 512)."""
    child, single = ctx < K.SINGLE, (ctx >= K.SINGLE) & (ctx < K.TREE)
    tree = (ctx >= K.TREE) & (ctx < K.P_CHILD)
    last = np.where(child, ctx // 2048, np.where(single, (ctx - K.SINGLE) // 64, (ctx - K.TREE) // 512)) == 1
    out = {}
    for name, kind in (("child_bits", child), ("single_flags", single), ("index_bits", tree)):
        for where, sel in (("last_depth", last), ("above", ~last)):
            out[f"{name}_{where}"] = round(float(cost[kind & sel].sum()) / n, 3)
    return out


def split_row(
    name: str, xyz: np.ndarray, rgb: np.ndarray, repeats: int, p: CompactParams = CompactParams(version=3)
) -> dict:
    """One row of a cloud (``run_codec_split``), with the streams for decode.js in ``_data``."""
    step = p.step_mm / 1000.0
    xyz = np.ascontiguousarray(xyz, np.float32)
    cells, top = K.grid_cells(xyz, xyz.min(0).astype(np.float64), 1.0 / step)
    levels = max(1, int(top).bit_length())
    leaves, mean = K.leaves_v3(cells, levels, rgb)
    m, n = len(leaves), len(xyz)
    no_occ, no_first, no_rq, no_leaf = (
        np.zeros(0, np.uint8),
        np.zeros(0, np.int64),
        np.zeros((0, 3), np.int64),
        np.full(m, -1, np.int64),
    )
    gctx, gbits, _ = K.geometry_decisions(leaves, levels, no_occ, no_first)
    gcost = decision_bits(gctx, gbits, K.INTER_GEO_CONTEXTS)
    qy, qc, flags = K.colour_values(mean, p.luma_step, p.chroma_step, p.chroma_block, p.split)
    cctx, cbits = K.colour_decisions(qy, qc, p.chroma_block, no_leaf, no_rq, flags, True)
    ccost = decision_bits(cctx, cbits, K.COL_CONTEXTS)
    group = cctx // K.RES
    (geo, _), enc_geo = cpu_ms(lambda: K.geometry_stream(leaves, levels, no_occ, no_first), repeats)
    (col, _), enc_col = cpu_ms(
        lambda: K.colour_stream(mean, p.luma_step, p.chroma_step, p.chroma_block, no_leaf, no_rq, p.split), repeats
    )
    _, dec_geo = cpu_ms(lambda: K.decode_geometry(geo, levels, m, no_occ, no_first), repeats)
    _, dec_col = cpu_ms(
        lambda: K.decode_colour(col, m, p.luma_step, p.chroma_step, p.chroma_block, no_leaf, no_rq, True), repeats
    )
    return {"cloud": name, "points": n, "points_sent": m, "levels": levels,
            "bits_per_point": round((len(geo) + len(col)) * 8 / n, 3),
            "geometry_bits_per_point": round(len(geo) * 8 / n, 3),
            "geometry_model_bits_per_point": round(float(gcost.sum()) / n, 3),
            **_geometry_parts(gctx, gcost, n),
            "geometry_decisions_per_point": round(len(gctx) / n, 2),
            "colour_bits_per_point": round(len(col) * 8 / n, 3),
            "luma_bits": round(float(ccost[(group < 3) | ((group >= 21) & (group < 24))].sum()) / n, 3),
            "chroma_bits": round(float(ccost[((group >= 3) & (group < 21)) | ((group >= 24) & (group < 30))].sum()) / n, 3),
            "split_flag_bits": round(float(ccost[cctx >= K.SPLIT].sum()) / n, 3),
            "colour_decisions_per_point": round(len(cctx) / n, 2),
            "encode_geometry_cpu_ms": round(enc_geo, 1), "encode_colour_cpu_ms": round(enc_col, 1),
            "python_decode_geometry_cpu_ms": round(dec_geo, 1), "python_decode_colour_cpu_ms": round(dec_col, 1),
            "_node": (np.concatenate([np.zeros(52, np.uint8), np.frombuffer(len(geo).to_bytes(4, "little"), np.uint8),
                                      np.zeros(4, np.uint8), geo, col]).tobytes(), m, levels, p)}  # fmt: skip


def node_split_ms(rows: list[dict], repeats: int, work: Path) -> None:
    """Add decode.js's ``geometry`` and ``colours`` CPU ms (node, median) to every row: a copy of
    decode.js that also exports them, fed each row's two streams."""
    src = DECODE_JS.read_text()
    api = "const api = { decodeFrame, createDecoder, keyGeometry };"
    if api not in src:
        raise RuntimeError("decode.js: its api line changed; update node_split_ms")
    (work / "decode_split.js").write_text(
        src.replace(api, "const api = { decodeFrame, createDecoder, keyGeometry, geometry, colours, NO_REF };")
    )
    (work / "split.js").write_text(NODE_SPLIT)
    for i, r in enumerate(rows):
        data, m, levels, p = r["_node"]
        f = work / f"streams{i}.bin"
        f.write_bytes(data)
        args = [str(v) for v in (m, levels, p.luma_step, p.chroma_step, p.chroma_block)]
        out = subprocess.run(["node", str(work / "split.js"), str(work / "decode_split.js"), str(repeats), str(f), *args],
                             capture_output=True, text=True, timeout=1800, check=True)  # fmt: skip
        r["node_decode_geometry_ms"], r["node_decode_colour_ms"] = (round(v, 1) for v in json.loads(out.stdout))


def run_codec_split(data_dir: Path, repeats: int = 5, node: bool = True, log=print) -> dict:
    """``split_row`` of the hocap-8rs frame, the simulated studio and the polyroom studio fused at
    200 k points (``live_codec_versions.fused_clouds``): {"meta": {load, cpus}, "rows": [...]}."""
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-split-") as tmp:
        work = Path(tmp)
        rows = [split_row(name, xyz, rgb, repeats) for name, (xyz, rgb) in fused_clouds(Path(data_dir), work).items()]
        if node and shutil.which("node"):
            node_split_ms(rows, repeats, work)
    for r in rows:
        r.pop("_node")
        log(json.dumps(r))
    load.append(os.getloadavg()[0])
    meta = {"load_1min_start_end": [round(x, 1) for x in load], "cpus": os.cpu_count()}
    log(json.dumps(meta))
    return {"meta": meta, "rows": rows}
