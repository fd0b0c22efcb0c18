"""Per camera pair (steps 2 and 3 of the package outline): the candidates of every route
(``candidates``, the people and subject routes), each verified, the best plausible one kept as
the pair's edge with the correspondences that support it."""

from __future__ import annotations

import numpy as np
import torch

from fuseflow.calib import progress
from fuseflow.calib.accuracy import expected_entry
from fuseflow.calib.backbones.rgbd.candidates import floor_candidates, pooled_matches, sift3d_candidates
from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.evidence import (
    CLOSE_DEPTH_SHARE,
    CameraEvidence,
    PairCheck,
    plausible,
    room_points,
    room_view,
    verify_pose,
)
from fuseflow.calib.backbones.rgbd.judge import subject_judge, subject_ok
from fuseflow.calib.geometric import kabsch
from fuseflow.calib.posegraph import Edge
from fuseflow.calib.symmetry import (
    SUBJECT_MAX_FREE_SPACE,
    SUBJECT_MIN_POINTS,
    Hypothesis,
    RoomOrbits,
    colocated,
    distinct_hypotheses,
    joint_axes,
    pose_gap,
    room_orbits,
    subject_free_space,
    views_room,
)
from fuseflow.types import Frame, Rig, invert_rigid

#: Verified candidates of a pair are ranked by their agreeing samples at this share of tau (the
#: pass / fail test stays at tau): tau = 5 % cannot tell 0.1 deg from 1 deg (``geometric_route._better``).
RANK_TAU_SHARE = 0.2

#: Tolerance of the joint choice (hypotheses closer than this are one; a pair agrees with a
#: solution within it): wider than the cycle test's (2 deg / 8 cm), since a growth chains
#: unrefined poses (hocap-8rs: at 2 deg / 8 cm 5 right pairs fell out); an alias of a 12-fold room
#: is 30 deg away.
JOINT_ROT_DEG, JOINT_TRANS_M = 5.0, 0.2


def person_route(frames: list[Frame], rig: Rig, order: list[int], cfg: RGBDConfig):
    """(``people.PersonRoute`` over the frames, None) or (None, the one-line reason it is skipped)."""
    if not cfg.people:
        return None, "skipped: RGBDConfig.people is off"
    from fuseflow.calib.people import MediapipePoseDetector, PeopleConfig, PersonRoute, people_unavailable

    reason = people_unavailable()
    if reason is not None:
        return None, f"skipped: {reason}"
    detector = MediapipePoseDetector()
    return PersonRoute(frames, rig, order, detector, PeopleConfig(seed=cfg.seed)), None


def subject_route(frames: list[Frame], rig: Rig, order: list[int], cams: list[CameraEvidence], cfg: RGBDConfig):
    """``subject.SubjectRoute`` over the frames (route (e)), or None (off, or under 3 frames)."""
    from fuseflow.calib.subject import MIN_FRAMES, SubjectRoute

    if not cfg.subject or len(frames) < MIN_FRAMES:
        return None
    return SubjectRoute.build(frames, rig, order, [c.plane for c in cams])


def sphere_route(frames: list[Frame], rig: Rig, order: list[int], cams: list[CameraEvidence], cfg: RGBDConfig):
    """``spheres.SphereRoute`` over the frames (route (f)), or None (off, or too few frames)."""
    from fuseflow.calib.backbones.rgbd.spheres import MIN_FRAMES, SphereRoute

    if not cfg.spheres or len(frames) < MIN_FRAMES:
        return None
    return SphereRoute.build(frames, rig, order, [c.plane for c in cams], cfg.seed)


