"""Where the compact codec's bits and time go, on the hocap-8rs frame, a simulated 8-camera studio
and a simulated polyroom studio fused at 200 k points (default parameters, version 5): bits a
point of the geometry's child bits, single-child flags and index bits (at the last depth and
above) and of luma, chroma and split flags; CPU of the geometry and colour kernels encoding and
decoding, and of decode.js's two halves in node (benchmarks.studies.live_codec_split;
docs/live.md, "Bandwidth").

    python -m benchmarks.live_codec_split [--data-dir ../shared/data] [--json PATH | --save]
        [--repeats 5] [--no-node]
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.live_codec_split import run_codec_split


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-node", action="store_true")
    a = ap.parse_args(argv)
    out = run_codec_split(common.data_dir(a.data_dir), a.repeats, node=not a.no_node, log=common.log)
    common.save(a, "live_codec_split", common.command("live_codec_split", argv), out["rows"], out["meta"])


if __name__ == "__main__":
    main()
