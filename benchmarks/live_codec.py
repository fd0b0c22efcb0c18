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
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from fuseflow.eval.bench.live_codec import browser_decode_ms, clouds, measure  # noqa: E402
from fuseflow.live.codec import CompactParams, encode_compact  # noqa: E402
from fuseflow.live.wire import encode_frame  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--grids", default="2,3,4")
    ap.add_argument("--no-browser", action="store_true")
    a = ap.parse_args()
    params = [CompactParams(step_mm=float(g)) for g in a.grids.split(",")]
    params += [CompactParams(luma_step=2, chroma_step=4, chroma_block=2),
               CompactParams(luma_step=8, chroma_step=16, chroma_block=8)]  # fmt: skip
    rows = []
    with tempfile.TemporaryDirectory(prefix="live_codec_") as tmp:
        found = clouds(a.data_dir, Path(tmp))
        for name, cloud in found.items():
            for r in measure(name, cloud, params):
                print(json.dumps(r))
                rows.append(r)
    browser = {}
    if not a.no_browser:
        c = found["hocap8-200k"]
        xyz, rgb = c.xyz.numpy(), c.rgb.numpy()
        browser = browser_decode_ms({"raw": encode_frame(c, 0, 0.0, 0.0, "raw"),
                                     "compact": encode_compact(xyz, rgb, 0, 0.0, 0.0, CompactParams())})  # fmt: skip
        print("headless Chromium decode ms (hocap8-200k):", browser)
    meta = {"command": "python benchmarks/live_codec.py " + " ".join(sys.argv[1:]),
            "date": time.strftime("%Y-%m-%d %H:%M"), "browser_decode_ms_hocap8_200k": browser}  # fmt: skip
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
