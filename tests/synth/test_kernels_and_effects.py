"""Simulator kernels against their numpy twins; single noise effects; rigs from a file."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.errors import ValidationError
from fuseflow.synth import SimConfig, Simulator
from fuseflow.synth import simulator as S
from fuseflow.synth.noise import apply_depth_noise, apply_depth_noise_ref

SMALL = (160, 120)
ALL_OFF = dict(axial_noise=False, lateral_noise=False, quantization=False, flying_pixels=False,
               grazing_dropout=False, range_dropout=False, random_dropout=False, color_noise=0.0)  # fmt: skip


@pytest.fixture(scope="module")
def studio():
    sim = Simulator(SimConfig(scene="studio", cameras=3, frames=1, resolution=SMALL, noise="kinect", seed=2))
    return sim, sim.render(0)


def _shade_args(sim: Simulator, noise_std: float):
    import open3d as o3d

    rs, _, tri_uv, tex, tint, pid = sim._geometry(0.0)
    hit = rs.cast_rays(o3d.core.Tensor(sim._rays))
    cn = np.random.default_rng(0).standard_normal((len(sim.rig), SMALL[1], SMALL[0], 3), dtype=np.float32)
    return (hit["t_hit"].numpy(), hit["primitive_ids"].numpy(), hit["primitive_uvs"].numpy(),
            hit["primitive_normals"].numpy(), sim._rays, tri_uv, tex, tint, pid, sim.textures, S._LIGHTS,
            S._LIGHT_W, 0.35, cn, noise_std)  # fmt: skip


@pytest.mark.parametrize("noise_std", [0.0, 2.0])
def test_shade_kernel_matches_reference(studio, noise_std):
    sim, _ = studio
    args = _shade_args(sim, noise_std)
    d, th, part, col = S._shade(*args)
    d_r, th_r, part_r, col_r = S._shade_ref(*args)
    assert np.array_equal(d, d_r) and np.array_equal(part, part_r)
    assert (d > 0).mean() > 0.9
    assert np.abs(th - th_r).max() < 1e-3
    diff = np.abs(col.astype(int) - col_r.astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 0.01  # float rounding at .5 only


@pytest.mark.parametrize("noise", ["kinect", "realsense"])
@pytest.mark.parametrize("off", [None, "lateral_noise", "flying_pixels", "quantization"])
def test_depth_noise_kernel_matches_reference(studio, noise, off):
    sim, sf = studio
    cfg = SimConfig(scene="studio", cameras=3, resolution=SMALL, noise=noise, **({off: False} if off else {}))
    gt = sf.depth_gt.numpy()
    th = S._shade(*_shade_args(sim, 0.0))[1]
    a = apply_depth_noise(cfg, gt, th, np.random.default_rng(5))
    b = apply_depth_noise_ref(cfg, gt, th, np.random.default_rng(5))
    assert (a > 0).mean() > 0.3
    assert np.mean(a != b) < 1e-4 and np.abs(a - b).max() <= 1e-3 + 1e-6


def test_flying_pixels_only_at_depth_discontinuities(studio):
    sim, sf = studio
    gt = sf.depth_gt.numpy()
    cfg = SimConfig(
        scene="studio", cameras=3, resolution=SMALL, noise="kinect", seed=2, **{**ALL_OFF, "flying_pixels": True}
    )
    z = Simulator(cfg).render(0).frame.depth.numpy()
    moved = np.abs(z - gt) > 0.6e-3  # beyond the 1 mm output rounding
    assert moved.sum() > 50
    zp = np.pad(gt, ((0, 0), (1, 1), (1, 1)), mode="edge")
    H, W = gt.shape[1:]
    win = np.stack([zp[:, 1 + dy : 1 + dy + H, 1 + dx : 1 + dx + W] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    lo, hi = win.min(0), win.max(0)
    edge = hi - lo > 0.05 * gt
    assert np.all(edge[moved])  # only at discontinuities
    assert np.all((z[moved] >= lo[moved] - 1e-3) & (z[moved] <= hi[moved] + 1e-3))  # mixed depth
    assert 0.3 < moved.sum() / (edge & (gt > 0) & (lo > 0)).sum() < 0.7  # rate 0.5 of the edge pixels


def test_lateral_noise_reads_nearby_pixels(studio):
    sim, sf = studio
    gt = sf.depth_gt.numpy()
    cfg = SimConfig(
        scene="studio", cameras=3, resolution=SMALL, noise="kinect", seed=2, **{**ALL_OFF, "lateral_noise": True}
    )
    z = Simulator(cfg).render(0).frame.depth.numpy()
    assert np.mean(np.abs(z - gt) > 0.6e-3) > 0.01  # some pixels read a neighbour
    # every value is the (mm-rounded) depth of a pixel within 5 px (> 6 sigma of 0.8 px)
    zp = np.pad(gt, ((0, 0), (5, 5), (5, 5)), mode="edge")
    H, W = gt.shape[1:]
    best = np.full(gt.shape, np.inf)
    for dy in range(-5, 6):
        for dx in range(-5, 6):
            best = np.minimum(best, np.abs(zp[:, 5 + dy : 5 + dy + H, 5 + dx : 5 + dx + W] - z))
    assert best.max() <= 0.5e-3 + 1e-6


def test_rig_from_a_file(tmp_path, studio):
    from fuseflow.io import write_rig

    sim, _ = studio
    write_rig(tmp_path, sim.rig)
    again = Simulator(SimConfig(scene="studio", cameras=3, frames=1, noise="none", rig=str(tmp_path / "rig.json")))
    for a, b in zip(again.rig.cameras, sim.rig.cameras):
        assert np.allclose(a.T_cam_world, b.T_cam_world) and np.allclose(a.K, b.K) and a.width == SMALL[0]
    assert again.render(0).depth_gt.shape == (3, SMALL[1], SMALL[0])
    with pytest.raises(ValidationError, match="3 cameras but 4"):
        Simulator(SimConfig(cameras=4, rig=str(tmp_path / "rig.json")))


def test_a_new_noise_model_is_one_definition(monkeypatch):
    """A sensor preset with new AxialNoise coefficients (every term on) is all a new model needs:
    the kernel and the numpy reference both evaluate it, and the depth spread follows sigma_z."""
    from fuseflow.synth import config as C
    from fuseflow.synth.noise import axial_sigma

    model = C.AxialNoise(a=0.002, b=0.001, z0=1.0, c=0.0002, stereo_rms=0.05)
    sensor = C.SensorModel(name="tof", kind="time-of-flight", depth_range=(0.2, 8.0), baseline_m=0.05,
                           disparity_subpixel=0.0, axial=model)  # fmt: skip
    monkeypatch.setitem(C.SENSORS, "tof", sensor)
    cfg = SimConfig(resolution=(64, 48), noise="tof", **{**ALL_OFF, "axial_noise": True})
    z = np.full((4, 48, 64), 3.0, np.float32)
    th = np.full_like(z, 0.5)
    a = apply_depth_noise(cfg, z, th, np.random.default_rng(1))
    b = apply_depth_noise_ref(cfg, z, th, np.random.default_rng(1))
    assert np.mean(a != b) < 1e-3 and np.abs(a - b).max() <= 1e-3 + 1e-6
    want = float(axial_sigma(sensor, np.array([3.0]), np.array([0.5]))[0])
    assert want == pytest.approx(0.002 + 0.001 * 4 + 0.0002 / 3**0.5 * 0.25 / (np.pi / 2 - 0.5) ** 2 + 9 * 0.05 / 29)
    assert np.std(a - 3.0) == pytest.approx(want, rel=0.05)


def test_stereo_term_needs_a_baseline():
    from fuseflow.synth.config import AxialNoise, SensorModel

    with pytest.raises(ValidationError, match="baseline"):
        SensorModel(name="x", kind="stereo", depth_range=(0.1, 5.0), baseline_m=0.0, disparity_subpixel=0.0,
                    axial=AxialNoise(stereo_rms=0.1))  # fmt: skip
