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

4. ``subject_free_space``: the room repeats, the subject at its centre does not. An alias turns
   one camera about the room's axis, so what it sees of the subject (a person, a figure, the
   things beside it) lands where the other camera sees through empty space. The check counts,
   on the points off the floor within ``SUBJECT_RADIUS_M`` of where the two optical axes meet,
   the share that the other camera sees through (every pixel of a 3x3 window beyond the point
   by more than tau: a depth edge alone does not count). Measured at tau 5 % on the simulated
   symmetric studio (seeds 0-6; 5-10 cameras, 8-12-fold, Kinect v2 noise): true pair poses
   0.00-0.04, aliases 0.04 (one, 36 deg) and 0.11-0.40 otherwise; hocap-8rs's pair poses at most
   0.002. Aliases that nearly stack the cameras (axes almost parallel) are left to step 1.
   Whole-view checks cannot tell them apart (aliases agree 0.92-0.97 overall).
   ``SUBJECT_MAX_FREE_SPACE`` is the limit.

5. ``room_orbits``: the room's period and axis from the pairs' verified aliases, and every
   turn of a verified pose about that axis (its orbit): where RANSAC found only aliases of a
   pair, the orbit holds the true pose (section 5 below).

Pure numpy on the backbone's sampled views; the verification that produces the hypotheses
stays in the backbone.
"""

from __future__ import annotations

import math
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
    "subject_centre",
    "subject_free_space",
    "SUBJECT_RADIUS_M",
    "SUBJECT_MAX_FREE_SPACE",
    "SUBJECT_MIN_POINTS",
    "RoomTurn",
    "RoomOrbits",
    "screw_axis",
    "room_turns",
    "room_period",
    "axis_points",
    "turn_about",
    "room_orbits",
    "ViewRoom",
    "view_room",
    "views_room",
    "carry_axes",
    "joint_axes",
    "settled_axis",
    "settled_axes",
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


def _reachable(start: int, edges: list[tuple[int, int]]) -> set[int]:
    """The nodes an undirected graph's ``edges`` connect to ``start`` (itself included)."""
    seen, stack = {start}, [start]
    while stack:
        k = stack.pop()
        for a, b in edges:
            for u, v in ((a, b), (b, a)):
                if u == k and v not in seen:
                    seen.add(v)
                    stack.append(v)
    return seen


def bridges(edges: list[tuple[int, int]]) -> set[tuple[int, int]]:
    """The edges of an undirected graph that lie on no cycle (their removal disconnects it)."""
    return {e for e in edges if e[1] not in _reachable(e[0], [f for f in edges if f != e])}


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
        part = _reachable(s0, rest)
        seen |= part
        parts.append(part)
    best = max(parts, key=lambda p: (len(p), -min(p)), default=set())
    return best if len(best) >= 3 else set()


#: The subject: points off the floor within this distance (metres, across the floor normal when
#: the view has a floor) of where the two cameras' optical axes meet (``subject_free_space``).
SUBJECT_RADIUS_M = 1.0
#: Depth tolerance of the subject check, relative (13 cm at 2.6 m).
SUBJECT_TAU = 0.05
#: A pair pose whose subject points the other camera sees through at more than this share is
#: rejected (module docstring, step 4).
SUBJECT_MAX_FREE_SPACE = 0.08
#: Fewest subject points with depth in the other view for the check to count.
SUBJECT_MIN_POINTS = 100


def subject_centre(T_ba: np.ndarray) -> np.ndarray | None:
    """Where the optical axes (+z) of cameras a and b pass closest, in camera a's frame
    (metres): the midpoint of the shortest segment between them. None when the axes are
    nearly parallel or meet behind either camera."""
    T_ab = invert_rigid(T_ba)
    c, d = T_ab[:3, 3], T_ab[:3, 2]  # camera b's centre and axis in a's frame
    b = float(d[2])
    den = 1.0 - b * b
    if den < 1e-4:
        return None
    w = -c
    s = (b * (d @ w) - w[2]) / den  # along a's axis
    t = ((d @ w) - b * w[2]) / den  # along b's axis
    if s <= 0 or t <= 0:
        return None
    return 0.5 * (np.array([0.0, 0.0, s]) + c + t * d)


