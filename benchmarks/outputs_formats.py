"""Cloud file sizes and Draco position error against binary PLY (``--format ply|drc|glb``).

For frame 0 of each recording (fused with its rig.json extrinsics, default preset), whole and
cropped to the capture volume: bytes of each format as ``fuseflow.io.exchange.write_cloud``
writes it, the ratio to binary PLY, the Draco position error per point (max and median, mm; the
file keeps the point order, so point k decodes to point k) and the CPU time of the Draco write.

    PYTHONPATH=src python benchmarks/outputs_formats.py /tmp/i29/ring8rs640 --error-mm 1
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def measure(rec_dir: str, error_mm: float) -> list[dict]:
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--error-mm", type=float, default=1.0)
    a = ap.parse_args()
    for r in a.recordings:
        for row in measure(r, a.error_mm):
            print(json.dumps(row))


if __name__ == "__main__":
    main()
