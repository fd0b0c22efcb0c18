#!/usr/bin/env python
"""Route (c) of the rgbd backbone, geometry only: a thin wrapper around
``fuseflow.eval.bench.calib_geometric`` (its docstring, shown by ``--help``, says what each data
set measures); appends its rows to --out and prints its tables.

    python benchmarks/calib_geometric.py primitives sim hocap --out benchmarks/results/calib_geometric.jsonl
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fuseflow.eval.bench import calib_geometric as bench

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> None:
    ap = argparse.ArgumentParser(description=bench.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="+", choices=["primitives", "sim", "hocap"])
    ap.add_argument("--out", type=Path, default=Path("/tmp/calib_geometric.jsonl"))
    ap.add_argument("--angles", type=float, nargs="+", default=[15, 25, 35, 45, 60])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--cameras", type=int, nargs="+", default=[3, 4])
    a = ap.parse_args()
    with a.out.open("a") as out:

        def emit(row: dict) -> None:
            print(json.dumps(row), file=out, flush=True)

        def log(line: str) -> None:
            print(line, flush=True)

        for d in a.data:
            if d == "primitives":
                bench.primitives(a.angles, a.seeds, emit, log)
            elif d == "sim":
                bench.sim(a.cameras, a.seeds[:3], emit, log)
            else:
                bench.hocap(SHARED, emit, log)


if __name__ == "__main__":
    main()
