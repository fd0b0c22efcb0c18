#!/usr/bin/env python
"""What the depth-aware joint refinement adds to the metric rgbd backbone: a thin wrapper around
``fuseflow.eval.bench.calib_refine`` (its docstring, shown by ``--help``, says what it measures
and how to run it); appends its rows to --out and prints them, or (--summary) the table of --out.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fuseflow.eval.bench import calib_refine

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> None:
    ap = argparse.ArgumentParser(description=calib_refine.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="*", help="'hocap' or recording folders with true extrinsics in rig.json")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calib_joint_refine.jsonl"))
    ap.add_argument("--summary", action="store_true")
    ap.add_argument("--no-tracks", action="store_true", help="dense term only (what the tracks add)")
    args = ap.parse_args()
    if args.summary:
        rows = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
        for line in calib_refine.joint_refine_summary(rows):
            print(line)
        return
    for name in args.data:
        row = calib_refine.run_joint_refine(name, SHARED, not args.no_tracks)
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
