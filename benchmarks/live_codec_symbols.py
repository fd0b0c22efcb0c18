"""The compact codec's octree geometry under other models, against version 5's coded stream of
the same cells: one symbol per occupancy byte (binarised as a 255-node tree, or from adaptive
frequency counts), a hybrid, and a direct mode for isolated nodes, on the hocap-8rs frame, two
simulated 8-camera studios and kinect3-room's first frame fused at 200 k points; with the random-occupancy estimate of what any
coder of those cells needs (benchmarks.studies.live_codec_symbols; docs/live.md, "Bandwidth").

    python -m benchmarks.live_codec_symbols [--data-dir ../shared/data] [--json PATH | --save]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_codec_symbols import run_codec_symbols


def main(argv: list[str] | None = None) -> None:
    a = common.parser(__doc__, data=True).parse_args(argv)
    out = run_codec_symbols(common.data_dir(a.data_dir), log=common.log)
    common.save(a, "live_codec_symbols", common.command("live_codec_symbols", argv), out["rows"], out["meta"])


if __name__ == "__main__":
    main()
