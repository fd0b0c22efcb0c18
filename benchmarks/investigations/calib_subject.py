"""The moving-subject route's pair poses alone (calib.subject, docs/gmac-trust.md "Moving-subject route").

    python benchmarks/investigations/calib_subject.py far3 0 1 2 3 4 5
    python benchmarks/investigations/calib_subject.py person 0 1 2

``far3``: the bench's far-range rig (``--scene farroom``, 10 frames at 5 fps, Kinect v2 noise);
``person``: the articulated figure of ``synth.person.walking_person_sim`` (head with hair, face,
ears; 11 frames at 3 fps, ``noise='kinect2'``). Floor planes are fitted to each camera's
per-pixel median depth as the rgbd backbone does; per pair: the track pose's error against the
simulator's truth, its inlier frames and ``expected_m``; per camera the fitted head radius.
"""

from __future__ import annotations

import sys
import warnings

import numpy as np

from fuseflow.calib.backbones.rgbd import relative_error
from fuseflow.calib.floor import fit_floor_plane
from fuseflow.calib.subject import SubjectRoute


def _sim(kind: str, seed: int):
    if kind == "far3":
        from benchmarks.studies.calib_studio import studio_config

        from fuseflow.synth import Simulator

        sim = Simulator(studio_config("far3", seed))
    else:
        from fuseflow.synth.person import walking_person_sim

        sim, _ = walking_person_sim(seed, noise="kinect2")
    return sim, [sim.render(t).frame for t in range(sim.cfg.frames)]


def _plane(frames, k, K):
    D = np.stack([f.depth[k].numpy() for f in frames]).astype(float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nan_to_num(np.nanmedian(np.where(D > 0, D, np.nan), axis=0))
    v, u = np.nonzero(med > 0)
    z = med[v, u]
    return fit_floor_plane(np.c_[(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z])


def main(kind: str, seeds: list[int]) -> None:
    for seed in seeds:
        sim, frames = _sim(kind, seed)
        cams = sim.rig.cameras
        order = list(range(len(cams)))
        route = SubjectRoute.build(frames, sim.rig, order, [_plane(frames, k, c.K) for k, c in enumerate(cams)])
        print(f"{kind} seed {seed}: {route.info()}")
        for a in order:
            for b in order[a + 1 :]:
                got = route.pair(a, b)
                if not got:
                    print(f"  {cams[a].id}-{cams[b].id}: no pose")
                    continue
                c = got[0]
                r, t = relative_error(c["T_ba"], cams[b].T_cam_world @ np.linalg.inv(cams[a].T_cam_world))
                print(f"  {cams[a].id}-{cams[b].id}: {r:.2f} deg {t * 100:.1f} cm, {c['track_frames']} frames, "
                      f"expected {c['expected_m'] * 100:.1f} cm")  # fmt: skip


if __name__ == "__main__":
    main(sys.argv[1], [int(s) for s in sys.argv[2:]] or [0])
