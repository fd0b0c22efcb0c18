#!/usr/bin/env python
"""Why MCM drops the far floor (completeness): on one static 8-camera studio frame
(640x480, seed 11), the floor pixels of every camera by range, the share whose 3x3 window is
incomplete (a neighbour without depth after range gating: c = 0 by docs/design.md, "a neighbour
with no depth makes the pixel an edge pixel") and the share with a complete window but c <= r_c.

    python benchmarks/investigations/fuse_mcm_floor.py > benchmarks/results/0.1.0/fuse_mcm_floor.txt
"""

import numpy as np
import torch

from fuseflow.fuse import FuseConfig
from fuseflow.fuse.mcm import confidence, gradient_and_variance
from fuseflow.synth import SimConfig, Simulator

sim = Simulator(SimConfig(cameras=8, frames=1, scene="studio", resolution=(640, 480), seed=11))
sf = sim.render(0)
rig = sim.rig
f = sf.frame
cfg = FuseConfig()
D = f.depth.clone()
for i, cam in enumerate(rig.cameras):
    lo, hi = cam.depth_range
    D[i] = torch.where((D[i] > lo) & (D[i] < hi), D[i], torch.zeros_like(D[i]))
g, v, full = gradient_and_variance(D)
c = confidence(D, cfg.mcm.alpha, cfg.mcm.beta)
K = rig.K().numpy()
print("depth ranges", set(c_.depth_range for c_ in rig.cameras), "r_c", cfg.rps.r_c)
for lo_r, hi_r in [(0, 2.5), (2.5, 3.5), (3.5, 4.5), (4.5, 9)]:
    tot = full_n = low = valid = 0
    for i, cam in enumerate(rig.cameras):
        z = D[i].numpy()
        h, w = z.shape
        vv, uu = np.mgrid[0:h, 0:w]
        X = np.stack([(uu - K[i, 0, 2]) / K[i, 0, 0] * z, (vv - K[i, 1, 2]) / K[i, 1, 1] * z, z], -1).reshape(-1, 3)
        W = np.linalg.inv(cam.T_cam_world)
        Xw = X @ W[:3, :3].T + W[:3, 3]
        floor = (Xw[:, 2] < 0.03).reshape(h, w) & (z > 0)
        zf = z
        band = floor & (zf >= lo_r) & (zf < hi_r)
        valid += band.sum()
        full_n += (band & full[i].numpy()).sum()
        low += (band & full[i].numpy() & (c[i].numpy() <= cfg.rps.r_c)).sum()
    print(
        f"floor pixels at {lo_r}-{hi_r} m: {valid}, window incomplete {1 - full_n / max(valid, 1):.1%}, complete but c<=r_c {low / max(full_n, 1):.1%}"
    )
# raw dropout: share of pixels without depth among floor-ish GT
