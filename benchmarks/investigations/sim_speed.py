"""Speed of the simulator: `fuseflow simulate` of 8 cameras x 30 frames at 640x480.

Runs the CLI in a fresh process (imports, texture synthesis, numba's cached kernels and PNG/PLY
writing included) into a temporary directory, ``--repeat`` times, and reports the wall time of
each run, plus an in-process breakdown of one frame. Run it alone on the machine:

    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/investigations/sim_speed.py
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numba
import numpy as np
import open3d as o3d


def cli_run(args: list[str], out: Path) -> float:
    exe = Path(sys.executable).with_name("fuseflow")
    cmd = [str(exe), "simulate", str(out), *args]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def breakdown(cameras: int, width: int, height: int, scene: str, dynamic: bool) -> dict[str, float]:
    """Seconds per step of one frame rendered in-process (after a warm-up frame)."""
    from fuseflow.synth import SimConfig, Simulator
    from fuseflow.synth import simulator as S
    from fuseflow.synth.noise import apply_depth_noise

    sim = Simulator(SimConfig(cameras=cameras, frames=3, resolution=(width, height), scene=scene, dynamic=dynamic))
    sim.render(0)
    out = {}
    t0 = time.perf_counter()
    rs, _, tri_uv, tex, tint, pid = sim._geometry(1 / sim.cfg.fps)
    out["scene geometry (BVH)"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    hit = rs.cast_rays(o3d.core.Tensor(sim._rays))
    out["ray casting (Open3D/Embree)"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    cn = np.random.default_rng(0).standard_normal(tuple(hit["t_hit"].shape) + (3,), dtype=np.float32)
    d, th, _, _ = S._shade(hit["t_hit"].numpy(), hit["primitive_ids"].numpy(), hit["primitive_uvs"].numpy(),
                           hit["primitive_normals"].numpy(), sim._rays, tri_uv, tex, tint, pid, sim.textures,
                           S._LIGHTS, S._LIGHT_W, 0.35, cn, 2.0)  # fmt: skip
    out["texture + shading + colour noise"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    apply_depth_noise(sim.cfg, d, th, np.random.default_rng(0))
    out["depth noise"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sim.render(2)
    out["whole render(t)"] = time.perf_counter() - t0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--scene", default="studio")
    ap.add_argument("--dynamic", action="store_true")
    ap.add_argument("--repeat", type=int, default=3, help="timed CLI runs after one warm-up run")
    a = ap.parse_args()
    w, h = (int(x) for x in a.resolution.split("x"))
    args = ["--cameras", str(a.cameras), "--frames", str(a.frames), "--resolution", a.resolution,
            "--scene", a.scene, "--seed", "1"] + (["--dynamic"] if a.dynamic else [])  # fmt: skip
    tmp = Path(tempfile.mkdtemp(prefix="ff-simspeed-"))
    try:
        times = []
        for k in range(a.repeat + 1):
            out = tmp / f"r{k}"
            times.append(cli_run(args, out))
            size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
            shutil.rmtree(out)
            what = "warm-up (fills numba's on-disk cache if empty)" if k == 0 else "timed"
            print(f"run {k}: {times[-1]:.1f} s wall, {size / 1e6:.0f} MB written  [{what}]", flush=True)
        t = np.array(times[1:])
        print(f"\nfuseflow simulate OUT {' '.join(args)}")
        print(f"  {a.cameras} cameras x {a.frames} frames at {a.resolution}: median {np.median(t):.1f} s wall "
              f"(min {t.min():.1f}, max {t.max():.1f}, {len(t)} runs; {np.median(t) / a.frames:.2f} s per frame "
              f"incl. start-up)")  # fmt: skip
        print(f"  machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; python "
              f"{platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}, open3d {o3d.__version__}, "
              f"opencv {cv2.__version__}")  # fmt: skip
        print("one frame in-process:")
        for k, v in breakdown(a.cameras, w, h, a.scene, a.dynamic).items():
            print(f"  {k:34s} {v * 1000:7.0f} ms")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
