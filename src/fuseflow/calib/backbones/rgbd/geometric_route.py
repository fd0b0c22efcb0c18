"""The geometry-only route (``RGBDConfig.geometric``): cameras the image routes left unplaced are
registered by 3-D shape alone (:mod:`fuseflow.calib.geometric`) against the placed ones, and the
poses re-solved after each round."""

from __future__ import annotations

import numpy as np

from fuseflow.calib.accuracy import expected_entry
from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.evidence import CameraEvidence, backproject, plausible, verify_pose
from fuseflow.calib.backbones.rgbd.judge import subject_ok
from fuseflow.calib.backbones.rgbd.pairs import check_row, median_depth
from fuseflow.calib.backbones.rgbd.poses import global_poses
from fuseflow.calib.geometric import kabsch
from fuseflow.calib.posegraph import Edge, prune_cycles
from fuseflow.types import invert_rigid


def geometric_edges(
    cams: list[CameraEvidence],
    T: np.ndarray,
    placed: np.ndarray,
    edges: dict[tuple[int, int], Edge],
    cfg: RGBDConfig,
    exclude: set[int] = frozenset(),
) -> tuple[dict[tuple[int, int], Edge], list[dict], tuple]:
    """Route (c) (:mod:`fuseflow.calib.geometric`) on every pair with an unplaced camera and no
    edge yet. A pair's passing pose cluster with the most ICP starts is its candidate when at
    least ``geometric_min_starts`` starts reached it and at least twice as many as reached any
    other passing pose. Candidates become edges in rounds, from the placed cameras outwards
    (pairs of two unplaced cameras wait while anything is placed, so that their pose can be
    judged against every placed view, ``_better``); after each round the poses are re-solved.
    Within a round, an unplaced camera's pairs are run in order of descriptor consensus
    (``RansacStarts.consensus``) until it has ``geometric_edges_per_camera`` candidates; the
    rest wait in case it is still unplaced after the round. Cameras in ``exclude`` (ambiguous
    ones, ``joint_choice``) get no candidate. Returns (new edges, per-pair info, (kept, dropped, untested, T, placed, refine info) of the
    last solve, or None when nothing was added)."""
    from fuseflow.calib.geometric import RansacStarts, ransac_starts

    feat = _cloud_cache(cams, cfg)
    n = len(cams)
    todo = [(i, j) for i in range(n) for j in range(i + 1, n)
            if not (placed[i] and placed[j]) and (i, j) not in edges and not {i, j} & exclude]  # fmt: skip
    cands: dict[tuple[int, int], tuple] = {}
    starts: dict[tuple[int, int], RansacStarts] = {}
    info = []
    out: dict[tuple[int, int], Edge] = {}
    solved = None
    while True:
        # a pair's candidates are computed when a round first considers it: a pair of two
        # unplaced cameras waits while anything is placed, and is never needed when both are
        # placed in the same round (hocap-8rs: 12 of its 13 pairs were needed)
        due = [e for e in todo if not (placed.any() and placed[e[0]] == placed[e[1]])]
        cap = cfg.geometric_edges_per_camera if placed.any() and cfg.geometric_edges_per_camera < n else None
        if cap is not None:  # most consensus first; a camera with `cap` candidates skips the rest
            for e in due:
                if e not in starts:
                    starts[e] = ransac_starts(feat(e[0]), feat(e[1]), cfg.geometric_starts, seed=cfg.seed + 2)
            due = sorted(due, key=lambda e: (-starts[e].consensus, e))
        found: dict[int, int] = {}
        for i, j in due:
            u = j if placed[i] else i  # the unplaced camera of the pair
            if cap is not None and found.get(u, 0) >= cap:
                continue  # stays in todo: needed again only if u is unplaced after this round
            todo.remove((i, j))
            entry, cand = _geometric_pair(cams, i, j, feat, cfg, starts.get((i, j)))
            info.append(entry)
            if cand is not None:
                cands[(i, j)] = cand
                found[u] = found.get(u, 0) + 1
        new = {}
        for i, j in sorted(cands):
            c, chk, entry = cands[(i, j)]
            if (i, j) in out or (placed.any() and placed[i] == placed[j]):
                continue
            a, b = cams[i], cams[j]
            T_ba, X_a, X_b, how = c.T_ba, c.X_a, c.X_b, "icp"
            # the ICP pose, or the rigid fit of the descriptor matches it explains: on clean
            # geometry ICP is the more precise (synthetic pair: 0.1 vs 1.2 deg), on hocap-8rs the
            # fit (ICP slides on the up-looking cameras' overlap); ``_better`` decides
            if len(c.M_a) >= 6:
                T_fit = kabsch(c.M_a[None], c.M_b[None])[0]
                chk_fit = verify_pose(a, b, T_fit, cfg.tau)
                if chk_fit.passes(cfg) and _better(cams, T, placed, i, j, T_fit, T_ba, cfg):
                    T_ba, X_a, X_b, chk, how = T_fit, c.M_a, c.M_b, chk_fit, "descriptor fit"
            sigma = np.maximum(cfg.geometric_voxel / 2, cfg.sigma0 + cfg.sigma2 * X_b[:, 2] ** 2)
            new[(i, j)] = Edge(i, j, T_ba, float(chk.agree), X_a, X_b, sigma)
            entry["edge"] = {"route": "geometric", "pose": how, "agreement": round(chk.agreement, 4),
                             "starts": c.starts, "support": int(len(X_a)), "T_ji": np.round(T_ba, 6).tolist()}  # fmt: skip
            # the descriptor matches, not ICP's nearest neighbours (ICP slides without a residual)
            entry["edge"].update(expected_entry(T_ba, c.M_a, c.M_b) if len(c.M_a) >= 6 else {})
        if not new:
            return out, info, solved
        out.update(new)
        kept, dropped, untested = prune_cycles({**edges, **out}, cfg.cycle_rot_deg, cfg.cycle_trans_m)
        T, placed, refine_info = global_poses(n, kept, cfg)
        solved = (kept, dropped, untested, T, placed, refine_info)


