"""The seen-surface reference (fuseflow.eval.reference): what counts as seen, and the sanity check
that noise-free pixels score near 1."""

from __future__ import annotations

import numpy as np
import pytest
from tests.conftest import look_at

from fuseflow import Camera, Rig
from fuseflow.eval.reference import SurfaceReference, seen_mask, simulated_reference, threshold_name

K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])


def _one_camera(depth_range=(0.3, 3.0)) -> tuple[Rig, np.ndarray]:
    """A camera at the origin looking along +z at a wall z = 2 m (noise-free depth 2 m everywhere)."""
    cam = Camera("c0", 101, 81, K, depth_range=depth_range, T_cam_world=look_at((0, 0, 0), (0, 0, 1)))
    return Rig((cam,)), np.full((1, 81, 101), 2.0, np.float32)


def test_seen_mask_occlusion_range_facing_and_grazing():
    rig, depth = _one_camera()
    P = np.array(
        [
            [0.0, 0.0, 2.0],  # on the wall, facing: seen
            [0.1, 0.1, 2.5],  # behind the wall: occluded
            [0.0, 0.0, 2.0],  # on the wall, normal away from the camera
            [0.0, 0.0, 2.0],  # on the wall, seen at 80 deg incidence
            [5.0, 0.0, 2.0],  # outside the image
        ]
    )
    g = np.radians(80.0)
    Nn = np.array([[0, 0, -1], [0, 0, -1], [0, 0, 1], [np.sin(g), 0, -np.cos(g)], [0, 0, -1]], np.float64)
    assert seen_mask(P, Nn, depth, rig).tolist() == [True, False, False, True, False]
    assert seen_mask(P, Nn, depth, rig, grazing_max_deg=75.0).tolist() == [True, False, False, False, False]
    near, d_near = _one_camera(depth_range=(0.3, 1.5))  # the wall beyond the sensor's range
    assert not seen_mask(P, Nn, d_near, near).any()


def test_seen_mask_checks_shapes():
    rig, depth = _one_camera()
    with pytest.raises(Exception, match="normals"):
        seen_mask(np.zeros((2, 3)), np.zeros((1, 3)), depth, rig)
    with pytest.raises(Exception, match="depth_gt"):
        seen_mask(np.zeros((1, 3)), np.zeros((1, 3)), depth[0], rig)


def test_precision_uses_the_exact_surface_distance():
    # a cloud exactly on the plane z = 0 against 1 cm random samples of it: sample distances put
    # about half of it beyond 5 mm; the exact distance puts none
    rng = np.random.default_rng(0)
    samples = np.c_[rng.random((10_000, 2)), np.zeros(10_000)]
    cloud = np.c_[rng.random((5_000, 2)) * 0.8 + 0.1, np.zeros(5_000)]
    by_samples = SurfaceReference(samples).score(cloud)
    exact = SurfaceReference(samples, lambda p: np.abs(p[:, 2])).score(cloud)
    assert by_samples["precision_5mm"] < 0.7
    assert exact["precision_5mm"] == 1.0 and exact["outlier_2cm"] == 0.0
    assert exact["recall_2cm"] > 0.6  # the cloud covers 64 % of the square
    assert set(exact) >= {"f_5mm", "f_1cm", "f_2cm", "recall_5mm", "chamfer_mm", "accuracy_mm", "completeness_mm"}
    assert [threshold_name(d) for d in (0.005, 0.01, 0.02, 0.0025)] == ["5mm", "1cm", "2cm", "2.5mm"]


def test_noise_free_pixels_score_near_one_on_the_seen_surface():
    from dataclasses import replace

    import torch

    from fuseflow.eval.baselines import naive_fusion
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=8, frames=1, resolution=(640, 480), seed=11, rig="ring"))
    sf = sim.render(0)
    ref = simulated_reference(sim, 0, (sf.surface_points.numpy(), sf.surface_normals.numpy()), sf.depth_gt.numpy())
    clean = replace(sf.frame, depth=torch.as_tensor(sf.depth_gt))
    s = ref.score(naive_fusion(clean, sim.rig).xyz.numpy())
    assert s["precision_1cm"] > 0.99 and s["recall_1cm"] > 0.97
    noisy = ref.score(naive_fusion(sf.frame, sim.rig).xyz.numpy())
    assert noisy["precision_1cm"] < s["precision_1cm"] - 0.1  # the reference tells noise apart
