"""Throughput of `fuseflow run`: the plain loop against Ray with 1 and 2 workers, and a projection.

    .venv/bin/python benchmarks/ray_scaling.py --cameras 8 --frames 24 --json /tmp/ray_scaling.json

Steps (one process, one machine):
1. simulate a static 8-camera 640x480 recording (GT extrinsics in rig.json, so no GMAC);
2. warm up (numba compiles, Ray workers start) on a throw-away run;
3. time `run(rec, out)` end to end (load, FUSE, health check, PLY write) in a plain loop, then
   with Ray at W = 1 and 2 workers (a local Ray with num_cpus = W, one CPU per task);
4. measure the per-frame transfer cost of a fused cloud through the object store
   (ray.put + ray.get of its arrays) and the driver's per-frame work (PLY write);
5. project the throughput on W workers: W / t_task while the driver keeps up, capped at
   1 / t_driver (the driver receives and writes every frame in order).

Prints a Markdown table; --json writes the rows.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path


def _sim(path: Path, cameras: int, frames: int, res: tuple[int, int]) -> Path:
    from fuseflow.synth import SimConfig, simulate_recording

    simulate_recording(path, SimConfig(cameras=cameras, frames=frames, scene="studio", resolution=res, seed=7))
    return path


def _timed_run(rec, out: Path, ray_opts=None) -> tuple[float, object]:
    from fuseflow.pipeline import run

    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    s = run(rec, out, use_rig_extrinsics=True, ray=ray_opts)
    return time.perf_counter() - t0, s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--workers", default="1,2", help="Comma list of local Ray worker counts.")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.resolution.split("x"))

    import ray

    from fuseflow.io import open_recording, write_ply
    from fuseflow.pipeline import cloud_path
    from fuseflow.pipeline.ray import RayOptions

    rows = []
    with tempfile.TemporaryDirectory(prefix="fuseflow-ray-bench-") as tmp:
        tmp = Path(tmp)
        rec = open_recording(_sim(tmp / "rec", args.cameras, args.frames, (w, h)))
        _timed_run(open_recording(rec.path), tmp / "warm", None)  # numba compile + caches
        wall, s = _timed_run(rec, tmp / "plain")
        rows.append({"mode": "plain loop", "workers": 1, "frames": s.frames, "wall_s": wall, "fps": s.frames / wall})
        print(f"plain loop: {s.frames / wall:.2f} frames/s ({s.ms_per_frame:.0f} ms FUSE per frame)", flush=True)

        # per-frame driver work and transfer cost, measured on the plain run's clouds
        from fuseflow.io import read_ply

        clouds = [read_ply(cloud_path(tmp / "plain", t)) for t in range(s.frames)]
        write_ms = []
        for t, c in enumerate(clouds):
            t0 = time.perf_counter()
            write_ply(tmp / "w" / f"{t}.ply", c)
            write_ms.append((time.perf_counter() - t0) * 1000)
        mb = statistics.median([len(c) * (12 + 3 + 4 + 2) / 1e6 for c in clouds])

        for W in [int(x) for x in args.workers.split(",") if x]:
            t0 = time.perf_counter()
            ray.init(num_cpus=W, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
            init_s = time.perf_counter() - t0
            try:
                opts = RayOptions(max_in_flight=2 * W)
                _timed_run(rec, tmp / "rwarm", opts)  # start and warm the workers
                wall, s = _timed_run(rec, tmp / f"ray{W}", opts)
                put_ms = []
                for c in clouds[:8]:
                    arrays = (c.xyz.numpy(), c.rgb.numpy(), c.weight.numpy(), c.camera.numpy())
                    t1 = time.perf_counter()
                    ref = ray.put(arrays)
                    ray.get(ref)
                    put_ms.append((time.perf_counter() - t1) * 1000)
            finally:
                ray.shutdown()
            rows.append(
                {"mode": "ray", "workers": W, "frames": s.frames, "wall_s": wall, "fps": s.frames / wall,
                 "ray_init_s": init_s, "transfer_ms": statistics.median(put_ms)}
            )  # fmt: skip
            print(f"ray W={W}: {s.frames / wall:.2f} frames/s (init {init_s:.1f} s)", flush=True)

    plain = rows[0]
    ray_rows = [r for r in rows if r["mode"] == "ray"]
    one = next((r for r in ray_rows if r["workers"] == 1), ray_rows[0])
    t_task = one["workers"] / one["fps"]  # seconds of one worker per frame
    t_driver = (statistics.median(write_ms) + one["transfer_ms"]) / 1000.0
    projection = [
        {
            "workers": W,
            "fps": min(W / t_task, 1.0 / t_driver),
            "bound": "workers" if W / t_task < 1 / t_driver else "driver",
        }
        for W in (1, 2, 4, 8, 16, 32, 64)
    ]
    import fuseflow

    out = {
        "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version(),
                    "fuseflow": fuseflow.__version__, "ray": ray.__version__},
        "cameras": args.cameras, "resolution": [w, h], "frames": args.frames,
        "cloud_mb_per_frame": mb, "write_ms_per_frame": statistics.median(write_ms),
        "t_task_s": t_task, "t_driver_s": t_driver, "rows": rows, "projection": projection,
    }  # fmt: skip
    print()
    print("| mode | workers | frames/s | speed-up vs plain |")
    print("| --- | --- | --- | --- |")
    for r in rows:
        print(f"| {r['mode']} | {r['workers']} | {r['fps']:.2f} | {r['fps'] / plain['fps']:.2f}x |")
    print()
    print(f"cloud per frame: {mb:.1f} MB; object-store put+get {one['transfer_ms']:.1f} ms; "
          f"PLY write {statistics.median(write_ms):.1f} ms; worker time per frame {t_task * 1000:.0f} ms")  # fmt: skip
    print()
    print("| workers W | projected frames/s | bound by |")
    print("| --- | --- | --- |")
    for p in projection:
        print(f"| {p['workers']} | {p['fps']:.1f} | {p['bound']} |")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
