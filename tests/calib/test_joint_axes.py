"""One room axis fitted to every camera's walls and carried through the verified poses
(calib.symmetry.joint_axes)."""

from __future__ import annotations

import math

import numpy as np

from fuseflow.calib import symmetry as S
from fuseflow.synth.rigs import look_at
from fuseflow.types import invert_rigid

from .test_room_axis_fit import _polygon_room

CENTRE = np.array([0.3, -0.2, 0.0])


def _camera(k: int, cams: int) -> np.ndarray:
    """Camera k of ``cams`` on a 2.8 m ring about CENTRE, 1.6 m high, looking at it: camera-from-world."""
    a = 2 * math.pi * (k + 0.5) / cams
    return look_at(CENTRE + [2.8 * math.cos(a), 2.8 * math.sin(a), 1.6], CENTRE + [0.0, 0.0, 1.0])


def _true_axis(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    up, q = T[:3, :3] @ [0.0, 0.0, 1.0], T[:3, :3] @ CENTRE + T[:3, 3]
    return up, q - (q @ up) * up


def _axis_error(axis, T) -> float:
    up, q = _true_axis(T)
    d = np.asarray(axis[1]) - q
    return float(np.linalg.norm(d - (d @ up) * up))


def _rig(sides=8, cams=5, seed=1):
    """Each camera's view (its points in its frame), its true pose, the pairs' verified poses
    (aliases: each a whole number of periods off the true one), own axes 3-5 cm off."""
    X, _, labels = _polygon_room(sides=sides, centre=tuple(CENTRE[:2]), cams=cams, noise=0.01)
    rng = np.random.default_rng(seed)
    T = [_camera(k, cams) for k in range(cams)]
    views = [((X[labels == k] @ T[k][:3, :3].T + T[k][:3, 3]),) for k in range(cams)]
    turn = S.turn_about(np.array([0.0, 0.0, 1.0]), CENTRE, 360.0 / sides)
    poses = {}
    for i in range(cams):
        for j in range(i + 1, cams):
            k = int(rng.integers(0, sides))  # the alias k periods off
            poses[(i, j)] = [T[j] @ np.linalg.matrix_power(turn, k) @ invert_rigid(T[i])]
    axes = {}
    for k in range(cams):
        up, q = _true_axis(T[k])
        a = rng.uniform(0, 2 * math.pi)
        off = 0.03 + 0.02 * rng.uniform()
        side = np.cross(up, [1.0, 0.0, 0.0])
        side /= np.linalg.norm(side)
        axes[k] = (up, q + off * (math.cos(a) * side + math.sin(a) * np.cross(up, side)))
    return views, T, poses, S.RoomOrbits(sides, axes, 0, 0, views=cams)


def test_one_fitted_axis_puts_every_camera_within_millimetres_of_the_truth():
    views, T, poses, room = _rig()
    assert min(_axis_error(room.axes[k], T[k]) for k in room.axes) > 0.025
    fitted = S.joint_axes(room, views, poses)
    errors = [_axis_error(fitted.axes[k], T[k]) for k in range(len(T))]
    assert max(errors) < 0.005, errors
    assert fitted.sides == room.sides and fitted.views == room.views


def test_a_camera_no_verified_pose_reaches_keeps_its_own_axis():
    views, T, poses, room = _rig()
    poses = {p: Ts for p, Ts in poses.items() if 4 not in p}
    fitted = S.joint_axes(room, views, poses)
    assert np.allclose(fitted.axes[4][1], room.axes[4][1])
    assert max(_axis_error(fitted.axes[k], T[k]) for k in range(4)) < 0.005


def test_walls_facing_one_way_leave_the_own_axes():
    views, T, poses, room = _rig()
    one = [(v[0][v[0][:, 0] > 0.5],) for v in views[:1]] + [None] * (len(views) - 1)
    fitted = S.joint_axes(room, one, {})
    assert all(np.allclose(fitted.axes[k][1], room.axes[k][1]) for k in room.axes)


def test_a_verified_pose_off_the_orbit_does_not_carry_its_camera():
    views, T, poses, room = _rig()
    good = poses[(0, 3)][0]
    off = S.turn_about(np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.5, 0.0]), 4.5)  # 4.5 deg about another line
    poses[(0, 3)] = [T[3] @ off @ invert_rigid(T[3]) @ good, good]  # the off pose listed first
    fitted = S.joint_axes(room, views, poses)
    errors = [_axis_error(fitted.axes[k], T[k]) for k in range(len(T))]
    assert max(errors) < 0.005, errors


def test_a_camera_whose_own_turns_agree_keeps_its_axis():
    views, T, poses, room = _rig()
    up, q = _true_axis(T[2])
    axes = {**room.axes, 2: (up, q + 0.001 * np.cross(up, [1.0, 0.0, 0.0]))}
    settled = S.RoomOrbits(room.sides, axes, 0, 0, views=room.views, settled=frozenset({2}))
    fitted = S.joint_axes(settled, views, poses)
    assert np.allclose(fitted.axes[2][1], axes[2][1])
    assert max(_axis_error(fitted.axes[k], T[k]) for k in range(len(T))) < 0.005


def test_settled_axes_need_enough_turns_that_agree():
    up = np.array([0.0, -1.0, 0.0])

    def turns(cam, n, scatter):
        rng = np.random.default_rng(cam)
        return [S.RoomTurn((0, 1), cam, 36.0, up, np.array([0.2, 0.0, 3.0]) + rng.normal(0, scatter, 3) * [1, 0, 1])
                for _ in range(n)]  # fmt: skip

    got = S.settled_axes(turns(0, 8, 0.001) + turns(1, 3, 0.001) + turns(2, 8, 0.05))
    assert got == frozenset({0})
