"""The output frame and the seen crop (``--world``, ``--crop auto``): a thin wrapper around
``fuseflow.eval.bench.outputs_seen``, whose docstring says what each measure counts. One JSON
line per recording (or per set of boxes).

    PYTHONPATH=src python benchmarks/outputs_world_crop.py keep /tmp/hocap
    PYTHONPATH=src python benchmarks/outputs_world_crop.py keep /tmp/hocap --calib /tmp/hocap-gmac.json
    PYTHONPATH=src python benchmarks/outputs_world_crop.py walls /tmp/studio
    PYTHONPATH=src python benchmarks/outputs_world_crop.py stability /tmp/icl26 /tmp/icl30 --frames 0
"""

from __future__ import annotations

import argparse
import json

from fuseflow.eval.bench.outputs_seen import box_motion, seen_keep, seen_walls


def _print(doc: dict) -> None:
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in doc.items()}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("measure", choices=("keep", "walls", "stability"))
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--calib", default=None, help="keep: extrinsics to use instead of rig.json's")
    ap.add_argument("--frames", default="0", help="stability: frame positions, comma-separated")
    a = ap.parse_args()
    if a.measure == "stability":
        _print(box_motion(a.recordings, [int(t) for t in a.frames.split(",")]))
        return
    for r in a.recordings:
        _print(seen_keep(r, a.calib) if a.measure == "keep" else seen_walls(r))


if __name__ == "__main__":
    main()
