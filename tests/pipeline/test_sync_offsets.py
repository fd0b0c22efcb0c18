"""The sync check's frame-offset solver (fuseflow.pipeline.sync.offsets): one camera's offset
from shifted agreement, pair lags and the joint per-camera offsets."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.errors import ValidationError
from fuseflow.pipeline.sync import estimate_frame_offset, pair_lags, solve_frame_offsets

P = 1 / 30


def _scores(offset: int, frames: int = 12, noise: float = 0.01, seed: int = 0, shifts=(-3, -2, -1, 0, 1, 2, 3)):
    """Agreement peaked at shift -offset (a camera `offset` frames late), falling 0.05 per frame away."""
    rng = np.random.default_rng(seed)
    s = np.array(shifts)
    sc = 0.8 - 0.05 * np.abs(s[None] + offset) + rng.normal(0, noise, (frames, len(s)))
    for t in range(frames):  # shifted frames outside the recording do not exist
        sc[t, (t + s < 0) | (t + s >= frames)] = np.nan
    return sc, list(shifts)


@pytest.mark.parametrize("offset", [-2, -1, 0, 1, 2, 3])
def test_offset_found_from_shifted_agreement(offset):
    sc, shifts = _scores(offset)
    e = estimate_frame_offset(sc, shifts, period_s=P)
    assert e.frames == offset and e.ms == pytest.approx(offset * P * 1000)
    if offset:
        assert e.consistency > 0.8 and e.gain > 0.03


def test_offset_zero_when_nothing_is_consistently_better():
    rng = np.random.default_rng(1)
    flat = 0.8 + rng.normal(0, 0.01, (12, 5))  # static scene: every shift agrees alike
    assert estimate_frame_offset(flat, [-2, -1, 0, 1, 2], period_s=P).frames == 0
    assert estimate_frame_offset(np.full((2, 3), 0.5), [-1, 0, 1]).frames == 0  # too few frames
    with pytest.raises(ValidationError, match="contain 0"):
        estimate_frame_offset(flat, [-2, -1, 1, 2, 3])
    with pytest.raises(ValidationError, match="scores must be"):
        estimate_frame_offset(flat, [0, 1])


SHIFTS = list(range(-5, 6))


def _curves(offsets: list[float], bias: dict[tuple[int, int], float] | None = None, flat=()) -> np.ndarray:
    """Directed score curves of a rig whose camera k is offsets[k] frames late: i's points at t
    agree best with j at t + (o_j - o_i) (+ a per-direction bias); pairs in ``flat`` share no surface."""
    n, s = len(offsets), np.array(SHIFTS, dtype=float)
    c = np.full((n, n, len(SHIFTS)), np.nan)
    for i in range(n):
        for j in range(n):
            if i != j:
                peak = offsets[j] - offsets[i] + (bias or {}).get((i, j), 0.0)
                c[i, j] = 0.1 + (0.0 if {i, j} in [set(f) for f in flat] else 0.1 * np.exp(-0.5 * (s - peak) ** 2))
    return c


def test_pair_lags_sub_frame_and_joint_offsets():
    pairs = pair_lags(_curves([0, 0, 0, 2.0], flat=[(0, 2), (1, 3)]), SHIFTS)
    lag = {(p.i, p.j): p for p in pairs}
    assert lag[0, 3].lag == pytest.approx(2.0, abs=0.1) and lag[0, 3].kept
    assert not lag[0, 2].kept and not lag[1, 3].kept  # flat: no shared surface
    res = solve_frame_offsets(pairs, 4)
    offset, sub = res.frames, res.sub_frame
    assert list(offset) == [0, 0, 0, 2] and sub[3] == pytest.approx(2.0, abs=0.1)
    # one camera early, 3 cameras
    offset = solve_frame_offsets(pair_lags(_curves([0, -1.0, 0]), SHIFTS), 3).frames
    assert list(offset) == [0, -1, 0]


def test_pair_lags_drops_one_sided_bias_and_in_sync_reads_zero():
    # in sync, but 0 -> 1 is biased by a frame in one direction only (a body's far side)
    pairs = pair_lags(_curves([0, 0, 0, 0], bias={(0, 1): -1.3}, flat=[(0, 2), (1, 3)]), SHIFTS)
    assert not next(p for p in pairs if (p.i, p.j) == (0, 1)).kept
    res = solve_frame_offsets(pairs, 4)
    offset, sub = res.frames, res.sub_frame
    assert list(offset) == [0, 0, 0, 0] and np.nanmax(np.abs(sub)) < 0.2


def test_solve_frame_offsets_needs_three_cameras_and_a_whole_frame():
    # two cameras alone: which one is late is not known
    res = solve_frame_offsets(pair_lags(_curves([0, 2.0]), SHIFTS), 2)
    offset, sub = res.frames, res.sub_frame
    assert list(offset) == [0, 0] and np.isnan(sub).all()
    # half a frame between two whole frames is not clearly supported
    res = solve_frame_offsets(pair_lags(_curves([0, 0, 1.5]), SHIFTS), 3)
    offset, sub = res.frames, res.sub_frame
    assert list(offset) == [0, 0, 0] and sub[2] == pytest.approx(1.5, abs=0.15)


def test_solve_frame_offsets_wants_two_pairs_for_a_camera():
    # cam01 "3 frames early" from its pair with cam00 only (cam01-cam02 and cam01-cam03 share no surface)
    pairs = pair_lags(_curves([0, -3.0, 0, 0], flat=[(1, 2), (1, 3), (0, 2)]), SHIFTS)
    res = solve_frame_offsets(pairs, 4)
    offset, sub = res.frames, res.sub_frame
    assert sub[1] == pytest.approx(-3.0, abs=0.1) and list(offset) == [0, 0, 0, 0]
    assert list(solve_frame_offsets(pairs, 4, min_pairs=1).frames) == [0, -3, 0, 0]