def pair_edges(cams: list[CameraEvidence], cfg: RGBDConfig, people=None, subject=None, spheres=None):
    """Candidates, verification and the accepted edge of every camera pair (canonical order);
    ``people``: a ``people.PersonRoute`` adding route (d)'s candidates, or None. In a room that
    repeats (``pair_room``: ``symmetry.room_orbits`` on the verified floor and image poses, else
    on all of them), a pair with no pose the subject confirms also gets the turns of its best
    verified pose (else, in a room only unverified poses show, of its best floor or image pose)
    about the room's axis
    (``turned_candidates``), and poses that stack its two cameras are refused (``unstacked``).
    Returns (edges: the best plausible candidate of each pair, per-pair
    info, hypotheses: pair -> its distinct plausible verified poses, best first, for the joint
    choice, the room's ``RoomOrbits`` info or None)."""
    edges: dict[tuple[int, int], Edge] = {}
    hyps: dict[tuple[int, int], list[Hypothesis]] = {}
    info, work = [], []
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            a, b = cams[i], cams[j]
            Xa, Xb = pooled_matches(a, b, cfg)
            cands = floor_candidates(a, b, cfg, (Xa, Xb)) + sift3d_candidates(Xa, Xb, cfg)
            cands += people.pair(i, j) if people is not None else []
            cands += subject.pair(i, j) if subject is not None else []
            cands += spheres.pair(i, j) if spheres is not None else []
            judge = subject_judge(a, b, cands, cfg, subject, i, j)
            rows, passing, verified, seen = [], [], [], []
            for c in cands:
                row, h, static_ok = judge_candidate(a, b, c, cands, cfg, judge, (i, j))
                rows.append(row)
                passing += [h] if h is not None else []
                verified += [c] if static_ok and c["route"] in ORBIT_ROUTES else []
                seen += [c] if c["route"] in ORBIT_ROUTES else []
            entry = {"pair": [i, j], "matches": int(len(Xa)), "candidates": rows, "edge": None}
            work.append((i, j, cands, judge, passing, (_distinct(verified), _distinct(seen)), entry))
            progress.report("rgbd: pairs", len(work), len(cams) * (len(cams) - 1) // 2)
    aliased = any(r.get("rejected") in ALIAS_REJECTIONS for w in work for r in w[6]["candidates"])
    room, unverified = pair_room(cams, [((w[0], w[1]), w[5]) for w in work], aliased)
    if room is not None:  # one axis for every camera (symmetry section 7)
        verified_poses = {(w[0], w[1]): [c["T_ba"] for c in w[5][0]] for w in work}
        room = joint_axes(room, [room_points(c) for c in cams], verified_poses)
    turned = 0
    for i, j, cands, judge, passing, (verified, seen), entry in work:
        near = max(cfg.min_separation, CLOSE_DEPTH_SHARE * median_depth(cams[i], cams[j]))
        confirmed = any(
            r["ok"] and "subject_free_space" in r and not colocated(np.array(r["T_ji"]), near)
            for r in entry["candidates"]
        )
        sources = verified or (seen[:1] if unverified else [])
        if room is not None and sources and not confirmed:
            more = turned_candidates(cams[i], cams[j], room, (i, j), cands, judge, sources, entry, cfg)
            passing.extend(more)
            turned += len(more)
    if unverified and not turned:  # the aliases' room confirmed no pose: no room was seen
        room = None
    for i, j, cands, _, passing, _, entry in work:
        if room is not None:
            passing[:] = unstacked(cams[i], cams[j], passing, cands, entry, cfg)
        a, b = cams[i], cams[j]
        kept = distinct_hypotheses(passing, JOINT_ROT_DEG, JOINT_TRANS_M, cfg.pair_hypotheses)
        if kept:
            hyps[(i, j)] = kept
            edges[(i, j)], entry["edge"] = edge_of(a, b, kept[0], cfg)
            entry["hypotheses"] = len(kept)
        info.append(entry)
    return edges, info, hyps, (room.info() if room is not None else None)


#: A room period that only this many pairs' verified poses show is checked against the period
#: of all the pairs' floor and image poses (``pair_room``): one pair's two verified poses 32.7
#: deg apart gave a 12-fold symstudio 11 sides (seed 5019 at 320x240), and every turned pose was
#: then 2.7 deg per period off, yet verified at tau.
MIN_ROOM_PAIRS = 2

#: A pose that turns one camera's floor normal more than this from the other's (cosine) is refused
#: when both cameras fit a floor: it puts one camera upside down, looking at the ceiling as a
#: floor. A repeating room whose floor and ceiling match alike gives such poses 6 sift3d inliers
#: and an agreement of 1.00 (only the far ceiling overlaps). 120 deg, not a few: a camera whose
#: floor fit took a wall is 90 deg off on a true pose.
FLOOR_FLIP_COS = -0.5


def upside_down(a: CameraEvidence, b: CameraEvidence, T_ba: np.ndarray) -> bool:
    """Whether ``T_ba`` maps a's floor normal more than acos(FLOOR_FLIP_COS) from b's (both
    floors fitted)."""
    if a.plane is None or b.plane is None:
        return False
    return float((T_ba[:3, :3] @ a.plane.normal) @ b.plane.normal) < FLOOR_FLIP_COS


#: Rejections of a pose that passed the depth checks which say the room may repeat: it stacks
#: the two cameras, or the other camera sees through its subject (``pair_room``).
ALIAS_REJECTIONS = ("co-located", "subject seen through")


def pair_room(cams: list[CameraEvidence], poses: list[tuple[tuple[int, int], tuple[list, list]]],
              aliased: bool = False):  # fmt: skip
    """(the room's ``RoomOrbits`` or None, whether it was found only from unverified poses).
    ``poses``: pair -> (its distinct verified floor / image poses, all its distinct floor / image
    poses). The room comes from the verified poses (``symmetry.room_orbits``); when they show
    none, from every pose of those routes: where the image routes match the repeating walls
    alone, every pose they find is an alias, a whole number of periods off (a 9-fold symstudio
    at 320x240: 0 of 21 pairs verified, their poses 40-160 deg off in multiples of 40), and the
    aliases of a pair show the room's turn as well as verified ones do. Such a room only
    proposes turned poses; the caller drops it when none of them passes verification. A room
    that fewer than MIN_ROOM_PAIRS pairs' verified poses show yields to the room of all poses
    when more pairs show that one. When no pose shows a room and some verified pose was
    rejected as an alias would be (``aliased``: ALIAS_REJECTIONS), the cameras' own views are
    searched for one (``symmetry.views_room``): where every pair's poses are consistent aliases
    no pose shows a turn."""
    ups = {k: (c.plane.normal if c.plane is not None else None) for k, c in enumerate(cams)}
    verified = {p: [c["T_ba"] for c in v] for p, (v, _) in poses}
    room = room_orbits(verified, ups)
    wide = None
    if room is None or room.pairs < MIN_ROOM_PAIRS:
        wide = room_orbits({p: [c["T_ba"] for c in s] for p, (_, s) in poses}, ups)
    if room is not None and (room.pairs >= MIN_ROOM_PAIRS or wide is None or wide.pairs <= room.pairs):
        return views_check(room, cams, verified), False
    if wide is None and aliased:
        return views_room([room_view(c) for c in cams], verified), False
    if wide is not None:
        return views_check(wide, cams, verified), room is None
    return None, False


#: A room that fewer pairs than this show is checked against the cameras' own views
#: (``views_check``).
VIEW_CHECK_PAIRS = 3


def views_check(room: RoomOrbits, cams: list[CameraEvidence], verified: dict) -> RoomOrbits:
    """``room``, or the room the cameras' own views show (``symmetry.views_room``) when ``room``
    rests on fewer than VIEW_CHECK_PAIRS pairs and the views read another period: a pose a few
    degrees off among a pair's aliases moves the period of a room that two pairs show
    (independent studio seed 1113, 6-sided: turns of 120 deg and of 162 deg, a 3-period alias
    18 deg off, read 9 sides; every view read 6)."""
    if room.pairs >= VIEW_CHECK_PAIRS:
        return room
    seen = views_room([room_view(c) for c in cams], verified)
    return seen if seen is not None and seen.sides != room.sides else room


def unstacked(a: CameraEvidence, b: CameraEvidence, passing: list[Hypothesis], cands: list[dict], entry: dict,
              cfg: RGBDConfig) -> list[Hypothesis]:  # fmt: skip
    """The passing hypotheses of a pair in a repeating room less those that put the two cameras
    on one spot (their rows marked rejected). ``evidence.plausible`` lets such a pose pass when
    the two views agree as one (a hand-held camera's frames taken as a rig), but in a room that
    repeats, cameras mounted at whole periods see the same room, and a pose that stacks one on
    the other agrees with it at 0.99 (polyroom, 12-fold, 10 cameras on its pillars: every pair
    had a stacking pose that passed, its subject seen through at 0.00-0.06, as little as the
    true pose's): the subject, small and far, cannot refute it, and the joint choice then folds
    the ring onto one spot. The pair's turned poses (``turned_candidates``) bring the unstacked
    members of the same orbit."""
    near = max(cfg.min_separation, CLOSE_DEPTH_SHARE * median_depth(a, b))
    out = []
    for h in passing:
        if not colocated(h.T_ji, near):
            out.append(h)
            continue
        for c, row in zip(cands, entry["candidates"]):
            if c is h.ref[0]:
                row.update(ok=False, rejected="stacked in a repeating room")
    return out


def judge_candidate(a: CameraEvidence, b: CameraEvidence, c: dict, cands: list[dict], cfg: RGBDConfig, judge,
                    pair: tuple[int, int]) -> tuple[dict, Hypothesis | None, bool]:  # fmt: skip
    """Verify candidate ``c`` of ``pair`` and apply every rejection (the moving subject's
    ``judge``, physical plausibility, the subject check). Returns (its info row, its Hypothesis
    when it passes all, else None, whether it passed the static depth checks alone)."""
    chk = verify_pose(a, b, c["T_ba"], cfg.tau)
    ok = chk.passes(cfg) or (c["route"] == "subject" and judge is not None) or sphere_passes(c, chk, cfg)
    row = {"route": c["route"], "inliers": c["inliers"], "ok": ok, **check_row(chk),
           "T_ji": np.round(c["T_ba"], 6).tolist()}  # fmt: skip
    if judge is not None and (verdict := judge(c["T_ba"])) is not None:
        row["subject_m"] = round(verdict, 4)
        if ok and verdict > judge.limit:  # the person says no (calib.subject)
            row.update(ok=False, rejected="subject")
            ok = False
    if ok and upside_down(a, b, c["T_ba"]):
        row.update(ok=False, rejected="upside down")
        ok = False
    if ok and not plausible(c["T_ba"], chk, cfg, median_depth(a, b)):
        # stacked on the other camera: rejected, not scored (calib.symmetry)
        row.update(ok=False, rejected="co-located")
        ok = False
    if ok and not subject_ok(a, b, c["T_ba"], cfg, row):
        ok = False  # the other camera sees through its subject: an alias (calib.symmetry)
    # rank by how much depth confirms the pose, not by the share alone: a wrong pose that turns
    # the cameras apart leaves a sliver of overlap that agrees 100 % (ICL, 40 frames apart: 529
    # samples at 1.0 against 7800 at 0.98); counted at RANK_TAU_SHARE of tau, which tells a
    # 0.5-deg pose from a 2.3-deg one (at tau the 2.3-deg one agreed on more samples than the
    # true pose: docs/gmac.md)
    if not ok:
        return row, None, chk.passes(cfg) and row.get("rejected") != "upside down"
    fine = verify_pose(a, b, c["T_ba"], cfg.tau * RANK_TAU_SHARE).agree
    row["agree_fine"] = fine
    return row, Hypothesis(pair[0], pair[1], c["T_ba"], float(fine), (c, chk, cands)), chk.passes(cfg)


def sphere_passes(c: dict, chk: PairCheck, cfg: RGBDConfig) -> bool:
    """A moving-sphere candidate's depth test (``spheres`` module docstring): the static depth
    agrees as for every candidate, the free space within ``spheres.MAX_FREE_SPACE``."""
    from fuseflow.calib.backbones.rgbd.spheres import MAX_FREE_SPACE

    return (
        c["route"].startswith("sphere")
        and chk.agreement >= cfg.min_agreement
        and chk.free_space <= MAX_FREE_SPACE
        and chk.agree >= cfg.min_agree_points
    )


#: Routes whose verified poses of a pair are turns of one another in a repeating room (the
#: floor and image routes match the room's repeating texture; the subject, person and geometry
#: routes do not).
ORBIT_ROUTES = ("floor", "sift4", "sift3d")
#: Of a pair's turned poses the subject confirms, those whose seen-through share is within this
#: of the smallest are verified (symstudio seeds 12 and 14: the true pose 0.000-0.036, the next
#: turn that passed 0.065, 0.037 more than the true pose of its pair).
ORBIT_MARGIN = 0.02


def _distinct(cands: list[dict]) -> list[dict]:
    """Candidates whose poses differ pairwise by more than the joint choice's tolerance, the
    most inliers first."""
    out: list[dict] = []
    for c in sorted(cands, key=lambda c: -c["inliers"]):
        gaps = [pose_gap(c["T_ba"], o["T_ba"]) for o in out]
        if all(r > JOINT_ROT_DEG or t > JOINT_TRANS_M for r, t in gaps):
            out.append(c)
    return out


def turned_candidates(a: CameraEvidence, b: CameraEvidence, room: RoomOrbits, pair: tuple[int, int], cands: list[dict],
                      judge, verified: list[dict], entry: dict, cfg: RGBDConfig) -> list[Hypothesis]:  # fmt: skip
    """The hypotheses among the turns of the pair's best-supported verified pose about the room's
    axis (``RoomOrbits.members``): every turn fits the repeating walls alike, so the subject
    chooses first (not stacked, at least SUBJECT_MIN_POINTS subject points seen, at most
    SUBJECT_MAX_FREE_SPACE of them seen through, within ORBIT_MARGIN of the best turn); those
    are verified and judged like any candidate (``judge_candidate``) and listed in the pair's
    candidates with ``turn_deg``. A turned candidate carries its source's correspondences,
    camera a's side turned back (T = A R, so T maps R^-1 X_a onto X_b)."""
    src = verified[0]
    near = max(cfg.min_separation, CLOSE_DEPTH_SHARE * median_depth(a, b))
    scored = []
    for angle, T in room.members(pair[0], src["T_ba"], [c["T_ba"] for c in verified]):
        if colocated(T, near):
            continue
        share, seen = subject_free_space(a, b, T, cfg.tau)
        if seen >= SUBJECT_MIN_POINTS and share <= SUBJECT_MAX_FREE_SPACE:
            scored.append((share, angle, T))
    entry["orbit"] = {"sides": room.sides, "subject_confirmed": len(scored)}
    out = []
    scored.sort(key=lambda x: x[0])
    for share, angle, T in scored:
        if share > scored[0][0] + ORBIT_MARGIN:
            break
        M = invert_rigid(T) @ src["T_ba"]
        c = {**src, "route": src["route"] + "+turn", "T_ba": T, "X_a": src["X_a"] @ M[:3, :3].T + M[:3, 3]}
        row, h, _ = judge_candidate(a, b, c, cands + [c], cfg, judge, pair)
        entry["candidates"].append({**row, "turn_deg": round(angle, 1)})
        if h is not None:
            cands.append(c)
            out.append(h)
    return out


def median_depth(a: CameraEvidence, b: CameraEvidence) -> float:
    """The median depth (metres) of two cameras' verification points."""
    z = torch.cat([a.samples_X[:, 2], b.samples_X[:, 2]])
    return float(z.median()) if len(z) else 0.0


def edge_of(a: CameraEvidence, b: CameraEvidence, h: Hypothesis, cfg: RGBDConfig) -> tuple[Edge, dict]:
    """The edge of hypothesis ``h`` (refit on every route's correspondences it explains) and its
    info entry."""
    c, chk, cands = h.ref
    # route (e)'s floor points restate its own pose: evidence for its edge only
    cands = [x for x in cands if x["route"] != "subject" or x is c]
    c, chk = _refit(a, b, c, chk, cands, cfg)
    X_i, X_j = _support(c["T_ba"], cands, cfg)
    sigma = cfg.sigma0 + cfg.sigma2 * X_j[:, 2] ** 2
    entry = {"route": c["route"], "agreement": round(chk.agreement, 4), "support": int(len(X_i)),
             "T_ji": np.round(c["T_ba"], 6).tolist()}  # fmt: skip
    entry.update({k: round(c[k], 4) for k in ("expected_m", "spread_m", "track_frames") if k in c})  # route (e)
    entry.update(expected_entry(c["T_ba"], X_i, X_j))
    return Edge(h.i, h.j, c["T_ba"], float(chk.agree), X_i, X_j, sigma), entry


def check_row(chk: PairCheck) -> dict:
    return {
        "agreement": round(chk.agreement, 4),
        "structure_agreement": None if np.isnan(chk.structure_agreement) else round(chk.structure_agreement, 4),
        "free_space": round(chk.free_space, 4),
        "agree": chk.agree,
        "structure_votes": chk.structure_votes,
    }


def _refit(a: CameraEvidence, b: CameraEvidence, c: dict, chk: PairCheck, cands: list[dict], cfg: RGBDConfig):
    """Refit the accepted pose on the correspondences of every route that it explains (6-DoF
    Kabsch, three times, re-collecting): the verified candidates of a pair are all roughly right
    (depth agreement at tau = 5 % cannot tell 0.1 deg from 1 deg), their pooled evidence is more
    precise than any one of them (the 4-DoF floor poses are). Kept when it still passes, agrees
    within 0.02 of the candidate and keeps at least 90 % of its agreeing samples."""
    T = c["T_ba"]
    if c["route"] == "subject":  # head centres and both floors: other routes' matches are coarser
        return c, chk
    for _ in range(3):
        Xa, Xb = _support(T, cands, cfg)
        if len(Xa) < 6:
            return c, chk
        T = kabsch(Xa[None], Xb[None])[0]
    new = verify_pose(a, b, T, cfg.tau)
    if new.passes(cfg) and new.agreement >= chk.agreement - 0.02 and new.agree >= 0.9 * chk.agree:
        return {**c, "T_ba": T, "route": c["route"] + "+refit"}, new
    return c, chk


def _support(T_ba: np.ndarray, cands: list[dict], cfg: RGBDConfig) -> tuple[np.ndarray, np.ndarray]:
    """Every candidate's correspondences (all routes) that the accepted pose explains: the
    edge's evidence for the joint solve."""
    XA = np.concatenate([c["X_a"] for c in cands])
    XB = np.concatenate([c["X_b"] for c in cands])
    r = np.linalg.norm(XA @ T_ba[:3, :3].T + T_ba[:3, 3] - XB, axis=1)
    ok = r < cfg.inlier_m + cfg.inlier_rel * XB[:, 2]
    XA, XB = XA[ok], XB[ok]
    _, first = np.unique(np.round(np.c_[XA, XB], 6), axis=0, return_index=True)  # a match seen twice counts once
    first.sort()
    return XA[first], XB[first]
