"""Symmetric rooms: physically plausible pair poses, several hypotheses per pair, a joint choice.

In a room that repeats every 360/N deg (a polygonal studio, a dome of panels) a camera pair has
several relative poses that its depth and images confirm: the true one and its aliases, one room
period apart. The aliases that put one camera on top of the other (centres a few cm apart) are
confirmed best of all, since two stacked cameras see the same symmetric walls with no occlusion.
Three steps keep that from becoming a confidently wrong calibration:

1. ``colocated``: a relative pose that puts the two camera centres closer than a device's
   width (``min_separation``) is rejected, not scored, unless the two views are nearly the same
   (then the cameras may really sit together).
2. ``distinct_hypotheses``: every verified pose of a pair that differs from the better ones by more
   than the cycle tolerance is kept as a hypothesis (up to ``keep``), not only the best.
3. ``select_consistent``: the hypotheses are chosen jointly: greedy consensus growth from every
   hypothesis (the next camera is placed by the link that the most other hypotheses to the placed
   cameras agree with; a placement closer than ``min_separation`` to a placed camera is vetoed),
   giving the distinct solutions ranked by their mutually consistent pairs. Aliases of different
   pairs mostly disagree around loops; where two wrong edges agree (seen: symstudio seed 0), the
   caller decides among the best solutions by what all views say together
   (``backbones.rgbd``: depth agreement of every pair at a tight tolerance, the subject weighted).

``bridges`` names the edges that lie on no cycle of a graph: a camera held only by such edges has
had no independent check, and when its link had another passing hypothesis it is ambiguous.

Pure numpy, no images: the verification that produces the hypotheses stays in the backbone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fuseflow.types import invert_rigid

__all__ = [
    "Hypothesis",
    "Solution",
    "main_block",
    "colocated",
    "distinct_hypotheses",
    "select_consistent",
    "bridges",
    "pose_gap",
]


@dataclass(frozen=True)
class Hypothesis:
    """One verified relative pose of the pair (i, j), i < j: ``T_ji`` maps camera i's coordinates
    to camera j's (metres); ``score`` its verification strength (higher is better); ``ref`` the
    caller's handle (e.g. the candidate it came from)."""

    i: int
    j: int
    T_ji: np.ndarray
    score: float
    ref: object = None


def colocated(T_ji: np.ndarray, min_separation: float) -> bool:
    """Does ``T_ji`` put the two camera centres closer than ``min_separation`` metres? (Camera i's
    centre in camera j's frame is T_ji's translation.)"""
    return float(np.linalg.norm(T_ji[:3, 3])) < min_separation


