"""The frame-offset solver of the camera-sync check: a camera's offset from shifted depth
agreement (``estimate_frame_offset``), per-pair lags from both directions of co-visible score
curves (``pair_lags``) and the per-camera offsets solved jointly over the pairs
(``solve_frame_offsets``: weighted least squares with Huber-like re-weighting).

Conventions (``fuseflow.io.timesync``): an offset of +k frames means the camera is k frames
*late*: its view paired with frame t shows the scene its neighbours showed at frame t - k.
Pure numpy over score tables: the scorers (``check``, ``covisible``) compute the scores.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fuseflow.errors import ValidationError

__all__ = [
    "FrameOffsets",
    "OffsetEstimate",
    "PairLag",
    "estimate_frame_offset",
    "pair_lags",
    "solve_frame_offsets",
]


@dataclass(frozen=True)
class OffsetEstimate:
    """A camera's frame offset estimated from depth agreement with its neighbours.

    Attributes:
        frames: the offset in frames; +k = k frames late (its view at frame t shows what the
            neighbours showed at t - k); 0 when no shift is consistently better.
        ms: ``frames`` times the frame period in milliseconds (NaN without a period).
        consistency: share of the frames having the chosen shift on which it is the best shift.
        gain: median over frames of score(chosen shift) - score(shift 0).
        frames_used: frames with a score for shift 0 and for the chosen shift.
        median_score: shift -> median score over usable frames.
    """

    frames: int
    ms: float
    consistency: float
    gain: float
    frames_used: int
    median_score: Mapping[int, float]


def estimate_frame_offset(
    scores: np.ndarray,
    shifts: Sequence[int],
    period_s: float | None = None,
    min_frames: int = 3,
    min_consistency: float = 0.6,
    min_gain: float = 0.02,
) -> OffsetEstimate:
    """Estimate how many frames a camera is late or early from shifted depth agreement.

    ``scores[t, k]`` is the agreement (e.g. ``fuseflow.geometry.pair_agreement`` averaged over
    the camera's neighbours, in [0, 1]) of the camera's view at frame t with its neighbours'
    views at frame ``t + shifts[k]``; NaN where that frame does not exist or nothing voted.
    A camera k frames late agrees best at shift -k. The candidate is the shift whose per-frame
    margin over shift 0 has the largest median; it is reported only when that median margin is
    at least ``min_gain`` and the candidate is the best shift on at least ``min_consistency``
    of the frames that have it ("consistently better"); a static scene, where every shift
    agrees equally, gives 0.

    Args:
        scores: (F, S) float, agreement in [0, 1] or NaN.
        shifts: (S,) distinct ints, must contain 0.
        period_s: frame period in seconds, for ``OffsetEstimate.ms``.
        min_frames: fewest usable frames for a non-zero answer.
    """
    sc = np.asarray(scores, dtype=np.float64)
    shifts = [int(s) for s in shifts]
    if sc.ndim != 2 or sc.shape[1] != len(shifts):
        raise ValidationError(f"scores must be (frames, {len(shifts)} shifts), got shape {sc.shape}")
    if len(set(shifts)) != len(shifts) or 0 not in shifts:
        raise ValidationError(f"shifts must be distinct and contain 0, got {shifts}")
    z = shifts.index(0)
    med = {
        s: (float(np.nanmedian(sc[:, k])) if np.isfinite(sc[:, k]).any() else float("nan"))
        for k, s in enumerate(shifts)
    }
    usable = np.isfinite(sc[:, z]) & (np.isfinite(sc).sum(axis=1) >= 2)
    ms = float("nan") if not period_s else 0.0

    def none(n: int, cons: float = 0.0, gain: float = 0.0) -> OffsetEstimate:
        return OffsetEstimate(0, ms, cons, gain, n, med)

    if usable.sum() < min_frames:
        return none(int(usable.sum()))
    # the candidate: the shift whose paired margin over shift 0 has the largest median
    gains = np.full(len(shifts), -np.inf)
    for k in range(len(shifts)):
        both = usable & np.isfinite(sc[:, k])
        if k != z and both.sum() >= min_frames:
            gains[k] = float(np.median(sc[both, k] - sc[both, z]))
    k = int(np.argmax(gains))
    if not np.isfinite(gains[k]) or gains[k] < min_gain:
        return none(int(usable.sum()), 0.0, float(max(gains[k], 0.0)) if np.isfinite(gains[k]) else 0.0)
    # consistency: among frames that have the candidate shift, how often it is the best shift
    have = usable & np.isfinite(sc[:, k])
    rows = np.where(np.isfinite(sc[have]), sc[have], -np.inf)
    consistency = float((np.argmax(rows, axis=1) == k).mean())
    gain = float(gains[k])
    if consistency < min_consistency:
        return none(int(have.sum()), consistency, gain)
    both = have
    frames = -shifts[k]
    return OffsetEstimate(frames, frames * period_s * 1000.0 if period_s else float("nan"), consistency, gain,
                          int(both.sum()), med)  # fmt: skip


def _subframe_peak(curve: np.ndarray, shifts: Sequence[int]) -> float:
    """The shift of a curve's maximum, refined by a parabola through it and its neighbours."""
    k = int(np.nanargmax(curve))
    d = 0.0
    if 0 < k < len(curve) - 1 and np.isfinite(curve[k - 1 : k + 2]).all():
        y0, y1, y2 = curve[k - 1 : k + 2]
        den = y0 - 2 * y1 + y2
        d = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5)) if den < 0 else 0.0
    return shifts[k] + d


