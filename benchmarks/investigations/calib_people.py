#!/usr/bin/env python
"""The person route (fuseflow.calib.people) on simulated rigs with a walking person.

Data: ``fuseflow.synth.person.walking_person_sim``: N Kinect-v2-like views (512x424, 70.6 deg,
Kinect-class depth noise, range 0.4-4.5 m) on a circle 3.5-4 m around a person walking 2.4 m
back and forth in a plain room; F frames 1/3 s apart; the walk's direction, the clothing colours
and the camera placement drawn from the seed. Reference: the simulator's true extrinsics.

Per seed and camera pair (``pairs``): the MediaPipe detector (the ``people`` extra) on every
view, the keypoint pose (RANSAC + Kabsch on the lifted joints pooled over frames) and the pose
after point-to-plane ICP on the per-pixel median depth, each against the true relative pose
(rotation deg, translation m); detection time per view. With ``--calibrate``: ``calibrate``
(default config, auto backbone, all frames) and per camera its error against the truth in the
calibration's world (the first placed camera's frame), placed or not.

Rows are JSON lines appended to --out; ``summary`` prints the table.

    python benchmarks/investigations/calib_people.py pairs --cameras 3 --seeds 0 1 2 3 4 5 6 7 8 9
    python benchmarks/investigations/calib_people.py pairs --cameras 6 --seeds 0 1 2 --no-icp
    python benchmarks/investigations/calib_people.py pairs --cameras 3 --seeds 0 1 2 --calibrate
    python benchmarks/investigations/calib_people.py summary
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent.parent / "results" / "calib_people.jsonl"


def _err(T, T_true):
    from fuseflow.calib.posegraph import rotation_angle_deg
    from fuseflow.types import invert_rigid

    D = T @ invert_rigid(T_true)
    return round(rotation_angle_deg(D[:3, :3]), 3), round(float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])), 4)


def run_seed(
    seed: int,
    cameras: int,
    n_frames: int,
    calibrate: bool,
    joint_depth: bool,
    normal_cos: float = -1.0,
    icp: bool = True,
) -> dict:
    from fuseflow.calib.people import MediapipePoseDetector, PeopleConfig, PersonRoute
    from fuseflow.synth.person import walking_person_sim
    from fuseflow.types import Rig, invert_rigid

    sim, _ = walking_person_sim(seed, cameras=cameras, frames=n_frames)
    t0 = time.perf_counter()
    frames = [sim.render(t).frame for t in range(n_frames)]
    t_render = time.perf_counter() - t0
    rig = sim.rig
    order = list(range(cameras))
    det = MediapipePoseDetector()
    route = PersonRoute(
        frames, rig, order, det, PeopleConfig(joint_depth=joint_depth, icp_normal_cos=normal_cos, icp=icp)
    )
    pairs = []
    for a in range(cameras):
        for b in range(a + 1, cameras):
            truth = rig.cameras[b].T_cam_world @ invert_rigid(rig.cameras[a].T_cam_world)
            row = {"pair": [a, b]}
            for c in route.pair(a, b):
                row[c["route"]] = _err(c["T_ba"], truth)
            pairs.append(row)
    det.close()
    info = route.info()
    out = {"seed": seed, "cameras": cameras, "frames": n_frames, "joint_depth": joint_depth, "icp_normal_cos": normal_cos, "render_s": round(t_render, 1),
           "frames_with_person": info["frames_with_person"], "detect_s_per_view": info["detect_s_per_view"],
           "pair_s": info["time_s"]["pairs"], "pairs": pairs}  # fmt: skip
    if calibrate:
        from fuseflow import calibrate as run_calibrate

        bare = Rig(tuple(replace(c, T_cam_world=None) for c in rig.cameras))
        t1 = time.perf_counter()
        cal = run_calibrate(frames, bare)
        out["calibrate_s"] = round(time.perf_counter() - t1, 1)
        T = cal.T_cam_world
        anchor = next(c.id for c in rig.cameras if c.id in T)
        W = (
            invert_rigid(rig.cameras[rig.ids.index(anchor)].T_cam_world) @ T[anchor]
        )  # true world from calibration world
        rep = cal.report
        out["suspect"] = list(rep.get("suspect_cameras", []))
        out["warnings"] = list(rep.get("warnings", []))
        bb = rep.get("backbone_info", None) or {}
        out["edges"] = [[p["cameras"], p["edge"]["route"]] for p in _rgbd_pairs(bb) if p.get("edge")]
        out["cameras_err"] = {c.id: (_err(T[c.id], c.T_cam_world @ W) if c.id in T else None) for c in rig.cameras}
    return out


def _rgbd_pairs(info) -> list[dict]:
    """The rgbd backbone's per-pair entries wherever the report nests them."""
    if isinstance(info, dict):
        if "pairs" in info and isinstance(info["pairs"], list) and info["pairs"] and "candidates" in info["pairs"][0]:
            return info["pairs"]
        for v in info.values():
            if found := _rgbd_pairs(v):
                return found
    return []


