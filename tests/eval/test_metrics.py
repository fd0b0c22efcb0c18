"""Every metric on synthetic input with a known answer, plus bad input and empty clouds."""

from __future__ import annotations

import gc
import math
import sys

import numpy as np
import pytest
import torch

from fuseflow import FusedCloud, ValidationError
from fuseflow.eval import metrics as M

_scenes = sys.modules["tests.eval.conftest"]  # hand-built scenes (importlib import mode)
PLANE_Z, make_scene = _scenes.PLANE_Z, _scenes.make_scene


def rot(axis, deg):
    axis = np.asarray(axis, dtype=np.float64)
    axis /= np.linalg.norm(axis)
    a = math.radians(deg)
    Kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * Kx + (1 - math.cos(a)) * Kx @ Kx


def rigid(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def random_poses(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([rigid(rot(rng.normal(size=3), rng.uniform(5, 170)), rng.normal(size=3)) for _ in range(n)])


def grid_plane(spacing=0.002, size=0.2, z=0.0):
    g = np.arange(0, size, spacing)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)


# --- pose errors ---------------------------------------------------------------------------


def test_identical_poses_zero_error():
    T = random_poses(4)
    e = M.pose_errors(T, T)
    assert e.rotation_deg == pytest.approx(0, abs=1e-5)
    assert e.translation_mm == pytest.approx(0, abs=1e-6)
    assert len(e.pairs) == 6


def test_world_frame_change_is_not_an_error():
    T = random_poses(3)
    G = rigid(rot([1, 2, 3], 40), [0.5, -1, 2])  # another world frame: T_i G
    e = M.pose_errors(T @ G, T)
    assert e.rotation_deg == pytest.approx(0, abs=1e-5)
    assert e.translation_mm == pytest.approx(0, abs=1e-6)


def test_known_rotation_gives_its_angle():
    T = random_poses(2)
    est = T.copy()
    est[1] = rigid(rot([0.3, -1, 0.2], 7.5), [0, 0, 0]) @ T[1]  # R_01 changes by exactly 7.5 deg
    e = M.pose_errors(est, T)
    assert e.rotation_deg == pytest.approx(7.5, abs=1e-6)
    assert M.rotation_error_deg(est, T) == pytest.approx(7.5, abs=1e-6)


@pytest.mark.parametrize("deg", [1e-4, 0.01, 90.0, 179.9])
def test_small_and_large_angles_are_exact(deg):
    T = random_poses(2, seed=9)
    est = T.copy()
    est[0] = rigid(rot([1, 0, 1], deg), [0, 0, 0]) @ T[0]
    assert M.rotation_error_deg(est, T) == pytest.approx(deg, rel=1e-6)


def test_known_translation_offset_in_mm_and_per_camera():
    T = random_poses(3)
    est = T.copy()
    est[2, :3, 3] += np.array([0.003, 0.0, 0.004])  # camera 2's t moved by 5 mm
    e = M.pose_errors(est, T)
    # pairs (0,1): 0; (0,2): |R_02 dt| = 5 mm; (1,2): 5 mm
    np.testing.assert_allclose(e.translation_mm_per_pair, [0.0, 5.0, 5.0], atol=1e-6)
    assert e.translation_mm == pytest.approx(10 / 3, abs=1e-6)
    assert M.translation_error_mm(est, T) == pytest.approx(10 / 3, abs=1e-6)
    assert e.per_camera["2"][1] == pytest.approx(5.0, abs=1e-6)
    assert e.per_camera["0"][1] == pytest.approx(2.5, abs=1e-6)
    assert e.rotation_deg == pytest.approx(0, abs=1e-5)


def test_scale_error_is_not_aligned_away():
    T = random_poses(2)
    est = T.copy()
    est[:, :3, 3] *= 2.0
    e = M.pose_errors(est, T)
    R01 = T[0, :3, :3] @ T[1, :3, :3].T
    t01 = T[0, :3, 3] - R01 @ T[1, :3, 3]
    assert e.translation_mm == pytest.approx(np.linalg.norm(t01) * 1000, rel=1e-9)


def test_dicts_compare_on_common_ids_and_tensors_accepted():
    T = random_poses(3)
    est = {"a": T[0], "b": T[1], "x": T[2]}
    ref = {"b": torch.from_numpy(T[1]), "a": torch.from_numpy(T[0]), "y": T[2]}
    e = M.pose_errors(est, ref)
    assert e.camera_ids == ("a", "b")
    assert e.pairs == (("a", "b"),)
    assert M.pose_errors(torch.from_numpy(T), T).rotation_deg == pytest.approx(0, abs=1e-5)


def test_pose_bad_input():
    T = random_poses(3)
    with pytest.raises(ValidationError, match="4, 4"):
        M.pose_errors(T[:, :3], T[:, :3])
    with pytest.raises(ValidationError, match="position"):
        M.pose_errors(T, T[:2])
    with pytest.raises(ValidationError, match="both"):
        M.pose_errors({"a": T[0], "b": T[1]}, T[:2])
    with pytest.raises(ValidationError, match="at least two"):
        M.pose_errors({"a": T[0], "b": T[1]}, {"a": T[0]})
    bad = T.copy()
    bad[0, :3, :3] *= 2
    with pytest.raises(ValidationError, match="rigid"):
        M.pose_errors(bad, T)
    with pytest.raises(ValidationError, match="4x4"):
        M.pose_errors("poses", T)


# --- PFR ------------------------------------------------------------------------------------


def test_perfect_plane_has_pfr_zero():
    # a tilted plane, two of them at right angles
    R = rot([1, 1, 0], 30)
    pts = (
        np.concatenate([grid_plane(), grid_plane()[:, [2, 0, 1]] + [0.3, 0, 0.05]]) @ R.T
    )  # apart: no point in the other band
    r = M.plane_fitting_residual(pts)
    assert r.pfr_mm == pytest.approx(0, abs=1e-6)
    assert len(r.planes) == 2
    assert r.inlier_share == pytest.approx(1.0)


def test_pfr_of_gaussian_noise_is_its_mean_absolute_deviation():
    rng = np.random.default_rng(1)
    pts = grid_plane(0.002, 0.4)
    sigma = 0.002
    pts[:, 2] += rng.normal(0, sigma, len(pts))
    r = M.plane_fitting_residual(pts)
    # E|N(0, s)| = s sqrt(2/pi) = 1.596 mm; the 1 cm band cuts nothing at 5 sigma
    assert r.pfr_mm == pytest.approx(sigma * 1000 * math.sqrt(2 / math.pi), rel=0.03)
    assert r.planes[0].normal[2] == pytest.approx(1.0, abs=1e-3) or r.planes[0].normal[2] == pytest.approx(
        -1.0, abs=1e-3
    )


def test_pfr_is_deterministic_and_handles_empty():
    rng = np.random.default_rng(2)
    pts = grid_plane(0.005, 0.5)
    pts[:, 2] += rng.normal(0, 0.003, len(pts))
    a, b = M.plane_fitting_residual(pts, seed=7), M.plane_fitting_residual(pts, seed=7)
    assert a.pfr_mm == b.pfr_mm and a.planes[0].num_inliers == b.planes[0].num_inliers
    e = M.plane_fitting_residual(np.zeros((0, 3)))
    assert math.isnan(e.pfr_mm) and e.planes == () and e.num_points == 0


# --- OR and outlier share -------------------------------------------------------------------


def test_outlier_ratio_counts_planted_outliers_at_their_rate():
    rng = np.random.default_rng(3)
    surface = grid_plane(0.002, 0.4)  # 40000 points, 2 mm grid: 12+ neighbours within 5 mm
    n_out = 2000
    far = rng.uniform(-1, 1, (n_out, 3)) * [1, 1, 0] + [0.2, 0.2, 0.5]  # 0.5 m above, sparse
    pts = np.concatenate([surface, far])
    r = M.outlier_ratio(pts)
    assert r.num_outliers == n_out
    assert r.ratio == pytest.approx(n_out / len(pts))
    assert r.outlier_mask[len(surface) :].all() and not r.outlier_mask[: len(surface)].any()


def test_outlier_ratio_neighbour_rule_is_exact():
    # a pair of points 4 mm apart: each has 1 neighbour -> outliers for n = 2, not for n = 1
    pts = np.array([[0, 0, 0], [0.004, 0, 0]], dtype=float)
    assert M.outlier_ratio(pts, min_neighbors=1).ratio == 0.0
    assert M.outlier_ratio(pts, min_neighbors=2).ratio == 1.0
    assert M.outlier_ratio(np.zeros((0, 3))).ratio == 0.0


def test_outlier_ratio_matches_open3d_radius_outlier_removal():
    import open3d as o3d

    rng = np.random.default_rng(6)
    pts = rng.uniform(0, 0.1, (4000, 3))  # ~2 neighbours within 5 mm on average: counts straddle n
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    for n in (1, 3, 6):
        _, kept = pcd.remove_radius_outlier(n, 0.005)
        r = M.outlier_ratio(pts, min_neighbors=n)
        assert 0 < r.num_outliers < len(pts)
        assert r.num_outliers == len(pts) - len(kept)


def test_outlier_share_against_gt():
    gt = grid_plane(0.005, 1.0)
    pts = grid_plane(0.01, 1.0)
    pts[:100, 2] += 0.05  # 100 of 10000 lifted 5 cm
    pts[100:200, 2] += 0.015  # within 2 cm
    assert M.outlier_share(pts, gt) == pytest.approx(100 / len(pts))
    assert M.outlier_share(np.zeros((0, 3)), gt) == 0.0


# --- CD and F-score -------------------------------------------------------------------------


def test_cloud_against_itself():
    pts = grid_plane()
    c = M.chamfer_distance(pts, pts)
    assert c.chamfer_mm == 0 and c.accuracy_mm == 0 and c.completeness_mm == 0
    f = M.f_score(pts, pts, threshold=0.001)
    assert (f.precision, f.recall, f.f_score) == (1.0, 1.0, 1.0)


def test_known_shift_gives_known_chamfer():
    rng = np.random.default_rng(4)
    pts = rng.uniform(-1, 1, (500, 3))  # sparse: the nearest neighbour of p + s is p itself
    c = M.chamfer_distance(pts + [0, 0, 0.003], pts)
    assert c.accuracy_mm == pytest.approx(3.0, abs=1e-9)
    assert c.completeness_mm == pytest.approx(3.0, abs=1e-9)
    assert c.chamfer_mm == pytest.approx(3.0, abs=1e-9)


def test_accuracy_and_completeness_are_directional():
    gt = grid_plane(0.01, 1.0)
    half = gt[gt[:, 0] < 0.495]  # prediction covers half the reference
    c = M.chamfer_distance(half, gt)
    assert c.accuracy_mm == 0.0
    assert c.completeness_mm > 100  # the missing half is on average ~25 cm away
    f = M.f_score(half, gt, threshold=0.005)
    assert f.precision == 1.0
    assert f.recall == pytest.approx(len(half) / len(gt))
    assert f.f_score == pytest.approx(2 * f.recall / (1 + f.recall))


def test_fscore_threshold_is_strict_and_empty_prediction():
    gt = np.zeros((1, 3))
    pts = np.array([[0.01, 0, 0], [0.002, 0, 0]])
    f = M.f_score(pts, gt, threshold=0.01)
    assert f.precision == 0.5 and f.recall == 1.0
    e = M.f_score(np.zeros((0, 3)), gt)
    assert (e.precision, e.recall, e.f_score) == (0.0, 0.0, 0.0)
    c = M.chamfer_distance(np.zeros((0, 3)), gt)
    assert math.isinf(c.chamfer_mm) and math.isnan(c.accuracy_mm)


def test_reference_metrics_agree_with_single_metrics():
    rng = np.random.default_rng(5)
    gt = rng.uniform(0, 1, (2000, 3))
    pts = gt[:1500] + rng.normal(0, 0.01, (1500, 3))
    r = M.reference_metrics(pts, gt, f_threshold=0.01, outlier_threshold=0.02)
    assert r.chamfer == M.chamfer_distance(pts, gt)
    assert r.fscore == M.f_score(pts, gt, 0.01)
    assert r.outlier_share == M.outlier_share(pts, gt, 0.02)


def test_reference_metrics_sampled_queries_estimate_the_full_means():
    rng = np.random.default_rng(6)
    gt = rng.uniform(0, 1, (40000, 3))
    pts = gt[:30000] + rng.normal(0, 0.01, (30000, 3))
    full = M.reference_metrics(pts, gt)
    part = M.reference_metrics(pts, gt, sample=5000, seed=1)
    assert part.chamfer.chamfer_mm == pytest.approx(full.chamfer.chamfer_mm, rel=0.05)
    assert part.fscore.f_score == pytest.approx(full.fscore.f_score, abs=0.02)
    assert part.outlier_share == pytest.approx(full.outlier_share, abs=0.02)
    assert part.chamfer != full.chamfer  # it did sample
    assert M.reference_metrics(pts, gt, sample=10**6) == full  # fewer points than sample: exact
    with pytest.raises(ValidationError):
        M.reference_metrics(pts, gt, sample=0)


def test_inputs_fusedcloud_tensor_numpy_agree():
    pts = grid_plane(0.01).astype(np.float32)
    cloud = FusedCloud.from_numpy(pts, np.zeros((len(pts), 3)), np.ones(len(pts)), np.zeros(len(pts)))
    ref = pts + [0, 0, 0.001]
    a = M.chamfer_distance(cloud, ref)
    b = M.chamfer_distance(torch.from_numpy(pts), ref)
    c = M.chamfer_distance(pts, ref)
    assert a == b == c


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.zeros((5, 2)), r"\(M, 3\)"),
        (np.array([[0, 0, np.nan]]), "NaN"),
        (np.array([["a", "b", "c"]]), "numeric"),
        (torch.zeros(3), r"\(M, 3\)"),
    ],
)
def test_bad_points_raise_validation_error(bad, match):
    with pytest.raises(ValidationError, match=match):
        M.chamfer_distance(bad, np.zeros((3, 3)))
    with pytest.raises(ValidationError, match=match):
        M.outlier_ratio(bad)


