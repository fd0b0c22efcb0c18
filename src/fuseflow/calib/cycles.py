"""CC: per-edge scales, triplet cycle residuals, pruning (paper eq. 13, corrected by docs/design.md 3).

With one global scale the cycle T_ik T_kj T_ji of backbone poses closes exactly, so eq. (13)
would test nothing. Here each edge (i, j) gets its own scale s_ij (the closed form restricted to
that edge's correspondences), and the cycle i -> j -> k -> i is composed from the three scaled
relative poses. The rotations come from one set of global backbone poses, so the cycle's rotation
is the identity and its residual on any point is the same vector c (the translation misclosure);
the residual over the sampled scene points of eq. (13) therefore equals |c|, which is what is
computed (``cycle_residual`` keeps the point form for fidelity and tests the identity).

Residuals are made relative (|c| divided by the mean metric length of the three edges) so one
threshold serves rigs of any size. Pruning removes, one at a time, the edge whose triangles have
the largest mean relative residual while that exceeds ``delta_cycle`` (the paper's "mean residual
exceeds delta" criterion over all triangles would let one bad edge among many hide below the
threshold; the per-edge mean does not). Graphs without a triangle fall back to the median of the
per-edge scales: edges farther than ``delta_cycle`` (relative) from it are pruned.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

__all__ = ["CycleResult", "triangles", "cycle_residual", "prune_by_cycles"]

Edge = tuple[int, int]


def _key(i: int, j: int) -> Edge:
    return (i, j) if i < j else (j, i)


def triangles(edges: Sequence[Edge]) -> list[tuple[int, int, int]]:
    """All (i, j, k), i < j < k, whose three edges are in ``edges`` (undirected)."""
    es = {_key(*e) for e in edges}
    nodes = sorted({n for e in es for n in e})
    return [(i, j, k) for i, j, k in combinations(nodes, 3) if (i, j) in es and (j, k) in es and (i, k) in es]


def _rel(T0: np.ndarray, i: int, j: int, s: float) -> np.ndarray:
    """T_ji(s) = [R_j R_i^T | s (t_j - R_ji t_i)], camera i -> camera j, from backbone poses."""
    R = T0[j, :3, :3] @ T0[i, :3, :3].T
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = s * (T0[j, :3, 3] - R @ T0[i, :3, 3])
    return out


def cycle_residual(
    T0: np.ndarray, tri: tuple[int, int, int], scales: Mapping[Edge, float], points: np.ndarray | None = None
) -> tuple[float, float]:
    """(absolute residual in metres, relative residual) of cycle i -> j -> k -> i.

    Args:
        T0: (N, 4, 4) backbone camera-from-world poses (unit scale).
        scales: per-edge scale keyed (min, max).
        points: (S, 3) sample points in camera i (metres) for eq. (13)'s RMS; None uses the origin.
    """
    i, j, k = tri
    C = _rel(T0, k, i, scales[_key(i, k)]) @ _rel(T0, j, k, scales[_key(j, k)]) @ _rel(T0, i, j, scales[_key(i, j)])
    P = np.zeros((1, 3)) if points is None else np.asarray(points, dtype=np.float64)
    moved = P @ C[:3, :3].T + C[:3, 3]
    absolute = float(np.sqrt(np.mean(np.sum((moved - P) ** 2, axis=1))))
    lengths = [np.linalg.norm(_rel(T0, a, b, scales[_key(a, b)])[:3, 3]) for a, b in ((i, j), (j, k), (k, i))]
    return absolute, absolute / max(float(np.mean(lengths)), 1e-12)


@dataclass(frozen=True)
class CycleResult:
    """Outcome of cycle-consistency validation.

    Attributes:
        kept: undirected edges kept. pruned: edges removed, in pruning order.
        mode: "cycles" (triangles used), "median" (no triangle: median fallback) or "single"
            (one edge: nothing to check).
        residuals: (i, j, k) -> relative residual at the end (kept triangles only).
        residuals_before: (i, j, k) -> relative residual before pruning.
        residuals_mm: (i, j, k) -> absolute residual in mm at the end.
    """

    kept: tuple[Edge, ...]
    pruned: tuple[Edge, ...]
    mode: str
    residuals: dict[tuple[int, int, int], float]
    residuals_before: dict[tuple[int, int, int], float]
    residuals_mm: dict[tuple[int, int, int], float]


def prune_by_cycles(
    T0: np.ndarray,
    scales: Mapping[Edge, float],
    delta: float,
    max_pruned_fraction: float = 0.5,
    points: Mapping[int, np.ndarray] | None = None,
    weights: Mapping[Edge, float] | None = None,
) -> CycleResult:
    """Prune cycle-inconsistent edges (see the module docstring).

    Args:
        T0: (N, 4, 4) backbone poses. scales: per-edge scales keyed (min, max), all > 0.
        delta: relative residual threshold. points: camera -> (S, 3) sample points (camera frame).
        weights: edge -> weight for the median fallback (e.g. correspondence counts).
    """
    edges = sorted(_key(*e) for e in scales)
    max_prune = int(np.floor(max_pruned_fraction * len(edges)))

    def residual_map(es):
        out, out_abs = {}, {}
        for tri in triangles(es):
            pts = None if points is None else points.get(tri[0])
            a, r = cycle_residual(T0, tri, scales, pts)
            out[tri], out_abs[tri] = r, a * 1000.0
        return out, out_abs

    res0, _ = residual_map(edges)
    if len(edges) <= 1:
        return CycleResult(tuple(edges), (), "single", {}, {}, {})
    if not res0:
        logs = np.log(np.array([scales[e] for e in edges]))
        w = np.array([1.0 if weights is None else float(weights.get(e, 1.0)) for e in edges])
        order = np.argsort(logs)
        cw = np.cumsum(w[order])
        med = logs[order][np.searchsorted(cw, cw[-1] / 2)]
        dev = np.abs(logs - med)
        bad = [edges[k] for k in np.argsort(-dev) if dev[k] > np.log1p(delta)][:max_prune]
        kept = tuple(e for e in edges if e not in bad)
        return CycleResult(kept, tuple(bad), "median", {}, {}, {})
    kept = list(edges)
    pruned: list[Edge] = []
    res, res_abs = res0, residual_map(kept)[1]
    while len(pruned) < max_prune and res:
        score = {}
        for e in kept:
            vals = [r for tri, r in res.items() if set(e) <= set(tri)]
            if vals:
                score[e] = float(np.mean(vals))
        med = float(np.median(np.log([scales[e] for e in kept])))
        # ties (e.g. the three edges of a lone triangle) go to the edge whose scale is farthest
        # from the median scale of the kept edges
        worst = max(score, key=lambda e: (round(score[e], 9), abs(np.log(scales[e]) - med)))
        if score[worst] <= delta:
            break
        kept.remove(worst)
        pruned.append(worst)
        res, res_abs = residual_map(kept)
    return CycleResult(tuple(kept), tuple(pruned), "cycles", res, res0, res_abs)
