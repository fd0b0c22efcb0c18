"""Cloud file sizes and Draco position error against binary PLY (``--format ply|drc|glb``): a thin
wrapper around ``fuseflow.eval.bench.outputs.format_sizes`` (also ``fuseflow bench outputs
formats``), whose docstring says what is measured. One JSON line per recording and cloud (frame
0, whole and cropped to the capture volume).

    PYTHONPATH=src python benchmarks/outputs_formats.py /tmp/i29/ring8rs640 --error-mm 1
"""

from __future__ import annotations

import argparse
import json

from fuseflow.eval.bench.outputs import format_sizes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--error-mm", type=float, default=1.0)
    a = ap.parse_args()
    for r in a.recordings:
        for row in format_sizes(r, a.error_mm):
            print(json.dumps(row))


if __name__ == "__main__":
    main()
