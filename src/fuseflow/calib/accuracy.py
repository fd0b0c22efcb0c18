"""Expected accuracy of a placed camera: how far its pose probably is from the truth.

Two estimates, the larger one kept (each sees an error the other cannot), or, for a camera the
joint refinement moved, the rule of 3; in a repeating room the position is at least 4:

1. **From the correspondences of its pair poses** (``pair_pose_accuracy``, stored per edge by
   the rgbd backbone): the 3-D correspondences a pair pose was fitted to are grouped into cells
   of ``CELL_M`` (points of one patch share their depth error, so a cell is one measurement,
   not hundreds), and the covariance of the rigid fit follows from the cells' residuals and
   their geometry: rotation sigma^2 H^-1 (H = sum of [q]x^T [q]x over the centred cells q),
   position of camera a's centre in camera b sigma^2 / n + the rotation's lever arm from the
   cells' centroid to the camera. A few cells far away (a ball 4 m off, a track 1 m long)
   give a large lever arm; hundreds of cells around the cameras give a small one. Each edge's
   estimate is at least ``SYSTEMATIC_DEG`` / ``SYSTEMATIC_MM`` (a depth bias common to all
   cells, which no residual shows). A camera linked by several agreeing pair poses gets their
   inverse-variance combination.
2. **From the disagreement of its pair poses with the result** (``residual_accuracy``): RMS /
   sqrt(n) over its n >= 2 agreeing pair poses: each pair is one independent measurement of
   the pose, so their scatter about the result shows errors of the individual pairs. After an
   accepted joint refinement that scatter is the pair poses' own error, not the refined
   result's, so it counts only where no pair pose has a fit covariance.
3. **After the joint refinement** (``calib.joint_refine``, a camera it moved and kept): the
   largest of (a) the refinement's cluster-robust covariance of the refined pose over every dense
   depth pair and keypoint track, cells of ``CELL_M`` as measurements, at least
   ``SYSTEMATIC_DEG`` / ``SYSTEMATIC_MM``, and (b) ``REFINED_SHARE`` x the larger of 1-2's
   estimate and how far the refinement moved the camera (deg and mm each on its own). (a) sees
   depth noise only; a misfit common to a sensor's whole image (depth bias, warp) does not shrink
   with the number of patches and no residual shows it (on HO-Cap the per-patch residual spread
   was 1.7-2.3 mm, on the simulated rings 3.3-6 mm, while (a) alone was 3-5x below the error
   against the reference on HO-Cap and right on the rings). (b) is the disagreement between the
   two sources the refined pose lies between: what the pair poses could be off by, and what depth
   says they were off by; half of it tracked the error on HO-Cap, ICL and the rings
   (docs/gmac-trust.md, "Expected accuracy"). 1-2 alone would describe the pose before it moved.
4. **In a repeating room, whatever applies above** (``turned_position_floor``, where a pair pose
   of the camera was measured against another period of the room and turned back, route
   ``+turn``): the position is at least 2's RMS / sqrt(n), also after the joint refinement. There
   the refinement sees the same repeating walls as the pair poses and does not correct what they
   share: on an independently rendered 10-sided studio it moved the cameras 0.7-7.8 mm while they were
   17-32 mm off, and the refinement's covariance with the pair poses' combined fit estimated 2-5 mm;
   the pair poses' scatter about the result 6-18 mm. Rotations were not affected (estimate /
   actual 0.26-8.7, median 1.2, over 144 cameras of 6-12-sided studios), so only the position is
   raised.

These four give the *estimate* the verdict policy judges (``verdicts.GOOD_DEG`` / ``GOOD_MM``).
It is a typical error, not a bound: against the truth it was below the error for 41-51 % of the
cameras. What is printed is the **bound** (``printed_bound``): the estimate times
``BOUND_DEG_FACTOR`` / ``BOUND_MM_FACTOR``, and for a camera the subject turned by an angle a about
the room's axis, the position combined (root sum of squares) with 2 sin(a / 2) x
``BOUND_AXIS_MM``, the room axis' error. The factors were fitted so that the bound covers the error
of at least 90 % of the cameras of independently rendered studios (seeds 1400-1419 one frame,
1440-1449 five moving frames) and checked on studio seeds not fitted on, HO-Cap, kinect3-room and
ICL (docs/gmac-trust.md, "Expected accuracy").
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = [
    "pair_pose_accuracy",
    "expected_entry",
    "TRACK_ROUTES",
    "residual_accuracy",
    "combine_pair_accuracies",
    "camera_accuracy",
    "CELL_M",
    "SYSTEMATIC_DEG",
    "SYSTEMATIC_MM",
    "REFINED_SHARE",
    "TURNED_ROUTE",
    "turned_position_floor",
    "printed_bound",
    "BOUND_DEG_FACTOR",
    "BOUND_MM_FACTOR",
    "BOUND_AXIS_MM",
]

#: Correspondences within one cube of this side (metres, in camera a) count as one measurement.
CELL_M = 0.10
#: Routes whose pair poses share each camera's one track of a moving object (not independent).
TRACK_ROUTES = ("sphere", "subject")
#: The least expected error of one pair pose (a depth bias every correspondence shares).
SYSTEMATIC_DEG, SYSTEMATIC_MM = 0.05, 2.0
#: A refined camera reads at least this share of the larger of its pair poses' estimate and the
#: motion of the joint refinement (module docstring, 3).
REFINED_SHARE = 0.5
#: The route part of a pair pose measured against another period of a repeating room and turned
#: back by whole periods (module docstring, 4).
TURNED_ROUTE = "turn"
#: The printed bound is the estimate times these (rotation, position; module docstring): the
#: smallest factors with which the bound covered the error against the truth of at least 90 % of
#: the cameras the subject did not turn (134 cameras of studio seeds 1400-1419 and 1440-1449;
#: the estimate alone covered 59 % of the rotations and 49 % of the positions).
BOUND_DEG_FACTOR, BOUND_MM_FACTOR = 2.5, 2.75
#: The room axis' error (mm) in the printed bound of a camera the subject turned about it: the 90th
#: percentile of error / (2 sin(a / 2)) over the 77 turned cameras of the same fitting seeds.
BOUND_AXIS_MM = 15.0


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def pair_pose_accuracy(T_ba: np.ndarray, X_a: np.ndarray, X_b: np.ndarray) -> tuple[float, float, int] | None:
    """(expected rotation error deg, expected position error mm, cells) of the pair pose
    ``T_ba`` (camera b from camera a) fitted to the correspondences ``X_a`` (M, 3) in camera a
    and ``X_b`` (M, 3) in camera b (module docstring, 1), or None with fewer than 4 cells or a
    degenerate geometry (cells on a line)."""
    X_a = np.asarray(X_a, dtype=np.float64).reshape(-1, 3)
    X_b = np.asarray(X_b, dtype=np.float64).reshape(-1, 3)
    if len(X_a) < 4:
        return None
    _, cell = np.unique(np.floor(X_a / CELL_M).astype(np.int64), axis=0, return_inverse=True)
    cell = cell.ravel()
    n = int(cell.max()) + 1
    if n < 4:
        return None
    cnt = np.bincount(cell, minlength=n).astype(np.float64)
    A = np.stack([np.bincount(cell, X_a[:, k], n) for k in range(3)], axis=1) / cnt[:, None]
    B = np.stack([np.bincount(cell, X_b[:, k], n) for k in range(3)], axis=1) / cnt[:, None]
    R, t = T_ba[:3, :3], T_ba[:3, 3]
    r = A @ R.T + t - B
    sigma2 = float((r**2).sum() / max(3 * n - 6, 1))
    q = (A - A.mean(axis=0)) @ R.T
    H = sum(_skew(x).T @ _skew(x) for x in q)
    if np.linalg.cond(H) > 1e8:
        return None
    cov_rot = sigma2 * np.linalg.inv(H)
    lever = _skew(R @ A.mean(axis=0))
    cov_pos = sigma2 / n * np.eye(3) + lever @ cov_rot @ lever.T
    deg = float(np.degrees(np.sqrt(np.trace(cov_rot))))
    mm = float(np.sqrt(np.trace(cov_pos)) * 1000)
    return max(deg, SYSTEMATIC_DEG), max(mm, SYSTEMATIC_MM), n


def expected_entry(T_ba: np.ndarray, X_a: np.ndarray, X_b: np.ndarray) -> dict:
    """``{"expected": {"deg", "mm", "cells"}}`` of ``pair_pose_accuracy`` for a pair pose's info
    entry, or {} when it cannot be estimated."""
    acc = pair_pose_accuracy(T_ba, X_a, X_b)
    if acc is None:
        return {}
    return {"expected": {"deg": round(acc[0], 3), "mm": round(acc[1], 1), "cells": acc[2]}}


def combine_pair_accuracies(acc: Sequence[tuple[float, float]]) -> tuple[float, float] | None:
    """Inverse-variance combination (deg, mm) of a camera's agreeing pair poses' estimates."""
    if not acc:
        return None
    a = np.asarray(acc, dtype=np.float64)
    return float(1.0 / np.sqrt((1.0 / a[:, 0] ** 2).sum())), float(1.0 / np.sqrt((1.0 / a[:, 1] ** 2).sum()))


def residual_accuracy(residuals: Sequence[tuple[float, float]]) -> tuple[float, float] | None:
    """RMS / sqrt(n) (deg, mm) of n >= 2 agreeing pair poses' disagreement with the result."""
    if len(residuals) < 2:
        return None
    r = np.asarray(residuals, dtype=np.float64)
    n = len(r)
    return float(np.sqrt(np.mean(r[:, 0] ** 2) / n)), float(np.sqrt(np.mean(r[:, 1] ** 2) / n))


