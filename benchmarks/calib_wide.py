#!/usr/bin/env python
"""Metric RGB-D backbone on sparse wide-baseline rigs, against ground truth: a thin wrapper
around ``fuseflow.eval.bench.calib_wide`` (also ``fuseflow bench calib-wide``), whose docstring
says what each run measures.

* ``sim``: ``fuseflow simulate`` rings (room / studio), reference = the true extrinsics;
* ``hocap``: ``shared/data/hocap-8rs``, reference = the target-based calibration;
* ``icl``: ``fuseflow convert shared/data/icl-livingroom1 OUT --cameras 8 --every 26``;
* ``pairs``: cameras 0 and 1 of each simulated ring and ICL rig, with their overlap;
* ``summary``: the markdown table of a results file (--out).

Rows are appended as JSON lines to --out. ``--backbone raw`` (default) runs ``rgbd_backbone``
alone; ``colmap|rgbd|auto`` runs ``calibrate`` with that backbone. ``--matcher`` picks the rgbd
backbone's image matcher.

    flock /tmp/fuseflow-cpu.lock python benchmarks/calib_wide.py sim --cameras 3 4 --scenes room --seeds 1 2 3
    flock /tmp/fuseflow-cpu.lock python benchmarks/calib_wide.py hocap
    flock /tmp/fuseflow-cpu.lock python benchmarks/calib_wide.py icl
    flock /tmp/fuseflow-cpu.lock python benchmarks/calib_wide.py sim --cameras 3 4 --frames 1 --matcher xfeat
    python benchmarks/calib_wide.py summary
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fuseflow.eval.bench.calib_wide import MATCHERS, WHAT, WideOptions, run_calib_wide

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
if not SHARED.exists():
    SHARED = Path("/work/shared/data")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=list(WHAT))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calib_wide.jsonl"))
    ap.add_argument("--data", type=Path, default=Path("/tmp/fuseflow-calib-wide"))
    ap.add_argument("--cameras", type=int, nargs="+", default=[3, 4, 6, 8])
    ap.add_argument("--scenes", nargs="+", default=["room", "studio"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--frames", type=int, default=5, help="frames simulated (runs use 1 and all of them)")
    ap.add_argument("--only-frames", type=int, default=None, help="run only with this many frames")
    ap.add_argument("--dynamic", action="store_true", help="simulate moving objects (fuseflow simulate --dynamic)")
    ap.add_argument("--resolution", default="640x480")
    ap.add_argument("--every", type=int, nargs="+", default=[26])
    ap.add_argument("--backbone", default="raw", choices=["raw", "colmap", "rgbd", "auto"])
    ap.add_argument("--matcher", default="sift", choices=list(MATCHERS), help="image matcher of the rgbd backbone")
    args = ap.parse_args()
    opts = WideOptions(shared=SHARED, **{k: v for k, v in vars(args).items() if k != "what"})
    run_calib_wide(args.what, opts, log=lambda line: print(line, flush=True))


if __name__ == "__main__":
    main()
