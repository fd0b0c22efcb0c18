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


def _ring_rig(n=6, radius=2.5):
    from tests.conftest import look_at

    K = [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]]
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        T = look_at((radius * np.cos(a), radius * np.sin(a), 1.8), (0, 0, 0.9), (0, 0, 1))
        cams.append(fuseflow.Camera(f"c{k}", 160, 120, K, T_cam_world=T))
    return fuseflow.Rig(tuple(cams))


def test_png_frames_the_capture_volume_with_cameras_label_and_colour_bar(tmp_path):
    import cv2

    from fuseflow.geometry.volume import capture_volume
    from fuseflow.viz.render import BACKGROUND, view_camera, weight_colors

    rig = _ring_rig()
    vol = capture_volume(rig)
    subject = _plane(0.0, 40)[:, [0, 2, 1]] + [0, 0, 1.0]  # a 1 m square standing in the middle
    wall = _plane(0.0, 40)[:, [2, 0, 1]] * [1, 4, 3] + [4.0, 0, 1.5]  # a wall beyond the ring
    xyz = np.concatenate([subject, wall])
    K, T, shown = view_camera(xyz, rig, vol, 480, 360)
    assert shown[: len(subject)].all() and not shown[len(subject) :].any()
    uv = (subject @ T[:3, :3].T + T[:3, 3]) @ K.T
    uv = uv[:, :2] / uv[:, 2:]
    assert (uv[:, 0] > 0).all() and (uv[:, 0] < 380).all() and (uv[:, 1] > 0).all() and (uv[:, 1] < 360).all()
    cloud = fuseflow.FusedCloud.from_numpy(xyz, np.full_like(xyz, 200), np.full(len(xyz), 1.0), np.zeros(len(xyz)))
    p = save_cloud_png(tmp_path / "w.png", cloud, "weight", width=480, height=360, rig=rig, volume=vol, label="frame 7")
    img = cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB)
    bar_top = img[int(0.15 * 360) + 2, 480 - 50]
    assert np.abs(bar_top.astype(int) - weight_colors(np.array([0.99]))[0]).max() <= 12  # colour bar
    assert (img[360 // 2, 480 - 50].astype(int) != BACKGROUND).any()
    assert (img[5:35, 12:80] != BACKGROUND).any(axis=-1).sum() > 30  # the label's ink


def test_one_sided_rig_is_seen_from_behind_its_cameras():
    from tests.conftest import look_at

    from fuseflow.geometry.volume import capture_volume
    from fuseflow.viz.render import view_camera

    K = [[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]]
    cams = tuple(
        fuseflow.Camera(f"c{k}", 160, 120, K, depth_range=(0.3, 4.0), T_cam_world=look_at((x, 0, 0), (x, 0, 3)))
        for k, x in enumerate((-0.4, 0.0, 0.4))
    )
    rig = fuseflow.Rig(cams)
    wall = _plane(3.0)
    K2, T, _ = view_camera(wall, rig, capture_volume(rig))
    assert T[2, :3] @ np.array([0, 0, 1.0]) > 0.8  # the view looks where the cameras look
    eye = -T[:3, :3].T @ T[:3, 3]
    assert eye[2] < 2.5  # on the cameras' side of the wall (z = 3), not behind it
