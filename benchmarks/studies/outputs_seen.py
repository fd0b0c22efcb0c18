"""The output frame (``--world``) and the seen crop (``--crop auto``) measured.

    python benchmarks/outputs_world_crop.py keep /tmp/hocap [--calib calib.json]
    python benchmarks/outputs_world_crop.py walls /tmp/studio
    python benchmarks/outputs_world_crop.py stability /tmp/icl26 /tmp/icl30 --frames 0,1,2

* :func:`seen_keep` (any calibrated recording): FUSE frame 0 uncropped; a fused point counts
  as seen by a camera when it lies in that camera's frustum within its depth range and the
  camera's depth at its pixel agrees (``geometry.volume.covisible_points``' test); of the
  points at least two cameras see and that lie more than 2 cm above the floor, the share the
  ``--crop auto`` box keeps.
* :func:`seen_walls` (simulated recordings, ``fuseflow simulate``): FUSE frame 0 with the true
  rig; each fused point labelled by the nearest scene part of the simulator's ground truth
  within 5 cm (wall = backdrop, room wall or ceiling; floor; subject = the rest); the share of
  wall points the box drops and of subject points it keeps.
* :func:`box_motion`: the box ``resolve_outputs`` computes from each of several frames of one
  or more recordings (e.g. virtual rigs of different spacing): the largest distance between a
  corner of one box and the same corner of another, in the first box's output frame.
"""

from __future__ import annotations

import numpy as np

__all__ = ["seen_keep", "seen_walls", "box_motion"]


def _setup(rec_dir: str, calib: str | None, t: int = 0):
    from fuseflow.io import open_recording, read_calibration
    from fuseflow.pipeline.config import OutputOptions
    from fuseflow.pipeline.exports import resolve_outputs

    rec = open_recording(rec_dir)
    cal = read_calibration(calib) if calib else None  # its floors (a GMAC report), as ``run`` reads them
    rig = cal.apply(rec.rig) if cal is not None else rec.rig
    world, volume = resolve_outputs(OutputOptions(crop="auto"), rig, cal, rec[t])
    return rec, rig, world, volume


def seen_keep(rec_dir: str, calib: str | None = None) -> dict:
    """Share of the points >= 2 cameras see above the floor that ``--crop auto`` keeps (module
    docstring), frame 0."""
    from fuseflow.fuse import fuse
    from fuseflow.geometry.volume import seen_count

    rec, rig, world, volume = _setup(rec_dir, calib)
    X = fuse(rec[0], rig).numpy().xyz.astype(np.float64)
    frame = rec.frame(0, numpy=True)
    n = seen_count(X, [np.asarray(frame.depth[i]) if frame.present[i] else None for i in range(len(rig))], rig)
    seen = (n >= 2) & (world.apply(X)[:, 2] > 0.02)
    inside = volume.contains(X)
    return {
        "recording": rec_dir,
        "calib": calib or "rig.json",
        "world": world.name,
        "floor_cameras": (world.floor or {}).get("cameras"),
        "box": volume.to_json(),
        "points": int(len(X)),
        "seen_above_floor": int(seen.sum()),
        "seen_kept": float(inside[seen].mean()) if seen.any() else float("nan"),
        "kept": float(inside.mean()),
    }


def _labels(rec_dir: str, xyz: np.ndarray) -> np.ndarray:
    """0 subject, 1 wall (backdrop, room wall, ceiling), 2 floor, -1 farther than 5 cm from all."""
    import open3d as o3d

    from fuseflow.synth import read_ground_truth
    from fuseflow.synth.scene import build_scene

    cfg = read_ground_truth(rec_dir).config
    scene = build_scene(cfg.scene, cfg.seed, cfg.dynamic, 6)
    tri, _, _, _, pid = scene.triangles_at(0.0)
    names = [p.name for p in scene.parts]
    group = np.array([1 if n.startswith(("backdrop", "wall", "ceiling")) else 2 if n == "floor" else 0 for n in names])
    rs = o3d.t.geometry.RaycastingScene()
    for g in (0, 1, 2):
        v = tri[group[pid] == g].reshape(-1, 3).astype(np.float32)
        f = np.arange(len(v), dtype=np.uint32).reshape(-1, 3)
        if len(v):
            rs.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
    present = [g for g in (0, 1, 2) if (group[pid] == g).any()]
    ans = rs.compute_closest_points(o3d.core.Tensor(xyz.astype(np.float32)))
    lab = np.array(present)[ans["geometry_ids"].numpy().astype(np.int64)]
    lab[np.linalg.norm(ans["points"].numpy() - xyz, axis=1) > 0.05] = -1
    return lab


def seen_walls(rec_dir: str) -> dict:
    """Share of wall points ``--crop auto`` drops and of subject points it keeps (module
    docstring), frame 0 of a simulated recording, true rig."""
    from fuseflow.fuse import fuse
    from fuseflow.synth import read_ground_truth

    rig = read_ground_truth(rec_dir).rig
    rec, _, world, volume = _setup(rec_dir, None)
    rig = rec.rig if rig is None else rig
    X = fuse(rec[0], rig).numpy().xyz.astype(np.float64)
    inside = volume.contains(X)
    lab = _labels(rec_dir, X)
    share = lambda m: float(m.mean()) if m.size else float("nan")  # noqa: E731
    return {
        "recording": rec_dir,
        "world": world.name,
        "box": volume.to_json(),
        "points": int(len(X)),
        "wall_points": int((lab == 1).sum()),
        "wall_dropped": share(~inside[lab == 1]),
        "subject_points": int((lab == 0).sum()),
        "subject_kept": share(inside[lab == 0]),
        "floor_kept": share(inside[lab == 2]),
    }


def box_motion(rec_dirs: list[str], frames: list[int]) -> dict:
    """The largest corner-to-corner distance between the boxes of each (recording, frame) and
    the first one's, metres, in the first one's output frame (module docstring)."""
    boxes = []
    for rec_dir in rec_dirs:
        for t in frames:
            _, _, world, volume = _setup(rec_dir, None, t)
            boxes.append((rec_dir, t, world, volume))
    ref_world = boxes[0][2]
    ref = ref_world.apply(boxes[0][3].corners())
    rows = []
    for rec_dir, t, world, volume in boxes:
        c = ref_world.apply(volume.corners())
        rows.append({"recording": rec_dir, "frame": t, "world": world.name,
                     "corner_move_m": float(np.linalg.norm(c - ref, axis=1).max()),
                     "size_m": np.round(volume.hi - volume.lo, 3).tolist()})  # fmt: skip
    return {"boxes": rows, "max_corner_move_m": max(r["corner_move_m"] for r in rows)}
