#!/usr/bin/env python
"""What the depth-aware joint refinement (issue 15 item 4, ``fuseflow.calib.joint_refine``) adds
to the metric ``rgbd`` backbone: the same backbone run, errors before and after.

Per recording: ``rgbd_backbone`` on frame 0 (its poses and its edges' verified 3-D matches, the
keypoint tracks), then ``joint_refine`` on the same frame with those tracks. Errors:
``fuseflow.eval.metrics.pose_errors`` over the placed cameras against rig.json (simulated: ground
truth; ICL: the Open3D trajectory estimate; hocap-8rs: the target-based reference), before and
after; ``kept`` is the refinement's own verdict (the depth-fit check), ``gain`` the change of the
mean share of depth samples within 1 cm of the neighbours' surfaces.

    python benchmarks/calib_wide.py sim --seeds 1 2 3 --frames 5 ...   # makes the recordings
    python benchmarks/calib_joint_refine.py --out benchmarks/results/calib_joint_refine.jsonl \\
        hocap /tmp/fuseflow-calib-wide/icl8_every26 /tmp/fuseflow-calib-wide/room3_s1_f5_640x480 ...
    python benchmarks/calib_joint_refine.py --summary --out benchmarks/results/calib_joint_refine.jsonl
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from fuseflow.calib.backbones.rgbd import RGBDConfig, rgbd_backbone
from fuseflow.calib.joint_refine import joint_refine
from fuseflow.eval.metrics import pose_errors
from fuseflow.types import Rig

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _load(name: str):
    if name == "hocap":
        from calib_wide import load_hocap

        frame, rig, T_ref = load_hocap(SHARED / "hocap-8rs")
        return frame, rig, dict(zip(rig.ids, T_ref))
    from fuseflow.io import open_recording

    rec = open_recording(name)
    T_ref = {c.id: c.T_cam_world for c in rec.rig}
    return rec[0], Rig(tuple(c.with_extrinsics(None) for c in rec.rig)), T_ref


def _errors(T: dict, T_ref: dict) -> dict:
    placed = [c for c in T_ref if c in T]
    e = pose_errors({c: T[c] for c in placed}, {c: T_ref[c] for c in placed})
    per = e.per_camera.values()
    return {
        "placed": len(placed),
        "rot_deg": float(e.rotation_deg),
        "trans_mm": float(e.translation_mm),
        "worst_deg": float(max(p[0] for p in per)),
        "worst_mm": float(max(p[1] for p in per)),
    }


def run(name: str, use_tracks: bool = True) -> dict:
    frame, rig, T_ref = _load(name)
    t0 = time.perf_counter()
    bb = rgbd_backbone([frame], rig, RGBDConfig())
    t_bb = time.perf_counter() - t0
    T = {rig.ids[k]: bb.T_cam_world[k] for k in range(len(rig)) if bb.registered[k]}
    row: dict = {"data": Path(name).name, "cameras": len(rig), "backbone_s": t_bb}
    if len(T) < 2:
        return {**row, "error": "rgbd placed fewer than two cameras"}
    t0 = time.perf_counter()
    res = joint_refine(T, [frame], rig, tracks=bb.tracks if use_tracks else ())
    row["tracks_used"] = use_tracks
    row["refine_s"] = time.perf_counter() - t0
    row["before"] = _errors(T, T_ref)
    row["after"] = _errors({**T, **res.T_refined}, T_ref)
    row["kept"] = res.accepted
    row["reason"] = res.reason
    row["tracks"] = int(sum(len(t[2]) for t in bb.tracks))
    b, a = res.inlier_before, res.inlier_after
    row["gain"] = float(np.mean([a[c] - b[c] for c in b])) if b else None
    return row


def summary(path: Path) -> None:
    rows = [json.loads(x) for x in path.read_text().splitlines() if x.strip()]
    print("| data | N | placed | before deg / mm (worst cam) | after deg / mm (worst cam) | kept | tracks | refine s |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            print(f"| {r['data']} | {r['cameras']} | <2 | {r['error']} | | | | |")
            continue
        b, a = r["before"], r["after"]
        print(
            f"| {r['data']} | {r['cameras']} | {b['placed']} | {b['rot_deg']:.3f} / {b['trans_mm']:.1f} "
            f"({b['worst_deg']:.2f} / {b['worst_mm']:.0f}) | {a['rot_deg']:.3f} / {a['trans_mm']:.1f} "
            f"({a['worst_deg']:.2f} / {a['worst_mm']:.0f}) | {'yes' if r['kept'] else 'no'} | {r['tracks']} "
            f"| {r['refine_s']:.1f} |"
        )
    sims = [r for r in rows if "error" not in r and r["data"].startswith(("room", "studio"))]
    if sims:
        for k in ("before", "after"):
            rot = [r[k]["rot_deg"] for r in sims]
            tr = [r[k]["trans_mm"] for r in sims]
            print(
                f"simulated, {len(sims)} runs, {k}: rot mean {np.mean(rot):.3f} max {np.max(rot):.3f} deg, "
                f"trans mean {np.mean(tr):.1f} max {np.max(tr):.1f} mm"
            )
        better = sum(r["after"]["rot_deg"] < r["before"]["rot_deg"] for r in sims)
        print(f"rotation error lower after on {better} of {len(sims)} simulated runs")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", nargs="*", help="'hocap' or recording folders with true extrinsics in rig.json")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/calib_joint_refine.jsonl"))
    ap.add_argument("--summary", action="store_true")
    ap.add_argument("--no-tracks", action="store_true", help="dense term only (what the tracks add)")
    args = ap.parse_args()
    if args.summary:
        summary(args.out)
        return
    for name in args.data:
        row = run(name, not args.no_tracks)
        with args.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
