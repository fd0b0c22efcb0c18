"""The walking figure (fuseflow.synth.person): ground-truth landmarks consistent with the
rendered body, a walk that moves, every view sees the person."""

from __future__ import annotations

import numpy as np

from fuseflow.synth.person import LANDMARK_NAMES, Walk, person_joints, person_parts, walking_person_sim


def _j(name: str) -> int:
    return LANDMARK_NAMES.index(name)


def test_landmarks_are_human_and_walk():
    walk = Walk(start=(-1.0, 0.0), end=(1.0, 0.0), speed=1.0)
    J0, J1 = person_joints(walk, 0.0), person_joints(walk, 0.5)
    assert J0.shape == (33, 3)
    assert 1.55 < J0[_j("nose"), 2] < 1.75  # head height of a 1.75 m adult
    assert abs(J0[_j("left_ankle"), 2] - 0.1) < 0.1 and abs(J0[_j("right_ankle"), 2] - 0.1) < 0.1
    assert J0[_j("left_shoulder"), 1] > J0[_j("right_shoulder"), 1]  # facing +x: left is +y
    assert J0[_j("nose"), 0] > J0[_j("left_ear"), 0]  # nose in front of the ears
    np.testing.assert_allclose(J1[:, 0].mean() - J0[:, 0].mean(), 0.5, atol=0.05)  # 1 m/s for 0.5 s
    # the legs swing: the two ankles are apart along the walk at some instant
    gaps = [
        abs(np.diff(person_joints(walk, t)[[_j("left_ankle"), _j("right_ankle")], 0])[0]) for t in np.linspace(0, 1, 9)
    ]
    assert max(gaps) > 0.3
    # turns back at the end of its path
    assert person_joints(walk, 2.5)[:, 0].mean() < person_joints(walk, 2.0)[:, 0].mean()
    assert len(person_parts(walk)) > 20


def test_rendered_body_is_where_the_landmarks_are():
    sim, walk = walking_person_sim(
        0, cameras=3, frames=2, resolution=(256, 212)
    )  # seed 0: textures shared with other tests
    sf = sim.render(1)
    J = person_joints(walk, 1 / sim.cfg.fps)
    person = {k for k, p in enumerate(sim.scene.parts) if p.name.startswith("person.")}
    part = sf.part_id.numpy()
    inner = [_j(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip", "nose")]
    hits = total = 0
    for k, cam in enumerate(sim.rig.cameras):
        assert np.isin(part[k], list(person)).sum() > 200  # every view sees the person
        Xc = J[inner] @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
        uv = np.rint(Xc[:, :2] / Xc[:, 2:] * np.diag(cam.K)[:2] + cam.K[:2, 2]).astype(int)
        for u, v in uv:
            total += 1
            hits += int(part[k, v, u] in person)
    assert hits >= 0.8 * total, (hits, total)
