"""Cloud file sizes and Draco position error against binary PLY (``--format ply|drc|glb``): a thin
wrapper around ``benchmarks.studies.outputs.format_sizes``, whose docstring says what is measured. One JSON line per recording and cloud (frame
0, whole and cropped to the capture volume).

    PYTHONPATH=src python -m benchmarks.outputs_formats /tmp/i29/ring8rs640 --error-mm 1
"""

from __future__ import annotations

import json

from benchmarks import common
from benchmarks.studies.outputs import format_sizes


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--error-mm", type=float, default=1.0)
    a = ap.parse_args(argv)
    rows = []
    for r in a.recordings:
        for row in format_sizes(r, a.error_mm):
            rows.append(row)
            print(json.dumps(row))
    common.save(a, "outputs_formats", common.command("outputs_formats", argv), rows)


if __name__ == "__main__":
    main()
