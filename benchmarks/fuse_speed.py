"""FUSE per-frame time and peak memory vs Open3D VoxelBlockGrid TSDF and naive + voxel_down_sample
(fuseflow.eval.bench.fuse_speed, also ``fuseflow bench fuse``; its docstring says what is timed).

    python -m benchmarks.fuse_speed --cameras 1,2,4,8,16 --save
    python -m benchmarks.fuse_speed --data sim,icl,hocap --cameras 8,16 --methods fuse,vbg --save
"""

from __future__ import annotations

import sys
from pathlib import Path

from benchmarks import common
from fuseflow.errors import FuseFlowError
from fuseflow.eval.bench import BenchmarkFailed
from fuseflow.eval.bench.fuse_speed import DEFAULT_METHODS, METHODS, parse_options, run_fuse_speed


def _parse(argv: list[str] | None):
    ap = common.parser(__doc__.split("\n\n")[0], num_frames=7, data=True)
    ap.add_argument("--cameras", default="1,2,4,8,16", help="comma list of N (default 1,2,4,8,16)")
    ap.add_argument("--warmup", type=int, default=2, help="untimed frames first (compilation, caches)")
    ap.add_argument("--device", default="cpu", help="cpu or cuda (FUSE only; baselines run on CPU)")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS), help=f"comma list of {list(METHODS)}")
    ap.add_argument("--no-baselines", action="store_true", help="time FUSE only")
    ap.add_argument("--resolution", default="640x480", help="WxH (default 640x480)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--data", default="sim", help="comma list of sim, icl, hocap (real 8-camera rigs, N <= 8)")
    ap.add_argument("--points", type=int, default=None, help="FUSE with FuseConfig.target_points = N")
    ap.add_argument("--work", type=Path, default=None, help="folder for the rendered frames (default: a temp dir)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse(argv)
    methods = ["fuse"] if args.no_baselines else common.names(args.methods)
    json_path = args.json or (common.results_path("fuse_speed") if args.save else None)
    try:
        cams, resolution = parse_options(args.cameras, args.resolution)
        run_fuse_speed(
            cams, args.num_frames, args.warmup, args.device, methods, resolution, args.seed, args.work, json_path,
            command=common.command("fuse_speed", argv), log=common.log, data=common.names(args.data),
            data_dir=common.data_dir(args.data_dir), points=args.points,
        )  # fmt: skip
    except BenchmarkFailed as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except FuseFlowError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
