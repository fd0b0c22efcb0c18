#!/usr/bin/env python
"""What the depth-aware joint refinement adds to the metric rgbd backbone: a thin wrapper around
``benchmarks.studies.calib_refine`` (its docstring, shown by ``--help``, says what it measures
and how to run it); appends its rows to --out and prints them, or (--summary) the table of --out.
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import common
from benchmarks.studies import calib_refine


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(calib_refine.__doc__, data=True)
    ap.add_argument("data", nargs="*", help="'hocap' or recording folders with true extrinsics in rig.json")
    ap.add_argument(
        "--out", type=Path, default=Path("/tmp/fuseflow-calib_joint_refine.jsonl"), help="JSON lines (appended)"
    )
    ap.add_argument("--summary", action="store_true")
    ap.add_argument("--no-tracks", action="store_true", help="dense term only (what the tracks add)")
    args = ap.parse_args(argv)
    if args.summary:
        rows = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
        for line in calib_refine.joint_refine_summary(rows):
            print(line)
        return
    for name in args.data:
        row = calib_refine.run_joint_refine(name, common.data_dir(args.data_dir), not args.no_tracks)
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)
    rows = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
    common.save(args, "calib_joint_refine", common.command("calib_joint_refine", argv), rows)


if __name__ == "__main__":
    main()
