#!/usr/bin/env python
"""Route (c) of the rgbd backbone, geometry only (``fuseflow.calib.geometric``): where does it
place cameras that no image or floor match places?

* ``primitives``: ``fuseflow.synth.primitives`` (random boxes, spheres, cylinders on a floor,
  ray-cast, uniform grey images: no texture at all), two cameras ``--angles`` apart, seeds
  ``--seeds``; the backbone alone (``rgbd_backbone``), error of the relative pose vs the truth.
* ``sim``: the simulator's rings (``--cameras``, room and studio, 320x240, Kinect noise) with
  every image replaced by uniform grey: what depth alone does on those scenes.
* ``hocap``: ``shared/data/hocap-8rs`` (real, 8 RealSense, one frame), the backbone alone;
  errors of each camera against the target-based reference (mean over the other cameras).

Rows: JSON lines appended to ``--out``; a markdown table is printed per data set.

    python benchmarks/calib_geometric.py primitives sim hocap --out benchmarks/results/calib_geometric.jsonl

The benchmark is fuseflow.eval.bench.calib_geometric; this program appends its rows to --out and
prints its tables.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fuseflow.eval.bench import calib_geometric as bench

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
