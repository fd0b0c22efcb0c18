"""FUSE per-frame time and peak memory vs Open3D VoxelBlockGrid TSDF and naive + voxel_down_sample.

    fuseflow bench fuse --cameras 1,2,4,8,16 --json OUT
    python -m benchmarks.fuse_speed --save

What it does:

* Renders ``warmup + frames`` frames of a *dynamic* simulated ring of max(N) cameras at 640x480
  (fuseflow.synth, Kinect-class noise, GT extrinsics) once, into a temporary folder (one .npy per
  frame). A rig of N cameras is every (max / N)-th camera of that ring, so every N sees the same
  frames. Frames differ (a figure walks, a box bounces): VoxelBlockGrid's time depends on content.
* Each (method, N) runs in a fresh Python process (``python -m fuseflow.eval.bench.fuse_speed``),
  so that peak memory is that method's alone: the child imports fuseflow, runs ``warmup`` frames
  untimed (numba compilation, Open3D start-up), then resets the kernel's RSS high-water mark
  (``echo 5 > /proc/self/clear_refs``) and times ``frames`` frames one after the other, loading
  each from disk outside the timed region.
  ``peak_mb`` is VmHWM (peak resident set, /proc/self/status) over the timed frames: the whole
  process (interpreter, torch, Open3D, one input frame, the method's working memory), which
  tracemalloc cannot see (torch / Open3D / numba allocate outside Python's allocator).
  ``base_mb`` is the resident set just before the timed frames; peak - base is what the method
  added. On CUDA, ``gpu_peak_mb`` is torch.cuda.max_memory_allocated over the timed frames.
* ``ms`` is the median wall time of one call over the timed frames (perf_counter around the
  call; CUDA synchronised): fuseflow.fuse.fuse, baselines.tsdf_fusion (tensor VoxelBlockGrid,
  1 cm voxels, integrate every view then extract_point_cloud), baselines.voxel_downsampled_fusion
  (back-project every valid pixel, Open3D voxel_down_sample at 1 cm).

Real data sets (``data``, beside the simulated ring ``sim``), read from ``data_dir`` (the
shared data folder) and written to the work folder as .npy frames and one rig per frame:

* ``icl``: the ICL-NUIM living room as an 8-camera static rig: frame t of the benchmark is ICL
  frames t, t + 25, ..., t + 175 as 8 cameras with the reference trajectory as extrinsics
  (every pixel valid, ~2.41 M valid pixels); different t are different rigs and views, so
  VoxelBlockGrid's content-dependent time is sampled over several. N < 8 = every (8 / N)-th view.
* ``hocap``: the 8 RealSense cameras of hocap-8rs with the reference extrinsics (io/hocap.py);
  one synchronised frame, fused ``warmup + frames`` times.

N = 16 exists only for ``sim``. ``points``: FUSE with FuseConfig.target_points (density control).

Output: report lines (a table) through ``log`` and, with ``json_path``, {"meta": ..., "rows":
[one row per (method, N)]}.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fuseflow.errors import ValidationError
from fuseflow.eval.bench import BenchmarkFailed
from fuseflow.eval.results import write_result

__all__ = [
    "DATA",
    "DEFAULT_METHODS",
    "METHODS",
    "FuseSpeedResult",
    "format_row",
    "parse_options",
    "run_fuse_speed",
]

METHODS = {
    "fuse": "FUSE (default preset; numba on CPU, PyTorch on CUDA)",
    "fuse_torch": "FUSE, PyTorch reference backend (eager)",
    "fuse_fast": "FUSE, PRESETS['fast'] (k_neighbours = 4, s0 = 6.3)",
    "fuse_live": "FUSE, PRESETS['live'] (pixel_stride = 2: every 2nd pixel of every 2nd row; s0 = 1; mcm_max_missing = 4)",
    "fuse_auto": "FUSE, PRESETS['auto'] (the CLI's default: live's grid on >= 6 well-filled views, every pixel otherwise)",
    "vbg": "Open3D tensor VoxelBlockGrid TSDF, 1 cm, integrate + extract_point_cloud",
    "naive_voxel": "naive back-projection + Open3D voxel_down_sample 1 cm",
}
DEFAULT_METHODS = ("fuse", "vbg", "naive_voxel")
DATA = {
    "sim": "simulated dynamic studio ring (rendered here)",
    "icl": "ICL-NUIM living room, 8 frames 25 apart as an 8-camera rig (icl-livingroom1)",
    "hocap": "hocap-8rs: 8 RealSense cameras, reference extrinsics",
}
DATA_FOLDERS = {"icl": "icl-livingroom1", "hocap": "hocap-8rs"}


@dataclass
class FuseSpeedResult:
    """What :func:`run_fuse_speed` measured.

    Attributes:
        rows: one dict per (method, N): ms (median), ms_min, ms_max, ms_all (milliseconds per
            frame), points (median), peak_mb / base_mb (MiB, VmHWM / VmRSS of the child), device,
            frames, warmup, and gpu_peak_mb on CUDA.
        derived: ratios of medians: vbg_over_fuse_N8, fuse_t16_over_t8 (when both rows exist).
        json_path: where the JSON was written, or None.
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    derived: dict[str, float] = field(default_factory=dict)
    json_path: Path | None = None


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


