"""FUSE quality against the simulator's ground-truth surface: FUSE, its Table VII ablations,
VoxelBlockGrid TSDF and naive fusion; plus FUSE's density / quality / time trade-off
(benchmarks.studies.fuse_ablations, whose docstring lists the data, the metrics and the rows).

    python -m benchmarks.fuse_ablations --num-frames 2 --save
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.fuse_ablations import run_fuse_ablations
from fuseflow.errors import ValidationError


def main(argv: list[str] | None = None) -> int:
    ap = common.parser(__doc__.split("\n\n")[0], num_frames=2)
    ap.add_argument("--density-frames", type=int, default=1, help="frames of the density rows")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--cameras", type=int, default=8, help="cameras of the ring (default 8)")
    ap.add_argument("--no-density", action="store_true", help="skip the density / quality trade-off rows")
    ap.add_argument("--only", default=None, help="comma-separated method names (default: all rows)")
    args = ap.parse_args(argv)
    try:
        w, h = (int(v) for v in args.resolution.lower().split("x"))
    except ValueError:
        ap.error(f"--resolution: expected WxH, got {args.resolution!r}")
    command = common.command("fuse_ablations", argv)
    only = common.names(args.only) if args.only else None
    try:
        out = run_fuse_ablations(args.num_frames, args.density_frames, args.seed, (w, h), args.cameras,
                                 not args.no_density, only, command, log=common.log)  # fmt: skip
    except ValidationError as exc:
        ap.error(str(exc))
    meta = {**out["meta"], "density": out["density"]}
    common.save(args, "fuse_ablations", command, out["rows"], meta)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
