#!/usr/bin/env python
"""Which extrinsics fit the images better: the calibration's or the data set's reference? A thin
wrapper around ``benchmarks.studies.calib_reference`` ,
whose docstring says what is measured: per data set, ``fuseflow.calibrate`` (default config)
against the reference, both scored by depth fit and colour consistency on the same frame. A
data name is ``hocap`` (shared/data/hocap-8rs) or a recording's path. The table goes to stdout,
one JSON line per data set to stderr.

    python -m benchmarks.calib_reference_check /tmp/fuseflow-calib-wide/icl8_every26 hocap
    python -m benchmarks.calib_reference_check hocap --per-camera
"""

from __future__ import annotations

import json
import sys

from benchmarks import common
from benchmarks.studies.calib_reference import per_camera_table, reference_table


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True, json=False)
    ap.add_argument("data", nargs="+")
    ap.add_argument("--per-camera", action="store_true", help="score each camera's pose against the reference's others")
    args = ap.parse_args(argv)
    shared = common.data_dir(args.data_dir)

    def log(line: str) -> None:
        print(line, flush=True)

    if args.per_camera:
        for name in args.data:
            per_camera_table(name, shared, log)
        return
    reference_table(args.data, shared, log, record=lambda row: print(json.dumps(row), file=sys.stderr))


if __name__ == "__main__":
    main()
