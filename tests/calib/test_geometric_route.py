"""Route (c) of the rgbd backbone, geometry only (calib/geometric.py): a textureless
pair is registered from depth alone, a pair that shares no geometry is refused, the result is
deterministic.

Scene: ``fuseflow.synth.primitives`` (ten random boxes, spheres and cylinders on a floor,
ray-cast; the simulator's rooms are too plain for any point descriptor: docs/gmac-rgbd.md), two
cameras 25 deg apart at 320x240, depth noise growing with z^2, a uniform grey image (no SIFT
keypoint at all).
"""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.calib.backbones.rgbd import RGBDConfig, relative_error, rgbd_backbone
from fuseflow.calib.geometric import pose_clusters
from fuseflow.synth.primitives import primitive_views
from fuseflow.types import invert_rigid


def _pair(seeds=(0, 0), angle_deg: float = 25.0):
    return primitive_views((0.0, angle_deg), seeds)


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


def test_calibrate_warns_that_a_tree_edge_is_unchecked(textureless):
    """Through ``calibrate`` (auto backbone): both cameras placed by route (c), and the report
    says their pose had no independent check (one edge, no cycle)."""
    from fuseflow.calib import calibrate

    frame, rig, T_true, _ = textureless
    cal = calibrate(frame, rig)
    assert set(cal.T_cam_world) == {"cam00", "cam01"}
    warn = [w for w in cal.report.warnings if "close no cycle" in w]
    assert len(warn) == 1 and "'cam00'" in warn[0] and "'cam01'" in warn[0]
    T = cal.T_cam_world
    rot, trans = relative_error(T["cam01"] @ invert_rigid(T["cam00"]), T_true[1] @ invert_rigid(T_true[0]))
    assert rot < 0.5 and trans < 0.015, (rot, trans)


def _mutual_reference(fa: np.ndarray, fb: np.ndarray) -> np.ndarray:
    """Brute force: (i, j) with j the first nearest of i in b and i the first nearest of j in a."""
    import torch

    D = torch.cdist(torch.from_numpy(fa), torch.from_numpy(fb)).numpy()
    ab, ba = D.argmin(axis=1), D.argmin(axis=0)
    i = np.flatnonzero(ba[ab] == np.arange(len(fa)))
    return np.stack([i, ab[i]], axis=1)


def test_mutual_matches_equal_brute_force_with_ties_and_chunks():
    """``_mutual_matches`` (chunked, numpy reductions) against one full distance matrix: rows
    over two chunks (> 4096) and many exact ties (duplicate descriptors), both argument orders."""
    from fuseflow.calib.geometric import _mutual_matches

    rng = np.random.default_rng(0)
    for fa, fb in [
        (rng.normal(size=(5000, 8)).astype(np.float32), rng.normal(size=(700, 8)).astype(np.float32)),
        (rng.integers(0, 2, (5000, 4)).astype(np.float32), rng.integers(0, 2, (300, 4)).astype(np.float32)),
    ]:
        for a, b in ((fa, fb), (fb, fa)):
            ref = _mutual_reference(a, b)
            assert len(ref) > 0
            np.testing.assert_array_equal(_mutual_matches(a, b), ref)


def test_point_plane_jacobian_is_cross_then_normal():
    from fuseflow.calib.geometric import _point_plane_jacobian

    rng = np.random.default_rng(1)
    q, n = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    np.testing.assert_array_equal(_point_plane_jacobian(q, n), np.c_[np.cross(q, n), n])


def _rigid(deg: float, t) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = t
    return T


def test_route_c_tries_an_unplaced_cameras_pairs_by_consensus(monkeypatch):
    """``geometric_edges_per_camera``: cameras 0 and 1 placed, camera 2 not. Its pairs are run
    in order of descriptor consensus ((1, 2) first here) until it has one candidate; (0, 2) is
    then never run. With the cap at the number of cameras, every pair runs, in pair order."""
    from types import SimpleNamespace

    from fuseflow.calib import geometric
    from fuseflow.calib.backbones.rgbd import geometric_route as rgbd
    from fuseflow.calib.posegraph import Edge

    rng = np.random.default_rng(0)
    T_cw = [np.eye(4), _rigid(40, [1.0, 0, 0.3]), _rigid(80, [1.8, 0, 1.0])]  # camera-from-world

    def rel(i, j):  # camera i -> camera j
        return T_cw[j] @ invert_rigid(T_cw[i])

    def points(i, j, k=12):
        Xi = rng.uniform([-1, -1, 2], [1, 1, 4], size=(k, 3))
        T = rel(i, j)
        return Xi, Xi @ T[:3, :3].T + T[:3, 3]

    Xi, Xj = points(0, 1)
    edges = {(0, 1): Edge(0, 1, rel(0, 1), 100.0, Xi, Xj, np.full(len(Xi), 0.005))}
    consensus = {(0, 2): 7, (1, 2): 40}
    run = []

    def fake_starts(a, b, *args, **kw):
        return geometric.RansacStarts(np.zeros((3, 3)), np.zeros((3, 3)), [(np.eye(4), consensus[(a, b)])])

    def fake_pair(cams, i, j, feat, cfg, prepared=None):
        run.append((i, j))
        Xa, Xb = points(i, j)
        c = SimpleNamespace(T_ba=rel(i, j), X_a=Xa, X_b=Xb, M_a=np.zeros((0, 3)), starts=5)
        entry = {"pair": [i, j], "stage": "geometric", "candidates": [], "edge": None}
        return entry, (c, SimpleNamespace(agree=500, agreement=0.95), entry)

    monkeypatch.setattr(geometric, "ransac_starts", fake_starts)
    monkeypatch.setattr(rgbd, "_cloud_cache", lambda cams, cfg: lambda k: k)
    monkeypatch.setattr(rgbd, "_geometric_pair", fake_pair)
    T0 = np.stack([T_cw[0], T_cw[1], np.eye(4)])
    placed = np.array([True, True, False])
    out, info, solved = rgbd.geometric_edges([None] * 3, T0, placed, edges, RGBDConfig())
    assert run == [(1, 2)] and list(out) == [(1, 2)]
    assert solved[4].all()  # camera 2 placed by the one edge
    run.clear()
    out, _, _ = rgbd.geometric_edges([None] * 3, T0, placed, edges, RGBDConfig(geometric_edges_per_camera=3))
    assert run == [(0, 2), (1, 2)] and sorted(out) == [(0, 2), (1, 2)]


def test_prepared_ransac_starts_give_the_same_candidates(textureless):
    from fuseflow.calib.backbones.rgbd.evidence import backproject
    from fuseflow.calib.geometric import cloud_features, geometric_candidates, ransac_starts

    frame, rig, _, _ = textureless
    f = [cloud_features(backproject(frame.depth[k].numpy(), rig.cameras[k].K, 2), 0.02) for k in range(2)]
    rs = ransac_starts(f[0], f[1], 3, seed=2)
    assert rs.consensus == rs.hypotheses[0][1] > 0
    a = geometric_candidates(f[0], f[1], 3, seed=2)
    b = geometric_candidates(f[0], f[1], 3, seed=2, prepared=rs)
    assert [c.starts for c in a] == [c.starts for c in b]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.T_ba, y.T_ba)
