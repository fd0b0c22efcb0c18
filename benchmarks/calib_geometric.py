#!/usr/bin/env python
"""Route (c) of the rgbd backbone, geometry only: a thin wrapper around
``benchmarks.studies.calib_geometric`` (its docstring, shown by ``--help``, says what each data
set measures); appends its rows to --out and prints its tables.

    python -m benchmarks.calib_geometric primitives sim hocap --out benchmarks/results/calib_geometric.jsonl
"""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import common
from benchmarks.studies import calib_geometric as bench


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(bench.__doc__, data=True)
    ap.add_argument("data", nargs="+", choices=["primitives", "sim", "hocap"])
    ap.add_argument(
        "--out", type=Path, default=Path("/tmp/fuseflow-calib_geometric.jsonl"), help="JSON lines (appended)"
    )
    ap.add_argument("--angles", default="15,25,35,45,60", help="comma list of degrees")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="comma list of seeds")
    ap.add_argument("--cameras", default="3,4", help="comma list of ring sizes")
    a = ap.parse_args(argv)
    with a.out.open("a") as out:

        def emit(row: dict) -> None:
            print(json.dumps(row), file=out, flush=True)

        def log(line: str) -> None:
            print(line, flush=True)

        for d in a.data:
            if d == "primitives":
                bench.primitives([float(v) for v in common.names(a.angles)], common.ints(a.seeds, "--seeds"), emit, log)
            elif d == "sim":
                bench.sim(common.ints(a.cameras, "--cameras"), common.ints(a.seeds, "--seeds")[:3], emit, log)
            else:
                bench.hocap(common.data_dir(a.data_dir), emit, log)
    rows = [json.loads(x) for x in a.out.read_text().splitlines() if x.strip()]
    common.save(a, "calib_geometric", common.command("calib_geometric", argv), rows)


if __name__ == "__main__":
    main()