def pose_gap(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation angle (deg) and centre distance (m) between camera-from-world poses; A (..., 4, 4)
    and B (..., 4, 4) broadcast."""
    R = np.einsum("...ij,...kj->...ik", A[..., :3, :3], B[..., :3, :3])
    c = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    ca = -np.einsum("...ji,...j->...i", A[..., :3, :3], A[..., :3, 3])
    cb = -np.einsum("...ji,...j->...i", B[..., :3, :3], B[..., :3, 3])
    return np.degrees(np.arccos(c)), np.linalg.norm(ca - cb, axis=-1)


def distinct_hypotheses(hyps: list[Hypothesis], rot_deg: float, trans_m: float, keep: int) -> list[Hypothesis]:
    """The best-scored hypotheses of one pair that differ pairwise by more than ``rot_deg`` or
    ``trans_m`` (relative poses compared as camera j's pose with camera i at the origin), at
    most ``keep``, best first."""
    out: list[Hypothesis] = []
    for h in sorted(hyps, key=lambda h: -h.score):
        if len(out) >= keep:
            break
        if all(_differ(h.T_ji, o.T_ji, rot_deg, trans_m) for o in out):
            out.append(h)
    return out


def _differ(A: np.ndarray, B: np.ndarray, rot_deg: float, trans_m: float) -> bool:
    r, t = pose_gap(A, B)
    return bool(r > rot_deg or t > trans_m)


def _link_poses(hyps: list[Hypothesis], poses: dict[int, np.ndarray]):
    """The hypotheses with exactly one end placed: their index, the unplaced camera, and the pose
    (camera-from-world) each implies for it."""
    idx, cams, P = [], [], []
    for k, h in enumerate(hyps):
        if (h.i in poses) == (h.j in poses):
            continue
        if h.i in poses:
            idx.append(k), cams.append(h.j), P.append(h.T_ji @ poses[h.i])
        else:
            idx.append(k), cams.append(h.i), P.append(invert_rigid(h.T_ji) @ poses[h.j])
    return np.array(idx, int), np.array(cams, int), np.array(P).reshape(-1, 4, 4)


def _grow(hyps: list[Hypothesis], start: int, rot_deg: float, trans_m: float, min_sep: float,
          rng: np.random.Generator | None = None) -> dict[int, np.ndarray]:  # fmt: skip
    """Greedy consensus growth from hypothesis ``start`` (module docstring, step 3): ties in
    support go to the larger summed score, or at random with ``rng``."""
    h0 = hyps[start]
    poses = {h0.i: np.eye(4), h0.j: h0.T_ji.copy()}
    scores = np.array([h.score for h in hyps])
    while True:
        idx, cams, P = _link_poses(hyps, poses)
        if not len(idx):
            return poses
        r, t = pose_gap(P[:, None], P[None, :])
        agree = (cams[:, None] == cams[None, :]) & (r <= rot_deg) & (t <= trans_m)
        support = agree.sum(axis=1).astype(float)
        placed = np.array([invert_rigid(T)[:3, 3] for T in poses.values()])
        centres = np.array([invert_rigid(T)[:3, 3] for T in P])
        near = np.linalg.norm(centres[:, None] - placed[None], axis=2).min(axis=1) < min_sep
        support[near] = -1.0
        if support.max() < 1:
            return poses
        tie = rng.random(len(idx)) if rng is not None else (agree * scores[idx][None, :]).sum(axis=1) / scores.sum()
        best = int(np.argmax(support + 0.5 * tie))
        poses[int(cams[best])] = P[best]


def _polish(hyps: list[Hypothesis], poses: dict, rot_deg: float, trans_m: float, min_sep: float, sweeps: int = 3):
    """Move each camera, in turn, to the pose that the most hypotheses to the other placed cameras
    agree on, while that is more than its present pose has (a greedy growth can commit early to
    a pose that two wrong edges agree on)."""
    poses = dict(poses)
    for _ in range(sweeps):
        moved = False
        for k in sorted(poses):
            rest = {c: T for c, T in poses.items() if c != k}
            idx, cams, P = _link_poses([h for h in hyps if k in (h.i, h.j)], rest)
            if not len(idx):
                continue
            r, t = pose_gap(P[:, None], P[None, :])
            support = ((r <= rot_deg) & (t <= trans_m)).sum(axis=1)
            rc, tc = pose_gap(P, poses[k][None])
            now = int(((rc <= rot_deg) & (tc <= trans_m)).sum())
            placed = np.array([invert_rigid(T)[:3, 3] for T in rest.values()])
            centres = np.array([invert_rigid(T)[:3, 3] for T in P])
            support[np.linalg.norm(centres[:, None] - placed[None], axis=2).min(axis=1) < min_sep] = -1
            best = int(np.argmax(support))
            if support[best] > now:
                poses[k], moved = P[best], True
        if not moved:
            return poses
    return poses


def _consistent(hyps: list[Hypothesis], poses: dict[int, np.ndarray], rot_deg: float, trans_m: float) -> dict:
    """(i, j) -> index of the hypothesis that agrees with ``poses`` (both ends placed)."""
    out = {}
    for k, h in enumerate(hyps):
        if h.i in poses and h.j in poses and (h.i, h.j) not in out:
            r, t = pose_gap(h.T_ji @ poses[h.i], poses[h.j])
            if r <= rot_deg and t <= trans_m:
                out[(h.i, h.j)] = k
    return out


#: Growths with random tie-breaks per starting hypothesis (``select_consistent``).
RANDOM_GROWTHS = 3


@dataclass(frozen=True)
class Solution:
    """One jointly consistent choice: ``poses`` camera -> camera-from-world (the growth's chained
    poses, world = its first camera), ``chosen`` (i, j) -> index into the hypotheses, ``score``
    the chosen hypotheses' summed score."""

    poses: dict
    chosen: dict
    score: float


def select_consistent(
    hyps: list[Hypothesis], rot_deg: float = 2.0, trans_m: float = 0.1, min_separation: float = 0.2
) -> list[Solution]:
    """The distinct jointly consistent choices of hypotheses (module docstring, step 3), best
    first: most consistent pairs, then the larger summed score. From every hypothesis one growth
    with ties to the larger score and RANDOM_GROWTHS with random ties (seeded), each polished;
    none starts from a hypothesis that stacks its two cameras (``colocated``)."""
    seen, out = set(), []
    rng = np.random.default_rng(0)
    starts = [s for s, h in enumerate(hyps) if not colocated(h.T_ji, min_separation)]
    for s, r in [(s, r) for s in starts for r in range(RANDOM_GROWTHS + 1)]:
        poses = _grow(hyps, s, rot_deg, trans_m, min_separation, rng if r else None)
        poses = _polish(hyps, poses, rot_deg, trans_m, min_separation)
        chosen = _consistent(hyps, poses, rot_deg, trans_m)
        key = frozenset(chosen.items())
        if key in seen:
            continue
        seen.add(key)
        out.append(Solution(poses, chosen, sum(hyps[k].score for k in chosen.values())))
    out.sort(key=lambda sol: (-len(sol.chosen), -sol.score))
    return out


def bridges(edges: list[tuple[int, int]]) -> set[tuple[int, int]]:
    """The edges of an undirected graph that lie on no cycle (their removal disconnects it)."""
    out = set()
    for e in edges:
        rest = [f for f in edges if f != e]
        seen, stack = {e[0]}, [e[0]]
        while stack:
            k = stack.pop()
            for a, b in rest:
                for u, v in ((a, b), (b, a)):
                    if u == k and v not in seen:
                        seen.add(v)
                        stack.append(v)
        if e[1] not in seen:
            out.add(e)
    return out


def main_block(edges: list[tuple[int, int]]) -> set[int]:
    """The cameras of the largest 2-edge-connected part of the graph (the edges on no cycle
    removed; ties: the part with the lowest camera): every camera in it is checked by a cycle,
    anything hanging from it by a bridge is not. Empty when that part has fewer than 3 cameras."""
    lone = bridges(edges)
    rest = [e for e in edges if e not in lone]
    parts, seen = [], set()
    for s0 in sorted({k for e in rest for k in e}):
        if s0 in seen:
            continue
        part, stack = {s0}, [s0]
        while stack:
            k = stack.pop()
            for a, b in rest:
                for u, v in ((a, b), (b, a)):
                    if u == k and v not in part:
                        part.add(v)
                        stack.append(v)
        seen |= part
        parts.append(part)
    best = max(parts, key=lambda p: (len(p), -min(p)), default=set())
    return best if len(best) >= 3 else set()