# ------------------------------------------------------------------------------------ options


def parse_options(cameras: str, resolution: str) -> tuple[list[int], tuple[int, int]]:
    """'1,2,4' and 'WxH' -> ([1, 2, 4], (W, H)); ValidationError on anything else."""
    try:
        cams = [int(x) for x in cameras.split(",") if x.strip()]
        w, h = (int(v) for v in resolution.lower().split("x"))
    except ValueError:
        raise ValidationError(
            f"--cameras expects integers and --resolution WxH, got {cameras!r}, {resolution!r}"
        ) from None
    return cams, (w, h)


def _check(cams: Sequence[int], methods: Sequence[str], device: str) -> None:
    if not cams or min(cams) < 1 or max(cams) > 16:
        raise ValidationError("--cameras must be in 1..16 (one ring of cameras)")
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise ValidationError(f"unknown methods {bad}; choose from {list(METHODS)}")
    if device.startswith("cuda"):
        import torch

        if not torch.cuda.is_available():
            raise ValidationError("--device cuda: torch sees no CUDA device")


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


def _method_fn(method: str, dev: Any, points: int | None = None) -> Callable:
    """``fn(frame, rig) -> FusedCloud`` for a key of :data:`METHODS`."""
    if method in ("fuse", "fuse_torch", "fuse_fast", "fuse_live", "fuse_auto"):
        from dataclasses import replace

        from fuseflow.fuse import PRESETS, FuseConfig, fuse

        base = {
            "fuse_fast": PRESETS["fast"],
            "fuse_live": PRESETS["live"],
            "fuse_auto": PRESETS["auto"],
        }.get(method, FuseConfig())
        cfg = replace(base, backend="torch" if method == "fuse_torch" else "auto", target_points=points)
        return lambda frame, rig: fuse(frame.to(dev), rig, cfg)
    if method == "vbg":
        from fuseflow.eval.baselines import tsdf_fusion

        return lambda frame, rig: tsdf_fusion(frame, rig, voxel=0.01)
    if method == "naive_voxel":
        from fuseflow.eval.baselines import voxel_downsampled_fusion

        return lambda frame, rig: voxel_downsampled_fusion(frame, rig, voxel=0.01)
    raise ValidationError(f"unknown method {method!r}")


