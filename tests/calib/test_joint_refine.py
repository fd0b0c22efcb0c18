"""The depth-aware joint refinement on the analytic box room: it recovers
perturbed poses from exact depth, uses keypoint tracks, refuses a refinement that fits the depth
worse, is deterministic, and calibrate reports it (off in the paper preset)."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.calib import CalibConfig, calibrate
from fuseflow.calib.joint_refine import _exp_se3, depth_fit, joint_refine
from fuseflow.eval.metrics import pose_errors


def _perturbed(T_true: np.ndarray, ids, deg: float, m: float, seed: int = 0) -> dict[str, np.ndarray]:
    """Camera-from-world poses with every camera but the first moved by about deg / m."""
    rng = np.random.default_rng(seed)
    out = {ids[0]: T_true[0].copy()}
    for k in range(1, len(ids)):
        xi = np.r_[rng.normal(0, np.radians(deg), 3), rng.normal(0, m, 3)]
        out[ids[k]] = T_true[k] @ _exp_se3(xi)
    return out


def _tracks(T_true: np.ndarray, ids, n: int = 40, noise_m: float = 0.0, seed: int = 0):
    """Keypoint tracks (as the rgbd backbone gives) between neighbouring cameras from the true
    poses: random points 2-4 m in front of camera a, seen by a and b, with optional noise."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(len(ids)):
        a, b = k, (k + 1) % len(ids)
        Xa = rng.uniform(-1, 1, (n, 3)) + [0, 0, 3]
        M = T_true[b] @ np.linalg.inv(T_true[a])
        Xb = Xa @ M[:3, :3].T + M[:3, 3] + rng.normal(0, noise_m, (n, 3)) if noise_m else Xa @ M[:3, :3].T + M[:3, 3]
        out.append((ids[a], ids[b], Xa, Xb, np.full(n, 0.005)))
    return tuple(out)


@pytest.fixture(scope="module")
def scene(scene_builder):
    return scene_builder(6, size=(240, 180))


def test_recovers_perturbed_poses_from_exact_depth(scene):
    frame, rig, T_true = scene
    ids = list(rig.ids)
    T0 = _perturbed(T_true, ids, 0.5, 0.01)
    truth = dict(zip(ids, T_true))
    before = pose_errors(T0, truth)
    res = joint_refine(T0, [frame], rig, tracks=_tracks(T_true, ids, noise_m=0.005))
    after = pose_errors(res.T_cam_world, truth)
    assert res.accepted, res.reason
    assert before.rotation_deg > 0.4 and after.rotation_deg < 0.05, (before, after)
    # the box room constrains some translations only through small box faces: a few mm remain
    assert after.translation_mm < min(6.0, before.translation_mm / 2), (before, after)
    assert np.array_equal(res.T_cam_world[ids[0]], T0[ids[0]])  # the anchor is held fixed
    assert np.mean(list(res.inlier_after.values())) > np.mean(list(res.inlier_before.values()))
    assert len(res.pairs) >= len(ids)


def test_deterministic(scene):
    frame, rig, T_true = scene
    T0 = _perturbed(T_true, list(rig.ids), 0.5, 0.01, seed=1)
    tracks = _tracks(T_true, list(rig.ids), noise_m=0.005)
    a = joint_refine(T0, [frame], rig, tracks=tracks)
    b = joint_refine(T0, [frame], rig, tracks=tracks)
    assert all(np.array_equal(a.T_cam_world[c], b.T_cam_world[c]) for c in rig.ids)


