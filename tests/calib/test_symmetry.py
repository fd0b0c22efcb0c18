"""Symmetric rooms (calib.symmetry, backbones.rgbd.plausible): a stacked pose is rejected, the
joint choice of pair hypotheses prefers the cycle-consistent truth over better-scored aliases."""

from __future__ import annotations

import math

import numpy as np

from fuseflow.calib.backbones.rgbd import PairCheck, RGBDConfig, plausible
from fuseflow.calib.symmetry import (
    Hypothesis,
    bridges,
    colocated,
    distinct_hypotheses,
    main_block,
    pose_gap,
    select_consistent,
)
from fuseflow.synth.rigs import look_at
from fuseflow.types import invert_rigid


def _rz(deg: float) -> np.ndarray:
    a = math.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


def _ring(n: int, radius: float = 2.6) -> list[np.ndarray]:
    return [
        look_at([radius * math.cos(2 * math.pi * k / n), radius * math.sin(2 * math.pi * k / n), 1.5], [0, 0, 1])
        for k in range(n)
    ]


def _rel(T: list[np.ndarray], i: int, j: int) -> np.ndarray:
    return T[j] @ invert_rigid(T[i])


GOOD_CHECK = PairCheck(agreement=0.92, structure_agreement=0.8, free_space=0.03, agree=4000, structure_votes=900)


def test_a_stacked_pose_is_rejected_however_well_it_agrees():
    cfg = RGBDConfig()
    T = _ring(5)
    # the alias of a 5-fold room that puts camera 1 on camera 0: 3 cm apart, 72 deg turned
    stacked = _rz(72.0)
    stacked[:3, 3] = [0.03, 0.0, 0.0]
    assert colocated(stacked, cfg.min_separation)
    assert GOOD_CHECK.passes(cfg)  # the depth checks alone accept it
    assert not plausible(stacked, GOOD_CHECK, cfg)
    # 0.29 m apart, 2.6 m from the subject: also too close unless the views are the same
    near = np.eye(4)
    near[:3, 3] = [0.29, 0.0, 0.0]
    assert not plausible(near, GOOD_CHECK, cfg, depth=2.6)
    assert plausible(near, GOOD_CHECK, cfg, depth=1.0)  # 0.29 m at 1 m: a distinct viewpoint
    same = PairCheck(agreement=0.99, structure_agreement=0.98, free_space=0.0, agree=5000, structure_votes=2000)
    assert plausible(stacked, same, cfg)  # nearly identical views: cameras may sit together
    assert plausible(_rel(T, 0, 1), GOOD_CHECK, cfg, depth=2.6)  # the true neighbour, 3 m away


def test_distinct_hypotheses_merge_near_duplicates_and_keep_aliases():
    T = _ring(4)
    true = _rel(T, 0, 1)
    nudged = true.copy()
    nudged[:3, 3] += [0.01, 0.0, 0.0]
    alias = _rel([T[0], T[1] @ _rz(90.0)], 0, 1)
    hs = [Hypothesis(0, 1, true, 5.0), Hypothesis(0, 1, nudged, 4.0), Hypothesis(0, 1, alias, 6.0)]
    kept = distinct_hypotheses(hs, 2.0, 0.08, keep=3)
    assert [h.score for h in kept] == [6.0, 5.0]


def _symmetric_case():
    """4 cameras on a ring in a 4-fold room: the true pose of every pair, and better-scored
    aliases (one room period off) on three pairs that do not agree around loops, plus a stacked
    alias with the highest score of all."""
    T = _ring(4)
    hyps = [Hypothesis(i, j, _rel(T, i, j), 10.0) for i in range(4) for j in range(i + 1, 4)]
    for i, j, deg in ((0, 1, 90.0), (1, 2, -90.0), (2, 3, 180.0)):
        hyps.append(Hypothesis(i, j, _rel([*T[:j], T[j] @ _rz(deg), *T[j + 1 :]], i, j), 12.0))
    stacked = _rel([T[0], T[0]], 0, 1)  # camera 1 on top of camera 0
    hyps.append(Hypothesis(0, 1, stacked, 30.0))
    return T, hyps


def test_joint_choice_prefers_the_cycle_consistent_truth():
    T, hyps = _symmetric_case()
    sols = select_consistent(hyps, 2.0, 0.1, min_separation=0.2)
    best = sols[0]
    assert len(best.chosen) == 6
    for (i, j), k in best.chosen.items():
        r, t = pose_gap(hyps[k].T_ji, _rel(T, i, j))
        assert r < 1e-6 and t < 1e-9, (i, j)
    # the poses are the truth up to one rigid transform
    W = invert_rigid(best.poses[0]) @ T[0]
    for k in range(4):
        r, t = pose_gap(best.poses[k] @ W, T[k])
        assert r < 1e-6 and t < 1e-9
    # no solution stacks camera 1 on camera 0
    for sol in sols:
        if 0 in sol.poses and 1 in sol.poses:
            assert np.linalg.norm(invert_rigid(sol.poses[0])[:3, 3] - invert_rigid(sol.poses[1])[:3, 3]) > 0.2


def test_bridges_and_main_block():
    edges = [(0, 1), (1, 2), (0, 2), (2, 3), (3, 4), (4, 5), (3, 5), (5, 6)]
    assert bridges(edges) == {(2, 3), (5, 6)}
    assert main_block(edges) == {0, 1, 2}  # ties: the part with the lowest camera
    assert main_block([(0, 1), (1, 2)]) == set()  # a chain: nothing is checked by a cycle


# ----------------------------------------------------------------------------- the subject check


