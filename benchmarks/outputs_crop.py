"""How well the automatic capture volume (``--crop auto``) keeps the subject and drops the studio:
a thin wrapper around ``benchmarks.studies.outputs.crop_quality``, whose docstring says how the points are labelled. One JSON line per simulated
recording (``fuseflow simulate``).

    PYTHONPATH=src python -m benchmarks.outputs_crop /tmp/i29/ring8 /tmp/i29/dome24
"""

from __future__ import annotations

import json

from benchmarks import common
from benchmarks.studies.outputs import crop_quality


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    a = ap.parse_args(argv)
    rows = []
    for r in a.recordings:
        m = crop_quality(r)
        rows.append({"recording": str(r), **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in m.items()}})
        print(json.dumps(rows[-1]))
    common.save(a, "outputs_crop", common.command("outputs_crop", argv), rows)


if __name__ == "__main__":
    main()