def summary(path: Path) -> None:
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    key = lambda r: (r["cameras"], r.get("joint_depth", True), r.get("icp_normal_cos", -1.0))  # noqa: E731
    for n, jd, nc in sorted({key(r) for r in rows}):
        rs = [r for r in rows if key(r) == (n, jd, nc)]
        kp = [p["people"] for r in rs for p in r["pairs"] if "people" in p]
        icp = [p["people+icp"] for r in rs for p in r["pairs"] if "people+icp" in p]
        npairs = sum(len(r["pairs"]) for r in rs)
        det = [r["detect_s_per_view"] for r in rs if r["detect_s_per_view"]]

        def stats(v, npairs=npairs):
            if not v:
                return "-"
            d = np.array([x[0] for x in v])
            m = np.array([x[1] for x in v])
            good = int(((d < 5) & (m < 0.10)).sum())
            fine = int(((d < 1) & (m < 0.03)).sum())
            return (f"median {np.median(d):.2f} deg / {1000 * np.median(m):.0f} mm, "
                    f"<5deg/10cm {good}/{npairs}, <1deg/3cm {fine}/{npairs}")  # fmt: skip

        print(
            f"{n} cameras, joint depth {'on' if jd else 'off'}, {len(rs)} seeds, {npairs} pairs, detection {1000 * np.mean(det):.0f} ms/view"
        )
        print(f"  keypoints: {stats(kp)}")
        print(f"  +ICP:      {stats(icp)}")
        cal = [r for r in rs if "cameras_err" in r]
        if cal:
            errs = [e for r in cal for e in r["cameras_err"].values()]
            placed = [e for e in errs if e is not None]
            ok = sum(1 for e in placed if e[0] < 1 and e[1] < 0.03)
            all3 = sum(
                1 for r in cal if all(e is not None and e[0] < 1 and e[1] < 0.03 for e in r["cameras_err"].values())
            )
            print(f"  calibrate: {len(placed)}/{len(errs)} placed, {ok} within 1 deg / 3 cm; "
                  f"all within in {all3}/{len(cal)} seeds; time {np.median([r['calibrate_s'] for r in cal]):.0f} s")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["pairs", "summary"])
    ap.add_argument("--cameras", type=int, default=3)
    ap.add_argument("--frames", type=int, default=11)
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(10)))
    ap.add_argument("--calibrate", action="store_true")
    ap.add_argument("--icp-normal-cos", type=float, default=-1.0, help="PeopleConfig.icp_normal_cos")
    ap.add_argument("--no-icp", action="store_true", help="keypoint poses only (PeopleConfig(icp=False))")
    ap.add_argument("--no-joint-depth", action="store_true", help="PeopleConfig(joint_depth=False)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args()
    if a.what == "summary":
        summary(a.out)
        return
    for s in a.seeds:
        row = run_seed(s, a.cameras, a.frames, a.calibrate, not a.no_joint_depth, a.icp_normal_cos, not a.no_icp)
        with a.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
