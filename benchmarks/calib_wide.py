#!/usr/bin/env python
"""Metric RGB-D backbone on sparse wide-baseline rigs, against ground truth: a thin wrapper
around ``benchmarks.studies.calib_wide`` , whose docstring
says what each run measures.

* ``sim``: ``fuseflow simulate`` rings (room / studio), reference = the true extrinsics;
* ``hocap``: ``shared/data/hocap-8rs``, reference = the target-based calibration;
* ``icl``: ``fuseflow convert shared/data/icl-livingroom1 OUT --cameras 8 --every 26``;
* ``pairs``: cameras 0 and 1 of each simulated ring and ICL rig, with their overlap;
* ``summary``: the markdown table of a results file (--out).

Rows are appended as JSON lines to --out. ``--backbone raw`` (default) runs ``rgbd_backbone``
alone; ``colmap|rgbd|auto`` runs ``calibrate`` with that backbone. ``--matcher`` picks the rgbd
backbone's image matcher.

    python -m benchmarks.calib_wide sim --cameras 3,4 --scenes room --seeds 1,2,3
    python -m benchmarks.calib_wide hocap
    python -m benchmarks.calib_wide icl
    python -m benchmarks.calib_wide sim --cameras 3,4 --num-frames 1 --matcher xfeat
    python -m benchmarks.calib_wide summary
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import common
from benchmarks.studies.calib_wide import MATCHERS, WHAT, WideOptions, run_calib_wide


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, num_frames=5, data=True)
    ap.add_argument("what", choices=list(WHAT))
    ap.add_argument("--out", type=Path, default=Path("/tmp/fuseflow-calib_wide.jsonl"), help="JSON lines (appended)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/fuseflow-calib-wide"), help="folder for the recordings")
    ap.add_argument("--cameras", default="3,4,6,8", help="comma list of ring sizes")
    ap.add_argument("--scenes", default="room,studio", help="comma list of simulated scenes")
    ap.add_argument("--seeds", default="1,2,3", help="comma list of simulator seeds")
    ap.add_argument("--only-frames", type=int, default=None, help="run only with this many frames")
    ap.add_argument("--dynamic", action="store_true", help="simulate moving objects (fuseflow simulate --dynamic)")
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--every", default="26", help="comma list of ICL frame steps")
    ap.add_argument("--backbone", default="raw", choices=["raw", "colmap", "rgbd", "auto"])
    ap.add_argument("--matcher", default="sift", choices=list(MATCHERS), help="image matcher of the rgbd backbone")
    args = ap.parse_args(argv)
    skip = ("what", "work", "data_dir", "num_frames", "json", "save", "cameras", "scenes", "seeds", "every")
    opts = WideOptions(shared=common.data_dir(args.data_dir), data=args.work, frames=args.num_frames,
                       cameras=tuple(common.ints(args.cameras, "--cameras")), scenes=tuple(common.names(args.scenes)),
                       seeds=tuple(common.ints(args.seeds, "--seeds")), every=tuple(common.ints(args.every, "--every")),
                       **{k: v for k, v in vars(args).items() if k not in skip})  # fmt: skip
    run_calib_wide(args.what, opts, log=common.log)
    if args.what != "summary" and args.out.exists():
        rows = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
        common.save(args, "calib_wide", common.command("calib_wide", argv), rows)


if __name__ == "__main__":
    main()
