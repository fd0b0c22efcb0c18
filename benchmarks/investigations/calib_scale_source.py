"""Where GMAC's global scale comes from: all kept edges, or the match-only ones.

For each simulated 8-camera frame (Kinect noise, 640x480) the colmap backbone runs once; GMAC's
default preset then runs with ``global_from_matches`` off and on over that same result, beside
the naive median depth ratio and the best scale any method could pick for those poses (the
least-squares fit of the backbone's camera centres to the true ones). Translation errors in mm
(docs/design.md section 4, no scale alignment).

    python benchmarks/investigations/calib_scale_source.py
"""

from __future__ import annotations

from dataclasses import replace

from benchmarks.studies.calib_accuracy import oracle_scale, scaled, sim_frame

from fuseflow.calib import calibrate, get_backbone
from fuseflow.calib.config import PRESETS
from fuseflow.eval.metrics import pose_errors

FRAMES = [
    ("demo studio (dynamic, seed 1)", dict(scene="studio", dynamic=True, seed=1)),
    *[(f"static studio, seed {s}", dict(scene="studio", dynamic=False, seed=s)) for s in (0, 2, 3, 4, 5)],
    ("room, seed 1", dict(scene="room", dynamic=False, seed=1)),
]


def main() -> int:
    print("| frame | all kept edges | match-only edges (default) | naive median ratio | best scale |")
    print("|---|---|---|---|---|")
    for label, kw in FRAMES:
        frame, rig, ref, _ = sim_frame(8, kw["seed"], kw["scene"], kw["dynamic"])
        bb = get_backbone("colmap")(frame, rig, PRESETS["default"])
        cells = []
        for on in (False, True):
            cal = calibrate(frame, rig, replace(PRESETS["default"], global_from_matches=on), backbone_result=bb)
            cells.append(f"{pose_errors(cal.T_cam_world, ref).translation_mm:.1f}")
        ids = frame.camera_ids
        naive = cal.report["scale_naive_median_depth_ratio"]
        cells.append(f"{pose_errors(scaled(bb, ids, naive), ref).translation_mm:.1f}" if naive else "-")
        cells.append(f"{pose_errors(scaled(bb, ids, oracle_scale(bb, ids, ref)), ref).translation_mm:.1f}")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
