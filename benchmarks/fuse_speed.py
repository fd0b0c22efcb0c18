"""FUSE per-frame time and peak memory vs Open3D VoxelBlockGrid TSDF and naive + voxel_down_sample.

    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/fuse_speed.py --json docs/data/fuse_speed.json
    fuseflow bench fuse --cameras 1,2,4,8,16 --json OUT          (the same program)

What it does (issue 5):

* Renders ``warmup + frames`` frames of a *dynamic* simulated ring of max(N) cameras at 640x480
  (fuseflow.synth, Kinect-class noise, GT extrinsics) once, into a temporary folder (one .npy per
  frame). A rig of N cameras is every (max / N)-th camera of that ring, so every N sees the same
  frames. Frames differ (a figure walks, a box bounces): VoxelBlockGrid's time depends on content.
* Each (method, N) runs in a fresh Python process, so that peak memory is that method's alone:
  the child imports fuseflow, runs ``warmup`` frames untimed (numba compilation, Open3D start-up),
  then resets the kernel's RSS high-water mark (``echo 5 > /proc/self/clear_refs``) and times
  ``frames`` frames one after the other, loading each from disk outside the timed region.
  ``peak_mb`` is VmHWM (peak resident set, /proc/self/status) over the timed frames: the whole
  process (interpreter, torch, Open3D, one input frame, the method's working memory), which
  tracemalloc cannot see (torch / Open3D / numba allocate outside Python's allocator).
  ``base_mb`` is the resident set just before the timed frames; peak - base is what the method
  added. On CUDA, ``gpu_peak_mb`` is torch.cuda.max_memory_allocated over the timed frames.
* ``ms`` is the median wall time of one call over the timed frames (perf_counter around the
  call; CUDA synchronised): fuseflow.fuse.fuse, baselines.tsdf_fusion (tensor VoxelBlockGrid,
  1 cm voxels, integrate every view then extract_point_cloud), baselines.voxel_downsampled_fusion
  (back-project every valid pixel, Open3D voxel_down_sample at 1 cm).

Output: a table on stdout and, with --json, {"meta": ..., "rows": [one row per (method, N)]}.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

METHODS = {
    "fuse": "FUSE (default preset; numba on CPU, PyTorch on CUDA)",
    "fuse_torch": "FUSE, PyTorch reference backend (eager)",
    "vbg": "Open3D tensor VoxelBlockGrid TSDF, 1 cm, integrate + extract_point_cloud",
    "naive_voxel": "naive back-projection + Open3D voxel_down_sample 1 cm",
}
DEFAULT_METHODS = ("fuse", "vbg", "naive_voxel")


def _status_mb(field: str) -> float:
    m = re.search(rf"{field}:\s+(\d+) kB", Path("/proc/self/status").read_text())
    return int(m.group(1)) / 1024.0 if m else float("nan")


def _reset_hwm() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _subset(n_total: int, n: int) -> list[int]:
    """n camera indices spread evenly round a ring of n_total (every n_total / n-th camera)."""
    step = n_total / n
    return sorted({int(round(k * step)) % n_total for k in range(n)})


# ------------------------------------------------------------------------------------ render


def _render(work: Path, cameras: int, frames: int, resolution: tuple[int, int], seed: int) -> None:
    import numpy as np

    from fuseflow.io import write_rig
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(
        SimConfig(cameras=cameras, frames=frames, resolution=resolution, dynamic=True, seed=seed, rig="ring")
    )
    write_rig(work, sim.rig)
    for t in range(frames):
        f = sim.render(t).frame
        np.save(work / f"depth_{t:03d}.npy", f.depth.numpy())
        np.save(work / f"color_{t:03d}.npy", f.color.numpy())


# ------------------------------------------------------------------------------------ child


def _child(method: str, n: int, work: Path, warmup: int, frames: int, device: str) -> dict:
    import gc

    import numpy as np
    import torch

    from fuseflow import Frame
    from fuseflow.io import read_rig

    rig_all = read_rig(work)
    sel = _subset(len(rig_all), n)
    rig = rig_all.subset(sel)
    dev = torch.device(device)

    if method in ("fuse", "fuse_torch"):
        from fuseflow.fuse import FuseConfig, fuse

        cfg = FuseConfig(backend="torch") if method == "fuse_torch" else FuseConfig()

        def run(frame):
            return fuse(frame.to(dev), rig, cfg)
    elif method == "vbg":
        from fuseflow.baselines import tsdf_fusion

        def run(frame):
            return tsdf_fusion(frame, rig, voxel=0.01)
    elif method == "naive_voxel":
        from fuseflow.baselines import voxel_downsampled_fusion

        def run(frame):
            return voxel_downsampled_fusion(frame, rig, voxel=0.01)
    else:
        raise SystemExit(f"unknown method {method!r}")

    def load(t: int) -> Frame:
        d = np.load(work / f"depth_{t:03d}.npy")[sel]
        c = np.load(work / f"color_{t:03d}.npy")[sel]
        return Frame(t, rig.ids, torch.from_numpy(c), torch.from_numpy(d), torch.ones(len(sel), dtype=torch.bool))

    for t in range(warmup):
        run(load(t))
    gc.collect()
    if dev.type == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    base = _status_mb("VmRSS")
    hwm_reset = _reset_hwm()
    ms, pts = [], []
    for t in range(warmup, warmup + frames):
        frame = load(t)
        t0 = time.perf_counter()
        cloud = run(frame)
        if dev.type == "cuda":
            torch.cuda.synchronize()
        ms.append((time.perf_counter() - t0) * 1000.0)
        pts.append(len(cloud))
        del cloud, frame
    row = {
        "method": method,
        "cameras": n,
        "ms": statistics.median(ms),
        "ms_min": min(ms),
        "ms_max": max(ms),
        "ms_all": [round(x, 2) for x in ms],
        "points": int(statistics.median(pts)),
        "peak_mb": _status_mb("VmHWM"),
        "base_mb": base,
        "peak_is_whole_run": not hwm_reset,
        "device": device,
        "frames": frames,
        "warmup": warmup,
    }
    if dev.type == "cuda":
        row["gpu_peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return row


# ------------------------------------------------------------------------------------ main


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cameras", default="1,2,4,8,16", help="comma list of N (default 1,2,4,8,16)")
    ap.add_argument("--frames", type=int, default=7, help="timed frames per (method, N); median over them")
    ap.add_argument("--warmup", type=int, default=2, help="untimed frames first (compilation, caches)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda (FUSE only; baselines run on CPU)")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS), help=f"comma list of {list(METHODS)}")
    ap.add_argument("--no-baselines", action="store_true", help="time FUSE only")
    ap.add_argument("--resolution", default="640x480", help="WxH (default 640x480)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--json", type=Path, default=None, help="write {meta, rows} here")
    ap.add_argument("--work", type=Path, default=None, help="folder for the rendered frames (default: a temp dir)")
    ap.add_argument("--child", nargs=2, metavar=("METHOD", "N"), help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse(argv)
    if args.child:
        row = _child(args.child[0], int(args.child[1]), args.work, args.warmup, args.frames, args.device)
        print("ROW " + json.dumps(row), flush=True)
        return 0
    try:
        cams = [int(x) for x in args.cameras.split(",") if x.strip()]
        w, h = (int(v) for v in args.resolution.lower().split("x"))
    except ValueError:
        print(f"error: --cameras expects integers and --resolution WxH, got {args.cameras!r}, {args.resolution!r}")
        return 2
    if not cams or min(cams) < 1 or max(cams) > 16:
        print("error: --cameras must be in 1..16 (one ring of cameras)")
        return 2
    methods = ["fuse"] if args.no_baselines else [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        print(f"error: unknown methods {bad}; choose from {list(METHODS)}")
        return 2
    if args.device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            print("error: --device cuda: torch sees no CUDA device")
            return 2
    n_total = max(cams)
    tmp = None
    if args.work is None:
        tmp = tempfile.TemporaryDirectory(prefix="fuse_speed_")
        work = Path(tmp.name)
    else:
        work = args.work
        work.mkdir(parents=True, exist_ok=True)
    total = args.warmup + args.frames
    if not (work / "rig.json").exists() or not (work / f"depth_{total - 1:03d}.npy").exists():
        t0 = time.perf_counter()
        print(f"rendering {total} frames of a {n_total}-camera dynamic ring at {w}x{h} ...", flush=True)
        _render(work, n_total, total, (w, h), args.seed)
        print(f"  {time.perf_counter() - t0:.0f} s", flush=True)
    rows = []
    for n in cams:
        for m in methods:
            dev = args.device if m in ("fuse", "fuse_torch") else "cpu"
            cmd = [sys.executable, str(Path(__file__).resolve()), "--child", m, str(n), "--work", str(work)]
            cmd += ["--warmup", str(args.warmup), "--frames", str(args.frames), "--device", dev]
            proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "PYTHONWARNINGS": "ignore"})
            line = [x for x in proc.stdout.splitlines() if x.startswith("ROW ")]
            if proc.returncode != 0 or not line:
                print(f"error: {m} N={n} failed:\n{proc.stderr[-3000:]}")
                return 1
            row = json.loads(line[-1][4:])
            rows.append(row)
            print(
                f"{m:12s} N={n:2d}  {row['ms']:8.1f} ms  (min {row['ms_min']:.1f}, max {row['ms_max']:.1f})  "
                f"peak {row['peak_mb']:6.0f} MB (base {row['base_mb']:.0f})  {row['points']:8d} points",
                flush=True,
            )
    by = {(r["method"], r["cameras"]): r for r in rows}
    derived = {}
    if ("fuse", 8) in by and ("vbg", 8) in by:
        derived["vbg_over_fuse_N8"] = by[("vbg", 8)]["ms"] / by[("fuse", 8)]["ms"]
    if ("fuse", 8) in by and ("fuse", 16) in by:
        derived["fuse_t16_over_t8"] = by[("fuse", 16)]["ms"] / by[("fuse", 8)]["ms"]
    for k, v in derived.items():
        print(f"{k}: {v:.2f}")
    if args.json is not None:
        import numba
        import open3d
        import torch

        meta = {
            "command": "benchmarks/fuse_speed.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "methods": {m: METHODS[m] for m in methods},
            "resolution": [w, h],
            "ring_cameras": n_total,
            "frames": args.frames,
            "warmup": args.warmup,
            "seed": args.seed,
            "scene": "studio, dynamic, Kinect-class noise, GT extrinsics",
            "memory": "peak_mb = VmHWM of a fresh process per row over the timed frames (reset with "
            "/proc/self/clear_refs after warm-up); base_mb = VmRSS before the timed frames",
            "machine": {
                "cpus": os.cpu_count(),
                "platform": platform.platform(),
                "python": platform.python_version(),
                "torch": torch.__version__,
                "torch_threads": torch.get_num_threads(),
                "numba": numba.__version__,
                "open3d": open3d.__version__,
            },
            "derived": derived,
            "date": time.strftime("%Y-%m-%d %H:%M"),
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
        print(f"wrote {args.json}")
    if tmp is not None:
        tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
