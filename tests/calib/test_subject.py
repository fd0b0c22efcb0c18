"""The moving-subject route (calib.subject): a walking person's head as a detector-free target.

Depth images are ray-cast here (a floor, a static crate, a person: a box body and a sphere head)
for small cameras, so every test runs in well under a second."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from fuseflow.calib.floor import fit_floor_plane
from fuseflow.calib.posegraph import rotation_angle_deg
from fuseflow.calib.subject import (
    REFUTE_M,
    SubjectRoute,
    camera_track,
    head_centre,
    subject_masks,
    track_pose,
    track_residual,
)
from fuseflow.synth.rigs import look_at
from fuseflow.types import invert_rigid

W, H, F_PX = 320, 240, 220.0
K = np.array([[F_PX, 0, W / 2], [0, F_PX, H / 2], [0, 0, 1.0]])
HEAD_R = 0.11


def _boxes_hit(o, d, lo, hi):
    """Ray parameter of the nearest hit of rays (o, d (M, 3)) with an axis-aligned box, inf if none."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / d, (hi - o) / d
    tn, tf = np.nanmax(np.minimum(t1, t2), axis=1), np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((tf >= tn) & (tn > 0), tn, np.inf)


def _render(T_cw, person_xy, crate=True, noise=0.0, rng=None):
    """(H, W) depth (metres along z) of the floor, a static crate and a person at ``person_xy``."""
    v, u = np.mgrid[0:H, 0:W]
    rays_c = np.stack([(u - K[0, 2]) / F_PX, (v - K[1, 2]) / F_PX, np.ones_like(u, float)], -1).reshape(-1, 3)
    T_wc = invert_rigid(T_cw)
    d = rays_c @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    t = np.where(d[:, 2] < -1e-9, -o[2] / np.minimum(d[:, 2], -1e-9), np.inf)  # floor z = 0
    if crate:
        t = np.minimum(t, _boxes_hit(o, d, np.array([1.5, -2.0, 0.0]), np.array([2.1, -1.4, 0.6])))
    if person_xy is not None:
        px, py = person_xy
        t = np.minimum(
            t, _boxes_hit(o, d, np.array([px - 0.15, py - 0.15, 0.0]), np.array([px + 0.15, py + 0.15, 1.45]))
        )
        c = np.array([px, py, 1.62])
        oc = o - c
        b = d @ oc
        disc = b**2 - (d * d).sum(1) * (oc @ oc - HEAD_R**2)
        ts = (-b - np.sqrt(np.maximum(disc, 0))) / (d * d).sum(1)
        t = np.minimum(t, np.where(disc > 0, ts, np.inf))
    z = np.where(np.isfinite(t), t, 0.0)  # rays_c has z = 1: t is the depth along z
    if noise and rng is not None:
        z = np.where(z > 0, z + rng.normal(0, noise, z.shape), 0.0)
    z = np.where(z < 6.0, z, 0.0)
    return z.reshape(H, W)


def _plane(depth):
    v, u = np.nonzero(depth > 0)
    z = depth[v, u]
    return fit_floor_plane(np.c_[(u - K[0, 2]) * z / F_PX, (v - K[1, 2]) * z / F_PX, z])


def _walk(n=8, length=2.0):
    return [(-length / 2 + length * k / (n - 1), 0.3 - 0.1 * k / (n - 1)) for k in range(n)]


def _cams():
    return [look_at((3.6 * math.cos(a), 3.6 * math.sin(a), 1.9), (0.0, 0.0, 1.0)) for a in (0.3, 0.3 + 2 * math.pi / 3)]


def _truth(Ta, Tb):
    return Tb @ invert_rigid(Ta)


def _err(T, T_true):
    D = T @ invert_rigid(T_true)
    return rotation_angle_deg(D[:3, :3]), float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))


@functools.lru_cache(maxsize=4)
def _cached(kind: str):
    """Tracks and floors of the two cameras for a walk ('walk'), a person standing ('still') or two
    frames ('two'), computed once per test run."""
    walk = {"walk": _walk(), "still": [(0.1, 0.2)] * 5, "two": _walk(2)}[kind]
    return _tracks(_cams(), walk)


def _tracks(cams, walk, noise=0.002):
    rng = np.random.default_rng(0)
    out, planes = [], []
    for T in cams:
        D = np.stack([_render(T, p, noise=noise, rng=rng) for p in walk])
        planes.append(_plane(_render(T, None)))
        out.append(camera_track(D, K, planes[-1])[0])
    return out, planes


