"""decode.js's wall time a compact key frame in headless Chromium, on the page's thread alone and
with the geometry in a worker beside it, and the encoder's wall and CPU time, on the hocap-8rs
frame and the simulated 8-camera studio fused at 200 k points
(benchmarks.studies.live_codec_browser; docs/live.md, "Bandwidth").

    python -m benchmarks.live_codec_browser [--repeats 20] [--data-dir ../shared/data] [--json PATH | --save]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_codec_browser import run_codec_browser


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--repeats", type=int, default=20, help="decodes per path and cloud (default 20)")
    a = ap.parse_args(argv)
    out = run_codec_browser(common.data_dir(a.data_dir), repeats=a.repeats, log=common.log)
    common.save(a, "live_codec_browser", common.command("live_codec_browser", argv), out["rows"], out["meta"])


if __name__ == "__main__":
    main()
