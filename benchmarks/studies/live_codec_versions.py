"""Bits a point of the live stream's compact codec, versions 7, 5 and 3 (range coded: the octree
as one symbol a node or as bits, with and without split chroma blocks) against version 2
(deflated) and raw, in one run on the same fused clouds: the hocap-8rs frame, a simulated
8-camera 640x480 studio and a simulated 8-camera polyroom studio, each fused with ``--preset live`` at 200 k points (the live path's
budget). Per codec setting: bits a point (of the fused cloud; and of its geometry stream, bytes
52-55 of both compact headers), points sent, position error (largest per-axis offset of a fused
point to its nearest decoded point, and that over half the grid step), colour error (|decoded -
fused| per RGB channel, median and 95th percentile), encode time (CPU of the process: the calling
thread and its geometry worker; and wall; median of ``repeats``), Python decode time, and
decode.js's CPU time in node (``process.cpuUsage``, median of ``repeats``; the viewer's decoder). Timings depend on the
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
from fuseflow.live.codec import CompactDecoder, CompactParams, InterEncoder, encode_compact
from fuseflow.live.wire import decode_frame

__all__ = [
    "SETTINGS",
    "fused_clouds",
    "fused_sequences",
    "measure",
    "measure_sequence",
    "node_decode_ms",
    "run_codec_v3_bench",
    "table",
]

DECODE_JS = Path(fuseflow.live.__file__).resolve().parent / "static" / "decode.js"
SETTINGS: list[tuple[str, CompactParams | None]] = [
    ("raw", None),
    ("v2, 3 mm / 4, 8, 4 (version 2 default)", CompactParams(3.0, 4, 8, 4, version=2)),
    ("v3, 3 mm / 8, 16, 4", CompactParams(3.0, 8, 16, 4, split=0.0)),
    ("v3, 3 mm / 8, 16, 1", CompactParams(3.0, 8, 16, 1, split=0.0)),
    ("v5, 3 mm / 8, 16, 4, split 1.5", CompactParams(3.0, 8, 16, 4, version=3)),
    ("v5, 3 mm / 12, 16, 4, split 1.5", CompactParams(3.0, 12, 16, 4, version=3)),
    ("v7, 3 mm / 12, 16, 4, split 1.5 (default)", CompactParams(3.0, 12, 16, 4)),
    ("v7, 3 mm / 14, 16, 4, split 1.5", CompactParams(3.0, 14, 16, 4)),
    ("v7, 3 mm / 12, 16, 4, split 1.75", CompactParams(3.0, 12, 16, 4, split=1.75)),
    ("v7, 5 mm / 12, 16, 4, split 1.5", CompactParams(5.0, 12, 16, 4)),
    ("v7, 8 mm / 12, 16, 4, split 1.5", CompactParams(8.0, 12, 16, 4)),
]
"""(label, parameters) of every row: v3 and v4 are the range-coded messages with chroma blocks
that never split (``split=0``), v5 and v6 those where they may (``version=3``), v7 (the default)
version 5 with the octree coded as one symbol a node."""
NODE_SCRIPT = """
const fs = require("fs"); const { decodeFrame } = require(process.argv[2]); const repeats = +process.argv[3];
(async () => {
  const out = {};
  for (const name of process.argv.slice(4)) {
    const b = fs.readFileSync(name), ab = b.buffer.slice(b.byteOffset, b.byteOffset + b.length), t = [];
    await decodeFrame(ab);
    for (let r = 0; r < repeats; r++) { const t0 = process.cpuUsage(); await decodeFrame(ab); const u = process.cpuUsage(t0); t.push((u.user + u.system) / 1e3); }
    t.sort((a, c) => a - c); out[name] = t[t.length >> 1];
  }
  console.log(JSON.stringify(out));
})();
"""


def fused_clouds(data_dir: Path, work: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (xyz float32, rgb uint8): hocap8-200k, sim8-200k and polyroom8-200k (a second,
    separately written simulated studio the codec's parameters were not chosen on)."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording
    from fuseflow.io.hocap import convert_hocap
    from fuseflow.synth import SimConfig, simulate_recording

    convert_hocap(data_dir / "hocap-8rs", work / "hocap8", with_extrinsics=True)
    simulate_recording(work / "sim8", SimConfig(cameras=8, frames=1, scene="studio", dynamic=True,
                                                resolution=(640, 480), seed=0, fps=10.0))  # fmt: skip
    simulate_recording(work / "poly8", SimConfig(cameras=8, frames=1, scene="polyroom", resolution=(640, 480),
                                                 seed=0, fps=10.0))  # fmt: skip
    out = {}
    for name, folder in (("hocap8-200k", "hocap8"), ("sim8-200k", "sim8"), ("polyroom8-200k", "poly8")):
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
    """Add ``node_decode_ms`` (decode.js's CPU time in node, median) to every row."""
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
    cols = ["cloud", "codec", "frames", "bits_per_point", "bits_per_point_after_first", "geometry_bits_per_point",
            "points_sent", "pos_err_axis_max_mm", "rgb_err_median", "rgb_err_p95", "encode_cpu_ms", "encode_wall_ms",
            "node_decode_ms"]  # fmt: skip
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    rows = [{**r, "points_sent": r.get("points_sent", r.get("points_sent_mean"))} for r in rows]
    return lines + ["| " + " | ".join(str(r.get(c)) for c in cols) + " |" for r in rows]


NODE_SEQUENCE = """
const fs = require("fs"); const { createDecoder } = require(process.argv[2]); const repeats = +process.argv[3];
(async () => {
  const bufs = process.argv.slice(4).map((n) => { const b = fs.readFileSync(n); return b.buffer.slice(b.byteOffset, b.byteOffset + b.length); });
  const t = bufs.map(() => []);
  for (let r = 0; r <= repeats; r++) {
    const dec = createDecoder();
    for (let i = 0; i < bufs.length; i++) { const t0 = process.cpuUsage(); await dec.decodeFrame(bufs[i]); const u = process.cpuUsage(t0); if (r) t[i].push((u.user + u.system) / 1e3); }
  }
  console.log(JSON.stringify(t.map((x) => x.sort((a, c) => a - c)[x.length >> 1])));
})();
"""


def fused_sequences(data_dir: Path, work: Path, sim_frames: int = 10) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """name -> fused clouds of a moving sequence at 200 k points (``--preset live``): kinect3-room
    (every frame, the reference extrinsics) and the simulated dynamic 8-camera studio."""
    from fuseflow.fuse import fuse
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording, read_calibration
    from fuseflow.synth import SimConfig, simulate_recording

    simulate_recording(work / "sim8dyn", SimConfig(cameras=8, frames=sim_frames, scene="studio", dynamic=True,
                                                   resolution=(640, 480), seed=0, fps=10.0))  # fmt: skip
    k3 = open_recording(data_dir / "kinect3-room")
    rigs = {
        "kinect3-room": (
            k3,
            k3.rig.with_extrinsics(read_calibration(data_dir / "kinect3-room" / "reference_calib.json").T_cam_world),
        )
    }
    sim = open_recording(work / "sim8dyn")
    rigs["sim8-dynamic"] = (sim, sim.rig)
    out = {}
    for name, (rec, rig) in rigs.items():
        out[name] = []
        for i in range(len(rec)):
            c = fuse(rec[i], rig, preset_config("live", 200_000))
            out[name].append((c.xyz.numpy().astype(np.float32), c.rgb.numpy().astype(np.uint8)))
    return out


def _sequence_pass(clouds, delta: bool) -> tuple[list[bytes], list[float]]:
    """Every frame in order (the first a key frame; then deltas, or key frames when not ``delta``;
    the default parameters: versions 7 and 6) and the process CPU ms of each."""
    enc, frames, cpu = InterEncoder(CompactParams()), [], []
    for n, (xyz, rgb) in enumerate(clouds):
        c = time.process_time()
        key, d = enc.encode(xyz, rgb, n, key=not delta, delta=delta)
        cpu.append((time.process_time() - c) * 1e3)
        frames.append(d if d is not None else key)
    return frames, cpu


def measure_sequence(name: str, clouds: list, repeats: int, work: Path | None = None) -> list[dict]:
    """Two rows: every frame a key frame (version 7), and a key frame then deltas (version 6):
    bits a point over all frames (fused points), of the deltas alone, encode CPU (median over
    frames of the median over ``repeats`` passes), errors over every frame, decode.js in node."""
    from scipy.spatial import cKDTree

    rows = []
    for label, delta in (("key frames", False), ("a key frame, then deltas", True)):
        passes = [_sequence_pass(clouds, delta) for _ in range(max(1, repeats))]
        frames = passes[0][0]
        cpu = np.median([p[1] for p in passes], 0)
        pts = [len(x) for x, _ in clouds]
        dec, cheb_max, errs, sent, repeated, prev = CompactDecoder(), 0.0, [], [], [], None
        for (xyz, rgb), data in zip(clouds, frames):
            _, dx, dc = dec.decode(data)
            cells = np.ascontiguousarray(dx).view(np.dtype((np.void, 12))).ravel()
            if prev is not None:  # decoded points on the cell of a point of the frame before
                repeated.append(float(np.isin(cells, prev).mean()))
            prev = cells
            cheb, idx = cKDTree(dx).query(xyz, p=np.inf)
            cheb_max = max(cheb_max, float(cheb.max()))
            errs.append(np.abs(dc[idx].astype(np.int16) - rgb.astype(np.int16)).reshape(-1))
            sent.append(len(dx))
        bits = [len(f) * 8 / n for f, n in zip(frames, pts)]
        err = np.concatenate(errs)
        rows.append({"cloud": name, "codec": label, "frames": len(frames), "points_mean": round(float(np.mean(pts))),
                     "points_sent_mean": round(float(np.mean(sent))),
                     "cells_repeated_mean": round(float(np.mean(repeated)), 3) if repeated else None,
                     "bits_per_point": round(sum(len(f) for f in frames) * 8 / sum(pts), 3),
                     "bits_per_point_after_first": round(float(np.mean(bits[1:])), 3) if len(bits) > 1 else None,
                     "pos_err_axis_max_mm": round(cheb_max * 1e3, 3), "rgb_err_median": float(np.median(err)),
                     "rgb_err_p95": float(np.percentile(err, 95)),
                     "encode_cpu_ms": round(float(np.median(cpu[1:] if len(cpu) > 1 else cpu)), 1),
                     "_frames": frames})  # fmt: skip
    if work is not None and shutil.which("node"):
        (work / "seq.js").write_text(NODE_SEQUENCE)
        for r in rows:
            names = []
            for f in r["_frames"]:
                names.append(str(work / f"{name}-{len(names)}-{r['codec'][:2]}.bin"))
                Path(names[-1]).write_bytes(f)
            out = subprocess.run(["node", str(work / "seq.js"), str(DECODE_JS), str(max(1, repeats)), *names],
                                 capture_output=True, text=True, timeout=1800, check=True)  # fmt: skip
            ms = json.loads(out.stdout)
            r["node_decode_ms"] = round(float(np.median(ms[1:] if len(ms) > 1 else ms)), 1)
    return rows


def run_codec_v3_bench(data_dir: Path, repeats: int = 7, node: bool = True, log=print, sequences: bool = True,
                       sim_frames: int = 10) -> dict:  # fmt: skip
    """Every SETTINGS entry on both clouds (and decode.js in node when ``node`` and node is
    there), then key frames against deltas on the moving sequences (``measure_sequence``):
    {"meta": {load at start and end, cpus}, "rows": [...]}; the table goes to ``log``."""
    load = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="fuseflow-codec-") as tmp:
        work = Path(tmp)
        rows = []
        for name, (xyz, rgb) in fused_clouds(Path(data_dir), work).items():
            rows += measure(name, xyz, rgb, repeats)
        if node and shutil.which("node"):
            node_decode_ms(rows, repeats, work)
        if sequences:
            for name, clouds in fused_sequences(Path(data_dir), work, sim_frames).items():
                rows += measure_sequence(name, clouds, max(1, repeats // 2), work if node else None)
    load.append(os.getloadavg()[0])
    for r in rows:
        r.pop("_data", None)
        r.pop("_frames", None)
    for line in table(rows):
        log(line)
    meta = {"load_1min_start_end": [round(x, 1) for x in load], "cpus": os.cpu_count()}
    log(json.dumps(meta))
    return {"meta": meta, "rows": rows}
