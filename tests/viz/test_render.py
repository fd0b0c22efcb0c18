"""Headless renderer: projection, z-buffer, framing."""

import numpy as np
import pytest

import fuseflow
from fuseflow.viz import orbit_camera, render_cloud, save_cloud_png


def _plane(z, n=50):
    g = np.linspace(-0.5, 0.5, n)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)


def test_nearest_point_wins_and_projection_is_centred():
    K = np.array([[100.0, 0, 49.5], [0, 100.0, 49.5], [0, 0, 1]])
    near, far = _plane(2.0), _plane(3.0)
    xyz = np.concatenate([far, near])  # far first: order must not matter
    rgb = np.concatenate([np.tile([0, 0, 255], (len(far), 1)), np.tile([255, 0, 0], (len(near), 1))]).astype(np.uint8)
    img = render_cloud(xyz, rgb, K, np.eye(4), 100, 100, point_size=3)
    assert tuple(img[50, 50]) == (255, 0, 0)
    assert tuple(img[0, 0]) == (255, 255, 255)  # outside the plane's footprint: background
    # the near plane spans +-0.5 m at 2 m: +-25 px around the centre
    red = np.argwhere((img == [255, 0, 0]).all(-1))
    assert red[:, 0].min() >= 22 and red[:, 0].max() <= 77


def test_orbit_camera_frames_the_cloud(tmp_path):
    xyz = _plane(0.0) + [3.0, -1.0, 2.0]
    K, T = orbit_camera(xyz, width=200, height=150)
    fuseflow.types.check_rigid(T)
    Xc = xyz @ T[:3, :3].T + T[:3, 3]
    assert (Xc[:, 2] > 0).all()
    u = K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]
    assert (u > 0).all() and (u < 200).all() and (v > 0).all() and (v < 150).all()
    cloud = fuseflow.FusedCloud.from_numpy(xyz, np.full_like(xyz, 128), np.linspace(0, 1, len(xyz)), np.zeros(len(xyz)))
    p = save_cloud_png(tmp_path / "w.png", cloud, color_by="weight", width=200, height=150)
    import cv2

    assert cv2.imread(str(p)).shape == (150, 200, 3)
    save_cloud_png(tmp_path / "e.png", fuseflow.FusedCloud.empty())
    with pytest.raises(fuseflow.ValidationError, match="color_by"):
        save_cloud_png(tmp_path / "x.png", cloud, color_by="normals")


def test_rerun_logger_writes_cameras_and_clouds(tmp_path):
    pytest.importorskip("rerun")
    from fuseflow.viz.rerun_log import RerunLogger

    K = [[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]]
    T = np.eye(4)
    T[0, 3] = 0.5
    rig = fuseflow.Rig(
        (fuseflow.Camera("a", 32, 24, K, T_cam_world=np.eye(4)), fuseflow.Camera("b", 32, 24, K, T_cam_world=T))
    )
    log = RerunLogger(tmp_path / "x.rrd")
    log.log_rig(rig)
    xyz = _plane(1.0, 10)
    log.log_cloud(3, fuseflow.FusedCloud.from_numpy(xyz, np.zeros_like(xyz), np.ones(len(xyz)), np.zeros(len(xyz))))
    log.close()
    data = (tmp_path / "x.rrd").read_bytes()
    assert len(data) > 1000
    for entity in (b"world/cameras/a", b"world/cameras/b", b"world/cloud"):
        assert entity in data
