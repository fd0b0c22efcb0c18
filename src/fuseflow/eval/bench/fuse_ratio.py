"""FUSE against VoxelBlockGrid TSDF as an interleaved time ratio, robust to a loaded machine.

    fuseflow bench fuse-ratio REC [REC ...] [--preset auto] [--rounds 5]

For each recording (fuseflow format, e.g. ``fuseflow convert ../shared/data/icl-livingroom1 ICL
--cameras 8``), its first frame is fused once by each method untimed (compilation, Open3D
start-up), then ``rounds`` times FUSE (``PRESETS[preset]``) and
``baselines.tsdf_fusion`` (1 cm) one after the other on the same frame. Each round gives the
ratio VBG time / FUSE time of two calls made seconds apart, so load that changes slowly cancels;
the report is the median ratio with its range and the median times. Then FUSE's CPU time on one
compiled-kernel thread (the least of ``rounds`` calls, ``time.process_time``): per million valid
depth pixels it is the cost presets.auto_config's pixel budget is derived from (docs/fuse.md).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

__all__ = ["run_fuse_ratio"]


def _timed(fn: Callable[..., object], *args, **kwargs) -> float:
    t0 = time.perf_counter()
    fn(*args, **kwargs)
    return (time.perf_counter() - t0) * 1000.0


def _core_ms(fn: Callable[..., object], rounds: int, *args) -> float:
    """The least process CPU time (ms) of ``rounds`` calls with one numba thread."""
    import numba

    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        times = []
        for _ in range(rounds):
            t0 = time.process_time()
            fn(*args)
            times.append((time.process_time() - t0) * 1000.0)
    finally:
        numba.set_num_threads(threads)
    return min(times)


def run_fuse_ratio(
    recordings: Sequence[Path], preset: str = "auto", rounds: int = 5, log: Callable[[str], None] | None = None
) -> list[dict]:
    """One row per recording: fuse_ms, vbg_ms (medians), ratio (median VBG / FUSE), ratio_min,
    ratio_max, points (FUSE), rounds, preset, grid (FuseReport.grid), valid_pixels, core_ms (FUSE's
    CPU time on one thread) and core_ms_per_mpx (per million valid depth pixels)."""
    from fuseflow.eval.baselines import tsdf_fusion
    from fuseflow.fuse import fuse_with_report
    from fuseflow.fuse.presets import preset_config
    from fuseflow.io import open_recording

    cfg = preset_config(preset)
    rows = []
    for path in recordings:
        rec = open_recording(path)
        frame, rig = rec[0], rec.rig
        res = fuse_with_report(frame, rig, cfg)
        tsdf_fusion(frame, rig, voxel=0.01)
        fuse_ms, vbg_ms = [], []
        for _ in range(rounds):
            fuse_ms.append(_timed(fuse_with_report, frame, rig, cfg))
            vbg_ms.append(_timed(tsdf_fusion, frame, rig, voxel=0.01))
        ratios = [v / f for v, f in zip(vbg_ms, fuse_ms)]
        core = _core_ms(fuse_with_report, rounds, frame, rig, cfg)
        valid = res.report.valid_pixels
        row = {
            "recording": str(path), "preset": preset, "rounds": rounds, "grid": res.report.grid,
            "points": len(res.cloud), "fuse_ms": statistics.median(fuse_ms), "vbg_ms": statistics.median(vbg_ms),
            "ratio": statistics.median(ratios), "ratio_min": min(ratios), "ratio_max": max(ratios),
            "valid_pixels": valid, "core_ms": core, "core_ms_per_mpx": core / max(valid, 1) * 1e6,
        }  # fmt: skip
        rows.append(row)
        if log:
            log(f"{path}: {preset} {row['fuse_ms']:.0f} ms ({row['points']} points; {row['grid'] or 'fixed grid'}), "
                f"VBG 1 cm {row['vbg_ms']:.0f} ms: VBG / FUSE median {row['ratio']:.2f} "
                f"({row['ratio_min']:.2f}-{row['ratio_max']:.2f}, {rounds} interleaved rounds); one thread {core:.0f} ms "
                f"CPU, {row['core_ms_per_mpx']:.0f} ms per million valid depth pixels ({valid / 1e6:.2f} M)")  # fmt: skip
    return rows
