"""Time cost of FuseConfig settings on the ICL-NUIM 8-view frame: settings interleaved.

    python -m benchmarks.fuse_switch_time \
        --settings "cvgc.multiview_mean=0;cvgc.k_neighbours=7;cvgc.k_neighbours=7,cvgc.multiview_mean=0" --runs 7

The rig is fuse_speed's ``--data icl`` frame 0 (ICL living room frames 0, 25, ..., 175 as 8
cameras, reference trajectory as extrinsics; real depth, 640x480). ``fuse()`` with the default
config and with each setting (``;``-separated; each a ``,``-separated list of NAME=VALUE, NAME
as ``FuseConfig.describe()`` spells it, bool fields as 0 / 1) is called in turn in one process, ``--runs`` rounds, after one untimed
warm-up call each (compilation); the report is the median per setting and the point count.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from benchmarks import common


def _config(text: str):
    from fuseflow.cli import parse_settings
    from fuseflow.fuse import FuseConfig

    return FuseConfig().replace(**parse_settings(t for t in text.split(",") if t))


def main(argv: list[str] | None = None) -> int:
    ap = common.parser(__doc__.split("\n\n")[0], data=True, json=False)
    ap.add_argument("--settings", default="cvgc.multiview_mean=0", help="';'-separated settings besides the default")
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args(argv)
    from fuseflow.fuse import fuse
    from fuseflow.io import make_virtual_rig, open_recording

    seq = open_recording(common.data_dir(args.data_dir) / "icl-livingroom1")
    with tempfile.TemporaryDirectory(prefix="fuse_switch_time_") as tmp:
        rig = make_virtual_rig(seq, [25 * k for k in range(8)], Path(tmp) / "rig")
        frame = open_recording(Path(tmp) / "rig")[0]
    names = ["default"] + [s for s in args.settings.split(";") if s]
    cfgs = {n: _config("" if n == "default" else n) for n in names}
    times: dict[str, list[float]] = {n: [] for n in names}
    points = {n: len(fuse(frame, rig, c)) for n, c in cfgs.items()}  # warm-up (compilation)
    for _ in range(args.runs):
        for n, cfg in cfgs.items():
            t0 = time.perf_counter()
            fuse(frame, rig, cfg)
            times[n].append((time.perf_counter() - t0) * 1000.0)
    for n in names:
        ms = sorted(times[n])
        print(
            f"{n}: median {statistics.median(ms):.1f} ms (runs {', '.join(f'{t:.0f}' for t in ms)}), {points[n]} points"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
