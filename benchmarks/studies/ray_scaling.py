"""Throughput of `fuseflow run`: the plain loop against Ray with W local workers, and a projection.

Steps (one process, one machine): simulate a static ``cameras``-camera recording (GT extrinsics
in rig.json, so no GMAC); warm up (numba compiles, Ray workers start) on a throw-away run; time
``run(rec, out)`` end to end (load, FUSE, health check, PLY write) in a plain loop, then with Ray
at each W (a local Ray with num_cpus = W, one CPU per task); measure the per-frame transfer cost of
a fused cloud through the object store (ray.put + ray.get of its arrays) and the driver's
per-frame work (PLY write); project the throughput on W workers: W / t_task while the driver keeps
up, capped at 1 / t_driver (the driver receives and writes every frame in order).
"""

from __future__ import annotations

import platform
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["run_ray_scaling", "ray_scaling_report"]


def _timed_run(rec, out: Path, ray_opts=None) -> tuple[float, object]:
    from fuseflow.pipeline import run

    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    s = run(rec, out, use_rig_extrinsics=True, ray=ray_opts)
    return time.perf_counter() - t0, s


def _driver_costs(tmp: Path, frames: int) -> tuple[list, list[float], float]:
    """The plain run's clouds, the PLY write time of each (ms) and the median cloud size (MB)."""
    from fuseflow.io import read_ply, write_ply
    from fuseflow.pipeline import cloud_path

    clouds = [read_ply(cloud_path(tmp / "plain", t)) for t in range(frames)]
    write_ms = []
    for t, c in enumerate(clouds):
        t0 = time.perf_counter()
        write_ply(tmp / "w" / f"{t}.ply", c)
        write_ms.append((time.perf_counter() - t0) * 1000)
    return clouds, write_ms, statistics.median([len(c) * (12 + 3 + 4 + 2) / 1e6 for c in clouds])


def _ray_row(rec, tmp: Path, W: int, clouds) -> dict:
    import ray

    from fuseflow.pipeline.ray import RayOptions

    t0 = time.perf_counter()
    ray.init(address="local", num_cpus=W, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    init_s = time.perf_counter() - t0
    try:
        opts = RayOptions(max_in_flight=2 * W)
        _timed_run(rec, tmp / "rwarm", opts)  # start and warm the workers
        wall, s = _timed_run(rec, tmp / f"ray{W}", opts)
        put_ms = []
        for c in clouds[:8]:
            arrays = (c.xyz.numpy(), c.rgb.numpy(), c.weight.numpy(), c.camera.numpy())
            t1 = time.perf_counter()
            ray.get(ray.put(arrays))
            put_ms.append((time.perf_counter() - t1) * 1000)
    finally:
        ray.shutdown()
    return {"mode": "ray", "workers": W, "frames": s.frames, "wall_s": wall, "fps": s.frames / wall,
            "ray_init_s": init_s, "transfer_ms": statistics.median(put_ms)}  # fmt: skip


def run_ray_scaling(
    cameras: int, frames: int, resolution: tuple[int, int], workers: list[int], log: Callable[[str], None]
) -> dict:
    """The measurement (module doc): {machine, cameras, resolution, frames, cloud_mb_per_frame,
    write_ms_per_frame, t_task_s, t_driver_s, rows, projection}."""
    import ray

    import fuseflow
    from fuseflow.io import open_recording
    from fuseflow.synth import SimConfig, simulate_recording

    rows = []
    with tempfile.TemporaryDirectory(prefix="fuseflow-ray-bench-") as tmp:
        tmp = Path(tmp)
        sim = SimConfig(cameras=cameras, frames=frames, scene="studio", resolution=resolution, seed=7)
        simulate_recording(tmp / "rec", sim)
        rec = open_recording(tmp / "rec")
        _timed_run(open_recording(rec.path), tmp / "warm", None)  # numba compile + caches
        wall, s = _timed_run(rec, tmp / "plain")
        rows.append({"mode": "plain loop", "workers": 1, "frames": s.frames, "wall_s": wall, "fps": s.frames / wall})
        log(f"plain loop: {s.frames / wall:.2f} frames/s ({s.ms_per_frame:.0f} ms FUSE per frame)")
        clouds, write_ms, mb = _driver_costs(tmp, s.frames)
        for W in workers:
            rows.append(_ray_row(rec, tmp, W, clouds))
            log(f"ray W={W}: {rows[-1]['fps']:.2f} frames/s (init {rows[-1]['ray_init_s']:.1f} s)")
    ray_rows = [r for r in rows if r["mode"] == "ray"]
    one = next((r for r in ray_rows if r["workers"] == 1), ray_rows[0])
    t_task = one["workers"] / one["fps"]  # seconds of one worker per frame
    t_driver = (statistics.median(write_ms) + one["transfer_ms"]) / 1000.0
    projection = [
        {"workers": W, "fps": min(W / t_task, 1.0 / t_driver), "bound": "workers" if W / t_task < 1 / t_driver else "driver"}
        for W in (1, 2, 4, 8, 16, 32, 64)
    ]  # fmt: skip
    return {
        "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "fuseflow": fuseflow.__version__, "ray": ray.__version__},
        "cameras": cameras, "resolution": list(resolution), "frames": frames,
        "cloud_mb_per_frame": mb, "write_ms_per_frame": statistics.median(write_ms),
        "t_task_s": t_task, "t_driver_s": t_driver, "rows": rows, "projection": projection,
    }  # fmt: skip


def ray_scaling_report(out: dict) -> list[str]:
    """Markdown lines of ``run_ray_scaling``'s result: throughput, per-frame costs, projection."""
    rows, plain = out["rows"], out["rows"][0]
    one = next((r for r in rows if r["mode"] == "ray" and r["workers"] == 1), rows[-1])
    lines = ["", "| mode | workers | frames/s | speed-up vs plain |", "| --- | --- | --- | --- |"]
    lines += [f"| {r['mode']} | {r['workers']} | {r['fps']:.2f} | {r['fps'] / plain['fps']:.2f}x |" for r in rows]
    lines += ["", f"cloud per frame: {out['cloud_mb_per_frame']:.1f} MB; object-store put+get "
              f"{one.get('transfer_ms', float('nan')):.1f} ms; PLY write {out['write_ms_per_frame']:.1f} ms; "
              f"worker time per frame {out['t_task_s'] * 1000:.0f} ms"]  # fmt: skip
    lines += ["", "| workers W | projected frames/s | bound by |", "| --- | --- | --- |"]
    lines += [f"| {p['workers']} | {p['fps']:.1f} | {p['bound']} |" for p in out["projection"]]
    return lines
