"""The joint choice in repeating rooms: when pairs keep several verified hypotheses
(``RGBDConfig.pair_hypotheses``), the set of one pose per pair that is consistent around cycles
(``symmetry.select_consistent``) and agrees best with every view; pairs it cannot tell apart are
marked ambiguous."""

from __future__ import annotations

import numpy as np
import torch

from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.pairs import JOINT_ROT_DEG, JOINT_TRANS_M, edge_of
from fuseflow.calib.posegraph import rotation_angle_deg
from fuseflow.calib.symmetry import (
    SUBJECT_MAX_FREE_SPACE,
    SUBJECT_MIN_POINTS,
    Hypothesis,
    bridges,
    main_block,
    pose_gap,
    select_consistent,
    subject_free_space,
)
from fuseflow.calib.verdicts import ALIASED_PAIRS
from fuseflow.geometry import project_votes
from fuseflow.types import invert_rigid

#: A verified hypothesis this far (deg) from the chosen solution is an alias (``_refutes``).
ALIAS_MIN_DEG = 10.0


#: The joint choice compares the best solutions (``symmetry.select_consistent``: at most this
#: many, with at most one consistent pair fewer than the best) by ``_views_agreement``.
JOINT_SOLUTIONS = 8


#: ``_views_agreement``'s depth tolerance, a share of tau (2 % at tau = 5 %): symstudio seed 0,
#: every pair of the 5 cameras: true poses 0.88 overall / 0.82 on the subject, the solution of two
#: agreeing wrong edges 0.80 / 0.71 (at tau: 0.97 / 0.91 against 0.93 / 0.85).
VIEWS_TAU_SHARE = 0.4


#: The subject: points within this distance (metres, horizontally) of the point nearest to every
#: camera's optical axis, where a studio's cameras converge (``_views_agreement``).
SUBJECT_RADIUS_M = 1.0


#: A lone camera (``joint_choice``) whose chosen pose beats each rival pose by at least this much
#: ``_views_agreement`` with the other cameras is not ambiguous.
AMBIGUITY_MARGIN = 0.05


def joint_choice(cams, edges: dict, hyps: dict, info: list[dict], ids: list[str], cfg: RGBDConfig):
    """Choose each pair's hypothesis jointly, in each group of cameras that the pairs with
    hypotheses connect (``hypothesis_groups``; a solution grows within one group, and its views'
    agreement counts only its own cameras, so groups are never compared with each other):
    the consistent solutions of ``symmetry.select_consistent``, the best few compared by
    ``_views_agreement``; the edges of the chosen hypotheses (other pairs lose theirs), and the
    ambiguous cameras (``_ambiguous``), which lose their edges. Returns (edges, info, ambiguous
    camera indices); with several groups, info has one entry per group under ``groups``."""
    groups = hypothesis_groups(hyps)
    every = set(range(len(cams)))
    if len(groups) <= 1:
        return _group_choice(cams, edges, hyps, info, ids, cfg, every)
    out, sels, ambiguous = {}, [], set()
    alone = every.difference(*groups)
    for g in groups:
        mine = {p: h for p, h in hyps.items() if p[0] in g}
        e, sel, amb = _group_choice(
            cams, {p: x for p, x in edges.items() if p in mine}, mine, info, ids, cfg, g | alone
        )
        out.update(e)
        sels.append(sel)
        ambiguous |= amb
    sel = {k: sum(x.get(k, 0) for x in sels) for k in ("solutions", "consistent_pairs", "refuted_pairs")}
    sel["ambiguous"] = {c: r for x in sels for c, r in x.get("ambiguous", {}).items()}
    return out, {**sel, "groups": sels}, ambiguous


def hypothesis_groups(hyps: dict) -> list[set[int]]:
    """The camera groups that the pairs with hypotheses connect (largest first, then by lowest
    camera)."""
    groups: list[set[int]] = []
    for p in sorted(p for p, hs in hyps.items() if hs):
        hit = [g for g in groups if set(p) & g]
        merged = set(p).union(*hit)
        groups = [g for g in groups if g not in hit] + [merged]
    return sorted(groups, key=lambda g: (-len(g), min(g)))


