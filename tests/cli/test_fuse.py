"""`fuseflow fuse` through the CLI on a tiny simulated recording (3 cameras, 160x120, 2 frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from fuseflow.cli import app
from fuseflow.io import read_calibration, read_ply, read_rig, write_calibration, write_rig
from fuseflow.types import Calibration


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from fuseflow.synth import SimConfig, simulate_recording

    out = tmp_path_factory.mktemp("fusecli") / "rec"
    simulate_recording(out, SimConfig(cameras=3, frames=2, resolution=(160, 120), seed=2))
    return out


def test_fuse_writes_one_ply_per_frame_and_a_summary(rec, tmp_path):
    out = tmp_path / "out"
    res = _invoke("fuse", rec, "--out", out)
    assert res.exit_code == 0, res.output
    plys = sorted((out / "clouds").glob("*.ply"))
    assert [p.name for p in plys] == ["000000.ply", "000001.ply"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 2 and summary["backend"] == "numba" and summary["cameras"] == 3
    clouds = [read_ply(p) for p in plys]
    assert summary["points_per_frame"]["mean"] == pytest.approx(np.mean([len(c) for c in clouds]))
    assert min(len(c) for c in clouds) > 1000
    assert set(clouds[0].camera.tolist()) == {0, 1, 2}
    for key in ("frames", "points per frame", "ms per frame"):
        assert key in res.output
    # the PLY holds what fuse() gives for that frame with the CLI's default preset, auto (same
    # extrinsics: rig.json's)
    from fuseflow.fuse import PRESETS, fuse
    from fuseflow.io import open_recording

    recording = open_recording(rec)
    direct = fuse(recording[1], recording.rig, PRESETS["auto"])
    T = np.asarray(read_calibration(out / "calib.json").report["world"]["T_out_world"])  # the floor frame
    back = (clouds[1].xyz.numpy().astype(np.float64) - T[:3, 3]) @ T[:3, :3]
    assert np.allclose(np.sort(direct.xyz.numpy(), axis=0), np.sort(back, axis=0), atol=1e-5)


def test_fuse_with_calib_frames_and_preset(rec, tmp_path):
    rig = read_rig(rec / "rig.json")
    calib = tmp_path / "calib.json"
    # a calibration that places only two of the three cameras: the third is left out
    write_calibration(calib, Calibration({c.id: c.T_cam_world for c in rig.cameras[:2]}, {}))
    out = tmp_path / "out"
    res = _invoke("fuse", rec, "--calib", calib, "--out", out, "--frames", "1:2", "--preset", "w/o CVGC")
    assert res.exit_code == 0, res.output
    assert [p.name for p in (out / "clouds").glob("*.ply")] == ["000001.ply"]
    cloud = read_ply(out / "clouds" / "000001.ply")
    assert set(cloud.camera.tolist()) == {0, 1}
    assert json.loads((out / "summary.json").read_text())["preset"] == "w/o CVGC"


def test_fuse_set_changes_one_setting_over_the_preset(rec, tmp_path):
    from fuseflow.fuse import PRESETS, fuse
    from fuseflow.io import open_recording

    out = tmp_path / "out"
    res = _invoke("fuse", rec, "--out", out, "--frames", "1:2", "--preset", "default", "--set", "rps.k_max=1",
                  "--set", "ash.s0=3", "--world", "calib")  # fmt: skip
    assert res.exit_code == 0, res.output
    cloud = read_ply(out / "clouds" / "000001.ply")
    recording = open_recording(rec)
    cfg = PRESETS["default"].replace(rps={"k_max": 1}, ash={"s0": 3.0})
    direct = fuse(recording[1], recording.rig, cfg)
    assert len(direct) != len(fuse(recording[1], recording.rig, PRESETS["default"]))  # the settings took effect
    assert np.array_equal(np.sort(direct.xyz.numpy(), axis=0), np.sort(cloud.xyz.numpy(), axis=0))
    recorded = json.loads((out / "manifest.json").read_text())["settings"]["fuse"]
    assert recorded["k_max"] == 1 and recorded["s0"] == 3.0 and recorded["k_neighbours"] == 7  # FuseConfig.as_dict


def test_fuse_errors_are_one_line(rec, tmp_path):
    # no extrinsics in rig.json and no --calib
    bare = tmp_path / "bare"
    bare.mkdir()
    rig = read_rig(rec / "rig.json")
    for cam in rig.cameras:
        (bare / cam.id).symlink_to(rec / cam.id)
    from fuseflow.types import Rig

    write_rig(bare, Rig(tuple(c.with_extrinsics(None) for c in rig.cameras)))
    res = _invoke("fuse", bare, "--out", tmp_path / "o")
    assert res.exit_code == 2 and "no extrinsics: run fuseflow calibrate first or pass --calib" in res.output
    for args, msg in (
        (("--frames", "x:y"), "expected A:B[:step]"),
        (("--frames", "5:9"), "selects no frame"),
        (("--device", "tpu"), "--device must be cpu or cuda"),
        (("--preset", "fastest"), "no FUSE preset 'fastest'"),
        (("--set", "rps.kmax=2"), "expected NAME=VALUE with NAME one of"),
        (("--set", "rps.k_max=two"), "--set rps.k_max=two: expected a value like 3"),
        (("--set", "rps.k_max=17"), "FuseConfig.rps.k_max: expected an integer in 1..16"),
        (("--calib", tmp_path / "missing.json"), "missing.json"),
    ):
        res = _invoke("fuse", rec, "--out", tmp_path / "o", *args)
        assert res.exit_code == 2 and msg in res.output, (args, res.output)
        assert "Traceback" not in res.output


def test_fuse_cuda_without_a_gpu_says_so(rec, tmp_path):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    res = _invoke("fuse", rec, "--out", tmp_path / "o", "--device", "cuda")
    assert res.exit_code == 2 and "no CUDA device" in res.output
