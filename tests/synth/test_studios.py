"""The scenes that break calibration (synth.studios): the symmetric studio repeats exactly, its
rigs have one or two rings, the far room's person walks and its walls are plain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fuseflow.synth import SimConfig, Simulator
from fuseflow.synth.rigs import camera_centres, make_rig
from fuseflow.synth.studios import PLAIN_CONTRAST, build_studio, plain_textures, sides_of


def _rz(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_symmetric_studio_repeats_exactly(seed):
    scene = build_studio("symstudio", seed, n_textures=6)
    n = sides_of(seed)
    assert 8 <= n <= 12 and scene.symmetry == n
    for kind in ("panel", "floor", "ceiling", "column"):
        parts = [p for p in scene.parts if p.name.rstrip("0123456789") == kind]
        assert len(parts) == n, kind
        first = parts[0]
        for k, p in enumerate(parts):
            # same mesh, texture, texture offset and tint; pose = the first one's turned k/n of a turn
            assert p.texture == first.texture and np.array_equal(p.tint, first.tint)
            assert np.array_equal(p.uv_offset, first.uv_offset) and np.array_equal(p.mesh.uv, first.mesh.uv)
            np.testing.assert_allclose(p.pose(0.0), _rz(2 * math.pi * k / n) @ first.pose(0.0), atol=1e-12)
    # the figure at the centre is what breaks the symmetry: parts of other names, off the axis
    assert any(p.name.startswith("figure.") for p in scene.parts)


@pytest.mark.parametrize("layout, heights", [("ring", 1), ("dome", 2)])
def test_symmetric_studio_rigs(layout, heights):
    scene = build_studio("symstudio", 3, n_textures=6)
    rig = make_rig(layout, 7, 64, 48, 70.0, 1000.0, (0.5, 4.5), scene, np.random.default_rng(0))
    C = camera_centres(rig)
    assert len(C) == 7
    assert len(np.unique(np.round(C[:, 2], 0))) == heights  # one or two ring heights (+-5 cm jitter)
    d = np.linalg.norm(C[:, None] - C[None], axis=2) + np.eye(7) * 9
    assert d.min() > 0.5  # no two cameras together


def test_far_room_person_walks_and_walls_are_plain():
    cfg = SimConfig(cameras=3, frames=3, scene="farroom", resolution=(64, 48), noise="kinect2", fps=2.0, seed=1)
    sim = Simulator(cfg)
    C = camera_centres(sim.rig)
    r = np.linalg.norm(C[:, :2], axis=1)
    assert np.all(np.abs(r - 3.6) < 0.1)
    ang = np.sort(np.degrees(np.arctan2(C[:, 1], C[:, 0])) % 360)
    np.testing.assert_allclose(np.diff(ang), 120.0, atol=3.0)
    person = [p for p in sim.scene.parts if p.name == "person.torso"][0]
    assert person.moving
    assert np.linalg.norm(person.pose(1.0)[:3, 3] - person.pose(0.0)[:3, 3]) > 0.5  # 1 m/s
    walls = [p for p in sim.scene.parts if p.name.startswith("wall")]
    assert walls and all(p.texture >= 6 for p in walls)  # the plain textures after the 6 normal ones
    plain = plain_textures(sim.textures[:6]).astype(float)
    assert plain.std() < 2 * PLAIN_CONTRAST * sim.textures[:2].astype(float).std()
    sf = sim.render(1)
    assert sf.frame.depth.shape == (3, 48, 64) and float((sf.frame.depth > 0).float().mean()) > 0.1


def test_symmetric_studio_figure_moves_only_when_dynamic():
    """With ``dynamic`` the figure turns and steps from frame to frame (the rest of the room and
    its props stay); frame 0 and the still scene render the same images."""
    cfg = dict(cameras=2, frames=3, scene="symstudio", rig="ring", resolution=(64, 48), noise="none", seed=5)
    still, moving = Simulator(SimConfig(**cfg)), Simulator(SimConfig(**cfg, dynamic=True))
    names = {p.name for p in moving.scene.parts if p.moving}
    assert names and all(n.startswith("figure.") for n in names)
    assert not any(p.moving for p in still.scene.parts)
    s0, m0, s2, m2 = (sim.render(t).frame for sim, t in ((still, 0), (moving, 0), (still, 2), (moving, 2)))
    assert np.array_equal(s0.depth.numpy(), m0.depth.numpy()) and np.array_equal(s0.color.numpy(), m0.color.numpy())
    assert np.array_equal(s0.depth.numpy(), s2.depth.numpy())
    changed = np.abs(m2.depth.numpy() - s2.depth.numpy()) > 0.01
    assert 0 < changed.mean() < 0.2  # the figure, not the room
    torso = [p for p in moving.scene.parts if p.name == "figure.torso"][0]
    step = np.linalg.norm(torso.pose(2 / 30.0)[:3, 3] - torso.pose(0.0)[:3, 3])
    assert 0.05 < step < 0.5