def test_wrong_tracks_that_spoil_the_depth_fit_are_refused(scene):
    """Keypoint tracks (tiny sigma) that pull one camera 3 deg away: the refined poses fit the
    depth worse, so the input poses come back, with the reason."""
    frame, rig, T_true = scene
    ids = list(rig.ids)
    T0 = dict(zip(ids, T_true))
    rng = np.random.default_rng(0)
    Xa = rng.uniform(-1, 1, (200, 3)) + [0, 0, 3]  # points in camera 0's frame
    T_wrong = _exp_se3(np.r_[0, np.radians(3.0), 0, 0, 0, 0]) @ T_true[1] @ np.linalg.inv(T_true[0])
    Xb = Xa @ T_wrong[:3, :3].T + T_wrong[:3, 3]
    res = joint_refine(T0, [frame], rig, tracks=[(ids[0], ids[1], Xa, Xb, np.full(200, 1e-4))])
    assert not res.accepted and ("worse" in res.reason or "fell" in res.reason), res.reason
    assert all(np.array_equal(res.T_cam_world[c], T0[c]) for c in ids)
    moved = pose_errors({c: res.T_refined[c] for c in ids}, T0)
    assert moved.rotation_deg > 0.5  # the tracks did pull: the check, not a no-op, refused it


def test_tracks_are_used(scene):
    """Correct tracks alone (no depth overlap sampled: one sample per camera) still pull a
    perturbed camera back."""
    frame, rig, T_true = scene
    ids = list(rig.ids)
    T0 = _perturbed(T_true, ids, 0.5, 0.01, seed=2)
    rng = np.random.default_rng(1)
    tracks = []
    for k in range(1, len(ids)):
        Xa = rng.uniform(-1, 1, (100, 3)) + [0, 0, 3]
        M = T_true[k] @ np.linalg.inv(T_true[0])
        tracks.append((ids[0], ids[k], Xa, Xa @ M[:3, :3].T + M[:3, 3], np.full(100, 0.005)))
    with_tracks = joint_refine(T0, [frame], rig, tracks=tracks)
    truth = dict(zip(ids, T_true))
    assert pose_errors(with_tracks.T_refined | {ids[0]: T0[ids[0]]}, truth).rotation_deg < 0.05


def test_no_overlap_returns_input(scene):
    frame, rig, T_true = scene
    ids = list(rig.ids)
    far = {c: T_true[k].copy() for k, c in enumerate(ids)}
    far[ids[1]][:3, 3] += [100.0, 0, 0]  # camera 1 placed 100 m away: it overlaps nobody
    res = joint_refine({ids[0]: far[ids[0]], ids[1]: far[ids[1]]}, [frame], rig)
    assert not res.accepted and res.reason == "no overlapping pair"
    assert np.array_equal(res.T_cam_world[ids[1]], far[ids[1]])


def test_without_tracks_nothing_moves(scene):
    """No keypoint tracks (a scale-free backbone, cameras COLMAP placed): dense depth alone slid
    the simulated rings away from the truth, so the poses come back unchanged, with the reason."""
    frame, rig, T_true = scene
    T0 = _perturbed(T_true, list(rig.ids), 0.5, 0.01, seed=4)
    res = joint_refine(T0, [frame], rig)
    assert not res.accepted and "keypoint" in res.reason
    assert all(np.array_equal(res.T_cam_world[c], T0[c]) for c in rig.ids)


def test_calibrate_reports_it_and_paper_preset_has_it_off(scene, backbone_builder):
    frame, rig, T_true = scene
    bb = backbone_builder(T_true, 1.0, rot_noise_deg=0.3, seed=3)
    tracks = _tracks(T_true, list(rig.ids), noise_m=0.005)
    bb = type(bb)(bb.T_cam_world, bb.registered, name="truth", metric=True, tracks=tracks)
    cal = calibrate(frame, rig, CalibConfig(backbone="colmap"), backbone_result=bb)
    jr = cal.report.joint_refinement
    assert jr is not None and jr["accepted"] and jr["pairs"] >= len(rig)
    assert "joint_refine" in cal.report.timings_s
    truth = dict(zip(rig.ids, T_true))
    assert pose_errors(cal.T_cam_world, truth).rotation_deg < 0.05
    paper = calibrate(frame, rig, CalibConfig.preset("paper"), backbone_result=bb)
    assert paper.report.joint_refinement is None
    assert type(cal.report).from_json(cal.report.to_json()).joint_refinement == jr


