"""The repeating room's axis fitted to the calibrated cloud's walls.

``calib.turns.room_axis`` finds the axis by a grid search on how many turned points land on the
cloud (a 5 cm landing tolerance, a 2 mm grid, 1500 points, up from the floor): on stored
calibrations of independently rendered 6-12-sided studios it was a median 10 mm (up to 54 mm) from
the truth, and a camera the subject turns by k of N periods about it moves by 2 sin(k pi / N)
times that. This module refines it by least squares: ``FIT_POINTS`` wall points (their normals
more horizontal than ``MAX_NORMAL_UP``), turned by every whole period k = 1..N-1 about the axis,
land on the walls of the cloud; the residual of a turned point is its distance to the tangent
plane of the nearest cloud point (point-to-plane ICP whose only unknowns are the axis' position
on the floor and its tilt; the period is kept). Gauss-Newton steps with the correspondences
held, Jacobian by finite differences, landing cut ``CUTS_M`` shrinking from 6 to 2 cm. Walls
facing many directions pin the position; walls that do not (the position block's smaller
eigenvalue below ``MIN_CONDITION`` of the larger) give no fit, and the grid search's axis stays.

How far the fitted axis may be off is not measured here: a jackknife over cameras (the fit
repeated leaving out each camera's points) gave standard errors the truth exceeded by a median 4
and up to 27 times on the same calibrations (what every camera shares, such as pair poses turned
about the pairs' own axis estimate, moves the axis without showing in it), so the verdicts keep
``verdicts.TURN_AXIS_MM`` (docs/gmac-trust.md, "Room turns decided by the subject").

Pure numpy plus scipy's KD-tree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["AxisFit", "fit_axis"]

#: Wall points whose normal is within this cosine of up are floor or ceiling: no horizontal pull.
MAX_NORMAL_UP = 0.5
#: Points used as sources of the fit, and neighbours of a point's normal.
FIT_POINTS, NORMAL_NEIGHBOURS = 4000, 10
#: A turned point counts when it lands within these distances of the cloud (metres), per step.
CUTS_M = (0.06, 0.04, 0.03, 0.02, 0.02, 0.02)
#: The smaller eigenvalue of the normal matrix's position block over the larger: walls facing one way only
#: leave the axis free along them.
MIN_CONDITION = 0.05
#: Fewer turned points landing than this: no fit.
MIN_LANDED = 200


@dataclass(frozen=True)
class AxisFit:
    """The axis through ``centre`` (x, y, floor height, in the basis the points are given in) along
    ``up`` (unit, same basis)."""

    centre: np.ndarray
    up: np.ndarray


def _normals(pts: np.ndarray, tree) -> np.ndarray:
    """Unit normals (P, 3) of ``pts`` from their NORMAL_NEIGHBOURS nearest points of ``tree``."""
    _, j = tree.query(pts, NORMAL_NEIGHBOURS)
    nb = tree.data[j]
    nb = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum("pki,pkj->pij", nb, nb)
    return np.linalg.eigh(cov)[1][:, :, 0]


def _turned(p: np.ndarray, theta: np.ndarray, angle: float, floor: float) -> np.ndarray:
    """``p`` (P, 3) turned by ``angle`` about the axis ``theta`` = (x, y, tilt x, tilt y): through
    (x, y, ``floor``), along (tilt x, tilt y, 1) normalised (Rodrigues)."""
    u = np.array([theta[2], theta[3], 1.0])
    u /= np.linalg.norm(u)
    K = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
    c = np.array([theta[0], theta[1], floor])
    return (p - c) @ R.T + c


def _fit(src: np.ndarray, tree, normals: np.ndarray, theta: np.ndarray, sides: int, floor: float):
    """The axis (x, y, tilt x, tilt y) from ``theta`` by Gauss-Newton steps on the point-to-plane
    residuals of the turned wall points (module docstring; the Jacobian by finite differences with
    the correspondences held), None when too few points land or the walls leave it free."""
    th = np.asarray(theta, np.float64).copy()
    angles = [2 * math.pi * k / sides for k in range(1, sides)]
    eps = np.array([1e-4, 1e-4, 1e-5, 1e-5])
    for cut in CUTS_M:
        J, r = [], []
        for a in angles:
            q = _turned(src, th, a, floor)
            d, j = tree.query(q, distance_upper_bound=cut)
            ok = np.isfinite(d)
            ok[ok] = np.abs(normals[j[ok], 2]) < MAX_NORMAL_UP
            if not ok.any():
                continue
            n, y, p = normals[j[ok]], tree.data[j[ok]], src[ok]
            r0 = np.einsum("pi,pi->p", n, q[ok] - y)
            cols = []
            for i in range(4):
                t2 = th.copy()
                t2[i] += eps[i]
                cols.append((np.einsum("pi,pi->p", n, _turned(p, t2, a, floor) - y) - r0) / eps[i])
            J.append(np.stack(cols, 1))
            r.append(r0)
        if not r or sum(len(x) for x in r) < MIN_LANDED:
            return None
        A, b = np.concatenate(J), np.concatenate(r)
        H = A.T @ A
        ev = np.linalg.eigvalsh(H[:2, :2])
        if ev[0] < MIN_CONDITION * ev[1]:
            return None
        th = th - np.linalg.solve(H + 1e-9 * np.trace(H) * np.eye(4), A.T @ b)
    return th


def fit_axis(cloud: np.ndarray, walls: np.ndarray, centre: np.ndarray, floor: float, sides: int,
             rng: np.random.Generator) -> AxisFit | None:  # fmt: skip
    """The room's axis refined from the vertical axis through ``centre`` (x, y) (module docstring).
    ``cloud`` (P, 3): the merged cloud in a basis whose third coordinate is the height, ``floor``
    the floor's; ``walls`` (P,) bool: the points of the room's walls (away from the subject, off
    floor and ceiling). None when the fit fails (too few points land, walls facing one way only)."""
    from scipy.spatial import cKDTree

    pts = cloud[walls]
    if len(pts) < MIN_LANDED:
        return None
    tree = cKDTree(pts)
    pick = rng.choice(len(pts), min(len(pts), FIT_POINTS), replace=False)
    th = _fit(pts[pick], tree, _normals(pts, tree), np.array([centre[0], centre[1], 0.0, 0.0]), sides, floor)
    if th is None:
        return None
    u = np.array([th[2], th[3], 1.0])
    return AxisFit(np.array([th[0], th[1], floor]), u / np.linalg.norm(u))