def _see_through(X: np.ndarray, T: np.ndarray, K: np.ndarray, depth: np.ndarray, tau: float):
    """(seen, through) for points X (M, 3) of one camera in another (T: this -> other, K and
    depth the other's sampled intrinsics and depth): seen, every pixel of the 3x3 window around
    the projection has depth; through, every one of them is beyond the point by more than tau."""
    Y = X @ T[:3, :3].T + T[:3, 3]
    z = Y[:, 2]
    h, w = depth.shape
    front = z > 1e-6
    zs = np.where(front, z, 1.0)
    u = np.floor(K[0, 0] * Y[:, 0] / zs + K[0, 1] * Y[:, 1] / zs + K[0, 2] + 0.5).astype(np.int64)
    v = np.floor(K[1, 1] * Y[:, 1] / zs + K[1, 2] + 0.5).astype(np.int64)
    inside = front & (u >= 1) & (u <= w - 2) & (v >= 1) & (v <= h - 2)
    u, v = np.clip(u, 1, w - 2), np.clip(v, 1, h - 2)
    win = np.stack([depth[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
    seen = inside & (win > 0).all(axis=1)
    through = seen & (win > (z * (1.0 + tau))[:, None]).all(axis=1)
    return seen, through


def subject_free_space(a, b, T_ba: np.ndarray, tau: float = SUBJECT_TAU, radius: float = SUBJECT_RADIUS_M):
    """(share, points): of the subject points of both views (module docstring, step 4) that the
    other view sees, the share it sees through under the relative pose ``T_ba`` (camera a ->
    camera b); ``points`` the number seen (share NaN when the axes do not meet in front of both).
    ``a``, ``b``: sampled views with ``samples_X`` (M, 3) metres, ``samples_floor`` (M,) bool,
    ``K_sub`` (3, 3), ``depth_sub`` (h, w) metres and ``plane`` (a floor with ``normal``, or
    None), as the rgbd backbone's ``CameraEvidence``."""
    centre = subject_centre(T_ba)
    if centre is None:
        return float("nan"), 0
    seen_n = through_n = 0
    for src, dst, T, ctr in ((a, b, T_ba, centre), (b, a, invert_rigid(T_ba), T_ba[:3, :3] @ centre + T_ba[:3, 3])):
        X = np.asarray(src.samples_X, dtype=np.float64)
        off = X - ctr
        if src.plane is not None:
            up = np.asarray(src.plane.normal, dtype=np.float64)
            off = off - np.outer(off @ up, up)
        subject = (np.linalg.norm(off, axis=1) < radius) & ~np.asarray(src.samples_floor, dtype=bool)
        K = np.asarray(dst.K_sub, dtype=np.float64)
        seen, through = _see_through(X[subject], T, K, np.asarray(dst.depth_sub), tau)
        seen_n += int(seen.sum())
        through_n += int(through.sum())
    return (through_n / seen_n if seen_n else float("nan")), seen_n


# ----------------------------------------------------------------------------- room turns
#
# 5. ``room_orbits``: in a repeating room a pair's verified poses (the true one and its aliases,
#    or only aliases) lie on one orbit, A_k = T_j S^k T_i^-1, S the room's turn by 360/N deg
#    about its vertical axis. Two of them give that turn in camera i's frame (A_k^-1 A_m = T_i
#    S^(m-k) T_i^-1: a rotation about the room's axis by a multiple of the period), so the axis
#    (a vertical line) and the period follow from the pairs that have two (``room_turns``,
#    ``room_period``); any verified pose carries the axis from one camera's frame into the
#    other's, since every pose of the orbit maps the axis onto itself (``axis_points``). Turning
#    one verified pose about camera i's axis by every multiple of the period gives the whole
#    orbit (``RoomOrbits.members``), the true pose included where RANSAC found only aliases.
#    Every member fits the repeating walls alike; the subject check tells them apart, and the
#    caller verifies the members it keeps like any candidate. Measured on symstudio seed 12 (5
#    cameras, 11-fold; poses from the floor and image routes): every member nearest the truth
#    was within 0.06 deg / 5 mm of it.

#: Two poses of a pair this far apart (deg) may be a room turn (nearer ones are one pose, noisy).
TURN_MIN_DEG = 10.0
#: A room turn's rotation axis is within this (deg) of the camera's floor normal ...
TURN_AXIS_DEG = 5.0
#: ... and it slides along that axis by at most this (metres): a turn, not a screw.
TURN_PITCH_M = 0.1
#: A room turn's angle is within this (deg) of a multiple of the period (``room_period``).
TURN_TOL_DEG = 3.0
#: The most sides ``room_period`` considers (a period of 22.5 deg), as many as the calibrated
#: cloud's room search (``turns.MAX_SIDES``) can confirm. A larger N fits loose turns by chance:
#: on an 8-sided independent studio (seed 1118) one pair's two verified poses turned by 45.9 deg
#: and a wrong pose of another pair by 34.2 deg; N = 23 fitted all four within 3 deg, the
#: pairs' room took it over the 8 of the verified poses, and every turned pose was 2 deg per
#: period off yet verified at tau.
MAX_SIDES = 16
#: A period fits when at least this share of the turns lands near its multiples: the rest are
#: turns to wrong poses that passed verification (independent studio seed 936, 10-sided: 14 of
#: 26 turns at multiples of 36 deg, the others to four poses 4-18 deg off the orbit).
TURN_MIN_FIT = 0.5
#: ... and random angles would land as many with at most this chance: five random angles fit a
#: 20-fold room 3 times within 3 deg (chance 0.21), one pair's two poses 40 deg apart a 9-fold
#: one twice (0.02: its two turns, one in each camera's frame).
TURN_MAX_CHANCE = 0.05
#: A pose whose turns alone fit a multiple of the period is dropped only when this many other
#: pairs turn by the period (``_outlier_pose``).
MIN_OTHER_PAIRS = 2


@dataclass(frozen=True)
class RoomTurn:
    """One room turn seen by pair ``pair`` in camera ``camera``'s frame: ``angle`` deg (signed,
    about ``up``), ``up`` the axis direction (unit, the camera's floor normal where it has one),
    ``point`` the foot of the axis nearest the camera centre (metres); ``poses`` the indices of
    the pair's two poses it lies between."""

    pair: tuple
    camera: int
    angle: float
    up: np.ndarray
    point: np.ndarray
    poses: tuple = ()


def screw_axis(D: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, float]:
    """(angle deg in [0, 180], unit axis u, the axis point nearest the origin, pitch m: the
    slide along u) of the rigid motion D (4, 4): x -> R x + t. The axis's sign makes the angle
    positive (any unit vector for the identity)."""
    R, t = D[:3, :3], D[:3, 3]
    ang = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    w, V = np.linalg.eigh(0.5 * (R + R.T))
    u = V[:, int(np.argmax(w))]
    skew = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if skew @ u < 0:
        u = -u
    pitch = float(u @ t)
    p = np.linalg.lstsq(np.eye(3) - R, t - pitch * u, rcond=None)[0]
    return ang, u, p - (p @ u) * u, pitch


def _turn_of(D: np.ndarray, pair: tuple, cam: int, up: np.ndarray | None, poses: tuple = ()) -> RoomTurn | None:
    """The room turn D (in camera ``cam``'s frame) is, or None: too small, tilted off ``up``
    (the camera's floor normal, or None) or sliding along its axis."""
    ang, u, p, pitch = screw_axis(D)
    if ang < TURN_MIN_DEG or abs(pitch) > TURN_PITCH_M:
        return None
    if up is not None:
        up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        if abs(u @ up) < np.cos(np.radians(TURN_AXIS_DEG)):
            return None
        ang, u = (ang if u @ up > 0 else -ang), up
    return RoomTurn(pair, cam, ang, u, p - (p @ u) * u, poses)


def room_turns(poses: dict[tuple[int, int], list[np.ndarray]], ups: dict[int, np.ndarray | None]) -> list[RoomTurn]:
    """The room turns of every pair with two or more verified poses (section 5): for poses A, B
    of pair (i, j) (camera i -> camera j), A^-1 B in camera i's frame and B A^-1 in camera j's.
    ``ups``: camera -> its floor normal (or None)."""
    out = []
    for (i, j), Ts in sorted(poses.items()):
        for k in range(len(Ts)):
            for m in range(k + 1, len(Ts)):
                A, B = np.asarray(Ts[k], np.float64), np.asarray(Ts[m], np.float64)
                for D, cam in ((invert_rigid(A) @ B, i), (B @ invert_rigid(A), j)):
                    turn = _turn_of(D, (i, j), cam, ups.get(cam), (k, m))
                    if turn is not None:
                        out.append(turn)
    return out


def _fit_weights(angles: np.ndarray, sides: int, tol: float) -> np.ndarray:
    """Per angle (deg): 1 - (r / ``tol``)^2 where its distance r to the nearest non-zero multiple
    of 360/``sides`` is within ``tol``, else 0 (a turn fits by how precisely it lands)."""
    a = np.abs(angles) % 360.0
    p = 360.0 / sides
    k = np.round(a / p)
    r = np.abs(a - k * p)
    return np.where((r <= tol) & (k % sides != 0), 1.0 - (r / tol) ** 2, 0.0)


def _fits(angles: np.ndarray, sides: int, tol: float) -> np.ndarray:
    """Which angles (deg) are within ``tol`` of a non-zero multiple of 360/``sides``."""
    return _fit_weights(angles, sides, tol) > 0


def room_period(angles: list[float], tol: float = TURN_TOL_DEG, max_sides: int = MAX_SIDES) -> int | None:
    """The number of sides N (2..``max_sides``) whose multiples of 360/N fit the turn angles
    (deg) best: each angle within ``tol`` of one counts 1 - (r / tol)^2 by its distance r, less
    what random angles would count (2 tol N / 360 of them fit, 2/3 on average: a larger N fits
    more by chance); ties to the smaller N. The count by distance keeps a wrong N from fitting
    every turn loosely: a 10-fold room's turns of 36.2-36.6 deg fit N = 21 (34.3 deg) within
    3 deg as well as N = 10, and the poses turned by 21ths were then 2 deg off per period yet
    verified at tau (independent studio seeds 919, 936). An N counts only when at least
    TURN_MIN_FIT of the angles fit it and random angles would fit as many with a chance of at
    most TURN_MAX_CHANCE (binomial tail); None when no N does."""
    a = np.asarray(angles, dtype=np.float64)
    best, best_score = None, -np.inf
    for n in range(2, max_sides + 1):
        w = _fit_weights(a, n, tol)
        hits, p = int((w > 0).sum()), min(1.0, 2 * tol * n / 360.0)
        score = float(w.sum()) - len(a) * p * 2.0 / 3.0
        chance = sum(math.comb(len(a), k) * p**k * (1 - p) ** (len(a) - k) for k in range(hits, len(a) + 1))
        if hits and hits >= TURN_MIN_FIT * len(a) and chance <= TURN_MAX_CHANCE and score > best_score + 1e-9:
            best, best_score = n, score
    return best


def _outlier_pose(turns: list[RoomTurn], sides: int) -> tuple | None:
    """(pair, pose index) of a pose that alone makes ``sides`` fit better than a divisor d of it:
    every turn that fits ``sides`` but not d lies between that pose and another of its pair, two
    other poses of that pair turn by a multiple of 360/d, and so do the turns of at least
    MIN_OTHER_PAIRS other pairs. One wrong pose verified among a pair's aliases brings a turn to
    each of them (independent studio seed 936, 10-sided: one pose 17.8 deg off among three
    aliases gave 6 of 26 turns at odd multiples of 18 deg, four other pairs turned by 36-deg
    multiples). A pair alone keeps its period (seed 501, 6-sided: one pair's three aliases 60 deg
    apart, no other pair turned). None when there is no such pose."""
    a = np.array([t.angle for t in turns])
    fit = _fits(a, sides, TURN_TOL_DEG)
    for d in sorted((d for d in range(2, sides) if sides % d == 0), reverse=True):
        fit_d = _fits(a, d, TURN_TOL_DEG)
        extra = [t for t, ok, ok_d in zip(turns, fit, fit_d) if ok and not ok_d]
        if not extra or any(not t.poses for t in extra) or len({t.pair for t in extra}) > 1:
            continue
        pair = extra[0].pair
        if len({t.pair for t, ok_d in zip(turns, fit_d) if ok_d and t.pair != pair}) < MIN_OTHER_PAIRS:
            continue
        for q in sorted(set.intersection(*(set(t.poses) for t in extra))):
            if any(t.pair == pair and q not in t.poses and ok_d for t, ok_d in zip(turns, fit_d)):
                return pair, q
    return None


def axis_points(turns: list[RoomTurn], poses: dict[tuple[int, int], list[np.ndarray]]) -> dict[int, tuple]:
    """Camera -> (up, point) of the room's axis in its frame: the median of its own turns' axis
    points, else carried from a camera that has one through the first verified pose of their
    pair (every pose of the orbit maps the axis onto itself), breadth first from the cameras
    with the most turns."""
    own: dict[int, list[RoomTurn]] = {}
    for t in turns:
        own.setdefault(t.camera, []).append(t)
    axes = {c: (ts[0].up, np.median([t.point for t in ts], axis=0)) for c, ts in own.items()}
    return carry_axes({c: axes[c] for c in sorted(axes, key=lambda c: (-len(own[c]), c))}, poses)


def turn_about(up: np.ndarray, point: np.ndarray, angle_deg: float) -> np.ndarray:
    """(4, 4) rotation by ``angle_deg`` about the line through ``point`` along ``up``."""
    u = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    th = np.radians(angle_deg)
    Kx = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, point - R @ point
    return T


@dataclass(frozen=True)
class RoomOrbits:
    """A repeating room seen through the pairs' verified poses (section 5): ``sides`` its period
    (360/sides deg), ``axes`` camera -> (up, point) of its axis in that camera's frame, ``turns``
    and ``pairs`` how many room turns, from how many pairs, fitted them; ``views`` how many
    cameras' own views showed it (section 6, ``views_room``), 0 when the pairs did."""

    sides: int
    axes: dict
    turns: int
    pairs: int
    views: int = 0
    #: cameras whose own axis rests on at least JOINT_KEEP_TURNS of its turns whose axis points lie
    #: a median JOINT_KEEP_MAD_M or less from their median (``settled_axes``): ``joint_axes`` keeps it
    settled: frozenset = frozenset()

    def members(self, i: int, T_ji: np.ndarray, known: list[np.ndarray], rot_deg: float = 5.0,
                trans_m: float = 0.2) -> list[tuple[float, np.ndarray]]:  # fmt: skip
        """The other poses of ``T_ji``'s orbit (camera i -> camera j), as (turn deg, pose):
        T_ji turned about camera i's axis by every non-zero multiple of the period, leaving out
        those within ``rot_deg`` / ``trans_m`` of a pose in ``known`` or of one listed before.
        Empty when camera i has no axis."""
        if i not in self.axes:
            return []
        up, p = self.axes[i]
        out: list[tuple[float, np.ndarray]] = []
        for k in range(1, self.sides):
            angle = 360.0 * k / self.sides
            T = np.asarray(T_ji, np.float64) @ turn_about(up, p, angle)
            if all(_differ(T, K, rot_deg, trans_m) for K in list(known) + [o for _, o in out]):
                out.append((angle, T))
        return out

    def info(self) -> dict:
        out = {"sides": self.sides, "turns": self.turns, "pairs": self.pairs, "cameras_with_axis": len(self.axes)}
        return {**out, "views": self.views} if self.views else out


def room_orbits(poses: dict[tuple[int, int], list[np.ndarray]], ups: dict[int, np.ndarray | None]) -> RoomOrbits | None:
    """The room's repeat (section 5) from the pairs' verified poses (pair (i, j) -> poses camera
    i -> camera j, each pair's mutually distinct ones) and the cameras' floor normals, or None:
    no pair shows a room turn, or no period fits the turns. One turn is enough (symstudio seed
    13: one pair had two poses, none other more than one): a wrong period or axis costs only
    time, since every turned pose must still pass the subject check and the depth checks."""
    turns = room_turns(poses, ups)
    sides = room_period([t.angle for t in turns])
    while sides is not None and (out := _outlier_pose(turns, sides)) is not None:
        turns = [t for t in turns if not (t.pair == out[0] and out[1] in t.poses)]
        sides = room_period([t.angle for t in turns])
    if sides is None:
        return None
    fit = [t for t, ok in zip(turns, _fits(np.array([t.angle for t in turns]), sides, TURN_TOL_DEG)) if ok]
    pairs = {t.pair for t in fit}
    if not pairs:
        return None
    return RoomOrbits(sides, axis_points(fit, poses), len(fit), len(pairs), settled=settled_axes(fit))


def settled_axes(turns: list[RoomTurn]) -> frozenset:
    """The cameras with at least JOINT_KEEP_TURNS of ``turns`` whose axis points lie a median
    JOINT_KEEP_MAD_M or less from their median (section 7)."""
    own: dict[int, list[np.ndarray]] = {}
    for t in turns:
        own.setdefault(t.camera, []).append(np.asarray(t.point, np.float64))
    out = set()
    for c, pts in own.items():
        P = np.array(pts)
        mad = float(np.median(np.linalg.norm(P - np.median(P, axis=0), axis=1)))
        if len(P) >= JOINT_KEEP_TURNS and mad <= JOINT_KEEP_MAD_M:
            out.add(c)
    return frozenset(out)


# ----------------------------------------------------------------------------- a room in one view
#
# 6. ``view_room``: where every pair's verified poses are mutually consistent aliases (cameras
#    mounted near whole periods of the room: every pose stacks one camera on the other, or turns
#    it by the same number of periods around every cycle) no pair shows a room turn, and
#    ``room_orbits`` finds nothing. One camera's own view shows the repeat: its wall points
#    (VIEW_BAND_M above the floor and below the top), turned by 360/N deg about the right
#    vertical axis, land on its own points of the same colour. The axis is searched on a grid
#    (VIEW_STEP_M) along the camera's look on the floor, VIEW_NEAR_M to VIEW_FAR_M out and
#    VIEW_ACROSS_M to each side (a studio's cameras look at its middle), for every N in
#    3..MAX_SIDES; points within VIEW_SUBJECT_M of the axis (the subject) do not count. The
#    period is the best N when its share is at least VIEW_MIN_SHARE, VIEW_MIN_CONTRAST times the
#    median over N and VIEW_MIN_PEAK times N - 1's and N + 1's (a round wall keeps every small
#    turn), then its largest multiple with at least VIEW_SUB_SHARE of the best share (a 12-sided
#    room also repeats every 60 deg); the axis is then graded to 5 mm. ``views_room`` takes a
#    room only when VIEW_MIN_CAMERAS cameras read the same N. Measured on independently
#    rendered studios at 320x240 (seeds 1107, 10-sided, and 1123, 6-sided): every one of 12
#    cameras read its room's N, share 0.22-0.43 at 2.0-3.3 times the median and 1.4-3.0 times
#    its neighbours, the axis within 1-6 cm of the truth on the 10 cm grid.

#: A turned wall point lands when within this (metres) of a point of the view of similar colour.
VIEW_TOL_M = 0.05
#: ... whose colour (each view's colours scaled to a mean of 128) is within this (8-bit levels).
VIEW_COLOUR_TOL = 30.0
#: Wall points: this far (metres) above the floor and below the highest points.
VIEW_BAND_M = 0.25
#: Points this close (metres, horizontally) to the axis are the subject, not the room.
VIEW_SUBJECT_M = 1.2
#: The axis grid: along the camera's look on the floor from VIEW_NEAR_M to VIEW_FAR_M, VIEW_ACROSS_M
#: to each side, every VIEW_STEP_M (metres).
VIEW_NEAR_M, VIEW_FAR_M, VIEW_ACROSS_M, VIEW_STEP_M = 1.5, 4.5, 0.8, 0.1
#: Wall points sampled per view (fixed seed).
VIEW_POINTS = 400
#: A view's period: share, contrast to the median over N, peak over N - 1 and N + 1.
VIEW_MIN_SHARE, VIEW_MIN_CONTRAST, VIEW_MIN_PEAK = 0.15, 1.8, 1.3
#: A multiple of the best period landing at least this share of the best's is the period.
VIEW_SUB_SHARE = 0.75
#: Cameras that must read the same period (``views_room``); the search stops after
#: VIEW_MAX_TRIES views without that many agreeing.
VIEW_MIN_CAMERAS, VIEW_MAX_TRIES = 2, 4


@dataclass(frozen=True)
class ViewRoom:
    """The room one view shows: ``sides``, its axis (``up`` and ``point`` on it, the view's frame,
    metres), ``share`` of turned wall points that land, ``contrast`` to the median over N."""

    sides: int
    up: np.ndarray
    point: np.ndarray
    share: float
    contrast: float


def _view_shares(tree, cols, P: np.ndarray, PC: np.ndarray, centres: np.ndarray, sides: int,
                 graded: bool = False) -> np.ndarray:  # fmt: skip
    """Per centre (C, 2): the share of wall points P (x, y, height) turned by 360/sides about the
    vertical through it that land on the view (``graded``: by 1 - distance / VIEW_TOL_M), points
    within VIEW_SUBJECT_M of it left out."""
    a = 2 * math.pi / sides
    R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    q = np.empty((len(centres), len(P), 3))
    q[:, :, :2] = (P[:, :2] @ R.T)[None] + (centres - centres @ R.T)[:, None]
    q[:, :, 2] = P[None, :, 2]
    d, j = tree.query(q.reshape(-1, 3), distance_upper_bound=VIEW_TOL_M)
    hit = np.isfinite(d)
    same = np.zeros(len(d))
    same[hit] = np.abs(cols[j[hit]] - np.tile(PC, (len(centres), 1))[hit]).mean(axis=1) < VIEW_COLOUR_TOL
    if graded:
        same[hit] *= 1.0 - d[hit] / VIEW_TOL_M
    far = np.linalg.norm(P[None, :, :2] - centres[:, None], axis=2) > VIEW_SUBJECT_M
    return (same.reshape(len(centres), -1) * far).sum(axis=1) / np.maximum(far.sum(axis=1), 1)


def _view_period(best: dict[int, tuple[float, np.ndarray]]) -> int | None:
    """The period from each N's best share (section 6), or None."""
    shares = {n: s for n, (s, _) in best.items()}
    top = max(shares, key=lambda n: shares[n])
    median = float(np.median(list(shares.values())))
    nb = max(shares.get(top - 1, 0.0), shares.get(top + 1, 0.0))
    if shares[top] < VIEW_MIN_SHARE or shares[top] < VIEW_MIN_CONTRAST * median or shares[top] < VIEW_MIN_PEAK * nb:
        return None
    return max(n for n in shares if n % top == 0 and shares[n] >= VIEW_SUB_SHARE * shares[top])


def view_room(X: np.ndarray, rgb: np.ndarray, up: np.ndarray, sides: int | None = None,
              seed: int = 0) -> ViewRoom | None:  # fmt: skip
    """The repeating room one view shows (section 6), or None. ``X`` (P, 3) the view's points in
    its frame (metres, camera looking along +z), ``rgb`` (P, 3) their colours scaled to a mean of
    128, ``up`` its floor normal; ``sides``: only that period is tried (its share at least
    VIEW_MIN_SHARE)."""
    from scipy.spatial import cKDTree

    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    B = np.stack([e1, np.cross(up, e1), up])
    cl = np.asarray(X, np.float64) @ B.T
    look = B[:2, 2]
    if len(cl) < 500 or np.linalg.norm(look) < 0.5:
        return None
    look = look / np.linalg.norm(look)
    h = cl[:, 2]
    low = h[h < np.percentile(h, 1) + 0.5]
    hist, edges = np.histogram(low, bins=max(int((low.max() - low.min()) / 0.01), 1))
    floor = float(edges[np.argmax(hist)] + 0.005)
    band = np.flatnonzero((h > floor + VIEW_BAND_M) & (h < np.percentile(h, 99.5) - VIEW_BAND_M))
    if len(band) < 200:
        return None
    pick = np.random.default_rng(seed).choice(band, min(len(band), VIEW_POINTS), replace=False)
    tree, cols, P, PC = cKDTree(cl), np.asarray(rgb, np.float64), cl[pick], np.asarray(rgb, np.float64)[pick]
    side = np.array([-look[1], look[0]])
    across = np.arange(-VIEW_ACROSS_M, VIEW_ACROSS_M + 1e-9, VIEW_STEP_M)
    centres = np.array([a * look + b * side for a in np.arange(VIEW_NEAR_M, VIEW_FAR_M + 1e-9, VIEW_STEP_M)
                        for b in across])  # fmt: skip
    best = {}
    for n in [sides] if sides else range(3, MAX_SIDES + 1):
        s = _view_shares(tree, cols, P, PC, centres, n)
        best[n] = (float(s.max()), centres[int(np.argmax(s))])
    n = (sides if best[sides][0] >= VIEW_MIN_SHARE else None) if sides else _view_period(best)
    if n is None:
        return None
    c = best[n][1]
    for half, step in ((VIEW_STEP_M, 0.025), (0.025, 0.005)):
        g = np.arange(-half, half + 1e-9, step)
        grid = c + np.array([[x, y] for x in g for y in g])
        c = grid[int(np.argmax(_view_shares(tree, cols, P, PC, grid, n, graded=True)))]
    median = float(np.median([s for s, _ in best.values()])) if not sides else float("nan")
    return ViewRoom(n, up, B.T @ np.array([c[0], c[1], floor]), best[n][0], best[n][0] / max(median, 1e-9))


def carry_axes(own: dict[int, tuple], poses: dict[tuple[int, int], list[np.ndarray]]) -> dict[int, tuple]:
    """Camera -> (up, point) of the room's axis: ``own`` (the cameras that have one), carried to
    the others through the first verified pose of their pair (every pose of the orbit maps the
    axis onto itself), breadth first in the order of ``own``."""
    out = dict(own)
    queue = list(out)
    while queue:
        c = queue.pop(0)
        up, p = out[c]
        for (i, j), Ts in sorted(poses.items()):
            other = j if c == i else i
            if c not in (i, j) or not len(Ts) or other in out:
                continue
            T = np.asarray(Ts[0], np.float64) if c == i else invert_rigid(np.asarray(Ts[0], np.float64))
            u2, q = T[:3, :3] @ up, T[:3, :3] @ p + T[:3, 3]
            out[other] = (u2, q - (q @ u2) * u2)
            queue.append(other)
    return out


def views_room(views, poses: dict[tuple[int, int], list[np.ndarray]]) -> RoomOrbits | None:
    """The room the cameras' own views show (section 6) as ``RoomOrbits``, or None. ``views``: per
    camera (X, rgb, up) for ``view_room``, or None (no floor); ``poses`` the
    pairs' verified poses, which carry the axis to cameras whose view does not show it. The
    period is the first one VIEW_MIN_CAMERAS views read (at most VIEW_MAX_TRIES views tried
    before that); every other view is then searched at that period only."""
    found: dict[int, ViewRoom] = {}
    tried, sides = 0, None
    for k, view in enumerate(views):
        if view is None or tried >= VIEW_MAX_TRIES:
            continue
        tried += 1
        vr = view_room(*view)
        if vr is not None:
            found[k] = vr
            if sum(v.sides == vr.sides for v in found.values()) >= VIEW_MIN_CAMERAS:
                sides = vr.sides
                break
    if sides is None:
        return None
    own = {k: (v.up, v.point) for k, v in found.items() if v.sides == sides}
    for k, view in enumerate(views):
        if view is not None and k not in own:
            vr = view_room(*view, sides=sides)
            if vr is not None:
                own[k] = (vr.up, vr.point)
    return RoomOrbits(sides, carry_axes(own, poses), 0, 0, views=len(own))


# ----------------------------------------------------------------------------- one axis for all
#
# 7. ``joint_axes``: the axes of sections 5 and 6 are each camera's own (the median of its turns'
#    axis points, or its view's grid search), a few centimetres off, and a pose turned by k of N
#    periods about camera i's axis moves camera j by 2 sin(k pi / N) times that error. Every
#    verified pose of the orbit maps the room's walls onto its walls, so the cameras' views, put
#    into one camera's frame through a tree of verified poses, form one wall cloud; the axis is
#    fitted to it by least squares (``room_axis_fit.fit_axis``: the walls turned by every period
#    land on the walls) and carried back to every camera through the same poses, so each
#    camera's axis is where its own points, as placed in the cloud, turn onto the others'.
#    Cameras the tree does not reach keep their own axis; a fit that moves the axis more than
#    JOINT_MAX_SHIFT_M from its start, or fails, changes nothing.

#: The fitted axis may lie at most this far (metres) from the starting one (the root camera's own):
#: further, the cloud was not one room (a verified pose off the orbit) and the own axes stay.
JOINT_MAX_SHIFT_M = 0.15
#: Points of each view used in the joint cloud (fixed seed).
JOINT_POINTS = 6000
#: ``fit_axis`` is repeated from its own result, at most JOINT_ROUNDS times, until it moves less
#: than JOINT_SETTLED_M (metres): one call's six steps covered 6 of 27 mm on independent studio
#: seed 1400 (8-sided), repeated calls settled 13 mm from the truth.
JOINT_ROUNDS, JOINT_SETTLED_M = 8, 0.001
#: A cycle of three verified poses closes when its loop is a whole number of periods within this
#: (deg) and moves at most JOINT_CYCLE_M (metres) otherwise; the tree of poses that carries the
#: views prefers poses that close the most cycles. On independent studio seed 1202 (10-sided,
#: moving subject) a verified alias 4.5 deg / 17 cm off the orbit carried one camera's walls 6 cm
#: off the others' when the tree took it as the first pose of its pair.
JOINT_CYCLE_DEG, JOINT_CYCLE_M = 0.6, 0.03
#: A camera whose own axis is the median of at least JOINT_KEEP_TURNS turns' axis points lying a
#: median JOINT_KEEP_MAD_M (metres) or less from it keeps that axis: on symstudio seed 10105
#: (10-sided, 158 turns of 15 pairs) the own axes were 0.1-0.9 mm from the truth, the joint one
#: 4 mm and, through one pose, 83 mm; on independent seed 935 the cameras with 5-11 turns within
#: 2.4-2.9 mm were 0.5-1.2 mm off, the two whose turns scattered 55-60 mm, 10 and 51 mm.
JOINT_KEEP_TURNS, JOINT_KEEP_MAD_M = 5, 0.005


def _directed(poses: dict[tuple[int, int], list[np.ndarray]], a: int, b: int) -> list[np.ndarray]:
    """The verified poses camera a -> camera b (inverted where the pair is stored as (b, a))."""
    if (a, b) in poses:
        return [np.asarray(T, np.float64) for T in poses[(a, b)]]
    return [invert_rigid(np.asarray(T, np.float64)) for T in poses.get((b, a), [])]


def _closes(C: np.ndarray, up: np.ndarray, sides: int) -> bool:
    """Whether the loop C (4, 4) around a cycle of three cameras, in the first camera's frame, is
    a room turn: within JOINT_CYCLE_DEG of a whole number of periods about the camera's ``up``,
    sliding at most JOINT_CYCLE_M along it (or moving at most that, unturned)."""
    ang, u, _, pitch = screw_axis(C)
    if ang < JOINT_CYCLE_DEG:
        return bool(np.linalg.norm(C[:3, 3]) < JOINT_CYCLE_M)
    period = 360.0 / sides
    off = abs(ang - period * round(ang / period))
    return off < JOINT_CYCLE_DEG and abs(u @ up) > np.cos(np.radians(JOINT_CYCLE_DEG)) and abs(pitch) < JOINT_CYCLE_M


def _cycle_support(poses: dict[tuple[int, int], list[np.ndarray]], ups: dict, sides: int) -> dict[tuple, int]:
    """(camera a, camera b, pose index) -> how many third cameras close a cycle with that pose
    (``_closes``, any of the other two pairs' poses): a pose off the room's orbit closes none."""
    cams = sorted({c for p in poses for c in p})
    out = {}
    for a, b in poses:
        for m, A in enumerate(_directed(poses, a, b)):
            n = 0
            for k in cams:
                if k in (a, b) or a not in ups:
                    continue
                n += any(_closes(C @ Bk @ A, ups[a], sides)
                         for Bk in _directed(poses, b, k) for C in _directed(poses, k, a))  # fmt: skip
            out[(a, b, m)] = out[(b, a, m)] = n
    return out


def _pose_tree(root: int, poses: dict[tuple[int, int], list[np.ndarray]], support: dict | None = None):
    """Camera -> the (4, 4) map from its frame into ``root``'s through verified poses: a tree
    grown from ``root`` by the pose that closes the most cycles (``support``: ``_cycle_support``;
    ties to the first pair in sorted order, then its first pose)."""
    support = support or {}
    tree = {root: np.eye(4)}
    while True:
        best = None
        for i, j in sorted(poses):
            for c, other in ((i, j), (j, i)):
                if c not in tree or other in tree:
                    continue
                for m, T in enumerate(_directed(poses, other, c)):  # other -> c
                    key = (-support.get((i, j, m), 0), i, j, m)
                    if best is None or key < best[0]:
                        best = (key, other, tree[c] @ T)
        if best is None:
            return tree
        tree[best[1]] = best[2]


def _wall_cloud(views, tree: dict[int, np.ndarray], B: np.ndarray, start: np.ndarray, seed: int):
    """(cloud (P, 3) in the basis ``B`` (x, y, height) of the root's frame, wall mask, floor
    height): every reached view's points, walls VIEW_BAND_M above the floor and below the top and
    VIEW_SUBJECT_M from ``start`` (x, y)."""
    rng = np.random.default_rng(seed)
    parts = []
    for c, M in tree.items():
        if c < len(views) and views[c] is not None:
            X = np.asarray(views[c][0], np.float64)
            X = X[rng.choice(len(X), min(len(X), JOINT_POINTS), replace=False)]
            parts.append((X @ M[:3, :3].T + M[:3, 3]) @ B.T)
    cloud = np.concatenate(parts) if parts else np.zeros((0, 3))
    if len(cloud) < 500:
        return cloud, np.zeros(len(cloud), bool), 0.0
    h = cloud[:, 2]
    low = h[h < np.percentile(h, 1) + 0.5]
    hist, edges = np.histogram(low, bins=max(int((low.max() - low.min()) / 0.01), 1))
    floor = float(edges[np.argmax(hist)] + 0.005)
    walls = (h > floor + VIEW_BAND_M) & (h < np.percentile(h, 99.5) - VIEW_BAND_M)
    walls &= np.linalg.norm(cloud[:, :2] - start, axis=1) > VIEW_SUBJECT_M
    return cloud, walls, floor


def settled_axis(wall_fit, start: np.ndarray, sides: int, seed: int = 0) -> np.ndarray | None:
    """``wall_fit`` (``room_axis_fit.WallFit``) repeated from ``start``, each round from where the
    last one ended (it re-collects the landing points), at most JOINT_ROUNDS times until it moves
    less than JOINT_SETTLED_M; None when a round fails."""
    fit = start
    for k in range(JOINT_ROUNDS):
        last, fit = fit, wall_fit.fit(fit, sides, np.random.default_rng(seed + k))
        if fit is None or np.linalg.norm(fit - last) < JOINT_SETTLED_M:
            break
    return fit


def joint_axes(room: RoomOrbits, views, poses: dict[tuple[int, int], list[np.ndarray]], seed: int = 0) -> RoomOrbits:
    """``room`` with one axis fitted to every reached camera's walls (section 7), expressed in each
    camera's frame through the verified poses ``poses``; ``views``: per camera (X, ...) its points
    in its frame (``view_room``'s input) or None. ``room`` unchanged when no fit holds."""
    from fuseflow.calib.room_axis_fit import WallFit

    with_view = [c for c in room.axes if c < len(views) and views[c] is not None]
    if not with_view:
        return room
    support = _cycle_support(poses, {c: np.asarray(u, np.float64) for c, (u, _) in room.axes.items()}, room.sides)
    root = max(with_view, key=lambda c: (len(_pose_tree(c, poses)), -c))
    tree = _pose_tree(root, poses, support)
    up, p = room.axes[root]
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    e1 = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    B = np.stack([e1, np.cross(up, e1), up])
    start = (B @ np.asarray(p, np.float64))[:2]
    cloud, walls, floor = _wall_cloud(views, tree, B, start, seed)
    if walls.sum() < 200:
        return room
    fit = settled_axis(WallFit(cloud, walls), start, room.sides, seed)
    if fit is None or np.linalg.norm(fit - start) > JOINT_MAX_SHIFT_M:
        return room
    q = B.T @ np.array([fit[0], fit[1], 0.0])
    axes = dict(room.axes)
    for c, M in tree.items():  # M: camera c -> root; the axis into c by its inverse
        if c in room.settled:
            continue
        Mi = invert_rigid(M)
        u2, q2 = Mi[:3, :3] @ up, Mi[:3, :3] @ q + Mi[:3, 3]
        axes[c] = (u2, q2 - (q2 @ u2) * u2)
    return RoomOrbits(room.sides, axes, room.turns, room.pairs, room.views, room.settled)
