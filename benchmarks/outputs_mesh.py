"""Per-frame meshes (``--mesh``): time and accuracy of TSDF, screened Poisson and ball pivoting: a
thin wrapper around ``fuseflow.eval.bench.outputs.mesh_quality`` (also ``fuseflow bench outputs
mesh``), whose docstring says what is measured. One JSON line per recording and method; torch
limited to ``--threads`` threads (set OMP_NUM_THREADS for Open3D).

    PYTHONPATH=src python benchmarks/outputs_mesh.py /tmp/i29/ring8rs --threads 2
"""

from __future__ import annotations

import argparse
import json


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--methods", default="tsdf,poisson,bpa")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    import torch

    from fuseflow.eval.bench.outputs import mesh_quality

    torch.set_num_threads(a.threads)
    for r in a.recordings:
        for row in mesh_quality(r, a.methods.split(","), a.repeats):
            print(json.dumps(row))


if __name__ == "__main__":
    main()
