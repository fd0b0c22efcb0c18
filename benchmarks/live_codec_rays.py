"""Could the compact codec send a fused point as (camera, pixel, depth along the pixel's ray)?
How far fused points lie from their camera's pixel-centre rays, and the ideal bits a point of a
per-camera pixel mask, a depth residual and a sub-pixel offset at a position bound, and of colour
in pixel order, on the hocap-8rs frame, two simulated 8-camera studios and kinect3-room's first
frame fused at 200 k points (benchmarks.studies.live_codec_rays; docs/live.md, "Bandwidth").

    python -m benchmarks.live_codec_rays [--data-dir ../shared/data] [--json PATH | --save]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_codec_rays import run_codec_rays


def main(argv: list[str] | None = None) -> None:
    a = common.parser(__doc__, data=True).parse_args(argv)
    out = run_codec_rays(common.data_dir(a.data_dir), log=common.log)
    common.save(a, "live_codec_rays", common.command("live_codec_rays", argv), out["rows"], out["meta"])


if __name__ == "__main__":
    main()
