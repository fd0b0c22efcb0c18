"""Room turns (calib.symmetry, section 5): the period and axis of a repeating room from a pair's
verified aliases, and the orbit that contains the true pose when RANSAC found only aliases."""

from __future__ import annotations

import math

import numpy as np

from fuseflow.calib.symmetry import pose_gap, room_orbits, room_period, screw_axis, turn_about
from fuseflow.synth.rigs import look_at
from fuseflow.types import invert_rigid

CENTRE = np.array([0.4, -0.3, 0.0])  # the room's axis: vertical through here (world)


def _room_turn(k: int, sides: int) -> np.ndarray:
    """World-frame turn by k periods about the room's axis."""
    return turn_about(np.array([0.0, 0.0, 1.0]), CENTRE, 360.0 * k / sides)


def _cameras(n: int = 4) -> list[np.ndarray]:
    return [
        look_at(
            CENTRE + [2.6 * math.cos(1.3 * k + 0.2), 2.6 * math.sin(1.3 * k + 0.2), 1.4 + 0.3 * k], CENTRE + [0, 0, 1]
        )
        for k in range(n)
    ]


def _alias(T: list[np.ndarray], i: int, j: int, k: int, sides: int, rng=None) -> np.ndarray:
    """Pair (i, j)'s pose as a k-period alias: camera j seen as if the room were turned."""
    A = T[j] @ _room_turn(k, sides) @ invert_rigid(T[i])
    if rng is not None:  # a RANSAC pose's noise: ~0.05 deg, ~3 mm
        A = turn_about(rng.normal(size=3), np.zeros(3), rng.normal(0, 0.05)) @ A
        A[:3, 3] += rng.normal(0, 0.003, 3)
    return A


def _ups(T: list[np.ndarray]) -> dict[int, np.ndarray]:
    return {k: Tk[:3, :3] @ np.array([0.0, 0.0, 1.0]) for k, Tk in enumerate(T)}


def test_screw_axis_of_a_turn_about_an_offset_line():
    D = turn_about(np.array([0.0, 1.0, 0.0]), np.array([0.5, 0.0, 2.0]), 40.0)
    ang, u, p, pitch = screw_axis(D)
    assert abs(ang - 40.0) < 1e-9 and abs(pitch) < 1e-9
    assert np.allclose(u, [0, 1, 0]) and np.allclose(p, [0.5, 0.0, 2.0])


def test_room_period_takes_the_fewest_sides_that_fit_and_none_for_random_angles():
    assert room_period([40.1, -80.3, 119.6, 40.0]) == 9  # 360 / 9 = 40
    assert room_period([65.5, 131.0, 32.6]) == 11  # multiples of 32.7 (11-fold)
    assert room_period([72.0, 144.0]) == 5
    assert room_period([]) is None
    assert room_period([17.0, 53.0, 101.0, 163.0, 29.0]) is None


def test_the_orbit_of_an_alias_holds_the_true_pose():
    sides, rng = 9, np.random.default_rng(3)
    T = _cameras()
    # pairs (0, 1) and (1, 2) have two verified aliases each (their turns give period and axis);
    # pair (0, 3) has one alias only, pair (2, 3) a single pose: the orbits must reach the truth
    poses = {(0, 1): [_alias(T, 0, 1, 2, sides, rng), _alias(T, 0, 1, 5, sides, rng)],
             (1, 2): [_alias(T, 1, 2, 1, sides, rng), _alias(T, 1, 2, 3, sides, rng)],
             (0, 3): [_alias(T, 0, 3, 4, sides, rng)], (2, 3): [_alias(T, 2, 3, 7, sides, rng)]}  # fmt: skip
    room = room_orbits(poses, _ups(T))
    assert room is not None and room.sides == sides and room.pairs == 2
    assert set(room.axes) == {0, 1, 2, 3}  # cameras 3 by carrying the axis through a pose
    for (i, j), Ts in poses.items():
        members = room.members(i, Ts[0], Ts)
        assert len(members) == sides - len(Ts)  # the rest of the orbit, nothing twice
        truth = T[j] @ invert_rigid(T[i])
        rot, pos = np.min([pose_gap(M, truth) for _, M in members], axis=0)
        assert rot < 0.3 and pos < 0.02, ((i, j), rot, pos)


def test_no_room_turns_without_aliases_or_with_turns_about_a_tilted_axis():
    T = _cameras()
    truth = {(i, j): [T[j] @ invert_rigid(T[i])] for i in range(4) for j in range(i + 1, 4)}
    assert room_orbits(truth, _ups(T)) is None  # one pose per pair: nothing repeats
    # two poses per pair that differ by a turn about a horizontal axis: not a room's repeat
    tilted = {p: [Ts[0], Ts[0] @ turn_about(np.array([1.0, 0.0, 0.0]), np.zeros(3), 40.0)] for p, Ts in truth.items()}
    assert room_orbits(tilted, _ups(T)) is None


def test_one_pair_with_one_turn_is_enough():
    sides, T = 11, _cameras()
    room = room_orbits({(0, 1): [_alias(T, 0, 1, k, sides) for k in (2, 6)]}, _ups(T))
    assert room is not None and room.sides == sides and room.pairs == 1 and room.turns == 2
    truth = T[1] @ invert_rigid(T[0])
    Ts = [_alias(T, 0, 1, 2, sides)]
    assert min(pose_gap(M, truth)[0] for _, M in room.members(0, Ts[0], Ts)) < 1e-6
