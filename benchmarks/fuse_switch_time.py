"""Time cost of one FuseConfig switch on the ICL-NUIM 8-view frame: on / off interleaved.

    flock /tmp/fuseflow-cpu.lock .venv/bin/python benchmarks/fuse_switch_time.py --switch multiview_mean --runs 7

The rig is fuse_speed's ``--data icl`` frame 0 (ICL living room frames 0, 25, ..., 175 as 8
cameras, reference trajectory as extrinsics; real depth, 640x480). ``fuse()`` with the default
config and with the switch flipped are called alternately in one process (after one untimed
warm-up call each, compilation), ``--runs`` times each; the report is the median per setting
and the output point counts. ``--base k_neighbours=7`` changes an integer field for both.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--switch", default="multiview_mean", help="a bool field of FuseConfig")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--base", default="", help="comma list NAME=INT applied to both settings, e.g. k_neighbours=7")
    ap.add_argument("--data-dir", type=Path, default=Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
    args = ap.parse_args(argv)
    from fuseflow.fuse import FuseConfig, fuse
    from fuseflow.io import make_virtual_rig, open_recording

    seq = open_recording(args.data_dir / "icl-livingroom1")
    with tempfile.TemporaryDirectory(prefix="fuse_switch_time_") as tmp:
        rig = make_virtual_rig(seq, [25 * k for k in range(8)], Path(tmp) / "rig")
        frame = open_recording(Path(tmp) / "rig")[0]
    base = dict((kv.split("=")[0], int(kv.split("=")[1])) for kv in args.base.split(",") if kv)
    default = replace(FuseConfig(), **base)
    cfgs = {v: replace(default, **{args.switch: v}) for v in (True, False)}
    times: dict[bool, list[float]] = {True: [], False: []}
    points = {}
    for v, cfg in cfgs.items():
        points[v] = len(fuse(frame, rig, cfg))  # warm-up (compilation)
    for _ in range(args.runs):
        for v, cfg in cfgs.items():
            t0 = time.perf_counter()
            fuse(frame, rig, cfg)
            times[v].append((time.perf_counter() - t0) * 1000.0)
    for v in (True, False):
        ms = sorted(times[v])
        print(f"{args.base} {args.switch}={v}: median {statistics.median(ms):.1f} ms (runs {', '.join(f'{t:.0f}' for t in ms)}), "
              f"{points[v]} points")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
