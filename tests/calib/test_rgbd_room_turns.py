"""The rgbd backbone in a repeating room: the room's turns found from pair poses that are all
aliases (none verified), every pair's turned poses verified, and poses that stack two cameras
refused as aliases."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch

from fuseflow.calib.backbones.rgbd import RGBDConfig, rgbd_backbone
from fuseflow.calib.backbones.rgbd.pairs import pair_room, unstacked, upside_down
from fuseflow.calib.symmetry import Hypothesis, turn_about
from fuseflow.synth.rigs import look_at
from fuseflow.types import Rig, invert_rigid

CENTRE = np.array([0.3, -0.2, 0.0])


def _cameras(n: int = 4) -> list[np.ndarray]:
    return [look_at(CENTRE + [2.6 * math.cos(1.1 * k), 2.6 * math.sin(1.1 * k), 1.3], CENTRE + [0, 0, 1])
            for k in range(n)]  # fmt: skip


def _alias(T: list[np.ndarray], i: int, j: int, k: int, sides: int) -> np.ndarray:
    return T[j] @ turn_about(np.array([0.0, 0.0, 1.0]), CENTRE, 360.0 * k / sides) @ invert_rigid(T[i])


def _cam(T: np.ndarray):
    up = T[:3, :3] @ np.array([0.0, 0.0, 1.0])
    samples = torch.tensor([[0.0, 0.0, 2.6]] * 4)
    return SimpleNamespace(plane=SimpleNamespace(normal=up), samples_X=samples, images=())  # no image: no view room


def test_the_room_comes_from_aliases_when_no_pose_is_verified():
    sides, T = 9, _cameras()
    cams = [_cam(Tk) for Tk in T]
    poses = {(i, j): [{"T_ba": _alias(T, i, j, k, sides)} for k in (1, 3)] for i in range(4) for j in range(i + 1, 4)}
    room, unverified = pair_room(cams, [(p, ([], s)) for p, s in poses.items()])
    assert room is not None and room.sides == sides and unverified
    # the orbit of an alias holds the true pose
    members = room.members(0, poses[(0, 1)][0]["T_ba"], [])
    true = T[1] @ invert_rigid(T[0])
    assert min(np.abs(M - true).max() for _, M in members) < 1e-6
    # verified poses come first; none at all: no room
    room_v, unverified_v = pair_room(cams, [(p, (s, s)) for p, s in poses.items()])
    assert room_v is not None and not unverified_v
    assert pair_room(cams, [(p, ([], [])) for p in poses]) == (None, False)


def test_a_pose_that_stacks_two_cameras_is_refused_in_a_repeating_room():
    T = _cameras(2)
    cams = [_cam(Tk) for Tk in T]
    stacked, true = np.eye(4), T[1] @ invert_rigid(T[0])
    stacked[:3, 3] = [0.05, 0.0, 0.0]
    cands = [{"T_ba": stacked}, {"T_ba": true}]
    entry = {"candidates": [{"ok": True}, {"ok": True}]}
    hyps = [Hypothesis(0, 1, c["T_ba"], 1.0, (c, None, cands)) for c in cands]
    kept = unstacked(cams[0], cams[1], hyps, cands, entry, RGBDConfig())
    assert kept == [hyps[1]]
    assert entry["candidates"][0] == {"ok": False, "rejected": "stacked in a repeating room"}
    assert entry["candidates"][1] == {"ok": True}


def test_a_symmetric_studio_at_320x240_is_placed_from_one_frame():
    """symstudio's image poses at 320x240 are all whole-period aliases (no pair verified): the
    room's turns of those aliases give the true poses."""
    from fuseflow.synth import SimConfig, Simulator

    cfg = SimConfig(cameras=5, frames=1, scene="symstudio", rig="ring", resolution=(320, 240), hfov_deg=70.0,
                    noise="kinect2", seed=5000)  # fmt: skip
    sim = Simulator(cfg)
    rig = Rig(tuple(c.with_extrinsics(None) for c in sim.rig.cameras))
    res = rgbd_backbone(sim.render(0).frame, rig)
    assert res.registered.all()
    assert res.info["room"]["sides"] == sim.scene.symmetry
    T_true = [c.T_cam_world for c in sim.rig.cameras]
    W = invert_rigid(res.T_cam_world[0]) @ T_true[0]
    for k in range(len(T_true)):
        D = res.T_cam_world[k] @ W @ invert_rigid(T_true[k])
        deg = math.degrees(math.acos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
        assert deg < 1.0 and np.linalg.norm(invert_rigid(D)[:3, 3]) < 0.03, k


def test_a_period_one_pair_shows_yields_to_the_period_every_pair_shows():
    """One pair's two verified poses 360/11 deg apart in a 12-fold room (a near miss, within
    tolerance of 11 sides) and every pair's aliases at multiples of 30 deg: the room has 12 sides."""
    T = _cameras()
    cams = [_cam(Tk) for Tk in T]
    wrong = T[1] @ turn_about(np.array([0.0, 0.0, 1.0]), CENTRE, 360.0 / 11) @ invert_rigid(T[0])
    verified = {(0, 1): [{"T_ba": T[1] @ invert_rigid(T[0])}, {"T_ba": wrong}]}
    poses = []
    for i in range(4):
        for j in range(i + 1, 4):
            seen = [{"T_ba": _alias(T, i, j, k, 12)} for k in (1, 2, 5)]
            poses.append(((i, j), (verified.get((i, j), []), verified.get((i, j), []) + seen)))
    room, unverified = pair_room(cams, poses)
    assert room is not None and room.sides == 12 and not unverified
    # with no other pair's poses, the one pair's period stands
    room_1, _ = pair_room(cams, [((0, 1), (verified[(0, 1)], verified[(0, 1)]))])
    assert room_1 is not None and room_1.sides == 11


def test_a_pose_that_puts_one_camera_upside_down_is_refused():
    """A room whose ceiling matches its floor gives poses that turn one camera's floor into the
    other's ceiling: the two fitted floor normals then point opposite ways."""
    T = _cameras(2)
    a, b = _cam(T[0]), _cam(T[1])
    true = T[1] @ invert_rigid(T[0])
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # a half turn about a horizontal axis of the world
    flipped = T[1] @ turn_about(np.array([1.0, 0.0, 0.0]), CENTRE + [0, 0, 1.4], 180.0) @ invert_rigid(T[0])
    assert not upside_down(a, b, true)
    assert not upside_down(a, b, _alias(T, 0, 1, 2, 6))  # a room turn keeps the floor
    assert upside_down(a, b, flipped)
    assert upside_down(a, b, true @ T[0] @ flip @ invert_rigid(T[0]))
    assert not upside_down(SimpleNamespace(plane=None), b, flipped)  # no floor fitted: no check
