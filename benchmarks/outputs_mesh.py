"""Per-frame meshes (``--mesh``): time and accuracy of TSDF, screened Poisson and ball pivoting: a
thin wrapper around ``benchmarks.studies.outputs.mesh_quality``, whose docstring says what is measured. One JSON line per recording and method; torch
limited to ``--threads`` threads (set OMP_NUM_THREADS for Open3D).

    PYTHONPATH=src python -m benchmarks.outputs_mesh /tmp/i29/ring8rs --threads 2
"""

from __future__ import annotations

import json

from benchmarks import common


def main(argv: list[str] | None = None) -> None:
    ap = common.parser(__doc__.splitlines()[0])
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--methods", default="range,poisson,tsdf,bpa")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args(argv)
    import torch

    from benchmarks.studies.outputs import mesh_quality

    torch.set_num_threads(a.threads)
    rows = []
    for r in a.recordings:
        for row in mesh_quality(r, a.methods.split(","), a.repeats):
            rows.append(row)
            print(json.dumps(row))
    common.save(a, "outputs_mesh", common.command("outputs_mesh", argv), rows)


if __name__ == "__main__":
    main()
