"""FUSE vs VoxelBlockGrid: precision / recall / F at 5 mm, 1 cm, 2 cm on simulated rings
(benchmarks.studies.fuse_quality, whose docstring says what a cell is). VoxelBlockGrid is
reported at Open3D's default extraction weight threshold (``vbg``) and at the threshold that
maximises its F-score on each rig (``vbg_best``, thresholds 0-3; fuseflow.eval.baselines).

    python -m benchmarks.fuse_quality --cameras 3,4,8 --resolutions 320x240,640x480 --save
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.fuse_quality import run_fuse_quality, summarize_quality


def main(argv: list[str] | None = None) -> int:
    ap = common.parser(__doc__.split("\n\n")[0], num_frames=1)
    ap.add_argument("--cameras", default="3,4,8", help="comma list of ring sizes")
    ap.add_argument("--resolutions", default="320x240,640x480", help="comma list of WxH")
    ap.add_argument("--seeds", default="11,29,47,61,73,89", help="comma list of simulator seeds")
    ap.add_argument("--kinds", default="static,dynamic", help="static, dynamic or both")
    ap.add_argument("--methods", default="auto,vbg,vbg_best,naive",
                    help="FUSE presets (PRESET+NAME=VALUE changes a setting), vbg, vbg_best, naive; the first is compared")  # fmt: skip
    a = ap.parse_args(argv)
    try:
        res = [tuple(int(v) for v in r.lower().split("x")) for r in common.names(a.resolutions)]
    except ValueError:
        ap.error(f"--resolutions: expected WxH[,WxH...], got {a.resolutions!r}")
    dyn = [{"static": False, "dynamic": True}.get(k) for k in common.names(a.kinds)]
    if any(d is None for d in dyn):
        ap.error(f"--kinds: expected static and/or dynamic, got {a.kinds!r}")
    cams, seeds = common.ints(a.cameras, "--cameras"), common.ints(a.seeds, "--seeds")
    rows = run_fuse_quality(cams, res, seeds, dyn, common.names(a.methods), a.num_frames, log=common.log)
    summary = summarize_quality(rows)
    for s in summary:
        m = s["method"]
        common.log(f"{s['cameras']}-ring {s['resolution']}: {m} F@1cm {s[f'{m}_f_1cm']:.3f}, "
                   f"VBG {s.get('vbg_f_1cm', float('nan')):.3f}, VBG best {s.get('vbg_best_f_1cm', float('nan')):.3f}: "
                   f"{m} >= VBG in {s['wins']} of {s['cells']} cells")  # fmt: skip
    common.save(a, "fuse_quality", common.command("fuse_quality", argv), rows, {"summary": summary})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
