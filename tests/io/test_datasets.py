"""Dataset readers on ../shared/data, the TUM layout, and the ICL virtual rig's geometry."""

import numpy as np
import pytest
import torch

import fuseflow
from fuseflow import FormatError, ValidationError
from fuseflow.io.datasets import (
    SequenceRecording,
    make_virtual_rig,
    quaternion_to_matrix,
    read_log_trajectory,
    read_rgbd_pair,
    write_log_trajectory,
)
from fuseflow.io.images import read_pgm16


def test_icl_reader(icl_path):
    rec = fuseflow.open_recording(icl_path)
    assert isinstance(rec, SequenceRecording)
    assert len(rec) == 211 and len(rec.rig) == 1 and rec.rig.resolution == (640, 480)
    cam = rec.rig[0]
    # intrinsic.json is column-major: cx, cy must land in the last column
    assert np.allclose(cam.K, [[525, 0, 319.5], [0, 525, 239.5], [0, 0, 1]])
    assert rec.has_poses and np.allclose(rec.T_world_cam[0], np.eye(4))
    f = rec[0]
    valid = f.depth[0][f.depth[0] > 0]
    assert 0.5 < float(valid.median()) < 5.0  # millimetres / 1000 -> indoor metres


@pytest.mark.parametrize(
    "fmt, c, d", [("tum", "TUM_color.png", "TUM_depth.png"), ("sun", "SUN_color.jpg", "SUN_depth.png")]
)
def test_format_samples_match_open3d_decoders(format_samples, fmt, c, d):
    import open3d as o3d

    rgb, depth = read_rgbd_pair(format_samples / c, format_samples / d, fmt)
    fn = {"tum": o3d.geometry.RGBDImage.create_from_tum_format, "sun": o3d.geometry.RGBDImage.create_from_sun_format}[
        fmt
    ]
    ref = np.asarray(fn(o3d.io.read_image(str(format_samples / c)), o3d.io.read_image(str(format_samples / d))).depth)
    m = ref > 0
    assert m.mean() > 0.5 and rgb.shape == (480, 640, 3)
    assert np.abs(ref[m] - depth[m]).max() < 1e-6


def test_nyu_sample_matches_open3d(format_samples):
    import open3d as o3d

    rgb, depth = read_rgbd_pair(format_samples / "NYU_color.ppm", format_samples / "NYU_depth.pgm", "nyu")
    raw = read_pgm16(format_samples / "NYU_depth.pgm")
    ref = np.asarray(
        o3d.geometry.RGBDImage.create_from_nyu_format(o3d.geometry.Image(rgb), o3d.geometry.Image(raw)).depth
    )
    m = ref > 0
    assert m.mean() > 0.9
    assert np.abs(ref[m] - depth[m]).max() < 1e-3  # float32 vs double
    assert np.array_equal(depth > 0, m)
    assert 1.0 < np.median(depth[m]) < 5.0


def test_unknown_format_and_size_mismatch(format_samples, tmp_path):
    with pytest.raises(ValidationError, match="unknown RGB-D format"):
        read_rgbd_pair(format_samples / "TUM_color.png", format_samples / "TUM_depth.png", "kitti")
    import cv2

    cv2.imwrite(str(tmp_path / "d.png"), np.zeros((10, 12), np.uint16))
    with pytest.raises(ValidationError, match="640x480 but .*d.png is 12x10"):
        read_rgbd_pair(format_samples / "TUM_color.png", tmp_path / "d.png", "tum")


def test_log_trajectory_roundtrip_and_bad_file(tmp_path, icl_path):
    poses = read_log_trajectory(icl_path / "trajectory_open3d_estimate.log")
    assert len(poses) == 211
    write_log_trajectory(tmp_path / "t.log", poses[:5])
    back = read_log_trajectory(tmp_path / "t.log")
    assert all(np.allclose(a, b, atol=1e-8) for a, b in zip(poses[:5], back))
    (tmp_path / "bad.log").write_text("0 0 1\n1 0 0 0\n0 1 0 0\n")
    with pytest.raises(FormatError, match="blocks of 5 lines"):
        read_log_trajectory(tmp_path / "bad.log")


def test_quaternion_convention():
    # 90 degrees about z, (x, y, z, w)
    R = quaternion_to_matrix([0, 0, np.sqrt(0.5), np.sqrt(0.5)])
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])


