"""What the depth-aware joint refinement (``fuseflow.calib.joint_refine``) adds
to the metric ``rgbd`` backbone: the same backbone run, errors before and after.

Per recording: ``rgbd_backbone`` on frame 0 (its poses and its edges' verified 3-D matches, the
keypoint tracks), then ``joint_refine`` on the same frame with those tracks. Errors:
``fuseflow.eval.metrics.pose_errors`` over the placed cameras against rig.json (simulated: ground
truth; ICL: the Open3D trajectory estimate; hocap-8rs: the target-based reference), before and
after; ``kept`` is the refinement's own verdict (the depth-fit check), ``gain`` the change of the
mean share of depth samples within 1 cm of the neighbours' surfaces.

    python -m benchmarks.calib_wide sim --seeds 1 2 3 --num-frames 5 ...   # makes the recordings
    python -m benchmarks.calib_joint_refine --out benchmarks/results/calib_joint_refine.jsonl \\
        hocap /tmp/fuseflow-calib-wide/icl8_every26 /tmp/fuseflow-calib-wide/room3_s1_f5_640x480 ...
    python -m benchmarks.calib_joint_refine --summary --out benchmarks/results/calib_joint_refine.jsonl

Also ``load_hocap``: one frame of hocap-8rs with its reference extrinsics, for the calibration
benchmarks.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from fuseflow.types import Camera, Frame, Rig, invert_rigid

__all__ = ["load_hocap", "run_joint_refine", "joint_refine_summary"]


def load_hocap(root: Path) -> tuple[Frame, Rig, np.ndarray]:
    """One frame of hocap-8rs: colour intrinsics (depth is registered to colour), depth in mm,
    reference camera-from-master extrinsics (the file stores camera -> master)."""
    import cv2
    import torch

    from fuseflow.io.images import read_depth

    ext = json.loads((root / "calibration" / "extrinsics" / "extrinsics_20231014.json").read_text())
    serials = sorted(p.name for p in (root / "frames").iterdir() if p.is_dir())
    cams, colors, depths, T_ref = [], [], [], []
    for s in serials:
        intr = json.loads((root / "calibration" / "intrinsics" / f"{s}_640x480.json").read_text())["color"]
        K = [[intr["fx"], 0, intr["ppx"]], [0, intr["fy"], intr["ppy"]], [0, 0, 1]]
        cams.append(Camera(s, intr["width"], intr["height"], K, depth_scale=1000.0, depth_range=(0.2, 1.6)))
        bgr = cv2.imread(str(root / "frames" / s / "color_000000.jpg"), cv2.IMREAD_COLOR)
        colors.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        depths.append(read_depth(root / "frames" / s / "depth_000000.png", 1000.0))
        T_c2m = np.vstack([np.array(ext["extrinsics"][s], dtype=np.float64).reshape(3, 4), [0, 0, 0, 1]])
        T_ref.append(invert_rigid(T_c2m))
    frame = Frame(
        index=0,
        camera_ids=tuple(serials),
        color=torch.from_numpy(np.stack(colors)),
        depth=torch.from_numpy(np.stack(depths).astype(np.float32)),
        present=torch.ones(len(serials), dtype=torch.bool),
    )
    return frame, Rig(tuple(cams)), np.stack(T_ref)


def _load(name: str, shared: Path):
    if name == "hocap":
        frame, rig, T_ref = load_hocap(shared / "hocap-8rs")
        return frame, rig, dict(zip(rig.ids, T_ref))
    from fuseflow.io import open_recording

    rec = open_recording(name)
    T_ref = {c.id: c.T_cam_world for c in rec.rig}
    return rec[0], Rig(tuple(c.with_extrinsics(None) for c in rec.rig)), T_ref


def _errors(T: dict, T_ref: dict) -> dict:
    from fuseflow.eval.metrics import pose_errors

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


def run_joint_refine(name: str, shared: Path, use_tracks: bool = True) -> dict:
    """One row (module doc) for ``name``: "hocap" (hocap-8rs under ``shared``) or a recording
    folder with true extrinsics in rig.json."""
    from fuseflow.calib.backbones.rgbd import RGBDConfig, rgbd_backbone
    from fuseflow.calib.joint_refine import joint_refine

    frame, rig, T_ref = _load(name, shared)
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


def joint_refine_summary(rows: list[dict]) -> list[str]:
    """The Markdown table and the simulated runs' means of ``run_joint_refine`` rows."""
    out = []
    out.append(
        "| data | N | placed | before deg / mm (worst cam) | after deg / mm (worst cam) | kept | tracks | refine s |"
    )
    out.append("|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "error" in r:
            out.append(f"| {r['data']} | {r['cameras']} | <2 | {r['error']} | | | | |")
            continue
        b, a = r["before"], r["after"]
        out.append(
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
            out.append(
                f"simulated, {len(sims)} runs, {k}: rot mean {np.mean(rot):.3f} max {np.max(rot):.3f} deg, "
                f"trans mean {np.mean(tr):.1f} max {np.max(tr):.1f} mm"
            )
        better = sum(r["after"]["rot_deg"] < r["before"]["rot_deg"] for r in sims)
        out.append(f"rotation error lower after on {better} of {len(sims)} simulated runs")
    return out
