"""FUSE quality against the simulator's ground-truth surface: FUSE, its Table VII ablations,
VoxelBlockGrid TSDF and naive fusion; plus FUSE's density / quality / time trade-off. A thin
wrapper around ``fuseflow.eval.bench.fuse_ablations`` (also ``fuseflow bench fuse-ablations``),
whose docstring lists the data, the metrics and the rows.

    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/fuse_quality.py --json docs/data/fuse_quality.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from fuseflow.errors import ValidationError
from fuseflow.eval.bench.fuse_ablations import run_fuse_ablations


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=2, help="frames per rig (mean over them)")
    ap.add_argument("--density-frames", type=int, default=1, help="frames of the density rows")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--cameras", type=int, default=8, help="cameras of the ring (default 8)")
    ap.add_argument("--no-density", action="store_true", help="skip the density / quality trade-off rows")
    ap.add_argument("--only", default=None, help="comma-separated method names (default: all rows)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    w, h = (int(v) for v in args.resolution.lower().split("x"))
    command = "benchmarks/fuse_quality.py " + " ".join(argv if argv is not None else sys.argv[1:])
    only = [m.strip() for m in args.only.split(",")] if args.only else None
    try:
        out = run_fuse_ablations(args.frames, args.density_frames, args.seed, (w, h), args.cameras,
                                 not args.no_density, only, command, log=lambda line: print(line, flush=True))  # fmt: skip
    except ValidationError as exc:
        ap.error(str(exc))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
