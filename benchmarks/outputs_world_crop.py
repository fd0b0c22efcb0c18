"""The output frame and the seen crop (``--world``, ``--crop auto``): a thin wrapper around
``benchmarks.studies.outputs_seen``, whose docstring says what each measure counts. One JSON
line per recording (or per set of boxes).

    python -m benchmarks.outputs_world_crop keep /tmp/hocap
    python -m benchmarks.outputs_world_crop keep /tmp/hocap --calib /tmp/hocap-gmac.json
    python -m benchmarks.outputs_world_crop walls /tmp/studio
    python -m benchmarks.outputs_world_crop stability /tmp/icl26 /tmp/icl30 --frames 0
"""

from __future__ import annotations

import argparse
import json

from benchmarks.studies.outputs_seen import box_motion, seen_keep, seen_walls


def _print(doc: dict) -> None:
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in doc.items()}))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("measure", choices=("keep", "walls", "stability"))
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--calib", default=None, help="keep: extrinsics to use instead of rig.json's")
    ap.add_argument("--frames", default="0", help="stability: frame positions, comma-separated")
    a = ap.parse_args(argv)
    if a.measure == "stability":
        _print(box_motion(a.recordings, [int(t) for t in a.frames.split(",")]))
        return
    for r in a.recordings:
        _print(seen_keep(r, a.calib) if a.measure == "keep" else seen_walls(r))


if __name__ == "__main__":
    main()
