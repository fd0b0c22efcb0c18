"""Live replay benchmark: recordings replayed as cameras through `fuseflow live --serve` with one
WebSocket viewer (fuseflow.eval.bench.live; the same as `fuseflow bench live`).

    python benchmarks/live_replay.py [--cases sim4,hocap8,hocap8-200k] [--duration 20]
        [--data-dir ../shared/data] [--json benchmarks/results/live_replay.json] [--stand-in-ms 56]

Prints per case: sustained fused frames/s, drop rate, latency (capture to sent) p50/p95, FUSE ms,
points per frame and the viewer's Mbit/s, with the issue's target and whether it was met.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from fuseflow.eval.bench.live import run_live_bench  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", default="sim4,hocap8,hocap8-200k")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--stand-in-ms", type=float, default=None, help="replace FUSE by a sleep (all but FUSE)")
    a = ap.parse_args()
    command = "python benchmarks/live_replay.py " + " ".join(sys.argv[1:])
    run_live_bench(
        [c for c in a.cases.split(",") if c],
        a.duration,
        a.data_dir,
        a.json,
        command=command,
        log=print,
        stand_in_ms=a.stand_in_ms,
    )


if __name__ == "__main__":
    main()
