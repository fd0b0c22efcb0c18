#!/usr/bin/env python
"""Where is the surface FUSE misses (completeness)? One static 8-camera studio frame
(640x480, seed 11, the seen surface of fuseflow.eval.reference): the GT samples farther than 2 cm from the
cloud, split by distance to the nearest camera centre and by height (floor / above), for FUSE
and four variants; "share of completeness sum" says which band the mean distance comes from.

    python benchmarks/investigations/fuse_completeness_bands.py > benchmarks/results/0.1.0/fuse_completeness_bands.txt
"""

import warnings

warnings.simplefilter("ignore", RuntimeWarning)

import numpy as np  # noqa: E402
from benchmarks.studies.fuse_ablations import seen_reference  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from fuseflow.eval.baselines import naive_fusion  # noqa: E402
from fuseflow.fuse import ABLATIONS, FuseConfig, fuse  # noqa: E402
from fuseflow.synth import SimConfig, Simulator  # noqa: E402

sim = Simulator(SimConfig(cameras=8, frames=1, scene="studio", resolution=(640, 480), seed=11))
sf = sim.render(0)
rig = sim.rig
gt = seen_reference(sf, sim).samples
C = np.stack([np.linalg.inv(c.T_cam_world)[:3, 3] for c in rig.cameras])
dcam = cKDTree(C).query(gt)[0]  # distance of each GT sample to the nearest camera centre
naive = naive_fusion(sf.frame, rig).xyz.numpy()
dn = cKDTree(naive).query(gt)[0]
variants = {
    "FUSE": FuseConfig(),
    "w/o MCM": ABLATIONS["w/o MCM"],
    "lone_cell_mean=0": FuseConfig().replace(rps={"lone_cell_mean": 0.0}),
    "w/o CVGC": ABLATIONS["w/o CVGC"],
    "visibility_aware=False": FuseConfig().replace(cvgc={"visibility_aware": False}),
}
print("GT samples", len(gt), "z (height) range", gt[:, 2].min().round(2), gt[:, 2].max().round(2))
bands = [(0, 2), (2, 3), (3, 4), (4, 9)]
for name, cfg in variants.items():
    pts = fuse(sf.frame, rig, cfg).xyz.numpy()
    d = cKDTree(pts).query(gt)[0]
    comp = d.mean() * 1000
    miss = d > 0.02
    print(
        f"{name}: points {len(pts)}, completeness {comp:.1f} mm, missing(>2cm) {miss.mean():.1%}, naive covers {((dn < 0.01) & miss).sum() / max(miss.sum(), 1):.0%} of them"
    )
    for lo, hi in bands:
        m = (dcam >= lo) & (dcam < hi)
        print(
            f"   cam dist {lo}-{hi} m: {m.mean():.0%} of GT, missing {miss[m].mean():.1%}, share of completeness sum {d[m].sum() / d.sum():.0%}"
        )
    for lo, hi, lab in [(-1, 0.05, "floor"), (0.05, 2.0, "objects/person/walls<2m"), (2.0, 9, "above 2 m")]:
        m = (gt[:, 2] >= lo) & (gt[:, 2] < hi)
        print(
            f"   height {lab}: {m.mean():.0%} of GT, missing {miss[m].mean():.1%}, share of completeness sum {d[m].sum() / d.sum():.0%}, mean dist of missing {d[m & miss].mean() * 1000 if (m & miss).any() else 0:.0f} mm"
        )
