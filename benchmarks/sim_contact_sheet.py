"""Contact sheet of one simulated frame: the 8 colour views above the 8 depth views.

python -m benchmarks.sim_contact_sheet --scene studio --out docs/img/sim_contact_sheet.png
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from fuseflow.synth import SimConfig, Simulator


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scene", default="studio")
    ap.add_argument("--dynamic", action="store_true")
    ap.add_argument("--cameras", type=int, default=8)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", default="kinect")
    ap.add_argument("--thumb", type=int, default=240, help="thumbnail width in pixels")
    ap.add_argument("--out", default="docs/img/sim_contact_sheet.png")
    a = ap.parse_args(argv)
    cfg = SimConfig(cameras=a.cameras, frames=a.frame + 1, scene=a.scene, dynamic=a.dynamic, seed=a.seed, noise=a.noise)
    sf = Simulator(cfg).render(a.frame)
    color = sf.frame.color.numpy()
    depth = sf.frame.depth.numpy()
    tw = a.thumb
    th = tw * color.shape[1] // color.shape[2]
    zmax = cfg.sensor.depth_range[1]
    cols, deps = [], []
    for c, d in zip(color, depth):
        cols.append(cv2.resize(c, (tw, th), interpolation=cv2.INTER_AREA))
        dm = cv2.applyColorMap((np.clip(d / zmax, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)[..., ::-1].copy()
        dm[d == 0] = 0
        deps.append(cv2.resize(dm, (tw, th), interpolation=cv2.INTER_NEAREST))
    per_row = 4
    rows = []
    for k in range(0, len(cols), per_row):
        pad = per_row - len(cols[k : k + per_row])
        blank = [np.zeros_like(cols[0])] * pad
        rows.append(np.concatenate(cols[k : k + per_row] + blank, 1))
    for k in range(0, len(deps), per_row):
        pad = per_row - len(deps[k : k + per_row])
        blank = [np.zeros_like(deps[0])] * pad
        rows.append(np.concatenate(deps[k : k + per_row] + blank, 1))
    sheet = np.concatenate(rows, 0)
    cv2.imwrite(a.out, sheet[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(
        f"wrote {a.out} {sheet.shape[1]}x{sheet.shape[0]}: top {len(cols)} colour, bottom depth (0-{zmax:g} m, black = none)"
    )


if __name__ == "__main__":
    main()
