"""Calibration with defaults on independently rendered repeating studios: how many cameras are
within 1 deg / 3 cm, and is any placed a whole room period off with verdict "good"?

Scene (benchmarks.studies.independent_scene, written apart from the simulator's studio
families): a regular 6-12-sided room whose walls, floor and ceiling repeat exactly, a seated
figure of boxes and cylinders, 5-10 cameras on one or two rings 2.5-3.5 m out, Kinect v2 /
Azure Kinect NFOV / 320x240 sensor models. Per seed the recording is written under --work and
``fuseflow calibrate REC -o OUT/calib.json --reference REC/reference.json`` runs with defaults
(in a subprocess: the source tree first on PYTHONPATH is the one measured). Scoring and the
definitions of within / silently wrong / flagged / unplaced: benchmarks.studies.independent_run.

    python -m benchmarks.calib_independent --seeds 100-119 --resolution 320x240 --save
    python -m benchmarks.calib_independent --seeds 100-109 --num-frames 5 --moving --json /tmp/m.json
"""

from __future__ import annotations

import sys
from pathlib import Path

from benchmarks.common import command, parser, save, seeds
from benchmarks.studies.independent_run import run_bench
from benchmarks.studies.independent_scene import SENSORS


def _reproducing(argv: list[str] | None) -> list[str]:
    """The arguments without the ones that only say where files go (--work, --progress,
    --json): the command stored with the results, free of absolute paths."""
    args, out, skip = list(sys.argv[1:] if argv is None else argv), [], False
    for x in args:
        if skip:
            skip = False
        elif x in ("--work", "--progress", "--json"):  # (--rescore only re-reads them: dropped too)
            skip = True
        elif x != "--rescore" and not x.startswith(("--work=", "--progress=", "--json=")):
            out.append(x)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = parser(__doc__, num_frames=1)
    ap.add_argument("--seeds", default="100-104", help="e.g. 100-119 or 3,5,7")
    ap.add_argument("--resolution", default="320x240", choices=sorted(SENSORS))
    ap.add_argument("--moving", action="store_true", help="the figure moves between frames")
    ap.add_argument("--work", type=Path, default=Path("/tmp/calib-independent"), help="recordings and outputs")
    ap.add_argument("--progress", type=Path, default=None, help="rewrite the rows here after each seed")
    ap.add_argument("--rescore", action="store_true", help="only score the outputs already under --work")
    ap.add_argument("--name", default=None, help="results name under --save (default: calib_independent_RES[_moving])")
    a = ap.parse_args(argv)
    rows, totals = run_bench(seeds(a.seeds), a.resolution, a.num_frames, a.moving, a.work, a.progress, a.rescore)
    name = a.name or f"calib_independent_{a.resolution}" + (f"_moving{a.num_frames}" if a.moving else "")
    meta = {"resolution": a.resolution, "frames": a.num_frames, "moving": a.moving, "totals": totals}
    save(a, name, command("calib_independent", _reproducing(argv)), rows, meta)


if __name__ == "__main__":
    main()