def test_tum_layout_associates_and_inverts(tmp_path, format_samples):
    import shutil

    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    shutil.copy(format_samples / "TUM_color.png", tmp_path / "rgb" / "1.000000.png")
    shutil.copy(format_samples / "TUM_depth.png", tmp_path / "depth" / "1.010000.png")
    shutil.copy(format_samples / "TUM_depth.png", tmp_path / "depth" / "5.000000.png")  # no colour near it
    (tmp_path / "rgb.txt").write_text("# rgb\n1.000000 rgb/1.000000.png\n")
    (tmp_path / "depth.txt").write_text("# depth\n1.010000 depth/1.010000.png\n5.000000 depth/5.000000.png\n")
    (tmp_path / "groundtruth.txt").write_text("# gt\n1.005 1.0 2.0 3.0 0 0 0.7071068 0.7071068\n")
    rec = fuseflow.open_recording(tmp_path)
    assert len(rec) == 1 and rec.rig[0].depth_scale == 5000.0
    T = rec.T_world_cam[0]
    assert np.allclose(T[:3, 3], [1, 2, 3]) and np.allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-6)
    f = rec[0]
    rgb, depth = read_rgbd_pair(format_samples / "TUM_color.png", format_samples / "TUM_depth.png", "tum")
    assert np.allclose(f.depth[0].numpy(), depth)


def _reproject_residual(rig, frame, i, j):
    """Median relative depth residual of camera i's points seen by camera j (and overlap share)."""
    H, W = frame.depth.shape[1:]
    Ki, Kj = rig[i].K, rig[j].K
    v, u = np.mgrid[0:H, 0:W]
    z = frame.depth[i].numpy().astype(np.float64)
    m = z > 0
    X = np.stack([(u[m] - Ki[0, 2]) / Ki[0, 0] * z[m], (v[m] - Ki[1, 2]) / Ki[1, 1] * z[m], z[m], np.ones(m.sum())])
    T_ji = rig[j].T_cam_world @ np.linalg.inv(rig[i].T_cam_world)
    Y = T_ji @ X
    zj = Y[2]
    front = zj > 0.1
    uj = np.round(Kj[0, 0] * Y[0][front] / zj[front] + Kj[0, 2]).astype(int)
    vj = np.round(Kj[1, 1] * Y[1][front] / zj[front] + Kj[1, 2]).astype(int)
    inside = (uj >= 0) & (uj < W) & (vj >= 0) & (vj < H)
    dj = frame.depth[j].numpy()[vj[inside], uj[inside]]
    ok = dj > 0
    r = np.abs(dj[ok] - zj[front][inside][ok]) / zj[front][inside][ok]
    return float(np.median(r)) if r.size else np.inf, r.size / m.sum()


def test_icl_virtual_rig_geometry(icl_path, tmp_path):
    """Back-projecting camera k into camera k+1 with the reference poses agrees with its depth.

    This fails if the axes or the extrinsic direction are wrong (checked below by inverting)."""
    seq = fuseflow.open_recording(icl_path)
    frames = list(range(0, 211, 30))
    rig = make_virtual_rig(seq, frames, tmp_path)
    rec = fuseflow.open_recording(tmp_path)
    assert len(rec.rig) == 8 and rec.rig.is_calibrated and len(rec) == 1
    frame = rec[0]
    checked = 0
    for i in range(7):
        med, overlap = _reproject_residual(rec.rig, frame, i, i + 1)
        if overlap < 0.2:
            continue
        checked += 1
        assert med < 0.01, (i, med, overlap)
    assert checked >= 4
    # the same check with the extrinsic direction flipped must fail
    flipped = rig.with_extrinsics(np.stack([c.T_world_cam for c in rig]))
    bad = [_reproject_residual(flipped, frame, i, i + 1)[0] for i in range(7)]
    assert np.median(bad) > 0.03


def test_virtual_rig_bad_indices(icl_path, tmp_path):
    seq = fuseflow.open_recording(icl_path)
    with pytest.raises(ValidationError, match="out of range"):
        make_virtual_rig(seq, [0, 500], tmp_path)
    with pytest.raises(ValidationError, match="distinct"):
        make_virtual_rig(seq, [3, 3], tmp_path)


def test_frame_depth_is_float32_metres(icl_path):
    f = fuseflow.open_recording(icl_path)[5]
    assert f.depth.dtype == torch.float32 and f.depth.max() < 20
