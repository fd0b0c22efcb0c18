"""Bits a point of the live stream's compact codec, versions 7, 5 and 3 (the octree as one symbol
a node or as bits; chroma blocks that split or never do) against version 2 and raw, in one run on the hocap-8rs frame, a simulated 8-camera
studio and a simulated polyroom studio (the parameters were not chosen on it) fused at 200 k
points, then key frames against deltas (version 6) on two moving sequences (kinect3-room, a
simulated dynamic studio): bits (and geometry bits) a point, points sent, position and colour
error, encode time, Python and decode.js (node) decode time
(benchmarks.studies.live_codec_versions; docs/live.md, "Bandwidth").

    python -m benchmarks.live_codec_versions [--data-dir ../shared/data] [--json PATH | --save]
        [--repeats 7] [--no-node] [--no-sequences] [--sim-frames 10]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_codec_versions import run_codec_v3_bench


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--no-node", action="store_true")
    ap.add_argument("--no-sequences", action="store_true")
    ap.add_argument("--sim-frames", type=int, default=10)
    a = ap.parse_args(argv)
    out = run_codec_v3_bench(common.data_dir(a.data_dir), a.repeats, node=not a.no_node, log=common.log,
                             sequences=not a.no_sequences, sim_frames=a.sim_frames)  # fmt: skip
    common.save(a, "live_codec_versions", common.command("live_codec_versions", argv), out["rows"], out["meta"])


if __name__ == "__main__":
    main()
