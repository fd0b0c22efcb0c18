"""Throughput of `fuseflow run`: the plain loop against Ray with 1 and 2 workers, and a projection.

    .venv/bin/python benchmarks/ray_scaling.py --cameras 8 --frames 24 --json /tmp/ray_scaling.json

The benchmark (steps, measurement, projection) is fuseflow.eval.bench.ray_scaling; this program
parses the command line, prints its Markdown report and writes the rows with --json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fuseflow.eval.bench.ray_scaling import ray_scaling_report, run_ray_scaling


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--workers", default="1,2", help="Comma list of local Ray worker counts.")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    w, h = (int(x) for x in args.resolution.split("x"))
    workers = [int(x) for x in args.workers.split(",") if x]
    out = run_ray_scaling(args.cameras, args.frames, (w, h), workers, log=lambda line: print(line, flush=True))
    for line in ray_scaling_report(out):
        print(line)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
