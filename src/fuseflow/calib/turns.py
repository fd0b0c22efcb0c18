"""The room's turn of every camera, decided by the subject from one frame.

In a room that repeats every 360/N deg about a vertical axis, a camera turned about that axis by a
whole number of periods sees the same walls, floor and ceiling: its background agrees, every
cycle of pair poses through it still closes (a set of cameras each turned by whole periods keeps
every relative pose of the room) and its floor stays the floor. Only what is not the room, the
subject in the middle, tells the turns apart. This module measures, for the final extrinsics:

1. **the room**: up (the cameras' floor normals, refined to the merged cloud's floor), the period N
   and the axis. The merged cloud of all placed cameras, less its middle (``ROOM_MIN_RADIUS_M``),
   is turned by 360/N deg about a vertical axis; the score is the share of its points that land
   within ``ROOM_TOL_M`` of a point of the cloud whose colour (each camera's colours scaled to a
   mean of 128) is within ``COLOUR_TOL`` (the floor and ceiling are planes that every turn keeps,
   their texture is not). The axis position maximises it (grid around where the cameras' optical
   axes meet, coarse for every N in 3..``MAX_SIDES``, finer for the four best and the backbone's
   period ``info["room"]["sides"]``, then graded to 2 mm for the chosen N). ``room_period``: the
   backbone's period, or its largest divisor, is the base when its share is at least
   ``SUB_PERIOD_SHARE`` of the best and ``HINT_MIN_CONTRAST`` times the median over all N; else
   the room repeats when the best share is at least ``ROOM_MIN_SHARE`` and ``ROOM_MIN_CONTRAST``
   times that median, and the best period is the base. N is the largest multiple of the base
   with at least ``SUB_PERIOD_SHARE`` of the best share (a 12-fold room also repeats every 60
   deg, and pairs that saw only 120-deg aliases of a 6-fold room hint 3: the smallest turn is
   the one that matters), or the backbone's period when it is a multiple of that landing at
   least ``ROOM_MIN_CONTRAST`` times the median (the pairs saw its turns). When no period
   passes, the walls alone are searched again (``WALL_*``: floor and ceiling, which every turn
   keeps, lift every period's share and so the median).
2. **the subject**: each camera's points within ``subject_radius`` of the axis, more than
   ``SUBJECT_FLOOR_M`` above the floor and below ``SUBJECT_TOP_M`` (the floor is the mode of the
   lowest heights; walls and ceiling are outside that volume).
3. **pair tables**: for the ordered pair (a, b) and each relative turn d, a's subject points turned
   by d periods, seen by b: how many b sees (a 3x3 window of depth around the projection), how
   many agree with b's depth (within ``TAU_M + TAU_REL z``), how many b sees through (every
   pixel of the window beyond the point by more than that: free space where a puts the subject).
4. **the joint choice**: one turn k_c per camera minimising the sum over ordered pairs of the
   see-through share (through / seen) at d = k_a - k_b: cycle-consistent by construction
   (absolute turns). Agreement is recorded but not scored: a subject that turns into itself (a
   column on the axis) agrees best where two cameras look from nearly the same place, which says
   where they see the same surface, not which turn is right; free space seen through the subject
   is a refutation whatever the subject's shape. Greedy
   growth from every camera as anchor, then coordinate sweeps; the first placed camera (the world
   camera) keeps turn 0 (a turn of all cameras together is a turn of the world).
5. **the margin**: per camera, the see-through share of its pairs in both directions (its subject
   points seen through by the others and theirs by it) at its best other turn minus that at its
   chosen turn (turns that would put it within
   ``STACKED_M`` of another camera's centre are not alternatives). ``verdicts`` reads it.

Pure numpy plus scipy's KD-tree; no backbone state.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from fuseflow.calib.room_axis_fit import fit_axis
from fuseflow.calib.verdicts import TurnEvidence
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = [
    "RoomAxis",
    "room_axis",
    "room_period",
    "camera_turns",
    "settle_turns",
    "stacking",
    "joint_turns",
    "MAX_SIDES",
    "ROOM_MIN_SHARE",
    "ROOM_TOL_M",
    "TAU_M",
    "TAU_REL",
]

MAX_SIDES = 16
#: A turned point lands on the cloud when within this distance of a point of it (metres).
ROOM_TOL_M = 0.05
#: Points this far (horizontally) from where the cameras look are the room, not the subject.
ROOM_MIN_RADIUS_M = 1.5
#: ... and have a colour within this mean absolute difference (8-bit levels).
COLOUR_TOL = 30.0
#: A room repeats when its best period's landing share is at least ROOM_MIN_SHARE and
#: ROOM_MIN_CONTRAST times the median share over the periods 3..MAX_SIDES (module docstring).
ROOM_MIN_SHARE, ROOM_MIN_CONTRAST = 0.08, 2.0
#: ... or, for the period the backbone's pair aliases found (``hint``), HINT_MIN_CONTRAST times
#: that median (the pairs already say the room repeats; the cloud confirms the period and finds
#: the axis: symstudio's plain floor and ceiling lift every period's share).
HINT_MIN_CONTRAST = 1.3
#: A multiple of the best period (or the hinted one) whose share is at least this share of the
#: best's is the room's period: its turns keep the room too (a 12-fold symstudio at 512x424: 0.84
#: of the 6-fold share), and an unchecked turn is what makes a camera silently wrong.
SUB_PERIOD_SHARE = 0.75
#: When the room points (floor and ceiling included) find no period, the walls alone (points more
#: than WALL_BAND_M above the floor and below the top) are searched again: a repeating room's walls
#: land WALL_MIN_SHARE or more at their period, WALL_MIN_CONTRAST times the median and WALL_MIN_PEAK
#: times the neighbouring periods N - 1 and N + 1 (a round wall keeps every small turn). Measured on
#: calibrated clouds: independently rendered 6-sided studios whose cameras were placed whole turns
#: off (the merged cloud's contrast 1.30-1.77) gave best wall shares 0.48-0.61 at contrast
#: 3.6-5.7; rooms that do not repeat (kinect3-room, icl-noisy5, simulated rings and studios) gave
#: best wall shares 0.03-0.11.
WALL_BAND_M, WALL_MIN_SHARE, WALL_MIN_CONTRAST, WALL_MIN_PEAK = 0.25, 0.25, 3.0, 1.5
#: Depth agreement tolerance of subject points: TAU_M + TAU_REL * depth (metres).
TAU_M, TAU_REL = 0.02, 0.005
SUBJECT_FLOOR_M = 0.08
SUBJECT_TOP_M = 2.3
#: Two camera centres closer than this cannot both be right (a turn that does this is no alternative).
STACKED_M = 0.15
#: Frames whose subject evidence adds up.
MAX_FRAMES = 5
#: Fewer subject points seen by the other cameras than this: no turn evidence.
MIN_SEEN = 60


@dataclass(frozen=True)
class RoomAxis:
    """A repeating room: ``sides`` periods of 360/sides deg about the axis through ``point`` along
    ``up`` (world metres); ``share`` of turned points that land on the cloud; ``floor`` the floor's
    height along ``up``."""

    sides: int
    point: np.ndarray
    up: np.ndarray
    share: float
    floor: float

    def to_json(self) -> dict:
        return {"sides": self.sides, "point": [round(float(x), 4) for x in self.point],
                "up": [round(float(x), 4) for x in self.up], "share": round(self.share, 3)}  # fmt: skip

    def turn(self, k: int | float) -> np.ndarray:
        """(4, 4) world rotation by k periods about the axis."""
        a = 2 * math.pi * k / self.sides
        u = self.up
        Kx = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
        R = np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, self.point - R @ self.point
        return T


def _camera_points(depth: np.ndarray, cam, stride: int):
    """(X (P, 3) camera-frame points, v, u pixel grids, ok mask) of one camera's depth (H, W)
    sampled every ``stride`` pixels within its depth range."""
    z = depth[::stride, ::stride]
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
    ok = (z > max(cam.depth_range[0], 0.05)) & (z < cam.depth_range[1])
    X = (np.stack([u[ok], v[ok], np.ones(ok.sum())], 1) @ np.linalg.inv(cam.K).T) * z[ok][:, None]
    return X, v, u, ok


def _world_points(frame: Frame, rig: Rig, T: Mapping[str, np.ndarray], stride: int, colour: bool = False):
    """Camera -> (P, 3) world points of its depth sampled every ``stride`` pixels (with ``colour``:
    camera -> ((P, 3) points, (P, 3) float colours))."""
    depth = frame.depth.cpu().numpy()
    rgb = frame.color.cpu().numpy() if colour else None
    out = {}
    for k, c in enumerate(frame.camera_ids):
        if c not in T:
            continue
        X, v, u, ok = _camera_points(depth[k], rig[c], stride)
        Tw = invert_rigid(T[c])
        X = X @ Tw[:3, :3].T + Tw[:3, 3]
        if colour:  # each camera's colours divided by its mean (gain and white balance differ per camera)
            col = rgb[k, v[ok], u[ok]].astype(np.float32)
            out[c] = (X, col / np.maximum(col.mean(axis=0), 1.0) * 128.0)
        else:
            out[c] = X
    return out


def _up(report, T: Mapping[str, np.ndarray], frame: Frame | None = None, rig: Rig | None = None) -> np.ndarray:
    """World up: the median of the cameras' floor normals carried into the world (the backbone's,
    else fitted here in each camera's depth of ``frame``), else the mean of the cameras' -y axes
    (upright cameras)."""
    info = report.backbone_info or {}
    info = info.get("sources", {}).get("rgbd", info) if isinstance(info.get("sources"), dict) else info
    ups = []
    for c, ci in (info or {}).get("cameras", {}).items():
        fl = ci.get("floor") if isinstance(ci, dict) else None
        if c in T and fl and "normal" in fl:
            ups.append(T[c][:3, :3].T @ np.asarray(fl["normal"], dtype=np.float64))
    if not ups and frame is not None and rig is not None:  # e.g. placed by image matching alone
        ups = [T[c][:3, :3].T @ n for c, n in _floor_normals(frame, rig, T).items()]
    u = np.median(np.stack(ups), axis=0) if ups else -np.mean([M[1, :3] for M in T.values()], axis=0)
    return u / np.linalg.norm(u)


def _floor_normals(frame: Frame, rig: Rig, T: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Camera -> its floor's normal (camera frame) fitted in its depth (``floor.fit_floor_plane``),
    for the cameras of ``T`` where one fits: a camera pitched down 15-35 deg at a subject puts
    the mean of the cameras' -y axes that far from up."""
    from fuseflow.calib.floor import fit_floor_plane

    depth = frame.depth.cpu().numpy()
    out = {}
    for k, c in enumerate(frame.camera_ids):
        if c not in T:
            continue
        X = _camera_points(depth[k], rig[c], 2)[0]
        if (plane := fit_floor_plane(X)) is not None:
            out[c] = plane.normal
    return out


