"""GMAC accuracy and timing (docs/design.md section 4 metrics).

Rows per data set: the backbone's poses scaled by the naive median depth ratio; GMAC with each
closed form (z-only = paper eq. 12 corrected, full-3D, point-to-plane = default); GMAC +
refinement; the paper's ablations (w/o RC, w/o CC, w/o feature weight); robust weights; the
oracle scale (best scale for these backbone poses, a lower bound for any scale method); and
Open3D RGB-D odometry + pose-graph multiway registration (classical target-free peer).
Rotation error (deg) and translation error (mm, no scale alignment) are means over camera pairs
(fuseflow.eval.metrics.pose_errors), then mean +- std over seeds. Time per calibration includes
the backbone (run once per seed and shared by the GMAC rows; its time is added to every row).

Data: ``sim4`` / ``sim8``: fuseflow.synth rigs with Kinect noise. ``icl8``: ICL-NUIM living
room virtual rig (8 frames, 26 apart, start = 3 x seed; reference = Open3D trajectory, ~1 cm).
``symstudio`` / ``far3``: the studio study (benchmarks.studies.calib_studio: per camera placed /
flagged / error). Robustness: per seed, an edge with wrong matches is injected (its points
shifted 0.3 m along the baseline) and we count how often CC prunes it.

    python -m benchmarks.calib_accuracy --seeds 10            # full table (long)
    python -m benchmarks.calib_accuracy --quick               # 2 seeds, sim8 + icl8
    python -m benchmarks.calib_accuracy --data symstudio,far3 --seeds 10 --save
"""

from __future__ import annotations

import sys

from benchmarks import common
from benchmarks.studies.calib_accuracy import run_calib_accuracy
from benchmarks.studies.calib_studio import STUDIO_DATA, run_studio_bench
from fuseflow.errors import FuseFlowError


def main(argv=None) -> int:
    ap = common.parser(__doc__, data=True)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seed-start", type=int, default=0, help="first seed of symstudio / far3 (held-out seeds)")
    ap.add_argument("--data", default="sim4,sim8,icl8", help="comma list of sim4, sim8, icl8, symstudio, far3")
    ap.add_argument("--quick", action="store_true", help="2 seeds on sim8 and icl8")
    ap.add_argument("--backbone", default="colmap", choices=["colmap", "perturbed"],
                    help="colmap or perturbed ground truth (isolates GMAC from the backbone)")  # fmt: skip
    ap.add_argument("--rot-noise-deg", type=float, default=0.3, help="perturbed backbone: rotation error per camera")
    ap.add_argument("--center-noise-m", type=float, default=0.01, help="perturbed backbone: centre error per camera")
    ap.add_argument("--no-peer", action="store_true", help="skip the Open3D multiway peer")
    a = ap.parse_args(argv)
    if a.quick:
        a.seeds, a.data = 2, "sim8,icl8"
    names = common.names(a.data)
    cmd = common.command("calib_accuracy", argv)
    studio = [d for d in names if d in STUDIO_DATA]
    names = [d for d in names if d not in STUDIO_DATA]
    try:
        if studio:
            rows = run_studio_bench(studio, a.seeds, log=common.log, seed_start=a.seed_start)
            common.save(a, "calib_studio", cmd, rows)
        if names:
            icl = common.data_dir(a.data_dir) / "icl-livingroom1"
            run_calib_accuracy(
                a.seeds, names, a.backbone, (a.rot_noise_deg, a.center_noise_m), not a.no_peer, icl,
                save=lambda res: common.save(a, "calib_accuracy", cmd, [{"data": k, **v} for k, v in res.items()]),
                log=common.log, progress=lambda line: print(line, file=sys.stderr, flush=True),
            )  # fmt: skip
    except FuseFlowError as exc:
        sys.exit(f"error: {exc}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
