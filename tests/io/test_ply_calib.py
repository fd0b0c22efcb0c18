"""PLY and calib.json round trips; readable by Open3D and trimesh; corrupt files rejected."""

import numpy as np
import pytest
import torch

import fuseflow
from fuseflow import Calibration, FormatError, FusedCloud


def cloud(m=100):
    g = torch.Generator().manual_seed(0)
    return FusedCloud(
        torch.randn((m, 3), generator=g),
        torch.randint(0, 256, (m, 3), generator=g, dtype=torch.uint8),
        torch.rand(m, generator=g),
        torch.randint(0, 8, (m,), generator=g).to(torch.int16),
    )


def test_ply_roundtrip_identical(tmp_path):
    c = cloud()
    fuseflow.write_ply(tmp_path / "a.ply", c)
    r = fuseflow.read_ply(tmp_path / "a.ply")
    for a, b in ((c.xyz, r.xyz), (c.rgb, r.rgb), (c.weight, r.weight), (c.camera, r.camera)):
        assert torch.equal(a, b)
    fuseflow.write_ply(tmp_path / "e.ply", FusedCloud.empty())
    assert len(fuseflow.read_ply(tmp_path / "e.ply")) == 0


def test_ply_support_roundtrip_and_old_files(tmp_path):
    c = cloud()
    assert c.support is None and fuseflow.read_ply(fuseflow.write_ply(tmp_path / "old.ply", c)).support is None
    sup = torch.arange(1, 101, dtype=torch.int16) % 5
    s = FusedCloud(c.xyz, c.rgb, c.weight, c.camera, sup)
    path = fuseflow.write_ply(tmp_path / "s.ply", s)
    assert b"property short support" in path.read_bytes()[:400]
    r = fuseflow.read_ply(path)
    assert torch.equal(r.support, sup) and torch.equal(r.xyz, c.xyz) and torch.equal(r.camera, c.camera)
    assert torch.equal(r.to("cpu").support, sup)
    with pytest.raises(fuseflow.ValidationError, match="support"):
        FusedCloud(c.xyz, c.rgb, c.weight, c.camera, sup[:5])


def test_ply_readable_by_open3d_and_trimesh(tmp_path):
    import open3d as o3d
    import trimesh

    c = cloud()
    fuseflow.write_ply(tmp_path / "a.ply", c)
    pc = o3d.io.read_point_cloud(str(tmp_path / "a.ply"))
    assert np.allclose(np.asarray(pc.points), c.xyz.numpy(), atol=1e-6)
    assert np.allclose(np.asarray(pc.colors) * 255, c.rgb.numpy(), atol=0.5)
    tm = trimesh.load(tmp_path / "a.ply")
    assert np.allclose(np.asarray(tm.vertices), c.xyz.numpy(), atol=1e-6)
    assert np.allclose(tm.metadata["_ply_raw"]["vertex"]["data"]["weight"], c.weight.numpy())


def test_read_foreign_ascii_ply(tmp_path):
    p = tmp_path / "b.ply"
    p.write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 1 2\n3 4 5\n"
    )
    r = fuseflow.read_ply(p)
    assert r.xyz.tolist() == [[0, 1, 2], [3, 4, 5]] and r.camera.tolist() == [-1, -1] and r.weight.tolist() == [1, 1]


def test_truncated_and_bogus_ply(tmp_path):
    fuseflow.write_ply(tmp_path / "a.ply", cloud())
    data = (tmp_path / "a.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-7])
    with pytest.raises(FormatError, match="t.ply: truncated"):
        fuseflow.read_ply(tmp_path / "t.ply")
    (tmp_path / "x.ply").write_bytes(b"hello")
    with pytest.raises(FormatError, match="not a PLY"):
        fuseflow.read_ply(tmp_path / "x.ply")


def test_calibration_roundtrip_identical(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [0.1, -0.2, 1.5]
    c = Calibration({"a": np.eye(4), "b": T}, {"scale": np.float64(2.5), "edges": [[0, 1]], "warnings": []})
    fuseflow.write_calibration(tmp_path / "calib.json", c)
    r = fuseflow.read_calibration(tmp_path / "calib.json")
    assert r.camera_ids == ("a", "b")
    assert all(np.array_equal(r.T_cam_world[k], c.T_cam_world[k]) for k in ("a", "b"))
    assert r.report == {"scale": 2.5, "edges": [[0, 1]], "warnings": []}


def test_calibration_errors_name_camera(tmp_path):
    p = tmp_path / "calib.json"
    p.write_text(
        '{"format": "fuseflow-calib/1", "cameras": {"left": {"T_cam_world": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,2]]}}}'
    )
    with pytest.raises(FormatError, match="'left'.*last row"):
        fuseflow.read_calibration(p)
    p.write_text('{"format": "fuseflow-calib/1", "cameras": {"left": {}}}')
    with pytest.raises(FormatError, match="'left': missing field 'T_cam_world'"):
        fuseflow.read_calibration(p)
