#!/usr/bin/env python
"""Where ``calibrate``'s seconds go: per stage, and optionally the cProfile functions.

One default ``calibrate`` (auto backbone + joint refinement) of ``hocap`` (shared/data/hocap-8rs,
one frame) or of a recording directory (``fuseflow simulate`` output; ````--num-frames`` of it). Prints
one JSON line: wall time, GMAC's ``report.timings_s`` (rgbd_backbone, rgbd_scale = the metric scale
check, joint_refine, total) and the rgbd backbone's own split (``info["time_s"]``: prepare =
per-camera floor / SIFT / samples, pairs = candidates and verification, geometric = route (c)).
``--cprofile N`` adds the N functions with the most own time (cProfile slows Python-heavy code
by 10-30 %: use the plain stage times for numbers, the profile for where to look).

    python -m benchmarks.calib_profile hocap
    python -m benchmarks.calib_profile /tmp/fuseflow-calib-wide/room8_s1_f5_640x480 --num-frames 1
    python -m benchmarks.calib_profile hocap --cprofile 30
"""

from __future__ import annotations

import json
import time

from benchmarks import common


def _load(what: str, frames: int, data_dir):
    if what == "hocap":
        from benchmarks.studies.calib_refine import load_hocap

        frame, rig, _ = load_hocap(common.data_dir(data_dir) / "hocap-8rs")
        return [frame], rig
    from fuseflow.io import open_recording
    from fuseflow.types import Rig

    rec = open_recording(what)
    rig = Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    return [rec[t] for t in range(min(frames, len(rec)))], rig


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__, num_frames=1, data=True, json=False)
    ap.add_argument("what", help="'hocap' or a recording directory")
    ap.add_argument("--cprofile", type=int, default=0, help="also print the N functions with the most own time")
    a = ap.parse_args(argv)
    from fuseflow.calib import CalibConfig, calibrate

    frames, rig = _load(a.what, a.num_frames, a.data_dir)
    prof = None
    if a.cprofile:
        import cProfile

        prof = cProfile.Profile()
        prof.enable()
    t0 = time.perf_counter()
    cal = calibrate(frames, rig, CalibConfig())
    wall = time.perf_counter() - t0
    if prof is not None:
        prof.disable()
    r = cal.report
    rgbd = r.backbone_info.get("sources", {}).get("rgbd", {}).get("time_s", {})
    with open("/proc/loadavg") as f:
        load = f.read().split()[:3]
    row = {"what": a.what, "frames": len(frames), "placed": len(cal.T_cam_world), "wall_s": round(wall, 2),
           **{k: round(v, 2) for k, v in r.timings_s.items()}, **{f"rgbd_{k}": round(v, 2) for k, v in rgbd.items()},
           "loadavg": load}  # fmt: skip
    print(json.dumps(row))
    if prof is not None:
        import pstats

        pstats.Stats(prof).sort_stats("tottime").print_stats(a.cprofile)


if __name__ == "__main__":
    main()
