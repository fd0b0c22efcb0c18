"""The output options measured: ``--crop auto``, ``--format ply|drc|glb`` and ``--mesh``.

    python -m benchmarks.outputs_crop /tmp/ring8rs640 /tmp/ring8rs
    python -m benchmarks.outputs_formats /tmp/ring8rs640 /tmp/hocap --error-mm 1
    python -m benchmarks.outputs_mesh /tmp/ring8rs640 --repeats 2 --threads 2

* :func:`crop_quality` (simulated recordings, ``fuseflow simulate``): fuse frame 0 with the true
  rig, label every fused point by the nearest scene part of the simulator's ground truth (Open3D
  closest point; "subject" = every part but floor, backdrop walls, room walls and ceiling; a
  point counts as near a group when within 5 cm of it), and report the share of subject points
  the capture volume keeps and the share of wall points it drops.
* :func:`format_sizes` (any recording with rig.json extrinsics): frame 0, default preset, whole
  and cropped to the capture volume: bytes of each format as ``fuseflow.io.exchange.write_cloud``
  writes it, the ratio to binary PLY, the Draco position error per point (max and median, mm;
  the file keeps the point order, so point k decodes to point k) and the CPU time of the writes.
* :func:`mesh_quality` (simulated recordings): FUSE with the true rig, crop to the capture
  volume, mesh with each method (``fuseflow.pipeline.mesh``), sample the mesh surface (50 000
  points, Open3D ``sample_points_uniformly``) and report the median / 90th percentile distance
  of the samples to the simulator's true surface and to the fused points, the vertex and face
  counts, and the wall and CPU time (all threads) of the meshing (normals included): on a shared
  machine the CPU time is the steadier figure.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["crop_quality", "format_sizes", "mesh_quality"]


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


def crop_quality(rec_dir: str) -> dict:
    """How well ``--crop auto`` keeps the subject and drops the studio on frame 0 of a simulated
    recording (module docstring)."""
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


def format_sizes(rec_dir: str, error_mm: float = 1.0) -> list[dict]:
    """Bytes of each cloud format, Draco's position error and write CPU time on frame 0, whole
    and cropped (module docstring)."""
    import DracoPy

    from fuseflow.fuse import fuse
    from fuseflow.geometry.volume import capture_volume, crop_cloud
    from fuseflow.io import open_recording
    from fuseflow.io.exchange import draco_bits, write_cloud

    rec = open_recording(rec_dir)
    whole = fuse(rec[0], rec.rig)
    rows = []
    for name, cloud in (("whole", whole), ("crop auto", crop_cloud(whole, capture_volume(rec.rig)))):
        xyz = cloud.xyz.numpy()
        sizes, cpu = {}, {}
        with tempfile.TemporaryDirectory() as tmp:
            for fmt in ("ply", "drc", "glb"):
                c0 = time.process_time()
                sizes[fmt] = write_cloud(Path(tmp) / f"c.{fmt}", cloud, fmt, error_mm).stat().st_size
                cpu[fmt] = time.process_time() - c0
            decoded = np.asarray(DracoPy.decode((Path(tmp) / "c.drc").read_bytes()).points)
        bits = draco_bits(float((xyz.max(0) - xyz.min(0)).max()), error_mm)
        err = np.linalg.norm(decoded - xyz, axis=1) * 1000
        rows.append({
            "recording": rec_dir, "cloud": name, "points": len(xyz), "bits": bits,
            "ply_bytes": sizes["ply"], "drc_bytes": sizes["drc"], "glb_bytes": sizes["glb"],
            "ply_over_drc": round(sizes["ply"] / sizes["drc"], 2), "ply_over_glb": round(sizes["ply"] / sizes["glb"], 2),
            "drc_err_max_mm": round(float(err.max()), 3), "drc_err_median_mm": round(float(np.median(err)), 3),
            "drc_write_cpu_s": round(cpu["drc"], 3), "ply_write_cpu_s": round(cpu["ply"], 3),
        })  # fmt: skip
    return rows


def mesh_quality(rec_dir: str, methods: list[str], repeats: int = 3) -> list[dict]:
    """Time and accuracy of each meshing method on frame 0 of a simulated recording (module
    docstring)."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    from fuseflow.fuse import fuse
    from fuseflow.geometry.volume import capture_volume, crop_cloud
    from fuseflow.io import open_recording
    from fuseflow.pipeline.mesh import mesh_frame
    from fuseflow.synth import read_ground_truth

    rec = open_recording(rec_dir)
    gt = read_ground_truth(rec_dir)
    frame = rec[0]
    vol = capture_volume(gt.rig)
    cloud = crop_cloud(fuse(frame, gt.rig), vol)
    surf, _ = gt.surface(0)
    surf = surf[vol.contains(surf)]
    gt_tree, cloud_tree = cKDTree(surf), cKDTree(cloud.xyz.numpy())
    rows = []
    for method in methods:
        times, cpu = [], []
        for _ in range(repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            mesh = mesh_frame(cloud, frame, gt.rig, method, vol)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices.astype(np.float64)),
                                      o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))  # fmt: skip
        pts = np.asarray(m.sample_points_uniformly(50000).points) if len(mesh.faces) else np.zeros((0, 3))
        d_gt, d_cloud = gt_tree.query(pts)[0] * 1000, cloud_tree.query(pts)[0] * 1000
        rows.append({
            "recording": rec_dir, "method": method, "points": len(cloud), "vertices": len(mesh.vertices),
            "faces": len(mesh.faces), "s_median": round(float(np.median(times)), 3), "s_min": round(min(times), 3),
            "cpu_s_median": round(float(np.median(cpu)), 3),
            "gt_median_mm": round(float(np.median(d_gt)), 2), "gt_p90_mm": round(float(np.percentile(d_gt, 90)), 2),
            "cloud_median_mm": round(float(np.median(d_cloud)), 2),
            "cloud_p90_mm": round(float(np.percentile(d_cloud, 90)), 2),
        })  # fmt: skip
    return rows
