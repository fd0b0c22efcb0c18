"""The live stream's frame codecs on real fused clouds (fuseflow.eval.bench.live_codec): bytes a
point, Mbit/s at 10 fps, encoding CPU ms, decoding ms (Python; the viewer in headless Chromium),
position and colour error, for raw and compact at several grid steps and colour settings.

    python benchmarks/live_codec.py [--data-dir ../shared/data] [--json benchmarks/results/live_codec.json]
        [--grids 2,3,4] [--no-browser]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from fuseflow.eval.bench.live_codec import run_codec_bench  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--grids", default="2,3,4")
    ap.add_argument("--no-browser", action="store_true")
    a = ap.parse_args()
    out = run_codec_bench(a.data_dir, [float(g) for g in a.grids.split(",")], browser=not a.no_browser)
    meta = {"command": "python benchmarks/live_codec.py " + " ".join(sys.argv[1:]),
            "date": time.strftime("%Y-%m-%d %H:%M"), "browser_decode_ms_hocap8_200k": out["browser_decode_ms"]}  # fmt: skip
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"meta": meta, "rows": out["rows"]}, indent=1) + "\n")


if __name__ == "__main__":
    main()
