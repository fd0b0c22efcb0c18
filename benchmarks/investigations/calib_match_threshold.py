"""How many keypoint matches an edge needs before GMAC takes its scale from them alone.

``fuseflow.calib.correspondences.MIN_MATCHES`` (per direction, after the depth and robust
gates) decides between match correspondences (s-independent) and the reprojection fallback.
This runs the colmap backbone once per simulated frame and GMAC's default preset with each
threshold on that same backbone result, printing the translation error (mm, docs/design.md
section 4) and the cameras placed.

    python benchmarks/investigations/calib_match_threshold.py                  # 20, 10, 6, 5, 3 on three frames
"""

from __future__ import annotations

import argparse

from benchmarks.studies.calib_accuracy import sim_frame

from fuseflow.calib import calibrate, get_backbone
from fuseflow.calib import correspondences as corr
from fuseflow.calib.config import PRESETS
from fuseflow.eval.metrics import pose_errors

FRAMES = {
    "demo studio (dynamic, seed 1)": dict(scene="studio", dynamic=True, seed=1),
    "static studio, seed 2": dict(scene="studio", dynamic=False, seed=2),
    "room, seed 1": dict(scene="room", dynamic=False, seed=1),
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--thresholds", default="20,10,6,5,3")
    a = ap.parse_args()
    ths = [int(x) for x in a.thresholds.split(",")]
    print("| frame | " + " | ".join(f"{t} matches" for t in ths) + " |")
    print("|---|" + "---|" * len(ths))
    for label, kw in FRAMES.items():
        frame, rig, ref, _ = sim_frame(8, kw["seed"], kw["scene"], kw["dynamic"])
        bb = get_backbone("colmap")(frame, rig, PRESETS["default"])
        cells = []
        default = corr.MIN_MATCHES
        for t in ths:
            corr.MIN_MATCHES = t
            cal = calibrate(frame, rig, PRESETS["default"], backbone_result=bb)
            e = pose_errors(cal.T_cam_world, ref)
            cells.append(f"{e.translation_mm:.1f} mm ({len(cal.T_cam_world)} placed)")
        corr.MIN_MATCHES = default
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