def test_empty_reference_and_bad_parameters():
    with pytest.raises(ValidationError, match="empty"):
        M.chamfer_distance(np.zeros((3, 3)), np.zeros((0, 3)))
    with pytest.raises(ValidationError, match="threshold"):
        M.f_score(np.zeros((3, 3)), np.zeros((3, 3)), threshold=0)
    with pytest.raises(ValidationError, match="radius"):
        M.outlier_ratio(np.zeros((3, 3)), radius=-1)


# --- PNCC -----------------------------------------------------------------------------------


def plane_samples(spacing=0.01, half=0.5):
    g = np.arange(-half, half, spacing)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, PLANE_Z)], 1)


def test_pncc_of_textured_plane_seen_by_two_cameras_is_one():
    frame, rig = make_scene(2)
    r = M.pncc(plane_samples(), frame, rig)
    assert r.num_evaluated > 0.8 * r.num_points
    assert r.pncc > 0.97


def test_pncc_drops_when_geometry_is_wrong_and_best_two_of_three():
    frame, rig = make_scene(3)
    good = M.pncc(plane_samples(), frame, rig)
    assert good.pncc > 0.97
    # points 5 cm off the surface (inside the depth test's 6 cm at 2 m) project to pixels that
    # see different parts of the texture: the two views disagree
    off = plane_samples() + [0, 0, -0.05]
    bad = M.pncc(off, frame, rig)
    assert bad.pncc < good.pncc - 0.2


