"""Data model: validation at construction, immutability, device moves."""

import dataclasses

import numpy as np
import pytest
import torch

from fuseflow import Calibration, Camera, Frame, FusedCloud, Rig, ValidationError
from fuseflow.types import check_rigid, invert_rigid

K = [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]


def cam(i=0, **kw):
    return Camera(f"c{i}", 640, 480, K, **kw)


def test_camera_fields_are_validated_and_frozen():
    c = cam(T_cam_world=np.eye(4))
    assert c.is_calibrated and c.K.dtype == np.float64
    with pytest.raises(ValueError):
        c.K[0, 0] = 1.0  # read-only array
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.width = 3  # frozen dataclass


@pytest.mark.parametrize(
    "kw, msg",
    [
        (dict(width=0), "width"),
        (dict(K=np.eye(2)), "K: expected shape"),
        (dict(K=[[0, 0, 1], [0, 5, 1], [0, 0, 1]]), "fx, fy > 0"),
        (dict(depth_scale=-1), "depth_scale"),
        (dict(depth_range=(2.0, 1.0)), "depth_range"),
        (dict(T_cam_world=np.full((4, 4), np.nan)), "NaN"),
        (dict(T_cam_world=np.diag([2.0, 1, 1, 1])), "not a rigid transform"),
        (dict(T_cam_world=np.diag([-1.0, 1, 1, 1])), "det R"),
    ],
)
def test_camera_rejects_bad_fields_naming_them(kw, msg):
    args = dict(id="cam7", width=640, height=480, K=K)
    args.update(kw)
    with pytest.raises(ValidationError, match=msg) as e:
        Camera(**args)
    assert "cam7" in str(e.value)


def test_rig_ids_unique_and_extrinsics_tensor():
    with pytest.raises(ValidationError, match="unique"):
        Rig((cam(0), cam(0)))
    rig = Rig((cam(0), cam(1)))
    assert not rig.is_calibrated
    with pytest.raises(ValidationError, match="c0"):
        rig.T_cam_world()
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    rig2 = rig.with_extrinsics({"c0": np.eye(4), "c1": T})
    assert rig2.is_calibrated
    assert rig2.T_cam_world().shape == (2, 4, 4)
    assert torch.allclose(rig2.T_cam_world()[1, :3, 3], torch.tensor([1.0, 2, 3]))
    with pytest.raises(ValidationError, match="not in the rig"):
        rig.with_extrinsics({"zz": np.eye(4)})
    assert rig.K().shape == (2, 3, 3)


def test_mixed_resolution_is_a_clear_error():
    rig = Rig((cam(0), Camera("small", 320, 240, K)))
    with pytest.raises(ValidationError, match="different resolutions"):
        _ = rig.resolution


def test_invert_rigid_roundtrip():
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = q, rng.normal(size=3)
    check_rigid(T)
    assert np.allclose(invert_rigid(T) @ T, np.eye(4))


def make_frame(n=2, h=4, w=5):
    return Frame(
        index=0,
        camera_ids=tuple(f"c{i}" for i in range(n)),
        color=torch.zeros((n, h, w, 3), dtype=torch.uint8),
        depth=torch.ones((n, h, w)),
        present=torch.tensor([True, False][:n]),
    )


def test_frame_shapes_checked_and_missing_listed():
    f = make_frame()
    assert f.missing == ("c1",) and f.resolution == (5, 4) and f.num_views == 2
    with pytest.raises(ValidationError, match="frame color: expected shape"):
        Frame(
            0,
            ("a", "b"),
            torch.zeros((2, 4, 6, 3), dtype=torch.uint8),
            torch.ones((2, 4, 5)),
            torch.ones(2, dtype=torch.bool),
        )
    with pytest.raises(ValidationError, match="dtype"):
        Frame(
            0,
            ("a",),
            torch.zeros((1, 4, 5, 3), dtype=torch.uint8),
            torch.ones((1, 4, 5), dtype=torch.float64),
            torch.ones(1, dtype=torch.bool),
        )
    sub = f.subset([1])
    assert sub.camera_ids == ("c1",) and sub.depth.shape == (1, 4, 5)
    assert f.to("cpu").depth.device.type == "cpu"


def test_fused_cloud_checks_dtypes():
    FusedCloud.empty()
    with pytest.raises(ValidationError, match="cloud rgb"):
        FusedCloud(
            torch.zeros((3, 3)),
            torch.zeros((2, 3), dtype=torch.uint8),
            torch.zeros(3),
            torch.zeros(3, dtype=torch.int16),
        )


def test_calibration_validates_each_camera():
    with pytest.raises(ValidationError, match="'b'"):
        Calibration({"a": np.eye(4), "b": np.ones((4, 4))})
    c = Calibration({"c1": np.eye(4)}, {"scale": 1.5})
    rig = Rig((cam(0, T_cam_world=np.eye(4)), cam(1)))
    assert c.apply(rig).is_calibrated


@pytest.mark.parametrize("cid", ["..", ".", ".hidden", "a/b", "a\\b", "", " cam", "cam ", "c:0", "a\nb"])
def test_camera_id_must_be_a_plain_name(cid):
    with pytest.raises(ValidationError, match="not a plain name"):
        Camera(cid, 640, 480, K)


@pytest.mark.parametrize("cid", ["cam00", "000123456789", "kinect-1", "left_ir.v2", "Kamera Ä"])
def test_camera_id_plain_names_pass(cid):
    assert Camera(cid, 640, 480, K).id == cid


@pytest.mark.parametrize(
    "k, msg",
    [
        ([[500.0, 0, 5000], [0, 500.0, 240], [0, 0, 1]], "principal point"),
        ([[500.0, 0, 320], [0, 500.0, -3], [0, 0, 1]], "principal point"),
        ([[20.0, 0, 320], [0, 20.0, 240], [0, 0, 1]], "field of view"),  # 172 degrees
        ([[5000.0, 0, 320], [0, 5000.0, 240], [0, 0, 1]], "field of view"),  # 7.3 degrees
        ([[500.0, 0, 320], [0, 5.0, 240], [0, 0, 1]], "field of view"),  # fy alone wrong
    ],
)
def test_camera_intrinsics_checked_against_image_size(k, msg):
    with pytest.raises(ValidationError, match=msg) as e:
        Camera("cam7", 640, 480, k)
    assert "cam7" in str(e.value)


def test_camera_intrinsics_edges_pass():
    # 10.0 and 170 degrees horizontally, principal point on the image border
    f10 = 320 / np.tan(np.radians(5.0))
    f170 = 320 / np.tan(np.radians(85.0))
    for f in (f10 * 0.9999, f170 * 1.0001):
        Camera("c", 640, 480, [[f, 0, 640], [0, f, 0], [0, 0, 1]])
