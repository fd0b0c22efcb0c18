"""Bits a point of the live stream's compact codec, version 3 (range coded) against version 2
(deflated) and raw, measured in one run on the same fused clouds: the hocap-8rs frame and a
simulated 8-camera 640x480 studio, each fused with ``--preset live`` at 200 k points (the live
path's budget). Per codec setting: bits a point (of the fused cloud; and of its geometry stream,
bytes 52-55 of both compact headers), points sent, position error
(largest per-axis offset of a fused point to its nearest decoded point, and that over half the
grid step), colour error (|decoded - fused| per RGB channel, median and 95th percentile), encode
time (CPU of the calling thread plus its geometry worker, and wall; median of ``--repeats``),
Python decode time, and decode.js's time in node (median of ``--repeats``; the viewer's decoder).
Timings depend on the machine's load, given in the output: compare rows of one run.

    python benchmarks/live_codec_v3.py [--data-dir ../shared/data] [--json benchmarks/results/live_codec_v3.json]
        [--repeats 7] [--no-node]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from fuseflow.live.codec import CompactParams, encode_compact  # noqa: E402
from fuseflow.live.wire import decode_frame  # noqa: E402

DECODE_JS = Path(__file__).resolve().parents[1] / "src" / "fuseflow" / "live" / "static" / "decode.js"
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
    from fuseflow.fuse.config import preset_config
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-node", action="store_true")
    a = ap.parse_args()
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-") as tmp:
        work = Path(tmp)
        rows = []
        for name, (xyz, rgb) in fused_clouds(a.data_dir, work).items():
            rows += measure(name, xyz, rgb, a.repeats)
        if not a.no_node and shutil.which("node"):
            node_decode_ms(rows, a.repeats, work)
    load.append(os.getloadavg()[0])
    cols = ["cloud", "codec", "bits_per_point", "geometry_bits_per_point", "points_sent", "pos_err_axis_max_mm", "rgb_err_median", "rgb_err_p95",
            "encode_cpu_ms", "encode_wall_ms", "node_decode_ms"]  # fmt: skip
    print("| " + " | ".join(cols) + " |\n|" + "---|" * len(cols))
    for r in rows:
        r.pop("_data")
        print("| " + " | ".join(str(r.get(c)) for c in cols) + " |")
    meta = {"command": "python benchmarks/live_codec_v3.py " + " ".join(sys.argv[1:]),
            "load_1min_start_end": [round(x, 1) for x in load], "cpus": os.cpu_count()}  # fmt: skip
    print(json.dumps(meta))
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
