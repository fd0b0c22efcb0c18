"""Baselines on a hand-built rig: cameras at 160x120 looking at the plane z = PLANE_Z."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from fuseflow import Camera, FusedCloud, Rig, ValidationError
from fuseflow.eval import baselines as B

_scenes = sys.modules["tests.eval.conftest"]
PLANE_Z, make_scene, texture = _scenes.PLANE_Z, _scenes.make_scene, _scenes.texture


def check_cloud(c: FusedCloud, tol: float) -> None:
    assert isinstance(c, FusedCloud) and len(c) > 0
    z = c.xyz[:, 2].double()
    assert float((z - PLANE_Z).abs().max()) < tol
    assert torch.all(c.weight == 1)


def test_naive_fusion_puts_every_pixel_on_the_plane_with_its_colour_and_camera():
    frame, rig = make_scene(3)
    c = B.naive_fusion(frame, rig)
    assert len(c) == 3 * 160 * 120
    check_cloud(c, 1e-5)
    assert torch.equal(torch.bincount(c.camera.long()), torch.tensor([160 * 120] * 3))
    # colour is the plane texture at the back-projected point (round-off of the texture: 1 grey level)
    xyz = c.xyz.double().numpy()
    expect = np.clip(np.rint(texture(xyz[:, 0], xyz[:, 1])), 0, 255)
    assert np.abs(c.rgb[:, 0].numpy().astype(float) - expect).max() <= 1


def test_naive_fusion_respects_depth_range_and_present():
    frame, rig = make_scene(3, present=[True, False, True])
    c = B.naive_fusion(frame, rig)
    assert set(c.camera.tolist()) == {0, 2} and len(c) == 2 * 160 * 120
    narrow = Rig(
        tuple(Camera(k.id, k.width, k.height, k.K, depth_range=(0.1, 2.05), T_cam_world=k.T_cam_world) for k in rig)
    )
    frame, _ = make_scene(3)
    z_cam = frame.depth
    c2 = B.naive_fusion(frame, narrow)
    assert len(c2) == int(((z_cam > 0) & (z_cam <= 2.05)).sum())
    # frame views in another order than the rig: camera is the rig index
    sub = frame.subset([2, 0])
    c3 = B.naive_fusion(sub, rig)
    assert set(c3.camera.tolist()) == {0, 2}


def test_voxel_and_sor_fusion_stay_on_the_plane():
    frame, rig = make_scene(2)
    naive = B.naive_fusion(frame, rig)
    v = B.voxel_downsampled_fusion(frame, rig, voxel=0.02)
    check_cloud(v, 1e-5)
    assert len(v) < len(naive) and torch.all(v.camera == -1)
    # one point per occupied 2 cm voxel of Open3D's grid (anchored at min bound - voxel / 2)
    p = naive.xyz.double()
    keys = torch.floor((p - p.min(0).values + 0.01) / 0.02).long()
    assert len(torch.unique(keys, dim=0)) == len(v)
    s = B.sor_fusion(frame, rig, voxel=None)
    check_cloud(s, 1e-5)
    assert set(s.camera.tolist()) <= {0, 1}
    s2 = B.sor_fusion(frame, rig)
    check_cloud(s2, 1e-5)


def test_sor_removes_planted_outliers():
    frame, rig = make_scene(2)
    depth = frame.depth.clone()
    gen = torch.Generator().manual_seed(0)
    idx = torch.randint(0, 160 * 120, (50,), generator=gen)
    depth[0].view(-1)[idx] = 1.0  # 50 pixels pulled 1 m towards camera 0
    from dataclasses import replace

    noisy = replace(frame, depth=depth)
    s = B.sor_fusion(noisy, rig, voxel=None)
    check_cloud(s, 1e-4)


@pytest.mark.parametrize("backend", ["vbg", "uniform"])
def test_tsdf_fusion_is_non_empty_and_near_the_plane(backend):
    frame, rig = make_scene(3)
    c = B.tsdf_fusion(frame, rig, config=B.TSDFConfig(voxel=0.02, backend=backend))
    check_cloud(c, 0.02 / 2)  # zero crossings within half a voxel of the surface
    assert torch.all(c.camera == -1)
    assert abs(float(c.rgb.float().mean()) - 128) < 10  # the texture's mean grey


def test_tsdf_fusion_of_a_single_camera_gives_its_surface():
    # weight_threshold 1.0 keeps voxels seen by >= 2 views; with one view it must not return nothing
    frame, rig = make_scene(1)
    check_cloud(B.tsdf_fusion(frame, rig, config=B.TSDFConfig(voxel=0.02)), 0.02 / 2)
    frame, rig = make_scene(2, present=[True, False])
    check_cloud(B.tsdf_fusion(frame, rig, config=B.TSDFConfig(voxel=0.02)), 0.02 / 2)


def test_tsdf_voxel_argument_and_absent_views():
    frame, rig = make_scene(2)
    coarse = B.tsdf_fusion(frame, rig, voxel=0.04)
    check_cloud(coarse, 0.02)
    assert len(coarse) < len(B.tsdf_fusion(frame, rig, config=B.TSDFConfig(voxel=0.02)))
    frame, rig = make_scene(2, present=[False, False])
    assert len(B.tsdf_fusion(frame, rig)) == 0
    assert len(B.naive_fusion(frame, rig)) == 0
    assert len(B.voxel_downsampled_fusion(frame, rig)) == 0


def test_tsdf_scalable_backend_runs():
    # open3d 0.20.0's ScalableTSDFVolume returns an empty cloud for every input (docs/metrics.md);
    # this only checks that the path runs and returns a FusedCloud.
    frame, rig = make_scene(2)
    c = B.tsdf_fusion(frame, rig, config=B.TSDFConfig(voxel=0.02, backend="scalable"))
    assert isinstance(c, FusedCloud)


def test_bad_input():
    frame, rig = make_scene(2)
    with pytest.raises(ValidationError, match="Frame"):
        B.naive_fusion(frame.depth, rig)
    with pytest.raises(ValidationError, match="Rig"):
        B.naive_fusion(frame, [rig])
    uncal = rig.with_extrinsics({"cam1": None})
    with pytest.raises(ValidationError, match="extrinsics"):
        B.naive_fusion(frame, uncal)
    with pytest.raises(ValidationError, match="cam0"):
        B.naive_fusion(frame, Rig((rig[1],)))
    with pytest.raises(ValidationError, match="voxel"):
        B.voxel_downsampled_fusion(frame, rig, voxel=0)
    with pytest.raises(ValidationError, match="contradicts"):
        B.tsdf_fusion(frame, rig, voxel=0.05, config=B.TSDFConfig(voxel=0.02))
    with pytest.raises(ValidationError, match="backend"):
        B.tsdf_fusion(frame, rig, config=B.TSDFConfig(backend="nope"))
    with pytest.raises(ValidationError, match="max_uniform_resolution"):
        B.tsdf_fusion(frame, rig, config=B.TSDFConfig(voxel=0.002, backend="uniform"))
    small = Rig(tuple(Camera(k.id, 80, 60, k.K, T_cam_world=k.T_cam_world) for k in rig))
    with pytest.raises(ValidationError, match="80x60"):
        B.naive_fusion(frame, small)


def test_views_without_any_valid_depth_give_empty_clouds():
    from dataclasses import replace

    frame, rig = make_scene(2)
    blank = replace(frame, depth=torch.zeros_like(frame.depth))
    for fn in (B.naive_fusion, B.voxel_downsampled_fusion, B.sor_fusion, B.tsdf_fusion):
        c = fn(blank, rig)
        assert isinstance(c, FusedCloud) and len(c) == 0


def test_backprojection_matches_open3d_create_from_depth_image():
    import open3d as o3d

    frame, rig = make_scene(3)
    ours = B.naive_fusion(frame, rig)
    for i, cam in enumerate(rig):
        K = cam.K
        intr = o3d.camera.PinholeCameraIntrinsic(cam.width, cam.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        ref = o3d.geometry.PointCloud.create_from_depth_image(
            o3d.geometry.Image(frame.depth[i].numpy()), intr, cam.T_cam_world, depth_scale=1.0, depth_trunc=5.0
        )
        mine = ours.xyz[ours.camera == i].double().numpy()
        np.testing.assert_allclose(mine, np.asarray(ref.points), atol=1e-5)  # same row-major pixel order


def test_tsdf_at_thresholds_matches_tsdf_fusion_and_thins_with_the_threshold():
    frame, rig = make_scene(3)
    clouds = B.tsdf_fusion_at_thresholds(frame, rig, B.WEIGHT_THRESHOLDS, voxel=0.02)
    assert sorted(clouds) == [0.0, 1.0, 2.0, 3.0]
    plain = B.tsdf_fusion(frame, rig, voxel=0.02)  # fuseflow's threshold 1.0
    assert np.array_equal(_sorted_rows(clouds[1.0]), _sorted_rows(plain))  # the same points (VBG's order varies)
    sizes = [len(clouds[t]) for t in sorted(clouds)]
    assert sizes == sorted(sizes, reverse=True) and sizes[-1] < sizes[0]  # a higher threshold keeps fewer
    for t in (0.0, 3.0):
        if len(clouds[t]):
            check_cloud(clouds[t], 0.02 / 2 if t else 0.02)


def test_best_threshold_is_the_argmax_of_the_score_lowest_on_a_tie():
    frame, rig = make_scene(3)
    sizes = {t: len(c) for t, c in B.tsdf_fusion_at_thresholds(frame, rig, voxel=0.02).items()}
    target = sizes[2.0]
    best = B.best_tsdf_threshold(frame, rig, lambda c: -abs(len(c) - target), voxel=0.02)
    assert best.threshold == min(t for t in sizes if sizes[t] == target)
    assert len(best.cloud) == target and best.scores[best.threshold] == 0
    flat = B.best_tsdf_threshold(frame, rig, lambda c: 1.0, voxel=0.02)
    assert flat.threshold == 0.0


def test_bad_thresholds_are_validation_errors():
    frame, rig = make_scene(2)
    with pytest.raises(ValidationError, match="at least one"):
        B.tsdf_fusion_at_thresholds(frame, rig, [])
    with pytest.raises(ValidationError, match=">= 0"):
        B.tsdf_fusion_at_thresholds(frame, rig, [-1.0])


def _sorted_rows(cloud: FusedCloud) -> np.ndarray:
    rows = np.concatenate([cloud.xyz.numpy(), cloud.rgb.numpy().astype(np.float32)], axis=1)
    return rows[np.lexsort(rows.T[::-1])]
