"""SIFT matches between the cameras of simulated rigs (issue 4: texture rich enough for
target-free calibration).

For each scene, one frame of an N-camera ring at 640x480 (Kinect noise, colour noise on) is
rendered; per image, OpenCV SIFT keypoints; per camera pair, Lowe's ratio test (0.75) on 2-NN
matches, then RANSAC on the fundamental matrix (1 px, confidence 0.999): the inliers are the
reported matches. Each inlier is also checked against the ground truth (keypoint of camera i
back-projected with the noise-free depth and projected into camera j lands within 3 px of its
match): 'correct' is that share.

    .venv/bin/python benchmarks/sim_matches.py --scenes studio room

The benchmark is fuseflow.eval.bench.sim_matches; this program parses the command line and prints
its report.
"""

from __future__ import annotations

import argparse

from fuseflow.eval.bench.sim_matches import run_scene, scene_report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["studio", "room"])
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", default="kinect")
    ap.add_argument("--dynamic", action="store_true")
    ap.add_argument("--ratio", type=float, default=0.75)
    a = ap.parse_args()
    for scene in a.scenes:
        r = run_scene(scene, a.cameras, a.seed, a.ratio, a.noise, a.dynamic)
        for line in scene_report(scene, r, a.cameras, a.seed, a.noise):
            print(line)


if __name__ == "__main__":
    main()