def test_head_centre_is_the_sphere_centre_not_the_visible_cap():
    rng = np.random.default_rng(1)
    c = np.array([0.2, -0.4, 3.7])
    n = rng.normal(size=(4000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    P = c + HEAD_R * n
    P = P[(n @ (-c / np.linalg.norm(c))) > 0.2]  # the cap the camera at the origin sees
    P += rng.normal(0, 0.002, P.shape)
    got = head_centre(P, HEAD_R)
    assert got is not None
    assert np.linalg.norm(got[0] - c) < 0.005
    assert np.linalg.norm(P.mean(axis=0) - c) > 0.05  # the centroid is biased towards the camera


def test_masks_find_the_moving_person_not_the_static_crate():
    T = _cams()[0]
    walk = _walk()
    D = np.stack([_render(T, p) for p in walk])
    plane = _plane(_render(T, None))
    masks = subject_masks(D, K, plane)
    for f, m in enumerate(masks):
        alone = _render(T, walk[f], crate=False) - _render(T, None, crate=False)
        person = np.abs(alone) > 0.05  # where the person changes the depth
        assert m.sum() > 0.8 * person.sum()
        assert (m & ~person).sum() < 0.05 * m.sum()


def test_track_pose_from_a_walk_is_accurate():
    cams = _cams()
    (Pa, Pb), (pa, pb) = _cached("walk")
    assert np.isfinite(Pa[:, 0]).sum() == len(_walk())
    fit = track_pose(Pa, Pb, pa, pb)
    assert fit is not None
    r, t = _err(fit[0], _truth(*cams))
    assert r < 0.5 and t < 0.03, (r, t)


def test_standing_still_or_too_few_frames_give_no_pose():
    (Pa, Pb), (pa, pb) = _cached("still")
    assert track_pose(Pa, Pb, pa, pb) is None  # no spread: no heading
    (Pa, Pb), (pa, pb) = _cached("two")
    assert track_pose(Pa, Pb, pa, pb) is None


def test_the_tracks_refute_a_pose_two_degrees_off():
    cams = _cams()
    (Pa, Pb), _ = _cached("walk")
    T_true = _truth(*cams)
    assert track_residual(Pa, Pb, T_true)[0] < 0.02
    turn = np.eye(4)
    turn[:3, :3] = np.array([[math.cos(0.035), 0, math.sin(0.035)], [0, 1, 0], [-math.sin(0.035), 0, math.cos(0.035)]])
    assert track_residual(Pa, Pb, turn @ T_true)[0] > REFUTE_M


def test_route_pairs_carry_floor_points_and_step_aside_without_motion():
    tracks, planes = _cached("walk")
    route = SubjectRoute(np.stack(tracks), planes, [HEAD_R, HEAD_R])
    (cand,) = route.pair(0, 1)
    assert cand["route"] == "subject" and cand["track_frames"] == len(_walk())
    assert len(cand["X_a"]) == 2 * len(_walk())  # head centres and their feet on the floor
    feet = cand["X_b"][len(_walk()) :]
    assert np.abs(planes[1].distance(feet)).max() < 0.02
    still, _ = _cached("still")
    assert SubjectRoute(np.stack(still), planes, [HEAD_R, HEAD_R]).pair(0, 1) == []


@pytest.mark.parametrize("frames", [1, 2])
def test_rgbd_backbone_skips_the_route_with_few_frames(frames):
    from fuseflow.calib.backbones.rgbd import RGBDConfig
    from fuseflow.calib.backbones.rgbd.pairs import subject_route

    assert subject_route([object()] * frames, None, [0, 1], [], RGBDConfig()) is None
    assert subject_route([object()] * 5, None, [0, 1], [], RGBDConfig(subject=False)) is None


def test_the_judge_refutes_relative_to_the_subject_pose():
    from fuseflow.calib.backbones.rgbd.judge import SUBJECT_MARGIN_M, SUBJECT_REFUTE_M, _SubjectJudge

    cams = _cams()
    tracks, planes = _cached("walk")
    route = SubjectRoute(np.stack(tracks), planes, [HEAD_R, HEAD_R])
    T_true = _truth(*cams)
    (cand,) = route.pair(0, 1)
    base = route.judge(0, 1, cand["T_ba"], cand["inliers_mask"])[0]
    judge = _SubjectJudge(route, 0, 1, cand["inliers_mask"], min(SUBJECT_REFUTE_M, base + SUBJECT_MARGIN_M))
    assert judge(T_true) <= judge.limit  # the true pose stays
    turn = np.eye(4)
    a = math.radians(1.0)  # 1 deg about the camera's vertical: the head moves ~6 cm at 3.6 m
    turn[:3, :3] = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    assert judge.limit < judge(turn @ T_true) < SUBJECT_REFUTE_M  # refuted only by the relative gate
