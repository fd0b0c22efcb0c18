#!/usr/bin/env python
"""Why does the rgbd backbone leave cameras of hocap-8rs unplaced? For each unplaced camera: does
the *reference* relative pose to every other camera pass the backbone's own verification
(``verify_pose`` + ``PairCheck.passes``), and which candidates did the routes produce?

If the reference passes, the verification is not what stops the camera: no route proposed a
right candidate (candidate generation is the gap).

    python benchmarks/investigations/calib_hocap_diagnose.py
"""

from __future__ import annotations

from benchmarks import common
from benchmarks.studies.calib_refine import load_hocap

from fuseflow.calib.backbones.rgbd import RGBDConfig, prepare_camera, rgbd_backbone, verify_pose
from fuseflow.types import invert_rigid

SHARED = common.data_dir()


def main() -> None:
    frame, rig, T_ref = load_hocap(SHARED / "hocap-8rs")
    cfg = RGBDConfig()
    bb = rgbd_backbone([frame], rig, cfg)
    ids = list(rig.ids)
    unplaced = [ids[k] for k in range(len(ids)) if not bb.registered[k]]
    print("unplaced:", unplaced)
    cams = {c: prepare_camera([frame], rig, k, cfg) for k, c in enumerate(ids)}
    for c in unplaced:
        k = ids.index(c)
        print(f"{c}: floor plane {'found' if cams[c].plane is not None else 'none'}, "
              f"valid depth {float((frame.depth[k] > 0).float().mean()):.0%}")  # fmt: skip
        for d in ids:
            if d == c:
                continue
            chk = verify_pose(cams[c], cams[d], T_ref[ids.index(d)] @ invert_rigid(T_ref[k]), cfg.tau)
            print(f"  reference pose to {d}: agreement {chk.agreement:.2f}, off-floor {chk.structure_agreement:.2f}, "
                  f"free space {chk.free_space:.3f}, passes {chk.passes(cfg)}")  # fmt: skip
        for p in bb.info["pairs"]:
            if c in p["cameras"]:
                cands = [(x["route"], x["inliers"], "ok" if x["ok"] else "refused") for x in p["candidates"]]
                print(f"  pair {p['cameras']}: {p.get('matches')} image matches, candidates {cands}")


if __name__ == "__main__":
    main()
