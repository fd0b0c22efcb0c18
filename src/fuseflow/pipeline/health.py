"""Health monitoring: per pair of neighbouring cameras and frame, the share of their depth that
agrees (``fuseflow.geometry.pair_agreement``, the CVGC vote of eq. 19-20 on a subsampled grid).
A camera whose pairs all fall below their baselines was probably bumped; ``HealthMonitor``
flags it."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from fuseflow.geometry import camera_agreement, pair_agreement
from fuseflow.types import Frame, Rig

__all__ = ["HealthMonitor", "frame_health"]


def frame_health(frame: Frame, rig: Rig, samples: int, tau: float) -> tuple[np.ndarray, dict[str, float | None]]:
    """One frame's (N, N) pair agreements (rig order, NaN = no vote) and, per camera id, the mean
    agreement of its pairs (None without a vote). ``frame`` holds the views of ``rig`` in order."""
    pairs = pair_agreement(frame, rig, samples, tau)
    per_camera = camera_agreement(pairs)
    agreement = {c: (None if not np.isfinite(a) else round(float(a), 4)) for c, a in zip(rig.ids, per_camera)}
    return pairs, agreement


class HealthMonitor:
    """Flags cameras that no longer agree with their neighbours (a bumped camera).

    Works on pair agreements (``pair_agreement``): a camera that moved disagrees with *all* its
    neighbours, while each of those neighbours disagrees only with it. So a camera is suspect
    in a frame when at least half of its pairs (and at least 2, where it has 2 or more) fell by
    more than ``drop`` below their baseline, and its mean drop is the largest among the cameras
    sharing those pairs. State, explicit and per run: each pair's baseline (median of its first
    ``warmup`` frames with votes) and each camera's count of consecutive suspect frames;
    ``patience`` suspect frames in a row flag it.
    """

    def __init__(self, camera_ids: Iterable[str], warmup: int = 3, drop: float = 0.1, patience: int = 2):
        self.ids = tuple(camera_ids)
        self.warmup, self.drop, self.patience = warmup, drop, patience
        n = len(self.ids)
        self._history: dict[tuple[int, int], list[float]] = {}
        self._suspect = np.zeros(n, dtype=np.int64)

    def _baseline(self, i: int, j: int) -> float | None:
        h = self._history.get((min(i, j), max(i, j)), [])
        return float(np.median(h)) if len(h) >= self.warmup else None

    def _drops(self, pairs: np.ndarray) -> np.ndarray:
        """(N, N) drop of each pair below its baseline (NaN while warming up or without a vote);
        pairs still warming up join their history."""
        n = len(self.ids)
        drops = np.full((n, n), np.nan)
        for i in range(n):
            for j in range(i + 1, n):
                a = pairs[i, j]
                if not np.isfinite(a):
                    continue
                base = self._baseline(i, j)
                if base is None:
                    self._history.setdefault((i, j), []).append(float(a))
                else:
                    drops[i, j] = drops[j, i] = base - float(a)
        return drops

    def update(self, pairs: np.ndarray) -> list[str]:
        """Feed one frame's (N, N) pair agreement in rig order; return the cameras flagged now."""
        n = len(self.ids)
        drops = self._drops(pairs)
        score = np.full(n, -np.inf)
        suspect = np.zeros(n, dtype=bool)
        for i in range(n):
            d = drops[i][np.isfinite(drops[i])]
            if d.size == 0:
                continue
            score[i] = float(d.mean())
            fell = int((d > self.drop).sum())
            suspect[i] = fell >= max(min(2, d.size), (d.size + 1) // 2)
        for i in range(n):  # of two cameras sharing fallen pairs, blame the one that fell most
            if suspect[i]:
                for j in range(n):
                    if j != i and np.isfinite(drops[i, j]) and drops[i, j] > self.drop and score[j] > score[i]:
                        suspect[i] = False
        self._suspect = np.where(suspect, self._suspect + 1, 0)
        return [self.ids[i] for i in range(n) if self._suspect[i] >= self.patience]

    def reset(self, cid: str) -> None:
        """Forget the baselines of a camera's pairs (after it was recalibrated)."""
        i = self.ids.index(cid)
        for key in [k for k in self._history if i in k]:
            del self._history[key]
        self._suspect[i] = 0