def test_pncc_subset_is_seeded_and_close_to_the_full_value():
    frame, rig = make_scene(2)
    pts = plane_samples(0.005)  # 40000 points
    full = M.pncc(pts, frame, rig, max_points=None)
    a = M.pncc(pts, frame, rig, max_points=5000, seed=3)
    b = M.pncc(pts, frame, rig, max_points=5000, seed=3)
    assert a.num_points == 5000 and full.num_points == len(pts)
    assert a.pncc == b.pncc
    assert abs(a.pncc - full.pncc) < 0.01


def test_pncc_depth_test_and_absent_views():
    frame, rig = make_scene(2, present=[True, False])
    r = M.pncc(plane_samples(), frame, rig)
    assert r.num_evaluated == 0 and math.isnan(r.pncc) and r.num_not_covisible == r.num_points
    frame, rig = make_scene(2)
    floating = plane_samples() + [0, 0, -0.5]  # in front of the surface: fails the depth test
    assert M.pncc(floating, frame, rig).num_evaluated == 0
    assert math.isnan(M.pncc(np.zeros((0, 3)), frame, rig).pncc)
    with pytest.raises(ValidationError, match="Rig"):
        M.pncc(plane_samples(), frame, None)


# --- timing ---------------------------------------------------------------------------------


def test_measure_sees_an_allocation_and_time_fn_counts_runs():
    calls = []

    def work():
        calls.append(1)
        a = np.ones(200_000_000, dtype=np.uint8)  # 200 MB touched (fresh mmap: above glibc's threshold)
        return int(a.sum())

    # the peaks of two windows are absolute: memory the process frees between them (the garbage of
    # earlier tests in a full-suite run) counts against the difference, so collect first and
    # allocate far more than such noise (40 MB was seen to vanish in a full run)
    gc.collect()
    with M.measure() as m0:
        pass
    gc.collect()
    with M.measure() as m1:
        work()
    assert m1.wall_s > 0 and m1.peak_rss_bytes >= m0.peak_rss_bytes
    if not m1.rss_peak_is_lifetime:
        assert m1.peak_rss_bytes - m0.peak_rss_bytes > 150_000_000
    t = M.time_fn(work, repeats=3, warmup=1)
    assert len(calls) == 1 + 4 and len(t.times_s) == 3
    assert t.fps == pytest.approx(1 / t.median_s) and t.peak_cuda_bytes is None
