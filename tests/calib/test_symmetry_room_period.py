"""The room's period from the pairs' turns (calib.symmetry, section 5) when some verified poses are
off the room's orbit: the period must fit the turns precisely, not loosely, and one wrong pose of a
pair must not turn a 10-fold room into a 20-fold one."""

from __future__ import annotations

import math

import numpy as np

from fuseflow.calib.symmetry import room_orbits, room_period, turn_about
from fuseflow.synth.rigs import look_at
from fuseflow.types import invert_rigid

CENTRE = np.array([0.4, -0.3, 0.0])  # the room's axis: vertical through here (world)
UP = np.array([0.0, 0.0, 1.0])


def _cameras(n: int) -> list[np.ndarray]:
    return [
        look_at(CENTRE + [2.6 * math.cos(1.3 * k + 0.2), 2.6 * math.sin(1.3 * k + 0.2), 1.4 + 0.3 * k], CENTRE + UP)
        for k in range(n)
    ]


def _pose(T: list[np.ndarray], i: int, j: int, angle: float, rng) -> np.ndarray:
    """Pair (i, j)'s pose with camera j seen as if the room were turned by ``angle`` deg, with a
    RANSAC pose's noise (~0.05 deg, ~3 mm)."""
    A = T[j] @ turn_about(UP, CENTRE, angle) @ invert_rigid(T[i])
    A = turn_about(rng.normal(size=3), np.zeros(3), rng.normal(0, 0.05)) @ A
    A[:3, 3] += rng.normal(0, 0.003, 3)
    return A


def test_the_period_fits_the_turns_precisely_not_every_turn_loosely():
    # independent studio seed 919 (10-sided, 320x240): six turns of 36.2-36.6 deg and two of 32.5
    # to a wrong pose; 21 sides (17.1 deg) fit all eight within 3 deg, 10 fit six within 0.6 deg
    assert room_period([32.5, 32.5, 36.2, 36.2, 36.3, 36.3, 36.6, 36.6]) == 10
    # seed 937 (12-sided): 11 sides (32.7 deg) fit the 30-deg turns within 3 deg and the wrong ones
    seen = [29.9, 29.9, 30.2, 30.2, 30.2, 30.2, 30.3, 30.3, 32.2, 32.2, 33.3, 33.3, 122.4, 122.4]
    assert room_period(seen) == 12


def test_no_period_above_what_the_cloud_can_confirm_fits_a_wrong_pose_loosely():
    # independent studio seed 1118 (8-sided): one pair's two poses 45.9 deg apart and a wrong pose
    # of another pair 34.2 deg from its alias; 23 sides (15.7 deg) fit all four within 3 deg
    assert room_period([-34.2, 34.2, 45.9, 45.9]) is None
    assert room_period([45.9, 45.9]) == 8
    assert room_period([22.6, 45.1, -22.4]) == 16  # the finest period still considered


def test_random_turns_give_no_period_even_when_half_of_them_fit_one():
    # 20 sides fit three of these five within 3 deg, as random angles do with a chance of 0.21
    assert room_period([17.0, 53.0, 101.0, 163.0, 29.0]) is None
    assert room_period([40.0, 40.0]) == 9  # one pair's two poses: its turn in each camera's frame


def test_one_wrong_pose_among_a_pairs_aliases_does_not_halve_the_period():
    sides = 10
    T = _cameras(4)
    rng = np.random.default_rng(3)
    p = 360.0 / sides
    # pair (0, 1): three aliases and one pose 17.8 deg off the orbit (half a period: it fits 20)
    poses = {
        (0, 1): [_pose(T, 0, 1, k * p, rng) for k in (0, 2, 3)] + [_pose(T, 0, 1, 17.8, rng)],
        (1, 2): [_pose(T, 1, 2, k * p, rng) for k in (1, 3)],
        (2, 3): [_pose(T, 2, 3, k * p, rng) for k in (0, 1)],
        (0, 3): [_pose(T, 0, 3, k * p, rng) for k in (2, 4)],
    }
    room = room_orbits(poses, {k: Tk[:3, :3] @ UP for k, Tk in enumerate(T)})
    assert room is not None and room.sides == 10
    assert room.pairs == 4 and room.turns == 12  # the wrong pose's six turns are left out


def test_one_pairs_three_aliases_keep_their_period_when_no_other_pair_turns():
    # independent studio seed 501 (6-sided): one pair's poses 60 deg apart, no other pair turned;
    # the middle pose alone makes 6 fit better than 3, yet it is an alias, not a wrong pose
    T = _cameras(3)
    rng = np.random.default_rng(4)
    poses = {(0, 1): [_pose(T, 0, 1, k * 60.0, rng) for k in (0, 1, 2)], (1, 2): [_pose(T, 1, 2, 0.0, rng)]}
    room = room_orbits(poses, {k: Tk[:3, :3] @ UP for k, Tk in enumerate(T)})
    assert room is not None and room.sides == 6 and room.turns == 6
