"""Per-frame meshes (``--mesh``): time and accuracy of TSDF, screened Poisson and ball pivoting.

For frame 0 of each simulated recording: FUSE with the true rig, crop to the capture volume,
mesh with each method (``fuseflow.pipeline.mesh``), sample the mesh surface (50 000 points,
Open3D ``sample_points_uniformly``) and report the median / 90th percentile distance of the
samples to the simulator's true surface (gt/surface_000000.ply) and to the fused points, the
vertex and face counts, and the wall and CPU time (all threads) of the meshing (normals
included): on a shared machine the CPU time is the steadier figure. Torch and Open3D
limited to ``--threads`` threads.

    PYTHONPATH=src python benchmarks/outputs_mesh.py /tmp/i29/ring8rs --threads 2
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def measure(rec_dir: str, methods: list[str], repeats: int) -> list[dict]:
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--methods", default="tsdf,poisson,bpa")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    import torch

    torch.set_num_threads(a.threads)
    for r in a.recordings:
        for row in measure(r, a.methods.split(","), a.repeats):
            print(json.dumps(row))


if __name__ == "__main__":
    main()