def _prominence(curve: np.ndarray) -> float:
    """(max - median) / median of a score curve: 0 when flat (a static scene, no co-visible motion)."""
    med = float(np.nanmedian(curve))
    return (float(np.nanmax(curve)) - med) / max(med, 1e-3)


@dataclass(frozen=True)
class PairLag:
    """The lag of camera j against camera i from both directions of their shifted scores.

    Attributes:
        i, j: camera indices (i < j). lag: frames camera j is late against i (sub-frame),
            the mean of ``forward`` and ``-backward``. forward: peak shift of i's points at t
            against j at t + s; backward: the same for j's points against i. prominence: the
            smaller prominence of the two curves. kept: used by ``solve_frame_offsets`` (both
            curves prominent and ``|forward + backward| <= max_asymmetry``).
    """

    i: int
    j: int
    lag: float
    forward: float
    backward: float
    prominence: float
    kept: bool


def pair_lags(
    curves: np.ndarray, shifts: Sequence[int], min_prominence: float = 0.05, max_asymmetry: float = 0.6
) -> list[PairLag]:
    """Per camera pair, the lag from the directed score curves ``curves[i, j, k]`` (camera i's
    points at frame t against camera j's depth at t + shifts[k], averaged over frames; NaN
    where not measured). A camera j late by k frames peaks at +k from i and at -k from j; a
    geometric bias of one direction (which side of a moving body each camera sees) shows as
    ``forward + backward != 0``, and such pairs are not kept."""
    c = np.asarray(curves, dtype=np.float64)
    shifts = [int(s) for s in shifts]
    out = []
    for i in range(c.shape[0]):
        for j in range(i + 1, c.shape[0]):
            ab, ba = c[i, j], c[j, i]
            if np.isfinite(ab).sum() < 5 or np.isfinite(ba).sum() < 5:  # too few shifts for a peak
                continue
            f, b = _subframe_peak(ab, shifts), _subframe_peak(ba, shifts)
            prom = min(_prominence(ab), _prominence(ba))
            kept = prom >= min_prominence and abs(f + b) <= max_asymmetry
            out.append(PairLag(i, j, (f - b) / 2, f, b, prom, bool(kept)))
    return out


