"""End-to-end throughput of `fuseflow run` (FUSE + health monitor + writing) against FUSE alone
(`fuse_recording`: FUSE + writing) on one recording, in one process.

    python benchmarks/investigations/run_throughput.py REC [--frames A:B] [--repeats 2]
    python benchmarks/investigations/run_throughput.py --icl ../shared/data/icl-livingroom1 [--icl-frames 20]

REC: any recording with extrinsics in rig.json (e.g. `fuseflow simulate R --cameras 4
--frames 150 --resolution 320x240 --dynamic`, or an ICL virtual rig from `fuseflow convert`).
``--icl``: the ICL 8-camera rig (ICL frames 0, 25, ..., 175 as 8 cameras with the
reference trajectory as extrinsics, every pixel valid) written as a static recording of
``--icl-frames`` identical frames (a static rig filming a static scene) in a temporary folder.

Prints frames/s of each (median over repeats, after a warm-up frame that compiles the kernels),
the ratio run / fuse-only (target >= 0.8), and the health monitor's ms per frame.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch


def _icl_recording(icl: Path, out: Path, frames: int) -> Path:
    """ICL frames 0, 25, ..., 175 as an 8-camera rig, its one frame repeated ``frames`` times."""
    import shutil

    from fuseflow.io import make_virtual_rig, open_recording

    rig = make_virtual_rig(open_recording(icl), [25 * k for k in range(8)], out)
    for cam in rig.cameras:
        for kind in ("color", "depth"):
            first = sorted((out / cam.id / kind).iterdir())[0]
            for t in range(1, frames):
                shutil.copyfile(first, first.with_name(f"{t:06d}{first.suffix}"))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("rec", type=Path, nargs="?", default=None)
    ap.add_argument("--icl", type=Path, default=None, help="ICL-NUIM folder: time the ICL 8-camera rig instead")
    ap.add_argument("--icl-frames", type=int, default=20)
    ap.add_argument("--frames", default=None, help="A:B frame positions (default all)")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)

    from fuseflow.io import open_recording
    from fuseflow.pipeline import PipelineConfig, fuse_recording, run
    from fuseflow.pipeline.health import frame_health

    if (args.rec is None) == (args.icl is None):
        ap.error("give REC or --icl")
    tmp_rec = tempfile.TemporaryDirectory(prefix="run_throughput_icl_") if args.icl else None
    if tmp_rec is not None:
        args.rec = _icl_recording(args.icl, Path(tmp_rec.name) / "icl8", args.icl_frames)
    rec = open_recording(args.rec)
    a, _, b = (args.frames or ":").partition(":")
    positions = range(len(rec))[int(a) if a else 0 : int(b) if b else len(rec)]
    n = len(positions)
    with tempfile.TemporaryDirectory() as tmp:
        fuse_recording(rec, Path(tmp) / "warm", frames=range(0, 1))  # numba compile
        fuse_fps, run_fps = [], []
        for r in range(args.repeats):
            t0 = time.perf_counter()
            fuse_recording(rec, Path(tmp) / f"f{r}", frames=positions)
            fuse_fps.append(n / (time.perf_counter() - t0))
            t0 = time.perf_counter()
            run(rec, Path(tmp) / f"r{r}", use_rig_extrinsics=True, frames=positions, config=PipelineConfig(sync="off"))
            run_fps.append(n / (time.perf_counter() - t0))
    cfg = PipelineConfig()
    health_ms = []
    for t in list(positions)[: min(n, 10)]:
        f = rec[t]
        t0 = time.perf_counter()
        frame_health(f, rec.rig, cfg.health_samples, cfg.health_tau)
        health_ms.append(1000 * (time.perf_counter() - t0))
    w, h = rec.rig.resolution
    print(f"# {args.rec}: {len(rec.rig)} cameras {w}x{h}, {n} frames; {platform.processor() or platform.machine()}, "
          f"{torch.get_num_threads()} torch threads, torch {torch.__version__}, numpy {np.__version__}")  # fmt: skip
    fo, ru = statistics.median(fuse_fps), statistics.median(run_fps)
    print(f"fuse only : {fo:.2f} frames/s  (repeats {[round(x, 2) for x in fuse_fps]})")
    print(f"run       : {ru:.2f} frames/s  (repeats {[round(x, 2) for x in run_fps]})")
    print(f"ratio run / fuse-only: {ru / fo:.2f}")
    print(f"health monitor: {statistics.median(health_ms):.1f} ms per frame (median of {len(health_ms)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
