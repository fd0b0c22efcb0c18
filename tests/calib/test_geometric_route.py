"""Route (c) of the rgbd backbone, geometry only (calib/geometric.py, issue 15): a textureless
pair is registered from depth alone, a pair that shares no geometry is refused, the result is
deterministic.

Scene: ten random boxes, spheres and cylinders on a floor, ray-cast by Open3D (the simulator's
rooms are too plain for any point descriptor: docs/gmac-rgbd.md), two cameras 25 deg apart at
320x240 with depth noise growing with z^2 and a uniform grey image (no SIFT keypoint at all).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fuseflow.calib.backbones.rgbd import RGBDConfig, relative_error, rgbd_backbone
from fuseflow.calib.geometric import pose_clusters
from fuseflow.synth.rigs import look_at
from fuseflow.types import Camera, Frame, Rig, invert_rigid

W, H = 320, 240
K = np.array([[280.0, 0.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])


def _scene(seed: int):
    import open3d as o3d

    rng = np.random.default_rng(seed)
    mesh = o3d.geometry.TriangleMesh.create_box(6, 6, 0.02).translate((-3, -3, -0.02))
    for k in range(10):
        if k % 3 == 0:
            m = o3d.geometry.TriangleMesh.create_box(*rng.uniform(0.15, 0.6, 3))
        elif k % 3 == 1:
            m = o3d.geometry.TriangleMesh.create_sphere(rng.uniform(0.1, 0.3))
        else:
            m = o3d.geometry.TriangleMesh.create_cylinder(rng.uniform(0.05, 0.2), rng.uniform(0.3, 1.2))
        m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, rng.uniform(0, np.pi))), center=(0, 0, 0))
        xy = rng.uniform(-1.0, 1.0, 2)
        m.translate((xy[0], xy[1], -m.get_axis_aligned_bounding_box().min_bound[2]))
        mesh += m
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene


def _depth(scene, T_cw: np.ndarray) -> np.ndarray:
    import open3d as o3d

    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(o3d.core.Tensor(K), o3d.core.Tensor(T_cw), W, H)
    z = scene.cast_rays(rays)["t_hit"].numpy()  # unnormalised pinhole rays: t is the z depth
    return np.where(np.isfinite(z), z, 0.0).astype(np.float32)


def _pair(seeds=(0, 0), angle_deg: float = 25.0):
    """A textureless two-camera frame (camera k sees scene seeds[k]), its bare rig and the true
    camera-from-world poses."""
    Ts, depths = [], []
    for k, a in enumerate((0.0, angle_deg)):
        eye = np.array([2.6 * np.cos(np.radians(a)), 2.6 * np.sin(np.radians(a)), 1.6])
        Ts.append(look_at(eye, np.array([0.0, 0.0, 0.3])))
        depths.append(_depth(_scene(seeds[k]), Ts[-1]))
    D = np.stack(depths)
    noise = np.random.default_rng(7).normal(0.0, 0.002, D.shape) * D**2
    D = np.where(D > 0, D + noise, 0.0).astype(np.float32)
    cams = tuple(Camera(f"cam{k:02d}", W, H, K, depth_range=(0.2, 8.0)) for k in range(2))
    frame = Frame(0, ("cam00", "cam01"), torch.full((2, H, W, 3), 128, dtype=torch.uint8), torch.from_numpy(D),
                  torch.ones(2, dtype=torch.bool))  # fmt: skip
    return frame, Rig(cams), np.stack(Ts)


@pytest.fixture(scope="module")
def textureless():
    frame, rig, T_true = _pair()
    return frame, rig, T_true, rgbd_backbone([frame], rig, RGBDConfig())


def test_textureless_pair_registered_by_geometry(textureless):
    frame, rig, T_true, res = textureless
    assert res.registered.all() and res.metric
    rot, trans = relative_error(
        res.T_cam_world[1] @ invert_rigid(res.T_cam_world[0]), T_true[1] @ invert_rigid(T_true[0])
    )
    assert rot < 0.5 and trans < 0.015, (rot, trans)
    edges = [p for p in res.info["pairs"] if p["edge"]]
    assert len(edges) == 1 and edges[0]["stage"] == "geometric" and edges[0]["edge"]["starts"] >= 3
    image_pairs = [p for p in res.info["pairs"] if p.get("stage") != "geometric"]
    assert image_pairs and all(p["edge"] is None for p in image_pairs)  # no texture: no other route
    # without route (c) nothing places the pair
    off = rgbd_backbone([frame], rig, RGBDConfig(geometric=False))
    assert not off.registered.any()


def test_geometric_route_is_deterministic(textureless):
    frame, rig, _, res = textureless
    again = rgbd_backbone([frame], rig, RGBDConfig())
    np.testing.assert_array_equal(again.T_cam_world, res.T_cam_world)


def test_pair_without_shared_geometry_refused():
    """Two cameras looking at different random scenes: every pose ICP reaches is a narrow basin
    or fails the depth check; nothing is placed, nothing silently wrong."""
    frame, rig, _ = _pair(seeds=(0, 5))
    res = rgbd_backbone([frame], rig, RGBDConfig())
    assert not res.registered.any()
    geo = [p for p in res.info["pairs"] if p.get("stage") == "geometric"]
    assert geo and geo[0]["edge"] is None


def test_pose_clusters_count_basins():
    def pose(deg, x):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[0, 3] = x
        return T

    poses = [pose(10, 0.0), pose(90, 1.0), pose(10.3, 0.005), pose(10.1, 0.01), pose(90.5, 1.0), pose(45, 0.0)]
    out = pose_clusters(poses, deg=1.0, m=0.02)
    assert [k for _, k in out] == [3, 2, 1]
    np.testing.assert_array_equal(out[0][0], poses[0])  # the first member represents its basin
