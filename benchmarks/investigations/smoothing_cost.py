"""Time of the `live` preset with and without 3x3 depth smoothing, interleaved in one process
(first frame of each recording, 7 rounds, median). Usage: python smoothing_cost.py REC [REC ...]"""

from __future__ import annotations

import statistics
import sys
import time

import fuseflow
from fuseflow.fuse import PRESETS, fuse


def main(paths: list[str]) -> None:
    for path in paths:
        rec = fuseflow.open_recording(path)
        frame, rig = rec[0], rec.rig
        plain = PRESETS["live"]
        smoothed = plain.replace(smoothing={"radius": 1})
        for cfg in (plain, smoothed):
            fuse(frame, rig, cfg)  # compile and warm
        t_s, t_p = [], []
        for _ in range(7):
            t = time.perf_counter()
            fuse(frame, rig, smoothed)
            t_s.append(time.perf_counter() - t)
            t = time.perf_counter()
            fuse(frame, rig, plain)
            t_p.append(time.perf_counter() - t)
        ratio = statistics.median(a / b for a, b in zip(t_s, t_p))
        print(f"{path}: smoothed {1e3 * statistics.median(t_s):.1f} ms, plain {1e3 * statistics.median(t_p):.1f} ms, "
              f"ratio {ratio:.2f}")  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1:])
