"""The simulator against the properties its ground truth promises."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fuseflow.errors import ValidationError
from fuseflow.synth import SimConfig, Simulator, visible_mask
from fuseflow.synth.noise import axial_sigma, quantization_step
from fuseflow.synth.simulator import visible_mask_ref
from fuseflow.synth.texture import make_textures, sample_texture, sample_texture_ref
from fuseflow.types import check_rigid

SMALL = (160, 120)


def _sim(**kw) -> Simulator:
    kw.setdefault("resolution", SMALL)
    return Simulator(SimConfig(**kw))


@pytest.fixture(scope="module")
def studio_clean():
    sim = _sim(scene="studio", cameras=8, frames=2, noise="none", seed=3)
    return sim, sim.render(0)


# --------------------------------------------------------------------------- noise statistics


def _wall_residuals(noise: str, **switches) -> tuple[np.ndarray, np.ndarray]:
    cfg = SimConfig(scene="wall", cameras=1, frames=6, resolution=SMALL, noise=noise, seed=5, lateral_noise=False,
                    flying_pixels=False, grazing_dropout=False, random_dropout=False, color_noise=0.0, **switches)  # fmt: skip
    sim = Simulator(cfg)
    res, expected = [], []
    for t in range(cfg.frames):
        sf = sim.render(t)
        d, g = sf.frame.depth.numpy()[0], sf.depth_gt.numpy()[0]
        ok = d > 0
        res.append((d - g)[ok])
        expected.append(g[ok])
    return np.concatenate(res), np.concatenate(expected)


@pytest.mark.parametrize("noise", ["kinect", "realsense"])
@pytest.mark.parametrize("quantization", [False, True])
def test_axial_sigma_at_2m_matches_the_published_formula(noise, quantization):
    res, z = _wall_residuals(noise, quantization=quantization)
    assert np.allclose(z, 2.0, atol=1e-5)  # the wall is fronto-parallel at 2 m
    assert len(res) > 0.99 * 6 * SMALL[0] * SMALL[1]
    sensor = SimConfig(noise=noise).sensor
    # incidence angle is at most ~31 deg off-axis; its term is < 2 % of sigma, included exactly
    want = float(axial_sigma(sensor, np.array([2.0]), np.array([0.0]))[0])
    got = float(res.std())
    assert abs(got / want - 1) < 0.10, (got, want)
    assert abs(res.mean()) < 0.2 * want  # unbiased


def test_sigma_formula_values():
    from fuseflow.synth import KINECT_V1, REALSENSE_D435

    # Nguyen et al. 2012 at 2 m: 0.0012 + 0.0019 * 1.6^2 = 6.064 mm
    assert axial_sigma(KINECT_V1, np.array([2.0]), np.array([0.0]))[0] == pytest.approx(0.006064)
    # Intel: 2^2 * 0.08 / (385 * 0.05) = 16.6 mm
    assert axial_sigma(REALSENSE_D435, np.array([2.0]), np.array([0.0]))[0] == pytest.approx(4 * 0.08 / 19.25)
    assert quantization_step(KINECT_V1, np.array([2.0]))[0] == pytest.approx(4 / 8 / (580 * 0.075))


def test_each_effect_switches_off():
    base = dict(scene="studio", cameras=2, frames=1, noise="kinect", seed=2)
    ref = _sim(**base).render(0)
    gt = ref.depth_gt.numpy()
    off = dict(axial_noise=False, lateral_noise=False, quantization=False, flying_pixels=False,
               grazing_dropout=False, range_dropout=False, random_dropout=False, color_noise=0.0)  # fmt: skip
    clean = _sim(**base, **off).render(0).frame.depth.numpy()
    # everything off: only the 1 mm output units remain
    assert np.abs(clean - gt).max() <= 0.5e-3 + 1e-6
    noisy = ref.frame.depth.numpy()
    assert (np.abs(noisy - gt) > 2e-3).mean() > 0.2
    # range dropout alone removes exactly the pixels beyond the sensor range
    only_range = _sim(**base, **{**off, "range_dropout": True}).render(0).frame.depth.numpy()
    far = gt > 4.5
    assert far.any() and np.all(only_range[far] == 0) and np.all(only_range[(gt > 0.4) & ~far] > 0)
    # random dropout alone drops ~0.5 % of the pixels
    only_drop = _sim(**base, **{**off, "random_dropout": True}).render(0).frame.depth.numpy()
    rate = ((only_drop == 0) & (gt > 0)).sum() / (gt > 0).sum()
    assert 0.002 < rate < 0.01


def test_grazing_surfaces_lose_depth(studio_clean):
    cfg = SimConfig(scene="studio", cameras=8, frames=1, resolution=SMALL, seed=3, noise="kinect", axial_noise=False,
                    lateral_noise=False, flying_pixels=False, random_dropout=False, range_dropout=False)  # fmt: skip
    sim = Simulator(cfg)
    depth = sim.render(0).frame.depth.numpy()
    gt = studio_clean[1].depth_gt.numpy()
    lost = (depth == 0) & (gt > 0)
    assert lost.any() and lost.mean() < 0.2


# --------------------------------------------------------------------------- geometry


def test_noise_free_depth_back_projects_onto_the_surface(studio_clean):
    sim, sf = studio_clean
    d = sf.depth_gt.numpy()
    dists = []
    for i, cam in enumerate(sim.rig.cameras):
        v, u = np.nonzero(d[i] > 0)
        z = d[i][v, u].astype(np.float64)
        X = (np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(cam.K).T) * z[:, None]
        Xw = X @ cam.T_world_cam[:3, :3].T + cam.T_world_cam[:3, 3]
        dists.append(sim.surface_distance(Xw, 0))
    dist = np.concatenate(dists)
    # float32 rays and Embree's float32 intersection: typical error ~1e-7 relative, the worst
    # pixels (grazing, triangle edges) ~2e-5 relative at 2-3 m
    assert np.median(dist) < 1e-6 and np.percentile(dist, 99) < 3e-5 and dist.max() < 1e-4


def test_noise_free_frame_equals_depth_gt(studio_clean):
    _, sf = studio_clean
    assert np.array_equal(sf.frame.depth.numpy(), sf.depth_gt.numpy())


def test_extrinsics_are_rigid_camera_from_world(studio_clean):
    sim, sf = studio_clean
    d = sf.depth_gt.numpy()
    sim_all = Simulator(SimConfig(scene="studio", cameras=8, frames=1, resolution=SMALL, noise="none", seed=3,
                                  surface_visible_only=False))  # fmt: skip
    sf_all = sim_all.render(0)
    pts_all = sf_all.surface_points.numpy().astype(np.float64)
    nrm_all = sf_all.surface_normals.numpy().astype(np.float64)
    for i, cam in enumerate(sim.rig.cameras):
        centre = cam.T_world_cam[:3, 3]
        pts = pts_all[((centre - pts_all) * nrm_all).sum(1) > 0]  # surface facing this camera
        check_rigid(cam.T_cam_world)
        for T, expect_hits in ((cam.T_cam_world, True), (cam.T_world_cam, False)):
            Xc = pts @ T[:3, :3].T + T[:3, 3]
            z = Xc[:, 2]
            front = z > 0.1
            uv = (Xc[front] @ cam.K.T)[:, :2] / z[front, None]
            u, v = np.rint(uv[:, 0]).astype(int), np.rint(uv[:, 1]).astype(int)
            inside = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
            dz = d[i][v[inside], u[inside]] - z[front][inside]
            share = (np.abs(dz) < 0.01).mean() if inside.any() else 0.0
            # a surface point projects where the renderer put that surface (unless occluded)
            if expect_hits:
                assert share > 0.25, (cam.id, share)
            else:
                assert share < 0.05, (cam.id, share)


def test_visible_mask_kernel_matches_reference(studio_clean):
    sim, sf = studio_clean
    rng = np.random.default_rng(0)
    pts = rng.uniform([-3, -3, 0], [3, 3, 2], (4000, 3))
    nrm = rng.standard_normal((4000, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    surf = sf.surface_points.numpy()[:4000].astype(np.float64)
    snrm = sf.surface_normals.numpy()[:4000].astype(np.float64)
    P, Nn = np.concatenate([pts, surf]), np.concatenate([nrm, snrm])
    a = visible_mask(P, Nn, sf.depth_gt.numpy(), sim.rig)
    b = visible_mask_ref(P, Nn, sf.depth_gt.numpy(), sim.rig)
    assert np.array_equal(a, b) and a[4000:].all()


def test_texture_kernel_matches_reference():
    tex = make_textures(0, count=2, size=64)
    rng = np.random.default_rng(1)
    uv = rng.uniform(-5, 5, (1000, 2)).astype(np.float32)
    ids = rng.integers(0, 2, 1000)
    assert np.allclose(sample_texture(tex, ids, uv), sample_texture_ref(tex, ids, uv), atol=1e-4)


def test_surface_samples_are_on_the_surface_with_unit_normals(studio_clean):
    sim, sf = studio_clean
    pts = sf.surface_points.numpy()
    n = sf.surface_normals.numpy()
    assert len(pts) > 10000 and pts.dtype == np.float32
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-4)
    sel = np.random.default_rng(0).choice(len(pts), 3000, replace=False)
    assert sim.surface_distance(pts[sel], 0).max() < 1e-4


# --------------------------------------------------------------------------- rigs and overlap


@pytest.mark.parametrize("scene", ["studio", "room"])
def test_ring_overlap_and_baselines_as_configured(scene):
    sim = _sim(scene=scene, cameras=8, frames=1, noise="none", seed=1)
    ov = sim.pairwise_overlap(0)
    C = np.stack([c.T_world_cam[:3, 3] for c in sim.rig.cameras])
    for i in range(8):
        j = (i + 1) % 8
        assert 0.3 <= ov[i, j] <= 0.9 and 0.3 <= ov[j, i] <= 0.9, (i, j, ov[i, j], ov[j, i])
        assert 0.5 <= np.linalg.norm(C[i] - C[j]) <= 3.0


@pytest.mark.parametrize("n", [1, 2, 24, 64])
def test_rig_sizes_and_dome(n):
    sim = _sim(scene="studio", cameras=n, frames=1, noise="none", seed=0, resolution=(64, 48))
    assert len(sim.rig) == n and len(set(sim.rig.ids)) == n
    C = np.stack([c.T_world_cam[:3, 3] for c in sim.rig.cameras])
    target = sim.scene.target
    for cam in sim.rig.cameras:  # looking inward: the target is in front, near the image centre
        Xc = cam.T_cam_world[:3, :3] @ target + cam.T_cam_world[:3, 3]
        assert Xc[2] > 1.0
        u, v = (cam.K @ Xc)[:2] / Xc[2]
        assert abs(u - cam.width / 2) < 0.25 * cam.width and abs(v - cam.height / 2) < 0.25 * cam.height
    if n >= 24:
        dist = np.linalg.norm(C[:, None] - C[None], axis=-1) + np.eye(n) * 99
        assert 0.3 <= dist.min(1).min() and dist.min(1).max() <= 3.0
        assert np.ptp(C[:, 2]) > 1.0  # several elevations
        sf = sim.render(0)
        ov = Simulator(
            SimConfig(scene="studio", cameras=n, frames=1, noise="none", resolution=(96, 72))
        ).pairwise_overlap(0)
        best = (ov - np.eye(n)).max(1)
        assert np.all(best >= 0.3), best
        assert sf.depth_gt.shape == (n, 48, 64)


# --------------------------------------------------------------------------- dynamic scenes, determinism


def test_dynamic_frames_differ_where_objects_move_and_nowhere_else():
    sim = _sim(scene="studio", cameras=4, frames=3, dynamic=True, noise="none", seed=4)
    moving_parts = np.array([p.moving for p in sim.scene.parts] + [False])  # index -1 -> False
    prev = sim.render(0)
    for t in (1, 2):
        sf = sim.render(t)
        a, b = prev.depth_gt.numpy(), sf.depth_gt.numpy()
        changed = (a != b) | np.any(prev.frame.color.numpy() != sf.frame.color.numpy(), -1)
        mov = moving_parts[prev.part_id.numpy()] | moving_parts[sf.part_id.numpy()]
        assert changed.sum() > 100  # every frame differs
        assert not np.any(changed & ~mov)  # static pixels identical
        prev = sf
    static = _sim(scene="studio", cameras=2, frames=2, noise="none", seed=4)
    assert np.array_equal(static.render(0).frame.color.numpy(), static.render(1).frame.color.numpy())


def test_deterministic_for_a_seed():
    a = _sim(scene="room", cameras=3, frames=2, dynamic=True, seed=7).render(1)
    b = _sim(scene="room", cameras=3, frames=2, dynamic=True, seed=7).render(1)
    c = _sim(scene="room", cameras=3, frames=2, dynamic=True, seed=8).render(1)
    assert np.array_equal(a.frame.depth.numpy(), b.frame.depth.numpy())
    assert np.array_equal(a.frame.color.numpy(), b.frame.color.numpy())
    assert np.array_equal(a.surface_points.numpy(), b.surface_points.numpy())
    assert not np.array_equal(a.frame.color.numpy(), c.frame.color.numpy())


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"cameras": 0}, "cameras"),
        ({"cameras": 65}, "cameras"),
        ({"scene": "moon"}, "scene"),
        ({"resolution": (640,)}, "resolution"),
        ({"resolution": (0, 480)}, "resolution"),
        ({"noise": "kinect9"}, "noise"),
        ({"frames": 0}, "frames"),
        ({"calib_error_deg": -1.0}, "calib_error_deg"),
        ({"rig": "/nonexistent/rig.json"}, "rig"),
    ],
)
def test_bad_config_is_a_clear_error(kw, word):
    with pytest.raises(ValidationError, match=word):
        Simulator(SimConfig(**{"resolution": SMALL, **kw}))


def test_bad_frame_index(studio_clean):
    sim, _ = studio_clean
    with pytest.raises(ValidationError, match="frame index"):
        sim.render(2)


_ = math


def test_observable_mask_drops_visible_points_beyond_the_depth_range():
    """The reference surface for scoring a fused cloud: visible AND measurable (depth_range:
    0.4-4.5 m with the Kinect model; the studio's walls are 5-8 m from some cameras)."""
    from fuseflow.synth import observable_mask

    sim = _sim(scene="studio", cameras=8, frames=1, noise="kinect", seed=3)
    sf = sim.render(0)
    P = sf.surface_points.numpy().astype(np.float64)
    Nn = sf.surface_normals.numpy().astype(np.float64)
    vis = visible_mask(P, Nn, sf.depth_gt.numpy(), sim.rig)
    obs = observable_mask(P, Nn, sf.depth_gt.numpy(), sim.rig)
    assert not (obs & ~vis).any()
    assert 0.1 * vis.sum() < obs.sum() < 0.9 * vis.sum()  # the studio's far walls drop out (25 % kept)
    # every kept point is within some camera's depth range (z-depth, with the 1 cm + 1 % tolerance)
    z = np.stack([P @ c.T_cam_world[2, :3] + c.T_cam_world[2, 3] for c in sim.rig])
    hi = np.array([c.depth_range[1] for c in sim.rig])[:, None]
    near = ((z > 0) & (z <= hi * 1.01 + 0.01)).any(0)
    assert near[obs].all()