def _geometric_pair(
    cams: list[CameraEvidence], i: int, j: int, feat, cfg: RGBDConfig, prepared=None
) -> tuple[dict, tuple | None]:
    """Route (c) on the pair (i, j): its info entry (every pose cluster with its verification)
    and its candidate (cluster, check, entry), or None: the passing cluster with the most starts
    when at least ``geometric_min_starts`` and twice as many as any other passing cluster
    reached it. ``prepared``: the pair's ``geometric.ransac_starts``, if already computed."""
    from fuseflow.calib.geometric import geometric_candidates

    a, b = cams[i], cams[j]
    clusters = geometric_candidates(feat(i), feat(j), cfg.geometric_starts, seed=cfg.seed + 2, prepared=prepared)
    rows, passing = [], []
    for c in clusters:
        chk = verify_pose(a, b, c.T_ba, cfg.tau)
        ok = chk.passes(cfg) and plausible(c.T_ba, chk, cfg, median_depth(a, b))
        rows.append({"route": "geometric", "inliers": int(len(c.X_a)), "starts": c.starts, "ok": ok,
                     **check_row(chk), "T_ji": np.round(c.T_ba, 6).tolist()})  # fmt: skip
        ok = ok and subject_ok(a, b, c.T_ba, cfg, rows[-1])
        if ok:
            passing.append((c, chk))
    entry = {"pair": [i, j], "stage": "geometric", "candidates": rows, "edge": None}
    if passing:
        c, chk = passing[0]  # clusters come largest first
        runner_up = passing[1][0].starts if len(passing) > 1 else 0
        if c.starts >= cfg.geometric_min_starts and c.starts >= 2 * runner_up and len(c.X_a) >= 3:
            return entry, (c, chk, entry)
    return entry, None


def _better(cams, T: np.ndarray, placed: np.ndarray, i: int, j: int, T_new, T_old, cfg: RGBDConfig) -> bool:
    """Is the relative pose T_new (camera i -> j) closer to the truth than T_old? With one of
    the two cameras placed (poses T (N, 4, 4)), by the depth agreement of the other, at the pose
    each implies, with every placed camera (a pair's overlap can favour a pose the other views
    refute: hocap-8rs); else by the pair's agreement at a fifth of tau (tau = 5 % cannot tell
    0.1 deg from 1 deg)."""
    if placed[i] != placed[j]:
        others = [v for v in range(len(cams)) if placed[v]]
        if placed[i]:  # T_j = T_ji T_i
            u, pose = j, (lambda R: R @ T[i])
        else:  # T_i = T_ji^-1 T_j
            u, pose = i, (lambda R: invert_rigid(R) @ T[j])
        return _agreement_with(cams, u, pose(T_new), T, others, cfg) > _agreement_with(
            cams, u, pose(T_old), T, others, cfg
        )
    tau = cfg.tau / 5
    return verify_pose(cams[i], cams[j], T_new, tau).agree > verify_pose(cams[i], cams[j], T_old, tau).agree


def _agreement_with(cams, u: int, T_u: np.ndarray, T: np.ndarray, others: list[int], cfg: RGBDConfig) -> float:
    """Pooled depth agreement (``verify_pose``) of camera u at pose T_u (4, 4) with the cameras
    ``others`` at their poses in T."""
    agree = votes = 0
    for v in others:
        chk = verify_pose(cams[u], cams[v], T[v] @ invert_rigid(T_u), cfg.tau)
        agree += chk.agree
        votes += round(chk.agree / chk.agreement) if chk.agree else 0
    return agree / votes if votes else 0.0


def _cloud_cache(cams: list[CameraEvidence], cfg: RGBDConfig):
    """k -> camera k's ``geometric.CloudFeatures`` (median depth, every 2nd pixel), each
    computed once."""
    from fuseflow.calib.geometric import cloud_features

    cache: dict[int, object] = {}

    def feat(k: int):
        if k not in cache:
            cache[k] = cloud_features(backproject(cams[k].depth, cams[k].K, 2), cfg.geometric_voxel)
        return cache[k]

    return feat
