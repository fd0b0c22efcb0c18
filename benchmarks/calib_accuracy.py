#!/usr/bin/env python
"""GMAC accuracy and timing benchmark (issue 6; docs/design.md section 4 metrics).

Rows per data set: the backbone's poses scaled by the naive median depth ratio; GMAC with each
closed form (z-only = paper eq. 12 corrected, full-3D, point-to-plane = default); GMAC +
refinement; the paper's ablations (w/o RC, w/o CC, w/o feature weight); robust weights; the
oracle scale (best scale for these backbone poses, a lower bound for any scale method); and
Open3D RGB-D odometry + pose-graph multiway registration (classical target-free peer).
Rotation error (deg) and translation error (mm, no scale alignment) are means over camera pairs
(fuseflow.eval.metrics.pose_errors), then mean +- std over seeds. Time per calibration includes
the backbone (run once per seed and shared by the GMAC rows; its time is added to every row).

Data: ``sim4`` / ``sim8``: fuseflow.synth rigs with Kinect noise when the simulator is
installed, else an analytic textured room with Kinect-model depth noise built here (the output
says which). ``icl8``: ICL-NUIM living room virtual rig (8 frames, 26 apart, start = 3 x seed;
reference = Open3D trajectory, ~1 cm). Robustness: per seed, an edge with wrong matches is
injected (its points shifted 0.3 m along the baseline) and we count how often CC prunes it.

The benchmark itself is fuseflow.eval.bench.calib_accuracy (also ``fuseflow bench calib``); this
program parses the command line and prints its report.

    python benchmarks/calib_accuracy.py --seeds 10            # full table (long)
    python benchmarks/calib_accuracy.py --quick               # 2 seeds, sim8 + icl8
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fuseflow.errors import FuseFlowError
from fuseflow.eval.bench.calib_accuracy import run_calib_accuracy

ICL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "icl-livingroom1"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--data", default="sim4,sim8,icl8")
    ap.add_argument("--quick", action="store_true", help="2 seeds on sim8 and icl8")
    ap.add_argument("--json", type=Path, help="also write all per-seed rows here")
    ap.add_argument(
        "--backbone",
        default="colmap",
        choices=["colmap", "perturbed"],
        help="colmap (the product's default) or perturbed ground truth (isolates GMAC from the backbone)",
    )
    ap.add_argument("--rot-noise-deg", type=float, default=0.3, help="perturbed backbone: rotation error per camera")
    ap.add_argument("--center-noise-m", type=float, default=0.01, help="perturbed backbone: centre error per camera")
    ap.add_argument("--no-peer", action="store_true", help="skip the Open3D multiway peer")
    ap.add_argument("--icl", type=Path, default=ICL, help="ICL-NUIM living room 1 folder (icl8)")
    a = ap.parse_args(argv)
    if a.quick:
        a.seeds, a.data = 2, "sim8,icl8"
    try:
        run_calib_accuracy(
            a.seeds, a.data.split(","), a.backbone, (a.rot_noise_deg, a.center_noise_m), not a.no_peer, a.icl, a.json,
            log=print, progress=lambda line: print(line, file=sys.stderr, flush=True),
        )  # fmt: skip
    except FuseFlowError as exc:
        sys.exit(str(exc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