def _group_choice(cams, edges: dict, hyps: dict, info: list[dict], ids: list[str], cfg: RGBDConfig, cameras: set[int]):
    """``joint_choice`` in one group of cameras; where the room repeats (ALIASED_PAIRS refuted
    pairs), the ``cameras`` outside its cycle-checked block are ambiguous."""
    flat = [h for hs in hyps.values() for h in hs]
    sols = select_consistent(flat, JOINT_ROT_DEG, JOINT_TRANS_M, joint_separation(flat, cfg))
    if not sols:  # no hypothesis to grow from: the pairs' best edges stand, nothing is chosen
        return edges, {"solutions": 0}, set()
    top = [sol for sol in sols if len(sol.chosen) >= len(sols[0].chosen) - 1][:JOINT_SOLUTIONS]
    views = [_views_agreement(cams, sol.poses, cfg) for sol in top] if len(top) > 1 else [float("nan")]
    best = top[int(np.nanargmax(views))] if len(top) > 1 else top[0]
    chosen = {p: flat[k] for p, k in best.chosen.items()}
    by_pair = {tuple(e["pair"]): e for e in info}
    out = {}
    for p, h in chosen.items():
        if h is hyps[p][0]:
            out[p] = edges[p]
        else:
            out[p], entry = edge_of(cams[p[0]], cams[p[1]], h, cfg)
            by_pair[p]["edge"] = {**entry, "joint_choice": True}
    for p in set(edges) - set(out):
        by_pair[p]["edge"] = None
        by_pair[p]["not_consistent"] = True
    refuted = sorted(p for p, hs in hyps.items() if set(p) <= set(best.poses) and _refutes(hs, best.poses))
    if len(refuted) >= ALIASED_PAIRS:
        block = main_block(sorted(out))
        names = ", ".join(f"{ids[a]}-{ids[b]}" for a, b in refuted[:4]) + (" ..." if len(refuted) > 4 else "")
        held = _subject_held(cams, out, chosen, hyps, block, cfg)
        ambiguous = {k: (f"ambiguous: the room repeats ({len(refuted)} pairs have verified poses the consistent "
                         f"solution refutes: {names}) and no cycle checks this camera against the main group")
                     for k in sorted({k for p in out for k in p} - block - held)}  # fmt: skip
    else:
        ambiguous = _ambiguous(cams, out, chosen, hyps, best.poses, ids, cfg)
    out = {p: e for p, e in out.items() if not set(p) & set(ambiguous)}
    sel = {"solutions": len(sols), "compared": [round(v, 4) for v in views], "consistent_pairs": len(chosen),
           "refuted_pairs": len(refuted), "ambiguous": {ids[k]: r for k, r in ambiguous.items()}}  # fmt: skip
    return out, sel, set(ambiguous) | (cameras - block if len(refuted) >= ALIASED_PAIRS else set())


def joint_separation(flat: list[Hypothesis], cfg: RGBDConfig) -> float:
    """The camera separation (metres) below which the joint choice neither starts from a
    hypothesis nor places a camera: ``min_separation``, or half the shortest baseline of a
    verified hypothesis when one is shorter. Every hypothesis passed ``evidence.plausible``, so a
    shorter one had two nearly identical views: the cameras really sit that close (a hand-held
    camera's frames taken as a rig: icl-noisy5 is 23 mm per frame), and a veto at
    ``min_separation`` would leave no solution at all."""
    shortest = min((float(np.linalg.norm(h.T_ji[:3, 3])) for h in flat), default=cfg.min_separation)
    return min(cfg.min_separation, 0.5 * shortest)


def _subject_held(cams, out: dict, chosen: dict, hyps: dict, block: set[int], cfg: RGBDConfig) -> set[int]:
    """Cameras outside the cycle-checked ``block`` that are not ambiguous: one of their chosen
    pair poses is the pair's only remaining hypothesis and the subject confirms it
    (``symmetry.subject_free_space`` on at least SUBJECT_MIN_POINTS points, within
    SUBJECT_MAX_FREE_SPACE): the alternatives were refuted. They stay placed, unchecked by a cycle
    (the verdict says "check it")."""
    held = set()
    for p in out:
        if len(hyps[p]) != 1 or set(p) <= block:
            continue
        h = chosen[p]
        share, seen = subject_free_space(cams[h.i], cams[h.j], h.T_ji, cfg.tau)
        if seen >= SUBJECT_MIN_POINTS and share <= SUBJECT_MAX_FREE_SPACE:
            held |= set(p) - block
    return held


