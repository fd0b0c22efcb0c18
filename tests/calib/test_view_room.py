"""A repeating room seen in one camera's own view (calib.symmetry, section 6: ``view_room``,
``views_room``), and the joint choice in groups of cameras that no pair links."""

from __future__ import annotations

import math

import numpy as np

from fuseflow.calib.symmetry import Hypothesis, view_room, views_room
from fuseflow.synth.rigs import look_at
from fuseflow.types import invert_rigid

CENTRE = np.array([0.3, -0.2, 0.0])  # the room's axis: vertical through here (world)
RADIUS, HEIGHT, CELL = 4.0, 2.6, 0.1


def _room(sides: int, repeat: bool, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """World points (every 4 cm) and colours of a regular ``sides``-gon room's walls and floor:
    every panel carries the same texture of 10-cm cells (``repeat``) or its own."""
    rng = np.random.default_rng(seed)
    width = 2 * RADIUS * math.sin(math.pi / sides)
    cells = (int(width / CELL) + 1, int(HEIGHT / CELL) + 1)
    shared = rng.uniform(20, 235, (*cells, 3))
    pts, cols = [], []
    u, h = np.meshgrid(np.arange(0, width, 0.04), np.arange(0, HEIGHT, 0.04), indexing="ij")
    u, h = u.ravel(), h.ravel()
    for k in range(sides):
        a, b = (2 * math.pi * k / sides, 2 * math.pi * (k + 1) / sides)
        p0 = CENTRE[:2] + RADIUS * np.array([math.cos(a), math.sin(a)])
        p1 = CENTRE[:2] + RADIUS * np.array([math.cos(b), math.sin(b)])
        xy = p0 + np.outer(u / width, p1 - p0)
        pts.append(np.c_[xy, h])
        tex = shared if repeat else rng.uniform(20, 235, (*cells, 3))
        cols.append(tex[(u / CELL).astype(int), (h / CELL).astype(int)])
    g = np.arange(-RADIUS, RADIUS, 0.04)
    fx, fy = np.meshgrid(g, g)
    floor = np.c_[fx.ravel() + CENTRE[0], fy.ravel() + CENTRE[1], np.zeros(fx.size)]
    floor = floor[np.linalg.norm(floor[:, :2] - CENTRE[:2], axis=1) < RADIUS * math.cos(math.pi / sides)]
    pts.append(floor)
    cols.append(np.full((len(floor), 3), 120.0))
    return np.concatenate(pts), np.concatenate(cols)


def _camera(angle_deg: float) -> np.ndarray:
    a = math.radians(angle_deg)
    return look_at(CENTRE + [2.8 * math.cos(a), 2.8 * math.sin(a), 1.3], CENTRE + [0, 0, 1.0])


def _view(T: np.ndarray, world: np.ndarray, cols: np.ndarray):
    """(points, colours scaled to a mean of 128, up) of what camera T (camera-from-world) sees
    within 35 deg of its axis (the room is convex: nothing hides a wall from inside)."""
    X = world @ T[:3, :3].T + T[:3, 3]
    z = X[:, 2]
    seen = (z > 0.3) & (np.abs(X[:, 0]) < 0.7 * z) & (np.abs(X[:, 1]) < 0.55 * z)
    c = cols[seen]
    return X[seen], c / c.mean(axis=0) * 128.0, T[:3, :3] @ np.array([0.0, 0.0, 1.0])


def _axis_error(T: np.ndarray, point: np.ndarray) -> float:
    """Horizontal distance (metres) of a camera-frame axis point from the room's axis."""
    w = invert_rigid(T)[:3, :3] @ point + invert_rigid(T)[:3, 3]
    return float(np.linalg.norm(w[:2] - CENTRE[:2]))


def test_one_view_shows_the_rooms_period_and_axis():
    for sides, angle in ((10, 25.0), (6, 200.0)):
        world, cols = _room(sides, repeat=True, seed=sides)
        T = _camera(angle)
        vr = view_room(*_view(T, world, cols))
        assert vr is not None and vr.sides == sides, (sides, vr)
        assert _axis_error(T, vr.point) < 0.03
        assert vr.contrast > 1.8


def test_panels_that_do_not_repeat_show_no_room():
    world, cols = _room(10, repeat=False, seed=3)
    assert view_room(*_view(_camera(25.0), world, cols)) is None


def test_two_views_agree_and_a_verified_pose_carries_the_axis_to_a_view_without_one():
    world, cols = _room(8, repeat=True, seed=8)
    T = [_camera(a) for a in (20.0, 120.0, 250.0)]
    views = [_view(T[0], world, cols), _view(T[1], world, cols), None]
    poses = {(1, 2): [T[2] @ invert_rigid(T[1])]}
    room = views_room(views, poses)
    assert room is not None and room.sides == 8 and room.views == 2
    assert set(room.axes) == {0, 1, 2}
    for k in range(3):
        assert _axis_error(T[k], room.axes[k][1]) < 0.03
    assert views_room([views[0], None, None], poses) is None  # one view alone is not enough


def test_the_joint_choice_keeps_every_group_of_cameras_that_no_pair_links(monkeypatch):
    from types import SimpleNamespace

    from fuseflow.calib.backbones.rgbd import RGBDConfig, choice
    from fuseflow.calib.backbones.rgbd.choice import hypothesis_groups, joint_choice
    from fuseflow.calib.posegraph import Edge

    monkeypatch.setattr(choice, "_views_agreement", lambda cams, poses, cfg, only=None: 0.9)  # no depth here
    T = [_camera(a) for a in (0.0, 60.0, 180.0, 240.0)]
    pairs = [(0, 1), (2, 3)]
    hyps = {p: [Hypothesis(p[0], p[1], T[p[1]] @ invert_rigid(T[p[0]]), 0.9, None)] for p in pairs}
    none = np.zeros((0, 3))
    edges = {p: Edge(p[0], p[1], hyps[p][0].T_ji, 100.0, none, none, np.zeros(0)) for p in pairs}
    info = [{"pair": list(p), "edge": {"route": "sift4"}} for p in pairs]
    cams = [SimpleNamespace() for _ in T]
    assert hypothesis_groups(hyps) == [{0, 1}, {2, 3}]
    out, sel, ambiguous = joint_choice(cams, edges, hyps, info, ["a", "b", "c", "d"], RGBDConfig())
    assert set(out) == {(0, 1), (2, 3)} and not ambiguous
    assert all(e["edge"] for e in info) and len(sel["groups"]) == 2


def test_a_room_that_few_pairs_show_yields_to_the_period_every_view_reads(monkeypatch):
    from types import SimpleNamespace

    from fuseflow.calib.backbones.rgbd import pairs
    from fuseflow.calib.symmetry import RoomOrbits

    world, cols = _room(6, repeat=True, seed=6)
    T = [_camera(a) for a in (10.0, 130.0)]
    cams = [SimpleNamespace(k=k) for k in range(2)]
    monkeypatch.setattr(pairs, "room_view", lambda c: _view(T[c.k], world, cols))
    poses = {(0, 1): [T[1] @ invert_rigid(T[0])]}
    weak = RoomOrbits(9, {}, 4, 2)  # two pairs' turns, one pose 18 deg off: 9 sides
    checked = pairs.views_check(weak, cams, poses)
    assert checked.sides == 6 and checked.views == 2
    assert pairs.views_check(RoomOrbits(9, {}, 6, 3), cams, poses).sides == 9  # three pairs stand
