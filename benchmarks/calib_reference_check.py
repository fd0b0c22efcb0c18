#!/usr/bin/env python
"""Which extrinsics fit the images better: the calibration's or the data set's reference? A thin
wrapper around ``fuseflow.eval.bench.calib_reference`` (also ``fuseflow bench calib-reference``),
whose docstring says what is measured: per data set, ``fuseflow.calibrate`` (default config)
against the reference, both scored by depth fit and colour consistency on the same frame. A
data name is ``hocap`` (shared/data/hocap-8rs) or a recording's path. The table goes to stdout,
one JSON line per data set to stderr.

    python benchmarks/calib_reference_check.py /tmp/fuseflow-calib-wide/icl8_every26 hocap
    python benchmarks/calib_reference_check.py hocap --per-camera
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from fuseflow.eval.bench.calib_reference import per_camera_table, reference_table

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"
if not SHARED.exists():
    SHARED = Path("/work/shared/data")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="+")
    ap.add_argument("--per-camera", action="store_true", help="score each camera's pose against the reference's others")
    args = ap.parse_args()

    def log(line: str) -> None:
        print(line, flush=True)

    if args.per_camera:
        for name in args.data:
            per_camera_table(name, SHARED, log)
        return
    reference_table(args.data, SHARED, log, record=lambda row: print(json.dumps(row), file=sys.stderr))


if __name__ == "__main__":
    main()