def _ray_depth(T: np.ndarray, K: np.ndarray, w: int, h: int) -> np.ndarray:
    """Depth (h, w) of a round room (radius 3.6 m, 3 m high: any turn about its axis maps it
    onto itself) with an asymmetric subject near its centre (a 1.7 m post and a low box beside
    it), ray-cast from camera-from-world ``T``."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    D = d @ T[:3, :3]  # world directions, z-component 1 in the camera: t along D is the depth
    C = invert_rigid(T)[:3, 3]
    t = np.full(len(D), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for z0 in (0.0, 3.0):  # floor, ceiling
            tz = (z0 - C[2]) / D[:, 2]
            t = np.where(tz > 0, np.minimum(t, tz), t)
        a = D[:, 0] ** 2 + D[:, 1] ** 2
        b = 2 * (C[0] * D[:, 0] + C[1] * D[:, 1])
        tc = (-b + np.sqrt(b * b - 4 * a * (C[0] ** 2 + C[1] ** 2 - 3.6**2))) / (2 * a)
        t = np.minimum(t, np.where(tc > 0, tc, np.inf))
        for lo, hi in (((0.0, -0.25, 0.0), (0.3, 0.25, 1.7)), ((0.35, 0.3, 0.0), (0.75, 0.6, 0.5))):
            t1, t2 = (np.array(lo) - C) / D, (np.array(hi) - C) / D
            near, far = np.minimum(t1, t2).max(axis=1), np.maximum(t1, t2).min(axis=1)
            t = np.where((near <= far) & (near > 0), np.minimum(t, near), t)
    return t.reshape(h, w).astype(np.float32)


def _view(T: np.ndarray):
    """A sampled view as the rgbd backbone keeps it (``CameraEvidence``'s fields the check reads)."""
    from types import SimpleNamespace

    K = np.array([[60.0, 0, 40], [0, 60.0, 30], [0, 0, 1]])
    depth = _ray_depth(T, K, 80, 60)
    v, u = np.mgrid[0:60, 0:80]
    z = depth.astype(float).ravel()
    X = np.stack([(u.ravel() - 40) / 60 * z, (v.ravel() - 30) / 60 * z, z], 1)
    W = invert_rigid(T)
    floor = (X @ W[:3, :3].T + W[:3, 3])[:, 2] < 0.05
    return SimpleNamespace(samples_X=X, samples_floor=floor, K_sub=K, depth_sub=depth,
                           plane=SimpleNamespace(normal=T[:3, :3] @ [0, 0, 1.0]))  # fmt: skip


def test_the_subject_check_rejects_a_turn_of_the_room_that_the_walls_confirm():
    from fuseflow.calib.symmetry import (
        SUBJECT_MAX_FREE_SPACE,
        SUBJECT_MIN_POINTS,
        subject_centre,
        subject_free_space,
    )

    T = [look_at([2.6 * math.cos(a), 2.6 * math.sin(a), 1.4], [0, 0, 1.0]) for a in np.radians([0.0, 72.0])]
    a, b = _view(T[0]), _view(T[1])
    true = _rel(T, 0, 1)
    centre = subject_centre(true)  # where the two optical axes meet: the look-at point
    np.testing.assert_allclose(invert_rigid(T[0])[:3, :3] @ centre + invert_rigid(T[0])[:3, 3], [0, 0, 1.0], atol=1e-6)
    share, seen = subject_free_space(a, b, true)
    assert seen >= SUBJECT_MIN_POINTS and share < 0.02, (share, seen)
    for deg in (30.0, -45.0, 90.0):  # camera 1 turned about the room's axis: the walls still agree
        alias = T[1] @ invert_rigid(_rz(deg)) @ invert_rigid(T[0])
        share, seen = subject_free_space(a, b, alias)
        assert seen >= SUBJECT_MIN_POINTS and share > SUBJECT_MAX_FREE_SPACE, (deg, share, seen)
    # parallel optical axes meet nowhere: no subject, no verdict
    side = look_at([0.0, -1.0, 1.4], [2.0, -1.0, 1.4])
    par = look_at([0.0, 1.0, 1.4], [2.0, 1.0, 1.4])
    assert subject_centre(par @ invert_rigid(side)) is None
    assert subject_free_space(_view(side), _view(par), par @ invert_rigid(side))[1] == 0


def test_a_camera_off_the_checked_group_stays_placed_only_when_the_subject_confirms_its_one_link():
    """In a repeating room a camera outside the cycle-checked group is ambiguous unless its
    link is its pair's only remaining hypothesis and the subject confirms it."""
    from fuseflow.calib.backbones.rgbd.choice import _subject_held

    T = [look_at([2.6 * math.cos(a), 2.6 * math.sin(a), 1.4], [0, 0, 1.0]) for a in np.radians([0.0, 72.0])]
    cams, cfg = [_view(T[0]), _view(T[1])], RGBDConfig()
    true = Hypothesis(0, 1, _rel(T, 0, 1), 10.0)
    alias = Hypothesis(0, 1, T[1] @ invert_rigid(_rz(36.0)) @ invert_rigid(T[0]), 12.0)
    out = {(0, 1): None}
    assert _subject_held(cams, out, {(0, 1): true}, {(0, 1): [true]}, {0}, cfg) == {1}
    assert _subject_held(cams, out, {(0, 1): alias}, {(0, 1): [alias]}, {0}, cfg) == set()
    # two hypotheses left for the pair: nothing tells them apart here, the camera stays ambiguous
    assert _subject_held(cams, out, {(0, 1): true}, {(0, 1): [alias, true]}, {0}, cfg) == set()
