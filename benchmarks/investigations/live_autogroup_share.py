"""FUSE's speed in a process with and without a local Ray cluster up (``fuseflow bench live --nodes``).

FUSE (``--preset live``, CPU) of the simulated 8-camera 640x480 dynamic studio of
``fuseflow bench live --nodes`` (10 frames, seed 0), 15 frames per measurement, in one process,
under three conditions taken in turn ``--reps`` times:

* ``none``: no Ray process on the machine;
* ``cluster_same_session``: a local cluster (``ray.cluster_utils.Cluster``: a head and 3 nodes,
  one CPU each, as the benchmark starts it) in a child process of the same session, i.e. the
  same Linux autogroup as this process;
* ``cluster_new_session``: the same cluster started in a new session (its own autogroup).

This process never connects to the cluster. Per condition it prints the wall time per frame and,
per FUSE thread (the caller and numba's OpenMP worker), the CPU time it ran, the time it was
runnable but waited for a CPU (``/proc/self/task/*/schedstat``) and the rest (sleeping), with the
machine's idle share and the 1-minute load. Run from the project root:

    PYTHONPATH=src python benchmarks/investigations/live_autogroup_share.py --reps 3
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fuseflow.fuse import fuse_with_report
from fuseflow.fuse.presets import preset_config
from fuseflow.io import open_recording
from fuseflow.synth import SimConfig, simulate_recording

CHILD = """
import sys
from ray.cluster_utils import Cluster
cl = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
for k in range(3):
    cl.add_node(num_cpus=1, resources={f"cap{k}": 1})
print("up", flush=True)
sys.stdin.read()
cl.shutdown()
"""


def schedstat() -> dict[str, tuple[int, int]]:
    out = {}
    for t in os.listdir("/proc/self/task"):
        try:
            run, wait, _ = map(int, Path(f"/proc/self/task/{t}/schedstat").read_text().split())
        except (OSError, ValueError):
            continue
        out[t] = (run, wait)
    return out


def cpu_times() -> np.ndarray:
    return np.array([int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]])


def measure(tag: str, frames: list, rig, cfg, n: int = 15) -> None:
    s0, c0, t0 = schedstat(), cpu_times(), time.perf_counter()
    for i in range(n):
        fuse_with_report(frames[i % len(frames)], rig, cfg)
    wall = (time.perf_counter() - t0) / n * 1e3
    s1, d = schedstat(), cpu_times() - c0
    threads = []
    for t in s1:
        if t in s0:
            run, wait = ((s1[t][k] - s0[t][k]) / n / 1e6 for k in (0, 1))
            if run > 1.0:
                who = "caller" if t == str(os.getpid()) else "worker"
                threads.append(f"{who} ran {run:.0f} waited {wait:.0f} slept {max(wall - run - wait, 0):.0f}")
    print(f"{tag:<28} {wall:5.0f} ms a frame | {'; '.join(threads)} (ms a frame) | idle {d[3] / d.sum():.0%}, "
          f"load {os.getloadavg()[0]:.1f}", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="autogroup_") as tmp:
        path = Path(tmp) / "sim8"
        simulate_recording(path, SimConfig(cameras=8, frames=10, scene="studio", dynamic=True, resolution=(640, 480),
                                           seed=0, fps=15.0))  # fmt: skip
        rec = open_recording(path)
        frames = [rec[i] for i in range(len(rec))]
        cfg = preset_config("live")
        fuse_with_report(frames[0], rec.rig, cfg)  # compiled kernels loaded
        print(f"this process: {Path('/proc/self/autogroup').read_text().split()[0]}")
        for rep in range(args.reps):
            for cond in ("none", "cluster_same_session", "cluster_new_session"):
                child = None
                if cond != "none":
                    child = subprocess.Popen([sys.executable, "-c", CHILD], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                             stderr=subprocess.DEVNULL, text=True,
                                             start_new_session=cond == "cluster_new_session")  # fmt: skip
                    if child.stdout.readline().strip() != "up":
                        raise SystemExit("the Ray cluster did not start")
                    time.sleep(2.0)
                    cond += f" ({Path(f'/proc/{child.pid}/autogroup').read_text().split()[0]})"
                measure(f"{rep} {cond}", frames, rec.rig, cfg)
                if child is not None:
                    child.stdin.close()
                    child.wait(timeout=120)


if __name__ == "__main__":
    main()