def _poses(n: int) -> str:
    return f"{n} pair pose{'s' * (n != 1)}"


def camera_accuracy(
    residuals: Sequence[tuple[float, float]],
    pair_estimates: Sequence[tuple[float, float, str]],
    refined: bool = False,
    refinement: tuple[float, float] | None = None,
    moved: tuple[float, float] | None = None,
) -> tuple[float | None, float | None, str]:
    """(deg, mm, how) of a camera from its agreeing pair poses' ``residuals`` with the result and
    their correspondence-based ``pair_estimates`` (deg, mm, route) (module docstring): the
    largest of the residual estimate, the inverse-variance combination of the independent pair
    poses and the worst pair pose of a moving-object track (``TRACK_ROUTES``: every pair pose of
    a camera reuses its one track, so they are not independent); (None, None, why) when none
    applies. ``refined``: the depth-aware joint refinement moved the cameras after the pair
    poses were measured, so their disagreement with the result is theirs, not the result's: the
    residual estimate then counts only where no pair pose has a fit covariance. ``refinement``:
    the joint refinement's own expected error of the camera's refined pose (deg, mm; module
    docstring, 3) and ``moved``, how far (deg, mm) it moved the camera: the largest of that
    covariance, ``SYSTEMATIC_DEG`` / ``SYSTEMATIC_MM`` and ``REFINED_SHARE`` of the larger of the
    pair poses' estimate and the motion (module docstring, 3; each of deg and mm on its own). In a
    repeating room the position is then at least ``turned_position_floor`` (module docstring, 4)."""
    pre = _pair_pose_accuracy(residuals, pair_estimates, refined)
    if refinement is None:
        return _turned_floor(pre, residuals, pair_estimates)
    deg, mm = max(refinement[0], SYSTEMATIC_DEG), max(refinement[1], SYSTEMATIC_MM)
    how = "the joint refinement's covariance of its refined pose"
    spread = [v for v in (pre[:2] if pre[0] is not None else None, moved) if v is not None]
    if spread:
        d = REFINED_SHARE * max(v[0] for v in spread)
        m = REFINED_SHARE * max(v[1] for v in spread)
        src = "its pair poses' estimate and its motion" if len(spread) == 2 else "its motion"
        if d > deg or m > mm:
            how = f"the larger of: {how}; {REFINED_SHARE:g} x the larger of {src} in the refinement"
        deg, mm = max(deg, d), max(mm, m)
    return _turned_floor((round(deg, 3), round(mm, 1), how), residuals, pair_estimates)


