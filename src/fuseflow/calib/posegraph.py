"""Global poses from verified metric pairwise poses: cycle test, spanning tree, robust solve.

An *edge* (i, j), i < j, carries ``T_ji`` (4, 4) float64, camera i's coordinates to camera
j's (T_ji = T_j T_i^-1 with T the camera-from-world extrinsics, metres), a verification score,
and the 3-D correspondences that support it: X_i (K, 3) in camera i, X_j (K, 3) in camera j,
metres, with a per-correspondence noise sigma (K,) metres.

Steps (each a function, tested alone):

1. ``prune_cycles``: GMAC's cycle test (docs/design.md 3) on *metric* relative poses: every triangle
   T_ki T_jk T_ij must be the identity within a rotation / translation tolerance; while some
   triangle fails, drop the edge that takes part in the most failing triangles (ties: the lower
   score). Edges in no triangle cannot be tested and are reported as such.
2. ``spanning_tree``: initial poses by a maximum-score spanning tree from the anchor.
3. ``refine_poses``: all cameras at once, robust least squares (soft-L1) on the world-frame
   distance of every correspondence pair, scaled by its sigma; the anchor is held fixed.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from fuseflow.types import invert_rigid

__all__ = ["Edge", "prune_cycles", "spanning_tree", "refine_poses", "rotation_angle_deg", "anchor_world"]


@dataclass
class Edge:
    """A verified pairwise pose (see the module docstring for the conventions)."""

    i: int
    j: int
    T_ji: np.ndarray
    score: float
    X_i: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    X_j: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))


def rotation_angle_deg(R: np.ndarray) -> float:
    """Geodesic angle of a (3, 3) rotation, degrees."""
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _T(edges: dict[tuple[int, int], Edge], a: int, b: int) -> np.ndarray:
    """Transform from camera a's coordinates to camera b's along the edge (a, b) or (b, a)."""
    if (a, b) in edges:
        return edges[(a, b)].T_ji
    return invert_rigid(edges[(b, a)].T_ji)


def prune_cycles(
    edges: dict[tuple[int, int], Edge], rot_tol_deg: float, trans_tol_m: float
) -> tuple[dict[tuple[int, int], Edge], list[dict], list[tuple[int, int]]]:
    """Drop edges that break triangle cycles (step 1 of the module docstring).

    Returns:
        (kept edges, dropped [{"edge": (i, j), "failing_triangles": k}], untested edges: kept
        edges that are in no triangle of the kept graph).
    """
    kept = dict(edges)
    dropped: list[dict] = []
    while True:
        nodes = sorted({k for e in kept for k in e})
        fails: dict[tuple[int, int], int] = {}
        tested: set[tuple[int, int]] = set()
        for a, b, c in itertools.combinations(nodes, 3):
            tri = [(a, b), (b, c), (a, c)]
            if not all(t in kept for t in tri):
                continue
            tested.update(tri)
            C = _T(kept, c, a) @ _T(kept, b, c) @ _T(kept, a, b)
            if rotation_angle_deg(C[:3, :3]) > rot_tol_deg or np.linalg.norm(C[:3, 3]) > trans_tol_m:
                for t in tri:
                    fails[t] = fails.get(t, 0) + 1
        if not fails:
            untested = sorted(e for e in kept if e not in tested)
            return kept, dropped, untested
        worst = max(fails, key=lambda e: (fails[e], -kept[e].score, e))
        dropped.append({"edge": worst, "failing_triangles": fails[worst]})
        del kept[worst]


def spanning_tree(n: int, edges: dict[tuple[int, int], Edge], anchor: int) -> tuple[np.ndarray, np.ndarray]:
    """Initial camera-from-world poses by a maximum-score spanning tree rooted at ``anchor``
    (world frame = the anchor's camera frame).

    Returns:
        T_cam_world (n, 4, 4) float64 (identity for unreached cameras), reached (n,) bool.
    """
    T = np.tile(np.eye(4), (n, 1, 1))
    reached = np.zeros(n, dtype=bool)
    reached[anchor] = True
    while True:
        best = None
        for (i, j), e in sorted(edges.items()):
            if reached[i] != reached[j] and (best is None or e.score > best.score):
                best = e
        if best is None:
            return T, reached
        if reached[best.i]:
            T[best.j] = best.T_ji @ T[best.i]
            reached[best.j] = True
        else:
            T[best.i] = invert_rigid(best.T_ji) @ T[best.j]
            reached[best.i] = True


def _rodrigues(w: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(w)
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx


def refine_poses(
    T_init: np.ndarray,
    placed: np.ndarray,
    edges: dict[tuple[int, int], Edge],
    anchor: int,
    loss_scale: float = 2.0,
    max_nfev: int = 50,
) -> tuple[np.ndarray, dict]:
    """Joint robust refinement of all placed cameras (step 3 of the module docstring).

    Parametrised as world-from-camera updates (rotation vector, translation) of every placed
    camera but the anchor. Residual of a correspondence: (T_wi X_i - T_wj X_j) / sigma, soft-L1
    loss with ``loss_scale`` sigmas.

    Args:
        T_init: (n, 4, 4) float64 camera-from-world. placed: (n,) bool. anchor: a placed index.

    Returns:
        (T_cam_world (n, 4, 4), info {"cost_before", "cost_after", "residuals"}).
    """
    from scipy.optimize import least_squares

    free = [k for k in range(len(T_init)) if placed[k] and k != anchor]
    use = [e for _, e in sorted(edges.items()) if placed[e.i] and placed[e.j] and len(e.X_i)]
    if not free or not use:
        return T_init.copy(), {"cost_before": 0.0, "cost_after": 0.0, "residuals": 0}
    slot = {k: s for s, k in enumerate(free)}
    T_wc0 = np.stack([invert_rigid(T) for T in T_init])

    def poses(p: np.ndarray) -> np.ndarray:
        out = T_wc0.copy()
        for k, s in slot.items():
            dR = _rodrigues(p[6 * s : 6 * s + 3])
            out[k, :3, :3] = dR @ T_wc0[k, :3, :3]
            out[k, :3, 3] = dR @ T_wc0[k, :3, 3] + p[6 * s + 3 : 6 * s + 6]
        return out

    def residuals(p: np.ndarray) -> np.ndarray:
        W = poses(p)
        res = []
        for e in use:
            a = e.X_i @ W[e.i, :3, :3].T + W[e.i, :3, 3]
            b = e.X_j @ W[e.j, :3, :3].T + W[e.j, :3, 3]
            res.append(((a - b) / e.sigma[:, None]).ravel())
        return np.concatenate(res)

    # each residual depends on two cameras: a sparse Jacobian keeps the finite differences and
    # the trust-region steps cheap (no dense SVD of the Jacobian)
    from scipy.sparse import lil_matrix

    rows = sum(3 * len(e.X_i) for e in use)
    S = lil_matrix((rows, 6 * len(free)), dtype=np.int8)
    r0 = 0
    for e in use:
        for k in (e.i, e.j):
            if k in slot:
                S[r0 : r0 + 3 * len(e.X_i), 6 * slot[k] : 6 * slot[k] + 6] = 1
        r0 += 3 * len(e.X_i)
    p0 = np.zeros(6 * len(free))
    sol = least_squares(
        residuals, p0, jac_sparsity=S, loss="soft_l1", f_scale=loss_scale, max_nfev=max_nfev, method="trf"
    )
    W = poses(sol.x)
    T = T_init.copy()
    for k in free:
        T[k] = invert_rigid(W[k])
    r0 = residuals(p0)
    return T, {"cost_before": float(np.mean(np.abs(r0))), "cost_after": float(np.mean(np.abs(sol.fun))),
               "residuals": int(sol.fun.size)}  # fmt: skip


def anchor_world(
    T_cam_world: dict[str, np.ndarray], order: tuple[str, ...]
) -> tuple[dict[str, np.ndarray], str | None]:
    """Re-express the extrinsics in the frame of the first placed camera in ``order`` (rig order),
    whose extrinsic becomes the identity: the backbone's own world frame depends on which image
    it happened to start from, so two calibrations of one rig would otherwise differ by a rigid
    motion. Returns (camera id -> camera-from-world, the anchor's id or None when none is placed)."""
    anchor = next((c for c in order if c in T_cam_world), None)
    if anchor is None:
        return T_cam_world, None
    world_from_anchor = invert_rigid(T_cam_world[anchor])
    out = {c: T @ world_from_anchor for c, T in T_cam_world.items()}
    out[anchor] = np.eye(4)
    return out, anchor
