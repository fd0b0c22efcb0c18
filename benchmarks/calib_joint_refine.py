#!/usr/bin/env python
"""What the depth-aware joint refinement (issue 15 item 4, ``fuseflow.calib.joint_refine``) adds
to the metric ``rgbd`` backbone: the same backbone run, errors before and after.

Per recording: ``rgbd_backbone`` on frame 0 (its poses and its edges' verified 3-D matches, the
keypoint tracks), then ``joint_refine`` on the same frame with those tracks. Errors:
``fuseflow.eval.metrics.pose_errors`` over the placed cameras against rig.json (simulated: ground
truth; ICL: the Open3D trajectory estimate; hocap-8rs: the target-based reference), before and
after; ``kept`` is the refinement's own verdict (the depth-fit check), ``gain`` the change of the
mean share of depth samples within 1 cm of the neighbours' surfaces.

    python benchmarks/calib_wide.py sim --seeds 1 2 3 --frames 5 ...   # makes the recordings
    python benchmarks/calib_joint_refine.py --out benchmarks/results/calib_joint_refine.jsonl \\
        hocap /tmp/fuseflow-calib-wide/icl8_every26 /tmp/fuseflow-calib-wide/room3_s1_f5_640x480 ...
    python benchmarks/calib_joint_refine.py --summary --out benchmarks/results/calib_joint_refine.jsonl

The benchmark is fuseflow.eval.bench.calib_refine; this program appends its rows to --out and
prints them, or (--summary) prints the table of --out.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fuseflow.eval.bench.calib_refine import joint_refine_summary, run_joint_refine

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="*", help="'hocap' or recording folders with true extrinsics in rig.json")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calib_joint_refine.jsonl"))
    ap.add_argument("--summary", action="store_true")
    ap.add_argument("--no-tracks", action="store_true", help="dense term only (what the tracks add)")
    args = ap.parse_args()
    if args.summary:
        rows = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
        for line in joint_refine_summary(rows):
            print(line)
        return
    for name in args.data:
        row = run_joint_refine(name, SHARED, not args.no_tracks)
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