def _turned(route: str) -> bool:
    return TURNED_ROUTE in str(route).split("+")


def turned_position_floor(
    residuals: Sequence[tuple[float, float]], pair_estimates: Sequence[tuple[float, float, str]]
) -> float | None:
    """The position (mm) of ``residual_accuracy`` when a pair pose of the camera was turned by a
    repeating room's period (route ``TURNED_ROUTE``), None otherwise (module docstring, 4)."""
    if not any(_turned(r) for _, _, r in pair_estimates):
        return None
    res = residual_accuracy(residuals)
    return None if res is None else res[1]


def _turned_floor(
    acc: tuple[float | None, float | None, str],
    residuals: Sequence[tuple[float, float]],
    pair_estimates: Sequence[tuple[float, float, str]],
) -> tuple[float | None, float | None, str]:
    """``acc`` with its position raised to ``turned_position_floor`` (module docstring, 4)."""
    floor = turned_position_floor(residuals, pair_estimates)
    if floor is None or (acc[1] is not None and acc[1] >= round(floor, 1)):
        return acc
    why = (
        f"position: RMS / sqrt({len(residuals)}) of its agreeing pair poses' disagreement with the result "
        "(a repeating room: the joint refinement sees the same walls)"
    )
    how = why if acc[1] is None else f"{acc[2]}; {why}"
    return acc[0], round(floor, 1), how