def _child(method: str, n: int, work: Path, warmup: int, frames: int, device: str, points: int | None = None) -> dict:
    """One (method, N) row, timed in this (fresh) process over the frames rendered in ``work``
    (one rig for all frames, or ``work/rigs/NNN/rig.json`` per frame)."""
    import gc

    import numpy as np
    import torch

    from fuseflow import Frame
    from fuseflow.io import read_rig

    per_frame = (work / "rigs").is_dir()
    rig_all = read_rig(work / "rigs" / "000" if per_frame else work)
    sel = _subset(len(rig_all), n)
    dev = torch.device(device)
    run = _method_fn(method, dev, points)

    def load(t: int) -> tuple[Frame, Any]:
        rig = (read_rig(work / "rigs" / f"{t:03d}") if per_frame else rig_all).subset(sel)
        d = np.load(work / f"depth_{t:03d}.npy")[sel]
        c = np.load(work / f"color_{t:03d}.npy")[sel]
        pres = torch.ones(len(sel), dtype=torch.bool)
        return Frame(t, rig.ids, torch.from_numpy(c), torch.from_numpy(d), pres), rig

    for t in range(warmup):
        run(*load(t))
    gc.collect()
    if dev.type == "cuda":
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    base = _status_mb("VmRSS")
    hwm_reset = _reset_hwm()
    ms, pts = [], []
    for t in range(warmup, warmup + frames):
        frame, rig = load(t)
        t0 = time.perf_counter()
        cloud = run(frame, rig)
        if dev.type == "cuda":
            torch.cuda.synchronize()
        ms.append((time.perf_counter() - t0) * 1000.0)
        pts.append(len(cloud))
        del cloud, frame
    row = {
        "data": work.name if work.name in DATA else "sim",
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
        "target_points": points,
        "valid_pixels": int(np.count_nonzero(np.load(work / f"depth_{warmup:03d}.npy")[sel] > 0)),
    }
    if dev.type == "cuda":
        row["gpu_peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return row


def _time_in_child(method: str, n: int, work: Path, warmup: int, frames: int, device: str,
                   points: int | None = None) -> dict:  # fmt: skip
    """Run :func:`_child` in a fresh interpreter that imports this same fuseflow; its row."""
    import fuseflow

    row_file = work / f"row_{method}_{n}.json"
    row_file.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", __name__, method, str(n), str(work), str(warmup), str(frames), device, str(row_file),
           str(points or 0)]  # fmt: skip
    src = str(Path(fuseflow.__file__).resolve().parents[1])  # the child imports this fuseflow
    path = os.pathsep.join([src] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))
    env = {**os.environ, "PYTHONWARNINGS": "ignore", "PYTHONPATH": path}
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if proc.returncode != 0 or not row_file.exists():
        raise BenchmarkFailed(f"{method} N={n} failed:\n{proc.stderr[-3000:]}")
    row = json.loads(row_file.read_text())
    row_file.unlink()
    return row


# ------------------------------------------------------------------------------------ run


def format_row(row: dict[str, Any]) -> str:
    """One row as the report line the program prints."""
    return (
        f"{row.get('data', 'sim'):5s} {row['method']:12s} N={row['cameras']:2d}  {row['ms']:8.1f} ms  (min {row['ms_min']:.1f}, max {row['ms_max']:.1f})  "
        f"peak {row['peak_mb']:6.0f} MB (base {row['base_mb']:.0f})  {row['points']:8d} points"
    )