def test_truth_is_a_fixed_point_on_exact_depth(scene):
    """Exact depth and true poses: the refinement must not move them (no bias from normals
    smoothed across edges and corners: those samples are dropped)."""
    frame, rig, T_true = scene
    ids = list(rig.ids)
    res = joint_refine(dict(zip(ids, T_true)), [frame], rig, tracks=_tracks(T_true, ids))
    e = pose_errors(res.T_refined, dict(zip(ids, T_true)))
    assert e.rotation_deg < 0.005 and e.translation_mm < 0.5, e


def test_depth_fit_prefers_the_true_poses(scene):
    frame, rig, T_true = scene
    ids = list(rig.ids)
    truth = dict(zip(ids, T_true))
    share, median_mm = depth_fit(frame, rig, truth)
    share_off, median_off = depth_fit(frame, rig, _perturbed(T_true, ids, 1.0, 0.02))
    assert share > 0.95 and median_mm < 1.0, (share, median_mm)  # exact depth: the truth fits
    assert share_off < share and median_off > median_mm
    one, _ = depth_fit(frame, rig, _perturbed(T_true, ids, 1.0, 0.02), only=ids[0])
    assert 0 <= one <= 1
    assert np.isnan(depth_fit(frame, rig, {ids[0]: T_true[0]})[0])  # one camera: no pair


def test_expected_error_of_each_refined_camera_follows_its_real_error(scene):
    """The refinement's own covariance of each refined camera (keypoint tracks with 2 and 20 mm
    of noise): within 3x of the camera's real rotation error either way, ten times larger for ten
    times the noise; none for the held world camera."""
    frame, rig, T_true = scene
    ids = list(rig.ids)
    est = {}
    for noise in (0.002, 0.02):
        res = joint_refine(_perturbed(T_true, ids, 0.5, 0.01), [frame], rig, tracks=_tracks(T_true, ids, noise_m=noise))
        assert res.accepted and ids[0] not in res.expected and set(res.expected) == set(ids[1:]), res.expected
        for k, c in enumerate(ids[1:], start=1):
            D = res.T_cam_world[c] @ np.linalg.inv(T_true[k])  # world = camera 0's, held at the truth
            err = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
            assert res.expected[c][0] / 3 < max(err, 0.005) < 3 * res.expected[c][0], (noise, c, err, res.expected[c])
        est[noise] = np.mean([v[0] for v in res.expected.values()])
        assert "expected_deg_mm" in res.as_dict()
    assert 5 < est[0.02] / est[0.002] < 20, est


def test_only_refines_the_named_cameras_on_depth_alone_and_holds_the_rest(scene):
    """A camera turned by whole room periods after the refinement: its tracks are aliases, so it
    is refined on the dense depth alone while every other camera is held bit for bit."""
    frame, rig, T_true = scene
    ids = list(rig.ids)
    truth = dict(zip(ids, T_true))
    T0 = dict(truth)
    T0[ids[2]] = T_true[2] @ _exp_se3(np.r_[np.radians([0.2, -0.3, 0.2]), 0.02, -0.015, 0.01])
    res = joint_refine(T0, [frame], rig, only={ids[2]})
    assert res.accepted, res.reason
    before = pose_errors({c: T0[c] for c in ids[:3]}, truth)
    after = pose_errors({c: res.T_cam_world[c] for c in ids[:3]}, truth)
    assert after.translation_mm < before.translation_mm / 2 and after.rotation_deg < before.rotation_deg / 2
    assert all(np.array_equal(res.T_cam_world[c], T0[c]) for c in ids if c != ids[2])
    assert not joint_refine(T0, [frame], rig, only=set()).accepted  # nothing to refine
