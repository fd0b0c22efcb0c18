"""The person route (fuseflow.calib.people) with a fake detector: ground-truth joints of the
simulator's walking figure projected into each view plus pixel noise, depth images holding the
joints' depth. One test runs the real MediaPipe detector on rendered views (skipped without
the ``people`` extra)."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
import torch

from fuseflow.calib.errors import CalibrationError
from fuseflow.calib.people import (
    BODY_JOINTS,
    JOINT_DEPTH,
    LANDMARKS,
    MediapipePoseDetector,
    PeopleConfig,
    PoseDetection,
    keypoint_pose,
    lift_landmarks,
    people_unavailable,
    person_candidates,
    refine_icp,
)
from fuseflow.calib.posegraph import rotation_angle_deg
from fuseflow.synth.person import LANDMARK_NAMES, Walk, person_joints, ring_rig
from fuseflow.types import Frame, invert_rigid

W, H = 320, 240


class FakeDetector:
    """Returns the detections registered for an image, keyed by the tag in pixel (0, 0)."""

    def __init__(self):
        self.table: dict[tuple[int, int], list[PoseDetection]] = {}

    def detect(self, image):
        return self.table.get((int(image[0, 0, 0]), int(image[0, 0, 1])), [])


def _project(X_world, T, K):
    Xc = X_world @ T[:3, :3].T + T[:3, 3]
    uv = Xc[:, :2] / Xc[:, 2:] * np.diag(K)[:2] + K[:2, 2]
    return uv, Xc[:, 2]


def _scene(n_cams=3, n_frames=6, px_noise=1.0, depth_noise=0.01, seed=0, extra=None):
    """Frames whose depth holds the figure's joints (discs around each projected joint, the
    background at 7 m), a fake detector with the projected joints (+ noise), the rig, truth."""
    rng = np.random.default_rng(seed)
    walk = Walk()
    rig = ring_rig(n_cams, np.array([0.0, 0.0, 0.9]), (3.5, 4.0), 1.6, rng, resolution=(W, H), hfov_deg=70.0)
    det = FakeDetector()
    frames = []
    for f in range(n_frames):
        J = person_joints(walk, 0.4 * f)
        color = np.zeros((n_cams, H, W, 3), np.uint8)
        depth = np.full((n_cams, H, W), 7.0, np.float32)
        for k, cam in enumerate(rig.cameras):
            uv, z = _project(J, cam.T_cam_world, cam.K)
            z = z - np.array([JOINT_DEPTH.get(j, 0.0) for j in range(33)])  # the skin facing the camera
            for (u, v), zz in sorted(zip(uv, z), key=lambda p: -p[1]):  # far joints first
                ui, vi = int(round(u)), int(round(v))
                depth[k, max(vi - 2, 0) : vi + 3, max(ui - 2, 0) : ui + 3] = zz + rng.normal(0, depth_noise)
            color[k, 0, 0, :2] = (k, f)
            uv_n = uv + rng.normal(0, px_noise, uv.shape)
            dets = [PoseDetection(uv_n, np.full(len(LANDMARKS), 0.9))]
            if extra is not None:
                dets = extra(dets, k, f) or dets
            det.table[(k, f)] = dets
        frames.append(
            Frame(f, rig.ids, torch.from_numpy(color), torch.from_numpy(depth), torch.ones(n_cams, dtype=bool))
        )
    return frames, rig, det


def _truth(rig, a, b):
    return rig.cameras[b].T_cam_world @ invert_rigid(rig.cameras[a].T_cam_world)


def _err(T, T_true):
    D = T @ invert_rigid(T_true)
    return rotation_angle_deg(D[:3, :3]), float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))


def test_landmark_order_matches_the_simulator():
    assert LANDMARK_NAMES == LANDMARKS
    assert len(LANDMARKS) == 33 and all(LANDMARKS[k].startswith(("left", "right")) for k in BODY_JOINTS)


def test_lift_rejects_background_low_visibility_and_outside():
    K = np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]])
    depth = np.full((H, W), 6.0, np.float32)
    uv = np.full((33, 2), -50.0)  # outside the image: rejected
    vis = np.full(33, 0.9)
    for n, k in enumerate(BODY_JOINTS):
        uv[k] = (40 + 15 * n, 120)
        depth[116:125, 36 + 15 * n : 45 + 15 * n] = 3.5 + 0.01 * n
    uv[15] = (300, 20)  # left wrist on the background (6 m)
    vis[16] = 0.2  # right wrist barely visible
    uv[31] = (-10, 5)
    X = lift_landmarks(PoseDetection(uv, vis), depth, K, PeopleConfig(joint_depth=False))
    ok = np.isfinite(X[:, 0])
    assert not ok[15] and not ok[16] and not ok[31] and not ok[0]  # background, visibility, outside, face
    assert ok.sum() == len(BODY_JOINTS) - 3
    k = BODY_JOINTS[0]
    z = 3.5
    np.testing.assert_allclose(X[k], [(uv[k, 0] - 160) * z / 300, 0.0, z], atol=1e-3)
    X2 = lift_landmarks(PoseDetection(uv, vis), depth, K, PeopleConfig())  # moved to the joint centre
    np.testing.assert_allclose(np.linalg.norm(X2[k] - X[k]), JOINT_DEPTH[k], atol=1e-6)
    np.testing.assert_allclose(np.cross(X2[k], X[k]), 0.0, atol=1e-9)


def test_keypoint_pose_from_walking_frames():
    frames, rig, det = _scene()
    cands, info = person_candidates(frames, rig, [0, 1, 2], det, PeopleConfig(icp=False))
    assert info["frames_with_person"] == [6, 6, 6]
    assert sorted(cands) == [(0, 1), (0, 2), (1, 2)]
    for (a, b), cs in cands.items():
        assert [c["route"] for c in cs] == ["people"]
        deg, m = _err(cs[0]["T_ba"], _truth(rig, a, b))
        assert deg < 2.0 and m < 0.12, (a, b, deg, m)
        assert cs[0]["X_a"].shape == cs[0]["X_b"].shape and len(cs[0]["X_a"]) == cs[0]["inliers"] >= 30


def test_most_complete_detection_is_used_and_a_second_person_ignored():
    def two_people(dets, k, f):
        other = PoseDetection(dets[0].uv + 40.0, np.where(np.arange(33) < 20, 0.9, 0.1))  # partial, elsewhere
        return [other, dets[0]]

    frames, rig, det = _scene(extra=two_people)
    cands, _ = person_candidates(frames, rig, [0, 1, 2], det, PeopleConfig(icp=False))
    deg, m = _err(cands[(0, 1)][0]["T_ba"], _truth(rig, 0, 1))
    assert deg < 2.0 and m < 0.12


def test_left_right_labels_are_taken_as_given():
    """A view whose detector swapped left and right in every frame gives a wrong pose or none:
    the route never relabels to gain inliers (a swap is its own, wrong, mirror pose), so the
    pose of the correctly labelled pairs is unaffected."""
    swap = np.arange(33)
    for k, name in enumerate(LANDMARKS):
        if name.startswith("left"):
            j = LANDMARKS.index("right" + name[4:])
            swap[k], swap[j] = j, k

    def swapped(dets, k, f):
        return [PoseDetection(dets[0].uv[swap], dets[0].visibility)] if k == 2 else None

    frames, rig, det = _scene(extra=swapped)
    cands, _ = person_candidates(frames, rig, [0, 1, 2], det, PeopleConfig(icp=False))
    deg, _ = _err(cands[(0, 1)][0]["T_ba"], _truth(rig, 0, 1))
    assert deg < 2.0
    for pair in ((0, 2), (1, 2)):
        if pair in cands:
            assert _err(cands[pair][0]["T_ba"], _truth(rig, *pair))[0] > 5.0


def test_no_person_gives_no_candidates():
    frames, rig, _ = _scene(n_frames=2)
    cands, info = person_candidates(frames, rig, [0, 1, 2], FakeDetector(), PeopleConfig(icp=False))
    assert cands == {} and info["frames_with_person"] == [0, 0, 0]
    assert all(p["common_joints"] == 0 for p in info["pairs"])


def test_keypoint_pose_needs_enough_joints():
    X = np.random.default_rng(0).normal(size=(4, 3))
    assert keypoint_pose(X, X, PeopleConfig()) is None


def test_icp_refines_a_keypoint_start():
    from fuseflow.calib.people import depth_cloud
    from fuseflow.synth.primitives import primitive_views

    frame, rig, T = primitive_views([0.0, 50.0], objects=12)
    T_true = T[1] @ invert_rigid(T[0])
    d = np.radians(5.0)
    P = np.eye(4)
    P[:3, :3] = [[math.cos(d), -math.sin(d), 0], [math.sin(d), math.cos(d), 0], [0, 0, 1]]
    P[:3, 3] = (0.05, -0.04, 0.03)
    start = P @ T_true
    for cos in (-1.0, 0.5):  # without and with the normal-compatibility gate
        cfg = PeopleConfig(icp_normal_cos=cos)
        ca = depth_cloud(frame.depth[0].numpy(), rig.cameras[0].K, cfg.icp_voxel)
        cb = depth_cloud(frame.depth[1].numpy(), rig.cameras[1].K, cfg.icp_voxel)
        T_icp, Xa, Xb = refine_icp([ca], [cb], start, cfg)
        deg, m = _err(T_icp, T_true)
        assert deg < 1.0 and m < 0.03, (cos, deg, m)
        assert len(Xa) == len(Xb) > 50


def test_missing_mediapipe_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "mediapipe", None)  # import mediapipe -> ImportError
    reason = people_unavailable()
    assert reason is not None and "fuseflow[people]" in reason
    with pytest.raises(CalibrationError, match=r"fuseflow\[people\]"):
        MediapipePoseDetector()


@pytest.mark.skipif(people_unavailable() is not None, reason=f"person detector unavailable: {people_unavailable()}")
def test_mediapipe_finds_the_simulated_person():
    from fuseflow.synth.person import walking_person_sim

    sim, walk = walking_person_sim(1, cameras=3, frames=1)
    sf = sim.render(0)
    J = person_joints(walk, 0.0)
    det = MediapipePoseDetector()
    found = 0
    for k, cam in enumerate(sim.rig.cameras):
        dets = det.detect(sf.frame.color[k].numpy())
        if not dets:
            continue
        uv, _ = _project(J, cam.T_cam_world, cam.K)
        vis = dets[0].visibility[list(BODY_JOINTS)] > 0.5
        err = np.linalg.norm(dets[0].uv[list(BODY_JOINTS)] - uv[list(BODY_JOINTS)], axis=1)[vis]
        found += int(vis.sum() >= 8 and np.median(err) < 15)
    det.close()
    assert found >= 2


def test_rgbd_backbone_says_why_the_route_is_skipped(monkeypatch):
    from fuseflow.calib.backbones.rgbd import RGBDConfig, rgbd_backbone
    from fuseflow.synth.primitives import primitive_views

    frame, rig, _ = primitive_views([0.0, 40.0], resolution=(160, 120))
    off = rgbd_backbone(frame, rig, RGBDConfig(geometric=False))
    assert off.info["people"] == "skipped: RGBDConfig.people is off"
    monkeypatch.setitem(sys.modules, "mediapipe", None)
    res = rgbd_backbone(frame, rig, RGBDConfig(people=True, geometric=False))
    assert (
        res.info["people"].startswith("skipped: mediapipe is not installed")
        and "fuseflow[people]" in res.info["people"]
    )
