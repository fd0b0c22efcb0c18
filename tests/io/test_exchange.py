"""Draco and GLB writers (io.exchange) and the mesh PLY, read back by independent readers
(DracoPy, trimesh, Open3D), including an empty cloud and a cloud of 3 points."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.io.exchange import draco_bits, read_cloud, write_cloud, write_drc, write_glb_mesh, write_glb_points
from fuseflow.types import FusedCloud

DracoPy = pytest.importorskip("DracoPy")
trimesh = pytest.importorskip("trimesh")


def _cloud(n: int, extent: float = 3.0, seed: int = 0) -> FusedCloud:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-extent / 2, extent / 2, (n, 3)).astype(np.float32)
    return FusedCloud.from_numpy(xyz, rng.integers(0, 256, (n, 3)), rng.uniform(0, 1, n), rng.integers(0, 4, n))


def test_draco_bits_follow_the_error_bound():
    assert draco_bits(3.6, 1.0) == 12  # sqrt(3)/2 * 3.6 m / 1 mm = 3118 steps -> 12 bits
    assert draco_bits(3.6, 0.5) == 13
    assert draco_bits(1e-6, 1.0) == 8
    with pytest.raises(Exception, match="positive"):
        draco_bits(1.0, 0.0)


@pytest.mark.parametrize("error_mm", [1.0, 2.0])
def test_draco_positions_stay_within_the_bound(tmp_path, error_mm):
    c = _cloud(20000)
    p = write_drc(tmp_path / "a.drc", c, error_mm)
    d = DracoPy.decode(p.read_bytes())  # the independent reader
    pts, cols = np.asarray(d.points), np.asarray(d.colors)
    assert pts.shape == (20000, 3) and cols.shape[0] == 20000
    err = np.linalg.norm(pts - c.xyz.numpy(), axis=1)  # the order is kept: point k is point k
    assert err.max() * 1000 <= error_mm and np.median(err) * 1000 > error_mm / 10  # quantised, not lossless
    assert (cols[:, :3] == c.rgb.numpy()).all()
    assert p.stat().st_size < 20000 * 21 / 2  # well under binary PLY (21 bytes a point)


@pytest.mark.parametrize("n", [0, 3])
def test_tiny_and_empty_clouds_in_every_format(tmp_path, n):
    c = _cloud(n)
    for fmt in ("ply", "drc", "glb"):
        back = read_cloud(write_cloud(tmp_path / f"c.{fmt}", c, fmt))
        assert len(back) == n
        assert np.allclose(np.sort(back.xyz.numpy(), axis=0), np.sort(c.xyz.numpy(), axis=0), atol=1e-3)
    d = DracoPy.decode((tmp_path / "c.drc").read_bytes())  # a zero-point file decodes as no points
    assert (d.points is None and n == 0) or np.asarray(d.points).shape == (n, 3)
    scene = trimesh.load(tmp_path / "c.glb")
    got = [g.vertices for g in scene.geometry.values()]
    assert (len(got) == 0) if n == 0 else np.allclose(got[0], c.xyz.numpy(), atol=1e-6)


def test_glb_points_load_in_trimesh_with_colours(tmp_path):
    c = _cloud(500)
    write_glb_points(tmp_path / "p.glb", c)
    (g,) = trimesh.load(tmp_path / "p.glb").geometry.values()
    assert isinstance(g, trimesh.PointCloud)
    assert np.allclose(g.vertices, c.xyz.numpy(), atol=1e-6)
    assert (np.asarray(g.colors)[:, :3] == c.rgb.numpy()).all()
    back = read_cloud(tmp_path / "p.glb")
    assert np.allclose(back.weight.numpy(), c.weight.numpy())


def test_glb_mesh_in_trimesh_and_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    cols = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9]], np.uint8)
    write_glb_mesh(tmp_path / "m.glb", v, f, cols, np.tile([0, 0, 1.0], (4, 1)))
    m = trimesh.load(tmp_path / "m.glb", force="mesh")
    assert m.vertices.shape == (4, 3) and m.faces.shape == (2, 3)
    assert (m.visual.vertex_colors[:, :3] == cols).all()
    om = o3d.io.read_triangle_mesh(str(tmp_path / "m.glb"))
    assert len(om.triangles) == 2 and np.allclose(np.asarray(om.vertices), v)
    write_glb_mesh(tmp_path / "e.glb", v[:0], f[:0], cols[:0])  # an empty mesh: a valid GLB
    assert len(trimesh.load(tmp_path / "e.glb").geometry) == 0
