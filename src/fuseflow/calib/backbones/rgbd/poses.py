"""Global placement (step 4 of the package outline): the largest connected component of the kept
edges, a maximum-score spanning tree and a joint robust solve (:mod:`fuseflow.calib.posegraph`),
plus the per-camera summary and ``relative_error``."""

from __future__ import annotations

import numpy as np

from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.posegraph import Edge, refine_poses, rotation_angle_deg, spanning_tree
from fuseflow.types import invert_rigid


def global_poses(n: int, edges: dict[tuple[int, int], Edge], cfg: RGBDConfig):
    """Poses (canonical order) of the largest connected component of the kept edges (ties: the
    one with the lowest index), anchored at its lowest index."""
    comps, seen = [], set()
    for s in range(n):
        if s in seen:
            continue
        comp, stack = set(), [s]
        while stack:
            k = stack.pop()
            if k in comp:
                continue
            comp.add(k)
            stack += [b if a == k else a for (a, b) in edges if k in (a, b)]
        seen |= comp
        comps.append(sorted(comp))
    comp = max(comps, key=lambda c: (len(c), -c[0]))
    if len(comp) < 2:
        return np.tile(np.eye(4), (n, 1, 1)), np.zeros(n, dtype=bool), {"note": "no verified pair"}
    anchor = comp[0]
    T, placed = spanning_tree(n, edges, anchor)
    info: dict = {"anchor": anchor}
    if cfg.refine:
        T, info = refine_poses(T, placed, edges, anchor)
        info["anchor"] = anchor
    return T, placed, info


def camera_info(cams, ids, kept, untested, placed, ambiguous: dict[str, str]) -> dict:
    out = {}
    for k, c in enumerate(cams):
        mine = [e for e in kept if k in e]
        out[ids[k]] = {
            "placed": bool(placed[k]),
            "floor": None
            if c.plane is None
            else {
                "height_m": round(c.plane.height, 4),
                "inliers": c.plane.inliers,
                "rms_m": round(c.plane.rms, 4),
                "normal": np.round(c.plane.normal, 6).tolist(),
            },
            "topdown_keypoints": int(len(c.td_xy)),
            "edges": [ids[b] if a == k else ids[a] for a, b in mine],
            # a camera held by edges none of which closes a cycle has had no independent check
            "cycle_checked": any(e not in untested for e in mine),
        }
        if ids[k] in ambiguous:  # left unplaced: why (``joint_choice``)
            out[ids[k]]["ambiguous"] = ambiguous[ids[k]]
    return out


def relative_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(rotation deg, translation m) between two relative transforms (4, 4)."""
    D = T_a @ invert_rigid(T_b)
    return rotation_angle_deg(D[:3, :3]), float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
