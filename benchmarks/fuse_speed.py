"""FUSE per-frame time and peak memory vs Open3D VoxelBlockGrid TSDF and naive + voxel_down_sample.

    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/fuse_speed.py --json docs/data/fuse_speed.json
    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/fuse_speed.py --data sim,icl,hocap --cameras 8,16 \
        --methods fuse,vbg --json benchmarks/results/fuse_speed_real.json   (the real rigs beside the ring)
    fuseflow bench fuse --cameras 1,2,4,8,16 --json OUT          (the same program)

The benchmark itself (method, memory measurement, output) is fuseflow.eval.bench.fuse_speed; this
program parses the command line and prints its report.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fuseflow.errors import FuseFlowError
from fuseflow.eval.bench import BenchmarkFailed
from fuseflow.eval.bench.fuse_speed import DEFAULT_METHODS, METHODS, parse_options, run_fuse_speed


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
    ap.add_argument("--data", default="sim", help="comma list of sim, icl, hocap (real 8-camera rigs, N <= 8)")
    ap.add_argument("--data-dir", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "data",
                    help="shared data folder with icl-livingroom1 and hocap-8rs (default ../shared/data)")  # fmt: skip
    ap.add_argument("--points", type=int, default=None, help="FUSE with FuseConfig.target_points = N")
    ap.add_argument("--work", type=Path, default=None, help="folder for the rendered frames (default: a temp dir)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse(argv)
    methods = ["fuse"] if args.no_baselines else [m.strip() for m in args.methods.split(",") if m.strip()]
    try:
        cams, resolution = parse_options(args.cameras, args.resolution)
        run_fuse_speed(
            cams, args.frames, args.warmup, args.device, methods, resolution, args.seed, args.work, args.json,
            command="benchmarks/fuse_speed.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            log=lambda line: print(line, flush=True),
            data=[d.strip() for d in args.data.split(",") if d.strip()], data_dir=args.data_dir, points=args.points,
        )  # fmt: skip
    except BenchmarkFailed as exc:
        print(f"error: {exc}")
        return 1
    except FuseFlowError as exc:
        print(f"error: {exc}")
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
