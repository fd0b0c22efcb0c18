"""Bits a point of the live stream's compact codec, version 3 (range coded) against version 2
(deflated) and raw, in one run on the same fused clouds: the hocap-8rs frame and a simulated
8-camera 640x480 studio, each fused with ``--preset live`` at 200 k points (the live path's
budget). Per codec setting: bits a point (of the fused cloud; and of its geometry stream, bytes
52-55 of both compact headers), points sent, position error (largest per-axis offset of a fused
point to its nearest decoded point, and that over half the grid step), colour error (|decoded -
fused| per RGB channel, median and 95th percentile), encode time (CPU of the process: the calling
thread and its geometry worker; and wall; median of ``repeats``), Python decode time, and
decode.js's time in node (median of ``repeats``; the viewer's decoder). Timings depend on the
machine's load, recorded in ``meta``: compare rows of one run.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import fuseflow.live
from fuseflow.live.codec import CompactParams, encode_compact
from fuseflow.live.wire import decode_frame

__all__ = ["SETTINGS", "fused_clouds", "measure", "node_decode_ms", "run_codec_v3_bench", "table"]

DECODE_JS = Path(fuseflow.live.__file__).resolve().parent / "static" / "decode.js"
SETTINGS: list[tuple[str, CompactParams | None]] = [
    ("raw", None),
    ("v2, 3 mm / 4, 8, 4 (version 2 default)", CompactParams(3.0, 4, 8, 4, version=2)),
    ("v2, 3 mm / 8, 16, 4", CompactParams(3.0, 8, 16, 4, version=2)),
    ("v3, 3 mm / 8, 16, 4 (default)", CompactParams(3.0, 8, 16, 4)),
    ("v3, 3 mm / 4, 8, 4", CompactParams(3.0, 4, 8, 4)),
    ("v3, 3 mm / 8, 16, 2", CompactParams(3.0, 8, 16, 2)),
    ("v3, 3 mm / 8, 16, 1", CompactParams(3.0, 8, 16, 1)),
    ("v3, 4 mm / 8, 16, 4", CompactParams(4.0, 8, 16, 4)),
    ("v3, 5 mm / 8, 16, 4", CompactParams(5.0, 8, 16, 4)),
    ("v3, 6 mm / 8, 16, 1", CompactParams(6.0, 8, 16, 1)),
    ("v3, 8 mm / 8, 16, 1", CompactParams(8.0, 8, 16, 1)),
]
NODE_SCRIPT = """
const fs = require("fs"); const { decodeFrame } = require(process.argv[2]); const repeats = +process.argv[3];
(async () => {
  const out = {};
  for (const name of process.argv.slice(4)) {
    const b = fs.readFileSync(name), ab = b.buffer.slice(b.byteOffset, b.byteOffset + b.length), t = [];
    await decodeFrame(ab);
    for (let r = 0; r < repeats; r++) { const t0 = performance.now(); await decodeFrame(ab); t.push(performance.now() - t0); }
    t.sort((a, c) => a - c); out[name] = t[t.length >> 1];
  }
  console.log(JSON.stringify(out));
})();
"""


def fused_clouds(data_dir: Path, work: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (xyz float32, rgb uint8): hocap8-200k and sim8-200k."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording
    from fuseflow.io.hocap import convert_hocap
    from fuseflow.synth import SimConfig, simulate_recording

    convert_hocap(data_dir / "hocap-8rs", work / "hocap8", with_extrinsics=True)
    simulate_recording(work / "sim8", SimConfig(cameras=8, frames=1, scene="studio", dynamic=True,
                                                resolution=(640, 480), seed=0, fps=10.0))  # fmt: skip
    out = {}
    for name, folder in (("hocap8-200k", "hocap8"), ("sim8-200k", "sim8")):
        rec = open_recording(work / folder)
        c = fuse(rec[0], rec.rig, preset_config("live", 200_000))
        out[name] = (c.xyz.numpy().astype(np.float32), c.rgb.numpy().astype(np.uint8))
    return out


def _encode(xyz: np.ndarray, rgb: np.ndarray, p: CompactParams | None) -> bytes:
    if p is not None:
        return encode_compact(xyz, rgb, 0, 0.0, 0.0, p)
    import torch

    from fuseflow.live.wire import encode_frame
    from fuseflow.types import FusedCloud

    m = len(xyz)
    cloud = FusedCloud(torch.from_numpy(xyz), torch.from_numpy(rgb), torch.ones(m), torch.zeros(m, dtype=torch.int16))
    return encode_frame(cloud, 0, 0.0, 0.0, "raw")


def _timed(fn, repeats: int) -> tuple[object, float, float]:
    """(result, median process CPU ms, median wall ms): process CPU counts the geometry worker."""
    out, cpu, wall = fn(), [], []
    for _ in range(repeats):
        c, w = time.process_time(), time.perf_counter()
        out = fn()
        cpu.append((time.process_time() - c) * 1e3)
        wall.append((time.perf_counter() - w) * 1e3)
    return out, float(np.median(cpu)), float(np.median(wall))


def measure(name: str, xyz: np.ndarray, rgb: np.ndarray, repeats: int) -> list[dict]:
    """One row per SETTINGS entry (without the node decode time) and the encoded frames."""
    from scipy.spatial import cKDTree

    rows = []
    for label, p in SETTINGS:
        data, cpu, wall = _timed(lambda p=p: _encode(xyz, rgb, p), repeats)
        d, _, dec_wall = _timed(lambda data=data: decode_frame(data), max(1, repeats // 2))
        cheb, idx = cKDTree(d.xyz).query(xyz, p=np.inf)
        err = np.abs(d.rgb[idx].astype(np.int16) - rgb.astype(np.int16))
        half = p.step_mm / 2 if p else None
        rows.append({"cloud": name, "codec": label, "points": len(xyz), "points_sent": len(d.xyz),
                     "bytes": len(data), "bits_per_point": round(len(data) * 8 / len(xyz), 3),
                     "geometry_bits_per_point": round(int.from_bytes(data[52:56], "little") * 8 / len(xyz), 3)
                     if p else None,
                     "mbit_per_s_200k_10fps": round(len(data) * 8 / len(xyz) * 200_000 * 10 / 1e6, 2),
                     "pos_err_axis_max_mm": round(float(cheb.max()) * 1e3, 3),
                     "pos_err_over_half_step": round(float(cheb.max()) * 1e3 / half, 3) if half else None,
                     "rgb_err_median": float(np.median(err)), "rgb_err_p95": float(np.percentile(err, 95)),
                     "encode_cpu_ms": round(cpu, 1), "encode_wall_ms": round(wall, 1),
                     "python_decode_wall_ms": round(dec_wall, 1), "_data": data})  # fmt: skip
    return rows


def node_decode_ms(rows: list[dict], repeats: int, work: Path) -> None:
    """Add ``node_decode_ms`` (decode.js in node, median) to every row."""
    files = []
    for i, r in enumerate(rows):
        f = work / f"frame{i}.bin"
        f.write_bytes(r["_data"])
        files.append(str(f))
    (work / "decode.js").write_text(NODE_SCRIPT)
    out = subprocess.run(["node", str(work / "decode.js"), str(DECODE_JS), str(repeats), *files],
                         capture_output=True, text=True, timeout=1800, check=True)  # fmt: skip
    ms = json.loads(out.stdout)
    for f, r in zip(files, rows):
        r["node_decode_ms"] = round(ms[f], 1)


def table(rows: list[dict]) -> list[str]:
    """The rows as markdown table lines."""
    cols = ["cloud", "codec", "bits_per_point", "geometry_bits_per_point", "points_sent", "pos_err_axis_max_mm",
            "rgb_err_median", "rgb_err_p95", "encode_cpu_ms", "encode_wall_ms", "node_decode_ms"]  # fmt: skip
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    return lines + ["| " + " | ".join(str(r.get(c)) for c in cols) + " |" for r in rows]


def run_codec_v3_bench(data_dir: Path, repeats: int = 7, node: bool = True, log=print) -> dict:
    """Every SETTINGS entry on both clouds (and decode.js in node when ``node`` and node is
    there): {"meta": {load at start and end, cpus}, "rows": [...]}; the table goes to ``log``."""
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-") as tmp:
        work = Path(tmp)
        rows = []
        for name, (xyz, rgb) in fused_clouds(Path(data_dir), work).items():
            rows += measure(name, xyz, rgb, repeats)
        if node and shutil.which("node"):
            node_decode_ms(rows, repeats, work)
    load.append(os.getloadavg()[0])
    for r in rows:
        r.pop("_data")
    for line in table(rows):
        log(line)
    meta = {"load_1min_start_end": [round(x, 1) for x in load], "cpus": os.cpu_count()}
    log(json.dumps(meta))
    return {"meta": meta, "rows": rows}
