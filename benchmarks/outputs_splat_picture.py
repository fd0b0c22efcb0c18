"""A picture of one frame's Gaussian splats (``--format splat``), rendered by FuseFlow's own splat
renderer (``fuseflow.viz.splat_render``, numpy, headless). The picture in docs/formats.md:

    fuseflow convert ../shared/data/hocap-8rs /tmp/hocap --with-extrinsics
    fuseflow fuse /tmp/hocap --out /tmp/hocap-out --format ply,splat --crop auto --points 100000
    python -m benchmarks.outputs_splat_picture /tmp/hocap-out/splats/000000.ply \\
        docs/img/hocap-splats.png --azimuth 200 --elevation 30
"""

from __future__ import annotations

import argparse
import time

from fuseflow.viz import save_splat_png


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("splats", help="a splat PLY (OUT/splats/<frame>.ply)")
    ap.add_argument("png")
    ap.add_argument("--azimuth", type=float, default=35.0)
    ap.add_argument("--elevation", type=float, default=25.0)
    ap.add_argument("--size", default="960x720")
    a = ap.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    t0 = time.process_time()
    save_splat_png(a.splats, a.png, w, h, a.azimuth, a.elevation)
    print(f"wrote {a.png} ({time.process_time() - t0:.1f} CPU s)")


if __name__ == "__main__":
    main()