def _components(n: int, pairs: Sequence[PairLag]) -> list[list[int]]:
    parent = list(range(n))

    def root(a: int) -> int:
        while parent[a] != a:
            a = parent[a]
        return a

    for p in pairs:
        parent[root(p.i)] = root(p.j)
    groups: dict[int, list[int]] = {}
    for a in range(n):
        groups.setdefault(root(a), []).append(a)
    return [g for g in groups.values() if len(g) > 2]


def _solve_component(cams: list[int], pairs: Sequence[PairLag]) -> np.ndarray:
    """Offsets of one connected group from its pair lags: weighted least squares (weight: the
    pair's prominence, then Huber-like re-weighting), referenced to the group's majority."""
    idx = {c: k for k, c in enumerate(cams)}
    rows = [p for p in pairs if p.i in idx and p.j in idx]
    A = np.zeros((len(rows) + 1, len(cams)))
    y = np.zeros(len(rows) + 1)
    for r, p in enumerate(rows):
        A[r, idx[p.j]], A[r, idx[p.i]], y[r] = 1.0, -1.0, p.lag
    A[-1] = 1.0  # gauge: offsets sum to 0 (replaced by the majority reference below)
    w = np.array([p.prominence for p in rows] + [1.0])
    for _ in range(5):
        o = np.linalg.lstsq(A * w[:, None], y * w, rcond=None)[0]
        res = np.abs(A[:-1] @ o - y[:-1])
        w[:-1] = np.array([p.prominence for p in rows]) / np.maximum(1.0, res / 0.5)
    # reference: the offset shared by most cameras (within half a frame), so that the in-sync
    # majority reads 0 and the odd camera out carries the offset
    support = [int((np.abs(o - ref) < 0.5).sum()) for ref in o]
    best = max(support)
    ref = float(np.median([o[k] for k in range(len(o)) if support[k] == best]))
    return o - ref


@dataclass(frozen=True)
class FrameOffsets:
    """Per camera offsets solved from pair lags (``solve_frame_offsets``).

    Attributes:
        frames: (N,) int64, whole frames (+ = late); 0 where not clearly supported.
        sub_frame: (N,) float64, the least-squares solution in frames, NaN for cameras in no
            group of >= 3 connected cameras.
        support: (N,) int64, kept pairs of each camera that fit the solution within half a frame.
    """

    frames: np.ndarray
    sub_frame: np.ndarray
    support: np.ndarray


def solve_frame_offsets(
    pairs: Sequence[PairLag], n: int, max_fraction: float = 0.35, min_offset: float = 0.6, min_pairs: int = 2
) -> FrameOffsets:
    """Per camera offsets (frames, + = late) jointly from pair lags (``pair_lags``).

    Only kept pairs count; cameras are solved per connected group of at least 3 cameras (two
    cameras alone cannot say which one is late). A camera's whole-frame offset is non-zero only
    where its sub-frame solution is at least ``min_offset`` from 0, within ``max_fraction`` of a
    whole frame, and fitted within half a frame by at least ``min_pairs`` of its kept pairs
    ("clearly supported": one pair alone gave a false -3 on an in-sync 30-fps rig)."""
    kept = [p for p in pairs if p.kept]
    sub = np.full(n, np.nan)
    for cams in _components(n, kept):
        sub[cams] = _solve_component(cams, kept)
    support = np.zeros(n, dtype=np.int64)
    for p in kept:
        if np.isfinite(sub[p.i]) and abs(p.lag - (sub[p.j] - sub[p.i])) < 0.5:
            support[[p.i, p.j]] += 1
    r = np.where(np.isfinite(sub), np.round(sub), 0.0)
    ok = np.isfinite(sub) & (np.abs(sub) >= min_offset) & (np.abs(sub - r) <= max_fraction) & (support >= min_pairs)
    return FrameOffsets(np.where(ok, r, 0).astype(np.int64), sub, support)
