"""The COLMAP backbone's conventions and repairs: pixel origin, split models, match-only edges."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from fuseflow import Camera, Frame, Rig
from fuseflow.calib import CalibConfig
from fuseflow.calib.backbones.colmap import colmap_backbone, merge_models

from .conftest import make_scene


def _rand_pose(rng) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    T[:3, 3] = rng.normal(size=3) * 2
    return T


def _in_gauge(T: np.ndarray, sigma: float, R: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The same camera in a world x' = sigma R x + tau (COLMAP's similarity gauge freedom)."""
    Rk = T[:3, :3] @ R.T
    c = sigma * R @ (-T[:3, :3].T @ T[:3, 3]) + tau
    out = np.eye(4)
    out[:3, :3] = Rk
    out[:3, 3] = -Rk @ c
    return out


def _relative(Ta, Tb, scale=1.0):
    T = Tb @ np.linalg.inv(Ta)
    return T[:3, :3], T[:3, 3] * scale


def test_merge_models_recovers_relative_poses_across_gauges():
    rng = np.random.default_rng(0)
    truth = [_rand_pose(rng) for _ in range(6)]
    R2 = _rand_pose(rng)[:3, :3]
    sigma = 0.37
    a = {k: (truth[k], np.zeros((3, 2)), np.ones(3)) for k in (0, 1, 2, 3, 4)}
    b = {
        k: (_in_gauge(truth[k], sigma, R2, np.array([1.0, -2.0, 0.5])), np.zeros((3, 2)), np.full(3, sigma))
        for k in (2, 3, 4, 5)
    }
    merged, used = merge_models([b, a])  # the larger model (a) is the reference whatever the order
    assert used == 2 and sorted(merged) == list(range(6))
    for i in range(6):
        for j in range(6):
            Rm, tm = _relative(merged[i][0], merged[j][0])
            Rt, tt = _relative(truth[i], truth[j])
            assert np.allclose(Rm, Rt, atol=1e-9) and np.allclose(tm, tt, atol=1e-9)
    assert np.allclose(merged[5][2], 1.0)  # depths of b's cameras are mapped into a's units


def test_merge_models_leaves_out_a_model_sharing_one_camera():
    rng = np.random.default_rng(1)
    truth = [_rand_pose(rng) for _ in range(5)]
    a = {k: (truth[k], np.zeros((0, 2)), np.zeros(0)) for k in (0, 1, 2)}
    b = {k: (_in_gauge(truth[k], 2.0, np.eye(3), np.zeros(3)), np.zeros((0, 2)), np.zeros(0)) for k in (2, 3, 4)}
    merged, used = merge_models([a, b])
    assert used == 1 and sorted(merged) == [0, 1, 2]  # one shared camera cannot fix the scale


def test_colmap_keypoints_use_integer_pixel_centres():
    """COLMAP puts the top-left pixel's centre at (0.5, 0.5); the backbone must hand back
    keypoints in docs/design.md's convention (centre at (0, 0)), or depth lookups and the reprojection
    model are half a pixel off. Isolated Gaussian blobs at known integer centres in two views."""
    W, H = 160, 120
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    rng = np.random.default_rng(3)
    centres = np.stack([rng.integers(15, W - 15, 40), rng.integers(15, H - 15, 40)], 1)
    img = np.zeros((H, W))
    for cx, cy in centres:
        img += np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * 2.0**2))
    rgb = np.repeat((255 * (1 - np.clip(img, 0, 1)))[..., None], 3, axis=2).astype(np.uint8)
    K = np.array([[150.0, 0, W / 2], [0, 150.0, H / 2], [0, 0, 1]])
    cams = tuple(Camera(f"c{k}", W, H, K) for k in range(2))
    frame = Frame(
        0, ("c0", "c1"), torch.from_numpy(np.stack([rgb, rgb])), torch.ones(2, H, W), torch.ones(2, dtype=torch.bool)
    )
    bb = colmap_backbone(frame, Rig(cams), CalibConfig())
    uv = bb.matches[(0, 1)][0]
    # each keypoint's offset from the nearest blob centre
    d = uv[:, None, :] - centres[None, :, :]
    nearest = d[np.arange(len(uv)), np.argmin(np.linalg.norm(d, axis=2), axis=1)]
    close = np.linalg.norm(nearest, axis=1) < 1.0
    assert close.sum() >= 10
    assert np.all(np.abs(np.median(nearest[close], axis=0)) < 0.15)


@pytest.fixture(scope="module")
def studio_like():
    return make_scene(6, size=(240, 180), seed=4)


def test_edges_with_few_precise_matches_are_kept(studio_like):
    """An edge whose correspondences are all keypoint matches stands on fewer than
    min_correspondences of them (they are s-independent; the reprojection fallback is biased)."""
    from fuseflow.calib import calibrate
    from fuseflow.calib.correspondences import match_only
    from fuseflow.calib.scale import Correspondences

    def corr(m, is_match):
        return Correspondences(0, 1, np.zeros((m, 3)), np.zeros((m, 3)), np.ones(3), np.ones(m), np.full(m, is_match))

    assert match_only([corr(6, True), corr(7, True)])
    assert not match_only([corr(6, True), corr(7, False)])
    assert not match_only([corr(6, True), corr(0, True)])
    frame, rig, T = studio_like
    cal = calibrate(frame, rig, CalibConfig(backbone="colmap", min_correspondences=10_000))
    counts = cal.report["correspondence_counts"]
    assert counts and all(v < 10_000 for v in counts.values())  # only match-only edges survive


def test_global_scale_comes_from_match_only_edges(studio_like):
    """global_from_matches: s* is estimated on the kept match-only edges alone (reprojection
    edges still join CC); off, on every kept edge."""
    from dataclasses import replace

    from fuseflow.calib import calibrate, get_backbone

    frame, rig, T = studio_like
    bb = get_backbone("colmap")(frame, rig, CalibConfig())
    on = calibrate(frame, rig, CalibConfig(), backbone_result=bb)
    off = calibrate(frame, rig, replace(CalibConfig(), global_from_matches=False), backbone_result=bb)
    assert off.report["scale_edges"] == off.report["kept_edges"]
    counts = on.report["correspondence_counts"]
    assert set(on.report["scale_edges"]) <= set(on.report["kept_edges"])
    if len(on.report["scale_edges"]) < len(on.report["kept_edges"]):
        # the edges left out of s* are the reprojection ones (many more correspondences)
        left = set(on.report["kept_edges"]) - set(on.report["scale_edges"])
        assert min(counts[e] for e in left) >= CalibConfig().min_correspondences
        assert on.report["scale"] != off.report["scale"]
