"""Calibration in a symmetric studio and a far-range room (issue 27): per camera placed / flagged /
error, "silently wrong" (placed, not flagged, > 5 deg or > 10 cm) and "within 1 deg / 3 cm".

The same as ``fuseflow bench calib --data symstudio,far3 --seeds N --json FILE``. Library code:
fuseflow.eval.bench.calib_studio.

    python benchmarks/calib_studio.py --data symstudio,far3 --seeds 10 --json results/calib_studio.json
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fuseflow.eval.bench.calib_studio import STUDIO_DATA, run_studio_bench


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=",".join(STUDIO_DATA), help="comma list of " + ", ".join(STUDIO_DATA))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--json", type=Path, default=None, help="write every per-seed row here")
    a = ap.parse_args()
    names = [d.strip() for d in a.data.split(",") if d.strip()]
    bad = [d for d in names if d not in STUDIO_DATA]
    if bad:
        ap.error(f"unknown data {bad}; choose from {', '.join(STUDIO_DATA)}")
    run_studio_bench(names, a.seeds, json_path=a.json)


if __name__ == "__main__":
    main()