def _derived(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Ratios of medians; keys of the real data sets start with their name (``icl_...``)."""
    derived = {}
    for data in dict.fromkeys(r.get("data", "sim") for r in rows):
        by = {(r["method"], r["cameras"]): r for r in rows if r.get("data", "sim") == data}
        pre = "" if data == "sim" else f"{data}_"
        if ("fuse", 8) in by and ("vbg", 8) in by:
            derived[pre + "vbg_over_fuse_N8"] = by[("vbg", 8)]["ms"] / by[("fuse", 8)]["ms"]
        if ("fuse_auto", 8) in by and ("vbg", 8) in by:
            derived[pre + "vbg_over_fuse_auto_N8"] = by[("vbg", 8)]["ms"] / by[("fuse_auto", 8)]["ms"]
        if ("fuse", 8) in by and ("fuse", 16) in by:
            derived[pre + "fuse_t16_over_t8"] = by[("fuse", 16)]["ms"] / by[("fuse", 8)]["ms"]
    return derived


def _meta(methods: Sequence[str], resolution: tuple[int, int], n_total: int, frames: int,
          warmup: int, seed: int, derived: dict[str, float]) -> dict[str, Any]:  # fmt: skip
    import torch

    return {
        "methods": {m: METHODS[m] for m in methods},
        "resolution": list(resolution),
        "ring_cameras": n_total,
        "frames": frames,
        "warmup": warmup,
        "seed": seed,
        "scene": "sim: studio, dynamic, Kinect-class noise, GT extrinsics; icl: ICL-NUIM living room frames "
        "t + 25 k (k < 8) as 8 cameras, reference trajectory; hocap: hocap-8rs, reference extrinsics",
        "load_average": os.getloadavg(),
        "memory": "peak_mb = VmHWM of a fresh process per row over the timed frames (reset with "
        "/proc/self/clear_refs after warm-up); base_mb = VmRSS before the timed frames",
        "torch_threads": torch.get_num_threads(),
        "derived": derived,
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }


def _write_real(work: Path, data: str, data_dir: Path, total: int) -> None:
    """``total`` frames of a real data set as .npy files plus one rig per frame (module docstring)."""
    import numpy as np

    from fuseflow.io import make_virtual_rig, open_recording, write_rig
    from fuseflow.io.hocap import convert_hocap

    src = Path(data_dir) / DATA_FOLDERS[data]
    if not src.is_dir():
        raise ValidationError(f"--data {data}: {src} not found (pass the shared data folder with --data-dir)")
    with tempfile.TemporaryDirectory(prefix=f"fuse_speed_{data}_") as tmp:
        if data == "icl":
            seq = open_recording(src)
            if total + 175 > len(seq):
                raise ValidationError(f"--data icl: at most {len(seq) - 175} warm-up + timed frames")
        else:
            convert_hocap(src, Path(tmp) / "rec", with_extrinsics=True)
            frame0 = open_recording(Path(tmp) / "rec")[0]
        for t in range(total):
            if data == "icl":
                rig = make_virtual_rig(seq, [t + 25 * k for k in range(8)], Path(tmp) / f"rig{t}")
                frame = open_recording(Path(tmp) / f"rig{t}")[0]
            else:
                frame, rig = frame0, open_recording(Path(tmp) / "rec").rig
            write_rig(work / "rigs" / f"{t:03d}", rig)
            np.save(work / f"depth_{t:03d}.npy", frame.depth.numpy())
            np.save(work / f"color_{t:03d}.npy", frame.color.numpy())
    write_rig(work, rig)


def _ensure_frames(work: Path, n_total: int, total: int, resolution: tuple[int, int], seed: int, log) -> None:
    if not (work / "rig.json").exists() or not (work / f"depth_{total - 1:03d}.npy").exists():
        t0 = time.perf_counter()
        log(f"rendering {total} frames of a {n_total}-camera dynamic ring at {resolution[0]}x{resolution[1]} ...")
        _render(work, n_total, total, resolution, seed)
        log(f"  {time.perf_counter() - t0:.0f} s")


def run_fuse_speed(
    cameras: Sequence[int] = (1, 2, 4, 8, 16),
    frames: int = 7,
    warmup: int = 2,
    device: str = "cpu",
    methods: Sequence[str] = DEFAULT_METHODS,
    resolution: tuple[int, int] = (640, 480),
    seed: int = 5,
    work: Path | None = None,
    json_path: Path | None = None,
    command: str = "",
    log: Callable[[str], None] | None = None,
    data: Sequence[str] = ("sim",),
    data_dir: Path | None = None,
    points: int | None = None,
) -> FuseSpeedResult:
    """Time every (method, N) in a fresh process each (module docstring) and report as it goes.

    Args:
        cameras: the N to time, each in 1..16 (subsets of one ring of max(cameras)).
        frames: timed frames per (method, N); ``ms`` is the median over them.
        warmup: untimed frames first (compilation, caches).
        device: cpu or cuda (FUSE only; the baselines run on CPU).
        methods: keys of :data:`METHODS`.
        resolution: (W, H) pixels of the simulated cameras.
        seed: simulator seed.
        work: folder for the rendered frames (reused when complete); None = a temporary folder.
        json_path: also write {"meta", "rows"} here (meta names ``command``, the machine, versions).
        log: called with each report line (progress, one line per row, derived ratios).
        data: keys of :data:`DATA` (``sim`` = the rendered ring; ``icl`` / ``hocap`` = real
            8-camera rigs from ``data_dir``, N <= 8 only).
        data_dir: the shared data folder holding icl-livingroom1 / hocap-8rs.
        points: time FUSE with FuseConfig.target_points = this (None = the default density).
    Raises:
        ValidationError: bad options (messages name the program's option).
        BenchmarkFailed: a timed child process failed (its stderr tail is in the message).
    """
    log = log or (lambda s: None)
    cams, methods, data = list(cameras), list(methods), list(data)
    _check(cams, methods, device)
    bad = [d for d in data if d not in DATA]
    if bad:
        raise ValidationError(f"unknown data sets {bad}; choose from {list(DATA)}")
    if any(d != "sim" for d in data) and data_dir is None:
        raise ValidationError("--data icl / hocap need the shared data folder (--data-dir)")
    n_total = max(cams)
    tmp = tempfile.TemporaryDirectory(prefix="fuse_speed_") if work is None else None
    work = Path(tmp.name) if tmp is not None else Path(work)
    try:
        work.mkdir(parents=True, exist_ok=True)
        result = FuseSpeedResult()
        for d in data:
            dwork = work if d == "sim" else work / d
            if d == "sim":
                _ensure_frames(work, n_total, warmup + frames, resolution, seed, log)
            elif not (dwork / f"depth_{warmup + frames - 1:03d}.npy").exists():
                dwork.mkdir(parents=True, exist_ok=True)
                _write_real(dwork, d, Path(data_dir), warmup + frames)
            for n in cams if d == "sim" else [c for c in cams if c <= 8]:
                for m in methods:
                    dev = device if m in ("fuse", "fuse_torch") else "cpu"
                    row = _time_in_child(m, n, dwork, warmup, frames, dev, points if m != "vbg" else None)
                    result.rows.append(row)
                    log(format_row(row))
        result.derived = _derived(result.rows)
        for k, v in result.derived.items():
            log(f"{k}: {v:.2f}")
        if json_path is not None:
            meta = _meta(methods, resolution, n_total, frames, warmup, seed, result.derived)
            result.json_path = write_result(json_path, "fuse_speed", command, result.rows, meta)
            log(f"wrote {json_path}")
        return result
    finally:
        if tmp is not None:
            tmp.cleanup()


def _child_main(argv: list[str]) -> None:
    """``python -m fuseflow.eval.bench.fuse_speed METHOD N WORK WARMUP FRAMES DEVICE ROW_JSON [POINTS]``."""
    ap = argparse.ArgumentParser(description="one timed (method, N) row of fuseflow's fuse_speed benchmark")
    for name in ("method", "n", "work", "warmup", "frames", "device", "row_json"):
        ap.add_argument(name)
    ap.add_argument("points", nargs="?", default="0")
    a = ap.parse_args(argv)
    pts = int(a.points) or None
    row = _child(a.method, int(a.n), Path(a.work), int(a.warmup), int(a.frames), a.device, pts)
    Path(a.row_json).write_text(json.dumps(row))


if __name__ == "__main__":
    _child_main(sys.argv[1:])
