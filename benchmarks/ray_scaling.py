"""Throughput of `fuseflow run`: the plain loop against Ray with 1 and 2 workers, and a projection.

    python -m benchmarks.ray_scaling --cameras 8 --num-frames 24 --json /tmp/ray_scaling.json

The benchmark (steps, measurement, projection) is benchmarks.studies.ray_scaling; this program
parses the command line, prints its Markdown report and writes the rows with --json.
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.ray_scaling import ray_scaling_report, run_ray_scaling


def main(argv: list[str] | None = None) -> int:
    ap = common.parser(__doc__, num_frames=24)
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--workers", default="1,2", help="Comma list of local Ray worker counts.")
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.resolution.split("x"))
    workers = [int(x) for x in args.workers.split(",") if x]
    out = run_ray_scaling(args.cameras, args.num_frames, (w, h), workers, log=lambda line: print(line, flush=True))
    for line in ray_scaling_report(out):
        print(line)
    rows = out.get("rows", [out]) if isinstance(out, dict) else out
    meta = {k: v for k, v in out.items() if k != "rows"} if isinstance(out, dict) else {}
    common.save(args, "ray_scaling", common.command("ray_scaling", argv), rows, meta)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
