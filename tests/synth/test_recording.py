"""`fuseflow simulate` and simulate_recording / read_ground_truth end to end."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

import fuseflow.cli  # noqa: F401  (registers the commands)
from fuseflow.cli.app import app
from fuseflow.errors import RecordingError, ValidationError
from fuseflow.io import open_recording
from fuseflow.synth import SimConfig, Simulator, read_ground_truth, simulate_recording

runner = CliRunner()


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "r"
    res = runner.invoke(app, ["simulate", str(out), "--cameras", "8", "--num-frames", "10", "--seed", "1",
                              "--resolution", "96x72"])  # fmt: skip
    assert res.exit_code == 0, res.output
    return out


def test_cli_recording_is_readable_by_info(rec):
    res = runner.invoke(app, ["info", str(rec), "--json"])
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    assert s["frames"] == 10 and s["cameras"] == 8 and s["resolution"] == [96, 72] and s["calibrated"]
    assert s["missing_views"] == {}


def test_ground_truth_files(rec):
    doc = json.loads((rec / "gt.json").read_text())
    assert doc["format"] == "fuseflow-gt/1" and len(doc["cameras"]) == 8
    for t in range(10):
        assert (rec / "gt" / f"surface_{t:06d}.ply").is_file()
    gt = read_ground_truth(rec)
    sim = Simulator(SimConfig(cameras=8, frames=10, seed=1, resolution=(96, 72)))
    for a, b in zip(gt.rig.cameras, sim.rig.cameras):
        assert np.allclose(a.T_cam_world, b.T_cam_world, atol=1e-12) and np.allclose(a.K, b.K)
    sf = sim.render(3)
    d = gt.depth(3).numpy()
    assert d.shape == (8, 72, 96) and d.dtype == np.float32
    assert np.abs(d - sf.depth_gt.numpy()).max() <= 0.5e-3 + 1e-6  # 1 mm units
    pts, nrm = gt.surface(3)
    assert np.array_equal(pts, sf.surface_points.numpy()) and np.array_equal(nrm, sf.surface_normals.numpy())
    frame = open_recording(rec)[3]
    assert np.array_equal(frame.color.numpy(), sf.frame.color.numpy())
    assert np.allclose(frame.depth.numpy(), sf.frame.depth.numpy(), atol=1e-6)
    with pytest.raises(ValidationError, match="frame index"):
        gt.depth(10)


def test_surface_ply_is_open3d_readable(rec):
    o3d = pytest.importorskip("open3d")
    pcd = o3d.io.read_point_cloud(str(rec / "gt" / "surface_000000.ply"))
    pts, nrm = read_ground_truth(rec).surface(0)
    assert len(pcd.points) == len(pts) and pcd.has_normals()
    assert np.allclose(np.asarray(pcd.points), pts, atol=1e-6)
    assert np.allclose(np.asarray(pcd.normals), nrm, atol=1e-6)


def test_uncalibrated_and_injected_calibration_error(tmp_path):
    cfg = SimConfig(cameras=3, frames=1, resolution=(48, 36), seed=2)
    u = simulate_recording(tmp_path / "u", cfg, uncalibrated=True)
    assert not open_recording(u).rig.is_calibrated
    assert read_ground_truth(u).rig.is_calibrated
    cfg_e = SimConfig(cameras=3, frames=1, resolution=(48, 36), seed=2, calib_error_deg=0.5, calib_error_mm=10.0)
    e = simulate_recording(tmp_path / "e", cfg_e)
    written = open_recording(e).rig
    true = read_ground_truth(e).rig
    for a, b in zip(written.cameras, true.cameras):
        dR = a.T_cam_world[:3, :3] @ b.T_cam_world[:3, :3].T
        ang = math.degrees(math.acos(np.clip((np.trace(dR) - 1) / 2, -1, 1)))
        assert ang == pytest.approx(0.5, abs=1e-6)
        assert np.linalg.norm(a.T_world_cam[:3, 3] - b.T_world_cam[:3, 3]) * 1000 == pytest.approx(10.0, abs=1e-6)
    with pytest.raises(RecordingError, match="already holds"):
        simulate_recording(e, cfg_e)


@pytest.mark.parametrize(
    "args, word",
    [
        (["--cameras", "0"], "cameras"),
        (["--scene", "moon"], "scene"),
        (["--resolution", "640by480"], "--resolution"),
        (["--noise", "lidar"], "noise"),
    ],
)
def test_cli_bad_input_is_a_clear_error(tmp_path, args, word):
    res = runner.invoke(app, ["simulate", str(tmp_path / "x"), "--num-frames", "1", *args])
    assert res.exit_code != 0
    message = str(res.exception) if isinstance(res.exception, ValidationError) else res.output
    assert word in message
    assert not (tmp_path / "x" / "rig.json").exists()


def test_cli_disable_switches_effects_off(tmp_path):
    out = tmp_path / "clean"
    res = runner.invoke(app, ["simulate", str(out), "--cameras", "2", "--num-frames", "1", "--resolution", "48x36",
                              "--disable", "axial_noise,lateral_noise,quantization,flying_pixels,grazing_dropout,"
                              "range_dropout,random_dropout,color_noise"])  # fmt: skip
    assert res.exit_code == 0, res.output
    gt = read_ground_truth(out)
    assert not gt.config.axial_noise and gt.config.color_noise == 0.0
    # every effect off: the sensor depth is the noise-free depth (both in whole mm; a value on a
    # half-mm boundary may round either way)
    d, g = open_recording(out)[0].depth.numpy(), gt.depth(0).numpy()
    assert np.abs(d - g).max() <= 1e-3 + 1e-6 and np.mean(d != g) < 0.01
    res = runner.invoke(app, ["simulate", str(tmp_path / "x"), "--num-frames", "1", "--disable", "blur"])
    assert res.exit_code != 0 and "unknown effect 'blur'" in res.output
