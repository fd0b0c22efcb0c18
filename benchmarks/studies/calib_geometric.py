"""Route (c) of the rgbd backbone, geometry only (``fuseflow.calib.geometric``): where does it
place cameras that no image or floor match places?

* ``primitives``: ``fuseflow.synth.primitives`` (random boxes, spheres, cylinders on a floor,
  ray-cast, uniform grey images: no texture at all), two cameras ``--angles`` apart, seeds
  ``--seeds``; the backbone alone (``rgbd_backbone``), error of the relative pose vs the truth.
* ``sim``: the simulator's rings (``--cameras``, room and studio, 320x240, Kinect noise) with
  every image replaced by uniform grey: what depth alone does on those scenes.
* ``hocap``: ``shared/data/hocap-8rs`` (real, 8 RealSense, one frame), the backbone alone;
  errors of each camera against the target-based reference (mean over the other cameras).

Rows: JSON lines appended to ``--out``; a markdown table is printed per data set.

    python -m benchmarks.calib_geometric primitives sim hocap --out benchmarks/results/calib_geometric.jsonl

Rows go to an ``emit`` callback, report lines to ``log`` (nothing here prints).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from benchmarks.studies.calib_refine import load_hocap
from fuseflow.calib.backbones.rgbd import RGBDConfig, relative_error, rgbd_backbone
from fuseflow.eval.metrics import pose_errors
from fuseflow.synth.primitives import primitive_views
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = ["primitives", "sim", "hocap"]


def _geo_edges(res) -> list:
    """[cameras, starts, pose] of the geometric route's edges."""
    return [
        [p["cameras"], p["edge"]["starts"], p["edge"].get("pose")]
        for p in res.info["pairs"]
        if p.get("stage") == "geometric" and p["edge"]
    ]


def primitives(angles, seeds, emit: Callable[[dict], None], log: Callable[[str], None]) -> None:
    """Two-camera primitive scenes ``angles`` apart, one row per seed and a table line per angle."""
    log("| angle deg | seeds | placed | rot deg (median / max) | trans mm (median / max) | s (median) |")
    log("|---|---|---|---|---|---|")
    for ang in angles:
        rows = []
        for seed in seeds:
            frame, rig, T = primitive_views((0.0, ang), (seed, seed))
            t0 = time.perf_counter()
            res = rgbd_backbone([frame], rig, RGBDConfig())
            dt = time.perf_counter() - t0
            row = {"data": "primitives", "angle": ang, "seed": seed, "placed": int(res.registered.sum()),
                   "time_s": dt, "geometric_edges": _geo_edges(res)}  # fmt: skip
            if res.registered.all():
                r, t = relative_error(res.T_cam_world[1] @ invert_rigid(res.T_cam_world[0]), T[1] @ invert_rigid(T[0]))
                row.update(rot_deg=r, trans_mm=t * 1000)
            rows.append(row)
            emit(row)
        ok = [r for r in rows if r["placed"] == 2]
        rot = [r["rot_deg"] for r in ok]
        tr = [r["trans_mm"] for r in ok]
        fmt = (lambda v: f"{np.median(v):.2f} / {np.max(v):.2f}") if ok else (lambda v: "-")
        log(f"| {ang:g} | {len(rows)} | {len(ok)}/{len(rows)} | {fmt(rot)} | {fmt(tr)} | "
              f"{np.median([r['time_s'] for r in rows]):.1f} |")  # fmt: skip


def sim(cameras, seeds, emit: Callable[[dict], None], log: Callable[[str], None]) -> None:
    """The simulator's rings with uniform grey images: one row and table line per run."""
    import torch

    from fuseflow.synth import SimConfig, Simulator

    log("| scene | N | seed | placed | rot deg / trans mm (placed) | geometric edges | s |")
    log("|---|---|---|---|---|---|---|")
    for scene in ("room", "studio"):
        for n in cameras:
            for seed in seeds:
                s = Simulator(SimConfig(cameras=n, frames=1, scene=scene, resolution=(320, 240), seed=seed))
                f = s.render(0).frame
                T = np.stack([c.T_cam_world for c in s.rig])
                rig = Rig(tuple(c.with_extrinsics(None) for c in s.rig))
                flat = Frame(f.index, f.camera_ids, torch.full_like(f.color, 128), f.depth, f.present)
                t0 = time.perf_counter()
                res = rgbd_backbone([flat], rig, RGBDConfig())
                dt = time.perf_counter() - t0
                reg = res.registered
                e = pose_errors(res.T_cam_world[reg], T[reg]) if reg.sum() > 1 else None
                row = {"data": "sim-textureless", "scene": scene, "n": n, "seed": seed, "placed": int(reg.sum()),
                       "rot_deg": e.rotation_deg if e else None, "trans_mm": e.translation_mm if e else None,
                       "time_s": dt, "geometric_edges": _geo_edges(res)}  # fmt: skip
                emit(row)
                err = f"{e.rotation_deg:.2f} / {e.translation_mm:.1f}" if e else "-"
                log(f"| {scene} | {n} | {seed} | {reg.sum()}/{n} | {err} | {len(row['geometric_edges'])} | {dt:.1f} |")


def hocap(shared: Path, emit: Callable[[dict], None], log: Callable[[str], None]) -> None:
    """hocap-8rs (under ``shared``): the backbone alone, each camera against the reference."""
    frame, rig, T_ref = load_hocap(shared / "hocap-8rs")
    t0 = time.perf_counter()
    res = rgbd_backbone([frame], rig, RGBDConfig())
    dt = time.perf_counter() - t0
    ids = list(rig.ids)
    T = res.T_cam_world
    per = {}
    for k in range(len(ids)):
        if not res.registered[k]:
            continue
        e = [relative_error(T[j] @ invert_rigid(T[k]), T_ref[j] @ invert_rigid(T_ref[k]))
             for j in range(len(ids)) if j != k and res.registered[j]]  # fmt: skip
        per[ids[k]] = [float(np.mean([x[0] for x in e])), float(np.mean([x[1] for x in e]) * 1000)]
    row = {"data": "hocap-8rs", "placed": int(res.registered.sum()), "time_s": dt,
           "time_geometric_s": res.info["time_s"]["geometric"], "per_camera_deg_mm": per,
           "geometric_edges": _geo_edges(res)}  # fmt: skip
    emit(row)
    log(f"hocap-8rs: {row['placed']}/8 placed in {dt:.1f} s (geometry route {row['time_geometric_s']:.1f} s); "
          f"per camera vs reference (deg, mm): {json.dumps({c: [round(v, 2) for v in x] for c, x in per.items()})}")  # fmt: skip
