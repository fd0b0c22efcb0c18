"""How well the automatic capture volume (``--crop auto``) keeps the subject and drops the studio.

For each simulated recording (``fuseflow simulate``): fuse frame 0 with the true rig, label
every fused point by the nearest scene part of the simulator's ground truth (Open3D closest
point; "subject" = every part but floor, backdrop walls, room walls and ceiling; a point counts
as near a group when within 5 cm of it), and report the share of subject points the capture
volume keeps and the share of wall points it drops.

    PYTHONPATH=src python benchmarks/outputs_crop.py /tmp/i29/ring8 /tmp/i29/dome24
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def _labels(rec_dir: str, xyz: np.ndarray, t: int = 0) -> np.ndarray:
    """0 subject, 1 wall (backdrop, room wall, ceiling), 2 floor, -1 farther than 5 cm from all."""
    import open3d as o3d

    from fuseflow.synth import read_ground_truth
    from fuseflow.synth.scene import build_scene

    gt = read_ground_truth(rec_dir)
    cfg = gt.config
    scene = build_scene(cfg.scene, cfg.seed, cfg.dynamic, 6)  # make_textures' default count, as the simulator
    tri, _, _, _, pid = scene.triangles_at(t / cfg.fps)
    names = [p.name for p in scene.parts]
    group = np.array([1 if n.startswith(("backdrop", "wall", "ceiling")) else 2 if n == "floor" else 0 for n in names])
    rs = o3d.t.geometry.RaycastingScene()
    ids = []
    for g in (0, 1, 2):
        sel = tri[group[pid] == g]
        if len(sel) == 0:
            ids.append(-1)
            continue
        v = sel.reshape(-1, 3)
        f = np.arange(len(v), dtype=np.uint32).reshape(-1, 3)
        ids.append(rs.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f)))
    q = o3d.core.Tensor(xyz.astype(np.float32))
    ans = rs.compute_closest_points(q)
    d = np.linalg.norm(ans["points"].numpy() - xyz, axis=1)
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    lab = np.array([ids.index(g) if g in ids else -1 for g in gid])
    lab[d > 0.05] = -1
    return lab


def measure(rec_dir: str) -> dict:
    from fuseflow.fuse import fuse
    from fuseflow.geometry.volume import capture_volume
    from fuseflow.io import open_recording
    from fuseflow.synth import read_ground_truth

    rec = open_recording(rec_dir)
    rig = read_ground_truth(rec_dir).rig
    xyz = fuse(rec[0], rig).xyz.numpy()
    vol = capture_volume(rig)
    inside = vol.contains(xyz)
    lab = _labels(rec_dir, xyz)
    share = lambda m: float(m.mean()) if m.size else float("nan")  # noqa: E731
    return {
        "recording": rec_dir,
        "cameras": len(rig),
        "kind": vol.kind,
        "box": vol.to_json(),
        "points": int(len(xyz)),
        "kept": share(inside),
        "subject_points": int((lab == 0).sum()),
        "subject_kept": share(inside[lab == 0]),
        "wall_points": int((lab == 1).sum()),
        "wall_dropped": share(~inside[lab == 1]),
        "floor_kept": share(inside[lab == 2]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    for r in ap.parse_args().recordings:
        m = measure(r)
        print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in m.items()}))


if __name__ == "__main__":
    main()
