"""fuse() end to end on analytic scenes: planes, flying pixels, occluders, determinism, degraded
inputs, errors. Runs the default backend ("auto" = numba on CPU) unless a test says otherwise;
test_numba.py shows both backends give the same cloud."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch
from tests.fuse.scenes import PLANE_Z, Rect, look_at, make_rig, render

from fuseflow import Frame
from fuseflow.errors import ValidationError
from fuseflow.fuse import ABLATIONS, FuseConfig, fuse, fuse_with_report

NOISE = 0.003  # relative depth noise of the analytic scenes: 6 mm at the 2 m plane


def _backproject(frame: Frame, rig) -> np.ndarray:
    """Naive fusion: every valid pixel back-projected to world (the baseline FUSE must beat)."""
    pts = []
    for i, cam in enumerate(rig.cameras):
        d = frame.depth[i].numpy().astype(np.float64)
        v, u = np.nonzero(d > 0)
        z = d[v, u]
        X = np.stack([u, v, np.ones_like(z)], 1) @ np.linalg.inv(cam.K).T * z[:, None]
        pts.append(X @ cam.T_world_cam[:3, :3].T + cam.T_world_cam[:3, 3])
    return np.concatenate(pts)


@pytest.mark.parametrize("n_cams", [2, 3, 4])
def test_plane_seen_by_several_cameras_fuses_to_the_plane(n_cams):
    eyes = [(x, 0.1 * i, 0.0) for i, x in enumerate(np.linspace(-0.6, 0.6, n_cams))]
    rig = make_rig(eyes)
    frame = render(rig, [Rect(PLANE_Z)], noise=NOISE, seed=n_cams)
    res = fuse_with_report(frame, rig)
    xyz = res.cloud.xyz.numpy()
    sigma = NOISE * PLANE_Z
    resid = xyz[:, 2] - PLANE_Z
    assert len(xyz) > 0.2 * n_cams * 40 * 30  # a real cloud, not a handful of points
    assert np.abs(resid).max() < 5 * sigma  # no outliers
    assert resid.std() < 1.2 * sigma  # an upper bound: multiview_mean and consensus average some noise away
    assert abs(resid.mean()) < 0.2 * sigma
    # the cloud covers the region the cameras see (not one corner of it)
    assert np.ptp(xyz[:, 0]) > 2.0 and np.ptp(xyz[:, 1]) > 1.2
    assert res.report.isolated == () and res.report.warnings == ()
    # fusion thins: fewer points than valid pixels, more than one per fine cell would give nothing
    assert len(xyz) < 0.7 * res.report.valid_pixels


def test_multiview_mean_averages_the_noise_without_crossing_depth_edges():
    """FuseConfig.cvgc.multiview_mean: a noisy plane seen by 3 cameras fuses to the plane with
    clearly less spread than with the switch off (each point averages the agreeing
    neighbours' measurements), and at a box's silhouette no point is pulled between the box
    and the wall behind it (only neighbours within the noise gate count)."""
    rig = make_rig([(-0.5, 0.0, 0.0), (0.0, 0.05, 0.0), (0.5, 0.0, 0.0)])
    frame = render(rig, [Rect(PLANE_Z)], noise=NOISE, seed=7)
    std = {}
    for on in (False, True):
        cloud = fuse(frame, rig, FuseConfig().replace(cvgc={"multiview_mean": on}))
        resid = cloud.xyz.numpy()[:, 2] - PLANE_Z
        assert abs(resid.mean()) < 0.2 * NOISE * PLANE_Z
        std[on] = resid.std()
    assert std[True] < 0.85 * std[False], std  # measured 5.2 vs 6.6 mm
    box = Rect(1.5, -0.25, 0.25, -0.25, 0.25)
    edge = render(rig, [Rect(PLANE_Z), box], noise=0.002, seed=3)
    cloud = fuse(edge, rig, FuseConfig().replace(cvgc={"multiview_mean": True}, mcm={"enabled": False}))
    assert len(cloud) > 2000 and _off_surface(cloud.xyz.numpy(), box).sum() == 0


def _flying_pixel_scene():
    rig = make_rig([(-0.5, 0.0, 0.0), (0.0, 0.05, 0.0), (0.5, 0.0, 0.0)])
    box = Rect(1.5, -0.25, 0.25, -0.25, 0.25)
    frame = render(rig, [Rect(PLANE_Z), box], noise=0.001, seed=2)
    depth = frame.depth.clone()
    # every camera: pixels next to the box's silhouette get a mixed depth halfway between the box
    # and the wall (Kinect-class flying pixels)
    for i in range(len(rig)):
        d = depth[i]
        near = d < 1.75
        ring = torch.zeros_like(near)
        ring[:, 1:] |= near[:, :-1] & ~near[:, 1:]
        ring[:, :-1] |= near[:, 1:] & ~near[:, :-1]
        ring[1:, :] |= near[:-1, :] & ~near[1:, :]
        ring[:-1, :] |= near[1:, :] & ~near[:-1, :]
        d[ring] = 1.75
    return rig, box, Frame(0, frame.camera_ids, frame.color, depth, frame.present)


def _off_surface(xyz: np.ndarray, box: Rect) -> np.ndarray:
    on_wall = np.abs(xyz[:, 2] - PLANE_Z) < 0.02
    in_box = (xyz[:, 0] > box.x0 - 0.02) & (xyz[:, 0] < box.x1 + 0.02) & (xyz[:, 1] > box.y0 - 0.02)
    on_box = in_box & (xyz[:, 1] < box.y1 + 0.02) & (np.abs(xyz[:, 2] - box.z0) < 0.02)
    return ~(on_wall | on_box)


def test_flying_pixel_edge_is_suppressed():
    rig, box, frame = _flying_pixel_scene()
    naive = _backproject(frame, rig)
    assert _off_surface(naive, box).sum() > 200  # the scene really has flying pixels
    cloud = fuse(frame, rig)
    assert _off_surface(cloud.xyz.numpy(), box).sum() == 0
    assert len(cloud) > 2000
    # with both reliability terms removed the flying pixels come through: the test can fail
    bare = fuse(frame, rig, FuseConfig().replace(mcm={"enabled": False}, cvgc={"enabled": False}))
    assert _off_surface(bare.xyz.numpy(), box).sum() > 50


@pytest.mark.parametrize("name", ["w/o CVGC", "w/o ASH", "w/o RPS"])
def test_each_ablation_keeping_mcm_suppresses_flying_pixels(name):
    """MCM alone (w/o CVGC), and the default without ASH or RPS, remove the mixed pixels."""
    rig, box, frame = _flying_pixel_scene()
    cloud = fuse(frame, rig, ABLATIONS[name])
    assert _off_surface(cloud.xyz.numpy(), box).sum() <= 0.002 * len(cloud)


def test_cvgc_alone_removes_most_flying_pixels_but_not_along_the_baseline():
    """CVGC alone (w/o MCM) halves the flying pixels of this rig; it cannot remove all of them.

    The three cameras sit on a horizontal line, so a mixed pixel along the box's top or bottom
    edge projects into a neighbour along that same edge, onto the neighbour's own mixed pixel
    at the same depth: the vote agrees (the epipolar line runs along the edge). Mixed pixels
    that land on the box in every neighbour are merely occluded there: no vote, omega_geo = c.
    MCM is what removes both kinds (test above)."""
    rig, box, frame = _flying_pixel_scene()
    bare = _off_surface(
        fuse(frame, rig, FuseConfig().replace(mcm={"enabled": False}, cvgc={"enabled": False})).xyz.numpy(), box
    )
    xyz = fuse(frame, rig, ABLATIONS["w/o MCM"]).xyz.numpy()
    off = _off_surface(xyz, box)
    assert off.sum() <= 0.6 * bare.sum()
    # most survivors lie along the horizontal edges (y = +-0.25 at the box, scaled to z = 1.5)
    y_at_box = xyz[off, 1] / xyz[off, 2] * box.z0
    assert (np.abs(np.abs(y_at_box) - 0.25) < 0.05).mean() > 0.6


def test_occluder_seen_by_one_camera_does_not_delete_surface_with_visibility_aware_votes():
    rig = make_rig([(-0.4, 0.0, 0.0), (0.4, 0.0, 0.0)])
    # an object 0.5 m in front of cam0 only (e.g. a person close to that camera)
    occluder = Rect(0.5, -0.55, -0.25, -0.15, 0.15)
    frame = render(rig, [Rect(PLANE_Z), occluder], noise=0.002, only={1: {0}})
    # the wall region cam0 cannot see: cam1 sees it, so it must stay
    centre = rig[0].T_world_cam[:3, 3]  # cam0's optical centre (world)
    shadow_x = []
    for x in np.linspace(-1.0, 1.0, 401):
        wall = np.array([x, 0.0, PLANE_Z])
        t = (occluder.z0 - centre[2]) / (PLANE_Z - centre[2])
        ray = centre + t * (wall - centre)  # where cam0's ray to this wall point crosses z = z0
        if occluder.x0 < ray[0] < occluder.x1:
            shadow_x.append(x)
    x0, x1 = min(shadow_x) + 0.03, max(shadow_x) - 0.03

    def wall_in_shadow(cfg):
        xyz = fuse(frame, rig, cfg).xyz.numpy()
        sel = (xyz[:, 0] > x0) & (xyz[:, 0] < x1) & (np.abs(xyz[:, 1]) < 0.12) & (np.abs(xyz[:, 2] - PLANE_Z) < 0.02)
        return int(sel.sum())

    aware = wall_in_shadow(FuseConfig().replace(cvgc={"visibility_aware": True}))
    literal = wall_in_shadow(FuseConfig().replace(cvgc={"visibility_aware": False}))
    assert aware > 30, (aware, literal)
    assert literal < 0.1 * aware, (aware, literal)  # eq. (20)-(21) as written: cam0's occluder votes the wall away


def test_repeated_runs_are_identical():
    rig, _, frame = _flying_pixel_scene()
    for backend in ("numba", "torch"):
        cfg = FuseConfig(backend=backend)
        a, b = fuse(frame, rig, cfg), fuse(frame, rig, cfg)
        for x, y in ((a.xyz, b.xyz), (a.rgb, b.rgb), (a.weight, b.weight), (a.camera, b.camera)):
            assert torch.equal(x, y)


def test_output_respects_candidate_filters():
    """Eq. (27) plus the minimum joint weight: every output point has omega >= min_weight."""
    rig, _, frame = _flying_pixel_scene()
    for cfg in (FuseConfig(), FuseConfig().replace(rps={"min_weight": 0.6})):
        w = fuse(frame, rig, cfg).weight
        assert float(w.min()) >= cfg.rps.min_weight and float(w.max()) <= 1.0


def test_missing_camera_is_reported_and_fused_without(caplog):
    rig = make_rig([(-0.5, 0.0, 0.0), (0.0, 0.0, 0.1), (0.5, 0.0, 0.0)])
    frame = render(rig, [Rect(PLANE_Z)], noise=NOISE)
    depth, color, pres = frame.depth.clone(), frame.color.clone(), frame.present.clone()
    depth[1], color[1], pres[1] = 0, 0, False
    dropped = Frame(0, frame.camera_ids, color, depth, pres)
    with caplog.at_level(logging.WARNING, logger="fuseflow.fuse"):
        cloud = fuse(dropped, rig)
    assert "missing" in caplog.text and "cam1" in caplog.text
    assert len(cloud) > 1000 and not bool((cloud.camera == 1).any())
    # a frame holding only some of the rig's cameras works too (camera = rig index)
    sub = Frame(0, ("cam0", "cam2"), frame.color[[0, 2]], frame.depth[[0, 2]], frame.present[[0, 2]])
    cams = set(fuse(sub, rig).camera.tolist())
    assert cams == {0, 2}


def test_all_zero_depth_in_one_camera():
    rig = make_rig([(-0.5, 0.0, 0.0), (0.5, 0.0, 0.0)])
    frame = render(rig, [Rect(PLANE_Z)], noise=NOISE)
    depth = frame.depth.clone()
    depth[0] = 0
    res = fuse_with_report(Frame(0, frame.camera_ids, frame.color, depth, frame.present), rig)
    assert res.report.empty == ("cam0",) and any("no valid depth" in w for w in res.report.warnings)
    # cam1 gets no votes from the empty camera: omega_geo = c (eq. 21), its points stay
    assert len(res.cloud) > 500 and set(res.cloud.camera.tolist()) == {1}
    allzero = Frame(0, frame.camera_ids, frame.color, torch.zeros_like(depth), frame.present)
    assert len(fuse(allzero, rig)) == 0


def test_single_camera_and_no_overlap_fall_back_to_c():
    one = make_rig([(0.0, 0.0, 0.0)])
    frame = render(one, [Rect(PLANE_Z)], noise=NOISE)
    res = fuse_with_report(frame, one)
    assert res.report.isolated == ("cam0",) and len(res.cloud) > 500
    # no neighbour -> omega_geo = c -> the same cloud as "w/o CVGC"
    assert torch.equal(res.cloud.xyz, fuse(frame, one, ABLATIONS["w/o CVGC"]).xyz)
    far = make_rig([(0.0, 0.0, 0.0), (0.0, 0.0, 1.0)])
    far = far.with_extrinsics({"cam0": look_at((0, 0, 0), (0, 0, -1.0)), "cam1": look_at((0, 0, 1.0), (0, 0, 2.0))})
    fr = render(far, [Rect(PLANE_Z), Rect(-1.5)], noise=NOISE)
    res = fuse_with_report(fr, far)
    assert set(res.report.isolated) == {"cam0", "cam1"}
    assert any("no overlapping neighbour" in w for w in res.report.warnings)
    assert torch.equal(res.cloud.weight, fuse(fr, far, ABLATIONS["w/o CVGC"]).weight)
    assert set(res.cloud.camera.tolist()) == {0, 1}


def test_64_cameras():
    """64 cameras fuse in one call. 80x60 keeps the test fast; at 32x24 (focal ~26 px) a pixel
    spans so much surface that MCM's gradient term marks almost every pixel unreliable."""
    from fuseflow.eval.baselines import naive_fusion
    from fuseflow.synth import SimConfig, Simulator

    sim = Simulator(SimConfig(cameras=64, resolution=(80, 60), frames=1, seed=1))
    sf = sim.render(0)
    res = fuse_with_report(sf.frame, sim.rig)
    assert res.report.views == 64 and len(res.cloud) > 5000 and res.report.isolated == ()
    assert len(set(res.cloud.camera.tolist())) > 48
    d = sim.surface_distance(res.cloud.xyz.numpy(), 0)
    d_naive = sim.surface_distance(naive_fusion(sf.frame, sim.rig).xyz.numpy(), 0)
    # the sensor noise at this resolution is large (disparity noise scales with 1 / f); FUSE
    # selects the reliable points: closer to the surface and fewer beyond 2 cm than naive
    assert np.median(d) < 0.8 * np.median(d_naive)
    assert (d > 0.02).mean() < 0.8 * (d_naive > 0.02).mean()


def test_bad_inputs_raise_clear_errors():
    rig = make_rig([(-0.5, 0.0, 0.0), (0.5, 0.0, 0.0)])
    frame = render(rig, [Rect(PLANE_Z)])
    with pytest.raises(ValidationError, match="extrinsics"):
        fuse(frame, _uncalibrated(rig))
    with pytest.raises(ValidationError, match="Frame"):
        fuse(frame.depth, rig)
    with pytest.raises(ValidationError, match="FuseConfig"):
        fuse(frame, rig, {"tau": 0.1})
    small = make_rig([(-0.5, 0.0, 0.0), (0.5, 0.0, 0.0)], w=40, h=30)
    with pytest.raises(ValidationError, match="40x30"):
        fuse(frame, small)
    other = Frame(0, ("cam0", "camX"), frame.color, frame.depth, frame.present)
    with pytest.raises(ValidationError, match="camX"):
        fuse(other, rig)


def _uncalibrated(rig):
    from fuseflow import Camera, Rig

    return Rig(tuple(Camera(c.id, c.width, c.height, c.K, depth_range=c.depth_range) for c in rig.cameras))