def _refutes(hs: list[Hypothesis], poses: dict) -> bool:
    """Does a solution (``poses``) refute one of a pair's verified hypotheses by more than
    ALIAS_MIN_DEG (an alias, not the noise of a right pose)?"""
    for h in hs:
        r, _ = pose_gap(h.T_ji @ poses[h.i], poses[h.j])
        if r > ALIAS_MIN_DEG:
            return True
    return False


def _ambiguous(cams, out: dict, chosen: dict, hyps: dict, poses: dict, ids: list[str], cfg: RGBDConfig) -> dict:
    """Camera -> reason, for the cameras held only by edges on no cycle (``symmetry.bridges``) one
    of whose pairs has another passing hypothesis scoring at least ``ambiguity_ratio`` of the
    chosen one, unless the chosen pose agrees better with all other views by AMBIGUITY_MARGIN."""
    lone = bridges(sorted(out))
    found = {}
    for k in sorted({k for p in out for k in p}):
        mine = [p for p in out if k in p]
        if any(p not in lone for p in mine) or k not in poses:
            continue
        for p in mine:
            rivals = [h for h in hyps[p] if h is not chosen[p] and h.score >= cfg.ambiguity_ratio * chosen[p].score]
            other = p[0] if p[1] == k else p[1]
            here = _views_agreement(cams, poses, cfg, only=k)
            margins = []
            for h in rivals:
                T = h.T_ji @ poses[other] if k == h.j else invert_rigid(h.T_ji) @ poses[other]
                margins.append(here - _views_agreement(cams, {**poses, k: T}, cfg, only=k))
            if rivals and min(margins) < AMBIGUITY_MARGIN:
                found[k] = (
                    f"ambiguous: its only link {ids[p[0]]}-{ids[p[1]]} closes no cycle and has {len(rivals) + 1} "
                    f"verified poses {_gap(chosen[p], rivals[0]):.0f} deg apart that score alike and agree alike "
                    f"with the other views (margin {min(margins):.3f}): a repeating room; nothing tells them apart"
                )
                break
    return found


def _views_agreement(cams, poses: dict, cfg: RGBDConfig, only: int | None = None) -> float:
    """What all views say of a solution (``poses``: camera -> camera-from-world): the mean of the
    share of agreeing votes over every ordered pair of placed cameras (tolerance VIEWS_TAU_SHARE
    of tau) and the same share on the subject (points within SUBJECT_RADIUS_M of the cameras'
    convergence point): the subject does not repeat, the walls may. ``only``: pairs with that
    camera only. NaN without votes."""
    ks = sorted(poses)
    world = {k: invert_rigid(poses[k]) for k in ks}
    A, b = np.zeros((3, 3)), np.zeros(3)
    for k in ks:
        d = world[k][:3, 2]
        M = np.eye(3) - np.outer(d, d)
        A, b = A + M, b + M @ world[k][:3, 3]
    centre = np.linalg.lstsq(A, b, rcond=None)[0]
    tau = cfg.tau * VIEWS_TAU_SHARE
    n = np.zeros(4)  # agree, votes, subject agree, subject votes
    for x in ks:
        Xw = cams[x].samples_X.numpy().astype(np.float64) @ world[x][:3, :3].T + world[x][:3, 3]
        subject = torch.from_numpy(np.linalg.norm(Xw[:, :2] - centre[:2], axis=1) < SUBJECT_RADIUS_M)
        for y in ks:
            if x == y or (only is not None and only not in (x, y)):
                continue
            M = torch.from_numpy((poses[y] @ world[x])[:3, :].astype(np.float32))
            ag, vo = project_votes(cams[x].samples_X, M, cams[y].K_sub, cams[y].depth_sub, tau, True)
            n += [int(ag.sum()), int(vo.sum()), int((ag & subject).sum()), int((vo & subject).sum())]
    if not n[1]:
        return float("nan")
    return 0.5 * n[0] / n[1] + 0.5 * (n[2] / n[3] if n[3] else n[0] / n[1])


def _gap(h: Hypothesis, g: Hypothesis) -> float:
    return rotation_angle_deg(h.T_ji[:3, :3] @ g.T_ji[:3, :3].T)