def _floor_normal(cloud: np.ndarray, up: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``up`` refined to the normal of the floor: the plane within 10 deg of ``up`` holding the
    most of the lowest third of the points (RANSAC, 2 cm), least-squares refitted."""
    h = cloud @ up
    low = cloud[h <= np.percentile(h, 33)]  # <=: a noise-free floor holds the whole lowest third
    if len(low) < 3:
        return up
    low = low[rng.choice(len(low), min(len(low), 6000), replace=False)]
    best, best_n = None, 0
    for _ in range(200):
        p = low[rng.choice(len(low), 3, replace=False)]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        if np.linalg.norm(n) < 1e-9:
            continue
        n = n / np.linalg.norm(n) * np.sign(n @ up)
        if n @ up < math.cos(math.radians(10)):
            continue
        inl = np.abs((low - p[0]) @ n) < 0.02
        if inl.sum() > best_n:
            best, best_n = inl, int(inl.sum())
    if best is None or best_n < 50:
        return up
    q = low[best] - low[best].mean(axis=0)
    n = np.linalg.svd(q, full_matrices=False)[2][-1]
    return n * np.sign(n @ up)


def _basis(up: np.ndarray) -> np.ndarray:
    e1 = np.cross(up, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(up, e1), up])


def _shares(room_pts, P: np.ndarray, centres: np.ndarray, angle: float, graded: bool = False) -> list[float]:
    """Per centre of ``centres`` (K, 2): the share of the room points ``P`` (x, y, height, r, g, b)
    that, turned by ``angle`` about the vertical axis through it, land within ROOM_TOL_M of a
    cloud point of similar colour; ``graded``: each landing counts 1 - distance / ROOM_TOL_M (a
    sharper optimum for the axis). One tree query for all centres, on all cores."""
    tree, cols = room_pts
    c, s = math.cos(angle), math.sin(angle)
    cx, cy = centres[:, :1], centres[:, 1:2]
    x, y = P[:, 0] - cx, P[:, 1] - cy
    q = np.broadcast_to(P[:, :3], (len(centres), *P[:, :3].shape)).copy()
    q[:, :, 0], q[:, :, 1] = cx + c * x - s * y, cy + s * x + c * y
    d, j = tree.query(q.reshape(-1, 3), distance_upper_bound=ROOM_TOL_M, workers=-1)
    hit = np.isfinite(d)
    same = np.zeros(len(d))
    src = np.flatnonzero(hit) % len(P)  # the room point each landing query turned
    same[hit] = np.abs(cols[j[hit]] - P[src, 3:]).mean(axis=1) < COLOUR_TOL
    if graded:
        same[hit] *= 1.0 - d[hit] / ROOM_TOL_M
    return [float(row.mean()) for row in same.reshape(len(centres), len(P))]


def _search_centre(room_pts, P: np.ndarray, start: np.ndarray, angle: float, levels,
                   graded: bool = False) -> tuple[np.ndarray, float]:  # fmt: skip
    """The grid point of best share (``_shares``), level by level ((half width, step) in metres,
    each grid about the last level's best): a level's best point (the first of equal shares)
    replaces the last level's only when its share is higher."""
    best, best_s = start, -1.0
    for half, step in levels:
        g = np.arange(-half, half + 1e-9, step)
        cands = np.array([best + np.array([dx, dy]) for dx in g for dy in g])
        shares = _shares(room_pts, P, cands, angle, graded)
        k = int(np.argmax(shares))
        if shares[k] > best_s:
            best, best_s = cands[k], shares[k]
    return best, best_s


def _axes_meet(T: Mapping[str, np.ndarray], B: np.ndarray) -> np.ndarray:
    """The floor-plane point (in basis ``B``) nearest, in least squares, to every camera's optical
    axis projected on the floor: where a studio's cameras look (a turn about the room's axis keeps
    it); the cameras' centroid when the axes are nearly parallel."""
    A, b, cs = np.zeros((2, 2)), np.zeros(2), []
    for M in T.values():
        c = (invert_rigid(M)[:3, 3] @ B.T)[:2]
        d = (M[2, :3] @ B.T)[:2]
        cs.append(c)
        if np.linalg.norm(d) < 0.2:
            continue
        d = d / np.linalg.norm(d)
        P = np.eye(2) - np.outer(d, d)
        A += P
        b += P @ c
    if np.linalg.cond(A) > 1e3:
        return np.mean(cs, axis=0)
    return np.linalg.solve(A, b)


def room_period(shares: Mapping[int, float], hint: int | None = None, min_share: float = ROOM_MIN_SHARE,
                min_contrast: float = ROOM_MIN_CONTRAST, min_peak: float = 0.0) -> int | None:  # fmt: skip
    """The room's period from each period's landing share (module docstring, step 1), None when
    the room does not repeat. The base period is the backbone's ``hint``, or its largest divisor,
    whose share is at least SUB_PERIOD_SHARE of the best and HINT_MIN_CONTRAST times the median
    (the pairs' turns also fit multiples of the room's period: a 10-fold room's pairs said 20, or
    more than MAX_SIDES); else, when the best share is at least ``min_share`` and ``min_contrast``
    times the median (and ``min_peak`` times the shares of its neighbouring periods N - 1 and
    N + 1: a round wall keeps every small turn), the best period. The room's period is the
    largest multiple of the base with at least SUB_PERIOD_SHARE of the best share (the smallest
    turn that keeps the room: pair aliases of 120 deg in a 6-sided room hint 3), or the hint
    when it is a multiple of that with at least ROOM_MIN_CONTRAST times the median: the pairs
    saw turns of that period, and a turn never weighed is what makes a camera silently wrong
    (polyroom seed 9030, 8-sided: the 4-fold share 0.70, the 8-fold 0.51, the median 0.13)."""
    best, median = max(shares.values()), float(np.median(list(shares.values())))
    near = {k for k, v in shares.items() if v >= SUB_PERIOD_SHARE * best}
    hinted = _hinted_base(shares, hint, near, median)
    if best < min_share or (hinted is None and best < min_contrast * median):
        return None
    base = hinted if hinted is not None else max(shares, key=lambda k: shares[k])
    if hinted is None and shares[base] < min_peak * max(shares.get(base - 1, 0.0), shares.get(base + 1, 0.0)):
        return None
    n = max(k for k in near if k % base == 0)
    if hint and hint > n and hint % n == 0 and shares.get(hint, 0.0) >= ROOM_MIN_CONTRAST * median:
        return hint
    return n


def _hinted_base(shares: Mapping[int, float], hint: int | None, near: set, median: float) -> int | None:
    """The hint or its largest divisor in ``near`` landing HINT_MIN_CONTRAST times the median,
    and a divisor or a multiple of the period that lands the most: turns of another period than
    the room's best are no turns of that room (independent studio seed 109, 6-sided: pairs read
    21, the 7-fold share 0.54 against the 6-fold 0.67; taken as 7, the subject turned cameras by
    51 deg and left two "good" 8.5 and 17 deg off)."""
    top = max(shares, key=lambda k: shares[k])
    for d in range(hint or 0, 2, -1):
        if hint % d == 0 and d in near and shares[d] >= HINT_MIN_CONTRAST * median and (top % d == 0 or d % top == 0):
            return d
    return None


def _period(room_pts, P: np.ndarray, start: np.ndarray, hint: int | None, **limits):
    """(N or None, the axis position, its share) from the room points ``P`` (step 1)."""
    coarse = {n: _search_centre(room_pts, P, start, 2 * math.pi / n, ((0.5, 0.125),)) for n in range(3, MAX_SIDES + 1)}
    fine = {n: _search_centre(room_pts, P, coarse[n][0], 2 * math.pi / n, ((0.125, 0.025),))
            for n in sorted(coarse, key=lambda n: -coarse[n][1])[:4] + ([hint] if hint in coarse else [])}  # fmt: skip
    n = room_period({n: fine.get(n, coarse[n])[1] for n in coarse}, hint, **limits)
    return (None, None, 0.0) if n is None else (n, *fine.get(n, coarse[n]))


def room_axis(points: Mapping[str, tuple[np.ndarray, np.ndarray]], T: Mapping[str, np.ndarray], up: np.ndarray,
              hint: int | None = None, rng_seed: int = 0) -> RoomAxis | None:  # fmt: skip
    """The repeating room of the merged cloud (module docstring, step 1), or None. ``points``:
    camera -> (world points, colours)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(rng_seed)
    world = np.concatenate([p for p, _ in points.values()])
    if len(world) < 500:
        return None
    up = _floor_normal(world, up, rng)
    B = _basis(up)
    cloud = world @ B.T  # (x, y, height)
    cols = np.concatenate([c for _, c in points.values()])
    h = cloud[:, 2]
    low = h[h < np.percentile(h, 1) + 0.5]
    hist, edges = np.histogram(low, bins=max(int((low.max() - low.min()) / 0.01), 1))
    floor = float(edges[np.argmax(hist)] + 0.005)
    start = _axes_meet(T, B)
    r = np.linalg.norm(cloud[:, :2] - start, axis=1)
    wall = r > ROOM_MIN_RADIUS_M  # the room, not the subject: floor and ceiling count by their colour
    if wall.sum() < 200:
        return None
    pick = np.flatnonzero(wall)
    P = np.c_[cloud, cols][rng.choice(pick, min(len(pick), 1500), replace=False)]
    room_pts = (cKDTree(cloud), cols)
    n, c, s = _period(room_pts, P, start, hint)
    band = wall & (h > floor + WALL_BAND_M) & (h < np.percentile(h, 99.5) - WALL_BAND_M)
    if n is None and band.sum() >= 200:  # the walls alone: floor and ceiling lift every period's share
        pick = np.flatnonzero(band)
        P = np.c_[cloud, cols][rng.choice(pick, min(len(pick), 1500), replace=False)]
        n, c, s = _period(
            room_pts, P, start, hint, min_share=WALL_MIN_SHARE, min_contrast=WALL_MIN_CONTRAST, min_peak=WALL_MIN_PEAK
        )
    if n is None:
        return None
    c, _ = _search_centre(room_pts, P, c, 2 * math.pi / n, ((0.03, 0.006), (0.006, 0.002)), graded=True)
    fit = fit_axis(cloud, band, c, n, rng)  # the walls pin it to least squares (calib.room_axis_fit)
    c = c if fit is None else fit
    point = B.T @ np.array([c[0], c[1], floor])
    return RoomAxis(n, point, up, s, floor)


def _subject(X: np.ndarray, room: RoomAxis, radius: float) -> np.ndarray:
    off = X - room.point
    h = off @ room.up
    r = np.linalg.norm(off - np.outer(h, room.up), axis=1)
    return X[(r < radius) & (h > SUBJECT_FLOOR_M) & (h < SUBJECT_TOP_M)]


def _tables(subj, frame: Frame, rig: Rig, T, room: RoomAxis, ids) -> np.ndarray:
    """(M, M, N, 3) seen, agree, through of a's subject turned by d periods, seen by b."""
    depth = frame.depth.cpu().numpy()
    n = room.sides
    out = np.zeros((len(ids), len(ids), n, 3))
    turns = [room.turn(d) for d in range(n)]
    for ia, a in enumerate(ids):
        X = subj[a]
        if not len(X):
            continue
        for ib, b in enumerate(ids):
            if a == b:
                continue
            cam, D = rig[b], depth[frame.camera_ids.index(b)]
            h, w = D.shape
            for d in range(n):
                M = T[b] @ turns[d]
                Y = X @ M[:3, :3].T + M[:3, 3]
                z = Y[:, 2]
                front = z > 0.05
                zs = np.where(front, z, 1.0)
                u = np.floor(cam.K[0, 0] * Y[:, 0] / zs + cam.K[0, 2] + 0.5).astype(np.int64)
                v = np.floor(cam.K[1, 1] * Y[:, 1] / zs + cam.K[1, 2] + 0.5).astype(np.int64)
                inside = front & (u >= 1) & (u <= w - 2) & (v >= 1) & (v <= h - 2)
                u, v, z = u[inside], v[inside], z[inside]
                win = np.stack([D[v + dv, u + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
                seen = (win > 0).all(axis=1)
                tau = TAU_M + TAU_REL * z
                agree = seen & (np.abs(win[:, 4] - z) <= tau)
                through = seen & (win > (z + tau)[:, None]).all(axis=1)
                out[ia, ib, d] = seen.sum(), agree.sum(), through.sum()
    return out


def _gain(tab: np.ndarray) -> np.ndarray:
    """(M, M, N) minus the share of a's subject points that b sees through, per relative turn
    (0 where b sees fewer than 20 of them)."""
    seen = tab[..., 0]
    return np.where(seen >= 20, -tab[..., 2] / np.maximum(seen, 1), 0.0)


def _objective(gain: np.ndarray, k: np.ndarray, n: int) -> float:
    d = (k[:, None] - k[None, :]) % n
    ia, ib = np.meshgrid(range(len(k)), range(len(k)), indexing="ij")
    return float(gain[ia, ib, d].sum())


def stacking(room: RoomAxis, centres: np.ndarray) -> np.ndarray:
    """(M, M, N) bool: camera a turned by d periods more than camera b has its centre within
    STACKED_M of b's (``centres`` (M, 3) world, as placed); False on the diagonal."""
    m = len(centres)
    out = np.zeros((m, m, room.sides), bool)
    for d in range(room.sides):
        M = room.turn(d)
        moved = centres @ M[:3, :3].T + M[:3, 3]
        out[:, :, d] = np.linalg.norm(moved[:, None] - centres[None], axis=2) < STACKED_M
    out[np.arange(m), np.arange(m)] = False
    return out


def joint_turns(tab: np.ndarray, n: int, stacked: np.ndarray | None = None) -> np.ndarray:
    """Absolute turns (M,) with the least summed see-through share over ordered pairs, never
    two cameras on one spot (``stacked``, :func:`stacking`): two cameras there see the same
    surface and so see through none of each other's subject, which no turn of a real rig does."""
    m = tab.shape[0]
    gain = _gain(tab)
    if stacked is not None:  # a stacking relative turn scores below any real one
        gain = np.where(stacked, -1e6, gain)  # stacked[a, b, d] == stacked[b, a, -d]: both directions
    best_k, best_j = np.zeros(m, int), _objective(gain, np.zeros(m, int), n)
    starts = [None] + list(range(m))
    for start in starts:
        if start is None:
            k = np.zeros(m, int)
        else:
            k, placed = np.zeros(m, int), [start]
            while len(placed) < m:
                cand = []
                for c in range(m):
                    if c in placed:
                        continue
                    sc = [
                        sum(gain[c, p, (t - k[p]) % n] + gain[p, c, (k[p] - t) % n] for p in placed) for t in range(n)
                    ]
                    cand.append((max(sc), c, int(np.argmax(sc))))
                _, c, t = max(cand)
                k[c] = t
                placed.append(c)
        for _ in range(4):
            changed = False
            for c in range(m):
                sc = [sum(gain[c, p, (t - k[p]) % n] + gain[p, c, (k[p] - t) % n] for p in range(m) if p != c)
                      for t in range(n)]  # fmt: skip
                t = int(np.argmax(sc))
                if sc[t] > sc[k[c]] + 1e-9:
                    k[c], changed = t, True
            if not changed:
                break
        j = _objective(gain, k, n)
        if j > best_j + 1e-9:
            best_k, best_j = k.copy(), j
    return (best_k - best_k[0]) % n  # the first placed camera (the world camera) keeps its pose


def camera_turns(
    frames, rig: Rig, T: Mapping[str, np.ndarray], report
) -> tuple[RoomAxis | None, dict[str, TurnEvidence]]:
    """(the room or None, camera -> its TurnEvidence) for the placed cameras of ``T`` (module
    docstring). Empty when fewer than two cameras are placed or the room does not repeat. With
    several frames (a Frame or a sequence), the room comes from the first and the pair tables of
    the first ``MAX_FRAMES`` add up (a moving subject gives new evidence every frame)."""
    frames = [frames] if isinstance(frames, Frame) else list(frames)
    frame = frames[0]
    ids = [c for c in frame.camera_ids if c in T]
    if len(ids) < 2:
        return None, {}
    w = rig[ids[0]].width
    pts = _world_points(frame, rig, T, max(1, round(w / 160)), colour=True)
    up = _up(report, T, frame, rig)
    info = report.backbone_info or {}
    info = info.get("sources", {}).get("rgbd", info) if isinstance(info.get("sources"), dict) else info
    hint = ((info or {}).get("room") or {}).get("sides")
    room = room_axis(pts, T, up, hint=int(hint) if hint else None)
    if room is None:
        return None, {}
    centres = {c: invert_rigid(T[c])[:3, 3] for c in ids}
    radial = [np.linalg.norm((centres[c] - room.point) - ((centres[c] - room.point) @ room.up) * room.up) for c in ids]
    radius = float(min(1.3, 0.6 * min(radial)))
    tab = 0
    for f in frames[:MAX_FRAMES]:
        fine = _world_points(f, rig, T, max(1, round(w / 160)))
        tab = tab + _tables({c: _subject(fine[c], room, radius) for c in ids}, f, rig, T, room, ids)
    k = joint_turns(tab, room.sides, stacking(room, np.stack([centres[c] for c in ids])))
    return room, _evidence(tab, k, room, ids, centres, radius)


def _share_of(tab, k, cams, n) -> tuple[float, float]:
    """(seen, score) summed over the ordered pairs with one end in ``cams`` at the turns ``k``:
    score is minus the share of the seen subject points seen through (nan below MIN_SEEN)."""
    s = np.zeros(3)
    for a in range(len(k)):
        for b in range(len(k)):
            if a != b and (a in cams or b in cams):
                s += tab[a, b, (k[a] - k[b]) % n]
    return s[0], (-s[2] / s[0] if s[0] >= MIN_SEEN else float("nan"))


def _alternatives(k, ic, stacked, n) -> list[tuple[int, np.ndarray, set]]:
    """(its turn, the rig's turns, the cameras moved) of every other placement of camera ``ic``
    that puts no two cameras on one spot: turned alone to a free spot, or onto another camera's
    spot with that one turned onto its own (a swap: a ring with a camera at every period has no
    free spot, yet two cameras swapped are as real an alternative as one turned)."""
    out = []
    for t in range(n):
        if t == k[ic]:
            continue
        on = [o for o in range(len(k)) if o != ic and stacked[ic, o, (t - k[o]) % n]]
        if not on:
            k2 = k.copy()
            k2[ic] = t
            out.append((t, k2, {ic}))
            continue
        if len(on) > 1:
            continue
        o = on[0]
        for to in range(n):
            k2 = k.copy()
            k2[ic], k2[o] = t, to
            if stacked[o, ic, (to - t) % n]:
                continue
            if stacked[o, ic, (to - k[ic]) % n] and not any(
                stacked[o, p, (to - k2[p]) % n] for p in range(len(k)) if p not in (ic, o)
            ):
                out.append((t, k2, {ic, o}))
    return out


def _evidence(tab, k, room: RoomAxis, ids, centres, radius) -> dict[str, TurnEvidence]:
    """Per camera: its score at the chosen turns, and the margin to its best alternative
    (:func:`_alternatives`), both scored over the pairs of the cameras that alternative moves."""
    n = room.sides
    stacked = stacking(room, np.stack([centres[c] for c in ids]))
    out = {}
    for ic, c in enumerate(ids):
        seen, chosen = _share_of(tab, k, {ic}, n)
        alts = _alternatives(k, ic, stacked, n)
        runner, margin, runner_score = None, None, None
        for t, k2, moved in alts:
            alt = _share_of(tab, k2, moved, n)[1]
            ref = _share_of(tab, k, moved, n)[1]
            if np.isfinite(alt) and np.isfinite(ref) and (margin is None or ref - alt < margin):
                runner, margin, runner_score = t, ref - alt, alt
        if not np.isfinite(chosen):
            margin = None
        out[c] = TurnEvidence(
            sides=n, turn=_signed(int(k[ic]), n), score=None if not np.isfinite(chosen) else round(float(chosen), 3),
            runner_up=None if runner is None else _signed(int(runner), n),
            runner_up_score=None if runner is None else round(float(runner_score), 3),
            margin=None if margin is None else round(float(margin), 3), seen=int(seen),
            alternatives=len({t for t, _, _ in alts}), subject_radius_m=round(radius, 2),
        )  # fmt: skip
    return out


def _signed(t: int, n: int) -> int:
    """A turn of whole periods as -n/2 < t <= n/2."""
    t %= n
    return int(t if t <= n // 2 else t - n)


def _turn_pose(T: np.ndarray, room: RoomAxis, e: TurnEvidence, min_margin: float) -> np.ndarray | None:
    """Camera-from-world ``T`` turned by its chosen turn about the room's axis, None when the turn
    is 0 or its margin below ``min_margin``."""
    if e.turn == 0 or e.margin is None or e.margin < min_margin:
        return None
    return T @ invert_rigid(room.turn(e.turn))


def settle_turns(T: Mapping[str, np.ndarray], room: RoomAxis, evidence: Mapping[str, TurnEvidence],
                 min_margin: float) -> tuple[dict[str, np.ndarray], dict[str, TurnEvidence]]:  # fmt: skip
    """Cameras whose chosen turn is not 0 with a margin of at least ``min_margin`` turned by it
    about the room's axis (the background keeps agreeing, the subject then agrees too); their
    evidence then reads turn 0 with ``moved`` set to the turn applied. Others unchanged."""
    T_out, ev_out = dict(T), dict(evidence)
    for c, e in evidence.items():
        if (P := _turn_pose(T[c], room, e, min_margin)) is not None:
            T_out[c] = P
            ev_out[c] = replace(e, turn=0, moved=e.turn,
                                runner_up=None if e.runner_up is None else _signed(e.runner_up - e.turn, e.sides))  # fmt: skip
    return T_out, ev_out
