"""The live stream's frame codecs on real fused clouds (benchmarks.studies.live_codec): bytes a
point, Mbit/s at 10 fps, encoding CPU ms, decoding ms (Python; the viewer in headless Chromium),
position and colour error, for raw and compact at several grid steps and colour settings.

    python -m benchmarks.live_codec [--data-dir ../shared/data] [--json benchmarks/results/live_codec.json]
        [--grids 2,3,4] [--no-browser]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_codec import run_codec_bench


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--grids", default="2,3,4")
    ap.add_argument("--no-browser", action="store_true")
    a = ap.parse_args(argv)
    out = run_codec_bench(common.data_dir(a.data_dir), [float(g) for g in a.grids.split(",")], browser=not a.no_browser)
    meta = {"browser_decode_ms_hocap8_200k": out["browser_decode_ms"]}
    common.save(a, "live_codec", common.command("live_codec", argv), out["rows"], meta)


if __name__ == "__main__":
    main()
