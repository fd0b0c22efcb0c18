"""The separately written repeating studio (synth.studio_b, scene 'polyroom'): it repeats exactly
every 360/N deg in geometry and colour, its figure does not, its sensors and rigs, and
``fuseflow simulate --scene polyroom`` writes an ordinary recording with ground truth."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fuseflow.errors import ValidationError
from fuseflow.synth import SimConfig, read_ground_truth, simulate_recording
from fuseflow.synth.studio_b import PolyroomSimulator, polyroom_sensor, polyroom_sides
from fuseflow.types import Camera, Rig


def _look(eye, target):
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ eye
    return T


def _pair(sim: PolyroomSimulator, periods: float) -> Rig:
    """Two cameras 2 m from the centre, ``periods`` room periods apart, each looking outward at the
    wall and floor (away from the figure)."""
    n = sim.layout.sides
    cams = []
    for j, a in enumerate((0.3, 0.3 + 2 * math.pi * periods / n)):
        eye = np.array([2.0 * math.cos(a), 2.0 * math.sin(a), 1.4])
        target = np.array([4.0 * math.cos(a), 4.0 * math.sin(a), 0.6])
        K = np.array([[80.0, 0, 47.5], [0, 80.0, 35.5], [0, 0, 1]])
        cams.append(Camera(f"c{j}", 96, 72, K, T_cam_world=_look(eye, target)))
    return Rig(tuple(cams))


@pytest.mark.parametrize("seed", [0, 5])
def test_polyroom_repeats_exactly_every_period(seed):
    cfg = SimConfig(cameras=2, frames=1, scene="polyroom", noise="none", color_noise=0.0, seed=seed)
    sim = PolyroomSimulator(cfg)
    assert 6 <= sim.layout.sides <= 12 and sim.layout.sides == polyroom_sides(seed)
    sim.rig = _pair(sim, 1)
    sf = sim.render(0)
    d, c = sf.depth_gt.numpy(), sf.frame.color.numpy().astype(float)
    assert (d[0] > 0).all() and np.allclose(d[0], d[1], atol=2e-4)
    # colours equal up to the per-camera channel gains (+-4 %)
    ratio = (c[1] + 1) / (c[0] + 1)
    assert np.median(np.abs(ratio - np.median(ratio, axis=(0, 1)))) < 0.03
    # half a period apart: a different picture of the room
    sim.rig = _pair(sim, 0.5)
    c2 = sim.render(0).frame.color.numpy().astype(float)
    assert np.abs(c2[1] - c2[0]).mean() > 20


def _rz(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


def test_figure_breaks_the_symmetry_and_moves_only_when_dynamic():
    cfg = SimConfig(cameras=5, frames=3, scene="polyroom", noise="none", seed=3)
    sim = PolyroomSimulator(cfg)
    tri, mat, sector = sim.mesh(0)
    fig = tri[sector < 0].reshape(-1, 3)
    n = sim.layout.sides
    R = _rz(2 * math.pi / n)[:3, :3]
    turned = fig @ R.T
    # the turned figure does not land on itself
    dist = np.min(np.linalg.norm(turned[:, None] - fig[None, ::7], axis=2), axis=1)
    assert np.median(dist) > 0.03
    assert np.array_equal(sim.mesh(2)[0], tri) and not sim.moving
    dyn = PolyroomSimulator(replace(cfg, dynamic=True))
    assert dyn.moving and not np.allclose(dyn.mesh(2)[0][sector < 0], dyn.mesh(0)[0][sector < 0])


def test_sensors_and_rings():
    assert polyroom_sensor(SimConfig(scene="polyroom", seed=4)) == "kinect2"
    assert polyroom_sensor(SimConfig(scene="polyroom", seed=5)) == "azure"
    assert polyroom_sensor(SimConfig(scene="polyroom", noise="azure", seed=4)) == "azure"
    with pytest.raises(ValidationError, match="polyroom"):
        PolyroomSimulator(SimConfig(scene="polyroom", noise="realsense"))
    for seed in range(6):
        sim = PolyroomSimulator(SimConfig(cameras=7, frames=1, scene="polyroom", seed=seed, resolution=(64, 48)))
        centres = np.stack([np.linalg.inv(c.T_cam_world)[:3, 3] for c in sim.rig.cameras])
        r = np.linalg.norm(centres[:, :2] - sim.layout.offset, axis=1)
        assert (r > 2.3).all() and (r < 4.2).all()
        gaps = [np.linalg.norm(a - b) for i, a in enumerate(centres) for b in centres[i + 1 :]]
        assert min(gaps) > 0.3  # no two cameras share a spot
        assert {c.sensor for c in sim.rig.cameras} == {"kinect_v2" if seed % 2 == 0 else "azure_kinect"}


def test_simulate_writes_a_recording_with_ground_truth(tmp_path):
    from fuseflow.io import open_recording

    cfg = SimConfig(cameras=5, frames=1, scene="polyroom", seed=7, resolution=(80, 60), surface_density=200.0)
    simulate_recording(tmp_path / "rec", cfg, uncalibrated=True)
    gt = read_ground_truth(tmp_path / "rec")
    assert gt.config.scene == "polyroom" and len(gt.rig) == 5 and gt.rig.is_calibrated
    rec = open_recording(tmp_path / "rec")
    assert not rec.rig.is_calibrated
    f = rec[0]
    assert f.depth.shape == (5, 60, 80) and (f.depth > 0).float().mean() > 0.3
    pts, _ = gt.surface(0)
    assert len(pts) > 100


def test_cli_simulate_polyroom_and_its_noise_check(tmp_path):
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, "-m", "fuseflow", "simulate", *args], capture_output=True, text=True,
                              timeout=300)  # fmt: skip

    bad = run(str(tmp_path / "bad"), "--scene", "polyroom", "--noise", "realsense", "--resolution", "64x48")
    assert bad.returncode == 2 and "polyroom" in bad.stderr and "Traceback" not in bad.stderr
    ok = run(str(tmp_path / "ok"), "--scene", "polyroom", "--cameras", "5", "--num-frames", "1",
             "--resolution", "64x48", "--uncalibrated", "--seed", "3")  # fmt: skip
    assert ok.returncode == 0, ok.stderr
    assert read_ground_truth(tmp_path / "ok").config.scene == "polyroom"
