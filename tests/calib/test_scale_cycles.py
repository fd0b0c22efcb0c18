"""GMAC core on known geometry: closed forms, the RC fixed point, cycle pruning, fallbacks."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.calib import CalibConfig, CalibrationError, calibrate, metric_scale
from fuseflow.calib.correspondences import prepare_cameras
from fuseflow.calib.cycles import cycle_residual, prune_by_cycles, triangles
from fuseflow.calib.scale import Correspondences, closed_form_scale, naive_median_scale


def _exact_correspondences(s_true: float, seed: int = 0, m: int = 200) -> list[Correspondences]:
    rng = np.random.default_rng(seed)
    out = []
    for i, j in [(0, 1), (1, 2), (0, 2)]:
        RX = rng.uniform([-1, -1, 1], [1, 1, 4], size=(m, 3))
        t = rng.normal(size=3)
        Y = RX + s_true * t
        n = rng.normal(size=(m, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        out.append(Correspondences(i, j, RX, Y, t, rng.uniform(0.1, 1, m), np.zeros(m, bool), n))
    return out


@pytest.mark.parametrize("form", ["plane", "full3d", "zonly"])
def test_closed_forms_recover_known_scale_exactly(form):
    corrs = _exact_correspondences(2.345)
    est = closed_form_scale(corrs, form)
    assert abs(est.s - 2.345) < 1e-6 * 2.345
    assert est.std_error < 1e-9
    assert est.count == 600


def test_closed_form_weights_matter_with_noise():
    corrs = _exact_correspondences(1.5)
    bad = corrs[0]
    noisy = Correspondences(bad.i, bad.j, bad.RX, bad.Y + 0.5 * bad.t, bad.t, bad.w, bad.is_match, bad.n)
    s_all = closed_form_scale([noisy, *corrs[1:]], "full3d").s
    s_down = closed_form_scale([noisy.reweighted(noisy.w * 0), *corrs[1:]], "full3d").s
    assert abs(s_all - 1.5) > 0.05
    assert abs(s_down - 1.5) < 1e-6


def test_zonly_degenerate_for_sideways_baseline():
    c = _exact_correspondences(1.0)[0]
    side = Correspondences(c.i, c.j, c.RX, c.RX + np.array([0.3, 0.0, 0.0]), np.array([0.3, 0.0, 0.0]), c.w, c.is_match)
    with pytest.raises(CalibrationError, match="degenerate"):
        closed_form_scale([side], "zonly")
    assert abs(closed_form_scale([side], "full3d").s - 1.0) < 1e-9


def test_no_correspondences_is_an_error():
    with pytest.raises(CalibrationError, match="no correspondences"):
        closed_form_scale([], "plane")


def test_naive_median_scale():
    z = np.linspace(1, 3, 50)
    assert naive_median_scale(z * 4.0, z) == pytest.approx(4.0)
    with pytest.raises(CalibrationError):
        naive_median_scale(np.zeros(5), np.ones(5))


def test_fixed_point_converges_to_true_scale(scene5, backbone_builder):
    frame, rig, T = scene5
    cal = calibrate(frame, rig, CalibConfig(), backbone_result=backbone_builder(T, 3.7))
    r = cal.report
    assert r["fixed_point"]["converged"]
    assert abs(r["scale"] - 3.7) / 3.7 < 2e-3
    # the coarse search alone is ~1 % accurate; the fixed point must improve on it
    assert abs(r["scale"] - 3.7) <= abs(r["scale_coarse"] - 3.7)
    assert r.world_anchor == frame.camera_ids[0]  # the world is the first placed camera's frame
    for k, cid in enumerate(frame.camera_ids):
        C_est = -cal.T_cam_world[cid][:3, :3].T @ cal.T_cam_world[cid][:3, 3]
        T_k = T[k] @ np.linalg.inv(T[0])  # ground truth in the anchor's frame
        C_true = -T_k[:3, :3].T @ T_k[:3, 3]
        assert np.linalg.norm(C_est - C_true) < 0.01  # metres
    assert r["unconnected_cameras"] == []
    assert set(r["timings_s"]) >= {"backbone", "scale", "total"}


def test_pruning_removes_injected_bad_edge(scene5, backbone_builder, corrupt_step):
    frame, rig, T = scene5
    cfg = CalibConfig()
    bb = backbone_builder(T, 3.7)
    cams = prepare_cameras(frame.depth.numpy(), rig.K().double().numpy(), rig.depth_range().double().numpy(), 3000)
    sr = metric_scale(bb, cams, cfg, step=corrupt_step({(0, 1): 0.4}))
    assert (0, 1) in sr.pruned
    assert sr.cycle_mode == "cycles"
    assert abs(sr.s - 3.7) / 3.7 < 0.01
    assert max(sr.cycle_residuals_before.values()) > cfg.delta_cycle
    # without CC the bad edge stays and biases the scale more
    sr_off = metric_scale(bb, cams, CalibConfig(cycle_consistency=False), step=corrupt_step({(0, 1): 0.4}))
    assert sr_off.pruned == () and sr_off.cycle_mode == "off"
    assert abs(sr_off.s - 3.7) > abs(sr.s - 3.7)


def test_cycle_residual_zero_with_equal_scales_and_point_independent(scene5, backbone_builder):
    _, _, T = scene5
    T0 = backbone_builder(T, 2.0).T_cam_world
    scales = {(0, 1): 2.0, (1, 2): 2.0, (0, 2): 2.0}
    a, r = cycle_residual(T0, (0, 1, 2), scales, np.random.default_rng(0).normal(size=(10, 3)))
    assert a < 1e-12 and r < 1e-12
    scales[(1, 2)] = 2.2
    a1, _ = cycle_residual(T0, (0, 1, 2), scales, None)
    a2, _ = cycle_residual(T0, (0, 1, 2), scales, np.random.default_rng(1).normal(size=(10, 3)) * 5)
    assert a1 > 0.01 and a1 == pytest.approx(a2)  # rotation closes: residual is a pure translation


def test_no_triangle_median_fallback(scene5, backbone_builder):
    _, _, T = scene5
    T0 = backbone_builder(T, 1.0).T_cam_world
    chain = {(0, 1): 1.0, (1, 2): 1.01, (2, 3): 0.99, (3, 4): 1.5}
    assert triangles(list(chain)) == []
    res = prune_by_cycles(T0, chain, 0.03)
    assert res.mode == "median"
    assert res.pruned == ((3, 4),)
    single = prune_by_cycles(T0, {(0, 1): 1.0}, 0.03)
    assert single.mode == "single" and single.pruned == ()


def test_lone_triangle_prunes_the_outlier_edge(scene5, backbone_builder):
    _, _, T = scene5
    T0 = backbone_builder(T, 1.0).T_cam_world
    res = prune_by_cycles(T0, {(0, 1): 1.0, (1, 2): 1.0, (0, 2): 1.0, (2, 3): 1.0, (1, 3): 1.0, (0, 3): 1.6}, 0.03)
    assert res.pruned[0] == (0, 3)
