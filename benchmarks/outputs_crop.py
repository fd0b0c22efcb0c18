"""How well the automatic capture volume (``--crop auto``) keeps the subject and drops the studio:
a thin wrapper around ``fuseflow.eval.bench.outputs.crop_quality`` (also ``fuseflow bench
outputs crop``), whose docstring says how the points are labelled. One JSON line per simulated
recording (``fuseflow simulate``).

    PYTHONPATH=src python benchmarks/outputs_crop.py /tmp/i29/ring8 /tmp/i29/dome24
"""

from __future__ import annotations

import argparse
import json

from fuseflow.eval.bench.outputs import crop_quality


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    for r in ap.parse_args().recordings:
        m = crop_quality(r)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in m.items()}))


if __name__ == "__main__":
    main()
