"""Bits a point of the live stream's compact codec, version 3 against version 2 and raw, in one run
on the hocap-8rs frame and a simulated 8-camera studio fused at 200 k points: bits (and geometry
bits) a point, points sent, position and colour error, encode time, Python and decode.js (node)
decode time (fuseflow.eval.bench.live_codec_v3; docs/live.md, "Bandwidth: the frame codecs").

    python benchmarks/live_codec_v3.py [--data-dir ../shared/data] [--json benchmarks/results/live_codec_v3.json]
        [--repeats 7] [--no-node]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from fuseflow.eval.bench.live_codec_v3 import run_codec_v3_bench  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-node", action="store_true")
    a = ap.parse_args()
    out = run_codec_v3_bench(a.data_dir, a.repeats, node=not a.no_node)
    out["meta"]["command"] = "python benchmarks/live_codec_v3.py " + " ".join(sys.argv[1:])
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