def _pair_pose_accuracy(
    residuals: Sequence[tuple[float, float]], pair_estimates: Sequence[tuple[float, float, str]], refined: bool
) -> tuple[float | None, float | None, str]:
    """``camera_accuracy`` from the pair poses alone (1 and 2 of the module docstring)."""
    res = None if refined and pair_estimates else residual_accuracy(residuals)
    track = [(d, m) for d, m, r in pair_estimates if str(r).split("+")[0] in TRACK_ROUTES]
    indep = combine_pair_accuracies([(d, m) for d, m, r in pair_estimates if str(r).split("+")[0] not in TRACK_ROUTES])
    worst = (max(d for d, _ in track), max(m for _, m in track)) if track else None
    n_ind = len(pair_estimates) - len(track)
    est = {
        f"RMS / sqrt({len(residuals)}) of its agreeing pair poses' disagreement with the result": res,
        f"the fit covariance of its {_poses(n_ind)}" + (" combined" if n_ind > 1 else ""): indep,
        f"the worst fit covariance of its {_poses(len(track))} on one moving-object track": worst,
    }
    est = {k: v for k, v in est.items() if v is not None}
    if not est:
        return None, None, "fewer than two agreeing pair poses and no correspondences: nothing to estimate from"
    deg, mm = max(v[0] for v in est.values()), max(v[1] for v in est.values())
    return round(deg, 3), round(mm, 1), ("the larger of: " if len(est) > 1 else "") + "; ".join(est)


def printed_bound(deg: float | None, mm: float | None, turned_deg: float = 0.0) -> tuple[float | None, float | None]:
    """The printed bound (deg, mm) of a camera whose estimate is (``deg``, ``mm``) (None: unknown)
    and which the subject turned by ``turned_deg`` about the room's axis (module docstring)."""
    axis = 2.0 * abs(np.sin(np.radians(turned_deg) / 2.0)) * BOUND_AXIS_MM
    d = None if deg is None else round(BOUND_DEG_FACTOR * deg, 3)
    if mm is None:
        return d, (round(axis, 1) if axis > 0 else None)
    return d, round(float(np.hypot(BOUND_MM_FACTOR * mm, axis)), 1)
