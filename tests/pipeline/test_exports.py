"""Crop, cloud formats, meshes and the manifest's sequence through `fuse` and `run`."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from fuseflow.cli import app
from fuseflow.geometry.volume import CaptureVolume
from fuseflow.geometry.world import World
from fuseflow.io import read_calibration
from fuseflow.io.exchange import read_cloud
from fuseflow.pipeline import fuse_recording
from fuseflow.pipeline.config import OutputOptions

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("DracoPy")


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from fuseflow.synth import SimConfig, simulate_recording

    out = tmp_path_factory.mktemp("exports") / "rec"
    simulate_recording(out, SimConfig(cameras=4, frames=2, resolution=(160, 120), seed=2, noise="realsense"))
    return out


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_fuse_crop_auto_drc_and_mesh(rec, tmp_path):
    from scipy.spatial import cKDTree

    out = tmp_path / "o"
    opts = OutputOptions(crop="auto", cloud_format="drc", mesh=True, mesh_ply=True)
    s = fuse_recording(rec, out, outputs=opts)
    seq = json.loads((out / "manifest.json").read_text())["sequence"]
    assert [f["index"] for f in seq["frames"]] == [0, 1]
    assert seq["cloud_format"] == "drc" and seq["units"] == "m" and seq["mesh"]["format"] == "glb"
    vol = CaptureVolume.from_json(seq["crop"])  # in the output frame, as the clouds
    cal = read_calibration(out / "calib.json")
    stored = CaptureVolume.from_json(cal.report["capture_volume"])  # in the calibration's world
    assert np.allclose(World.from_json(cal.report["world"]).apply(stored.corners()), vol.corners(), atol=1e-5)
    for f in seq["frames"]:
        cloud = read_cloud(out / f["cloud"])
        assert len(cloud) == f["points"] > 1000
        assert vol.contains(cloud.xyz.numpy()).mean() > 0.999  # Draco moves points by <= 1 mm
        mesh = trimesh.load(out / f["mesh"], force="mesh")
        assert len(mesh.faces) == f["faces"] > 100
        assert (out / f["mesh_ply"]).exists()
        up = World.from_json(cal.report["world"]).gltf_from_out[:3, :3]  # the GLB node turns z up to +y up
        d = cKDTree(cloud.xyz.numpy() @ up.T).query(mesh.vertices)[0]
        assert np.median(d) < 0.02 and d.max() <= 0.032  # trimmed at 3 cm from the points (+ Draco moves them <= 1 mm)
    # the same call resumes; another format is added to the same output; another crop is not
    s2 = fuse_recording(rec, out, outputs=opts)
    assert s2.frames_resumed == 2 and s.points_per_frame == s2.points_per_frame
    r = _invoke("fuse", rec, "--out", out, "--format", "glb", "--crop", "auto", "--mesh", "--mesh-ply")
    assert r.exit_code == 0, r.output
    assert (out / "clouds" / "000001.glb").exists()
    r = _invoke("fuse", rec, "--out", out, "--format", "drc", "--mesh", "--mesh-ply")
    assert r.exit_code == 2 and "settings" in r.output and "crop" in r.output


def test_run_crop_box_glb_and_bad_boxes(rec, tmp_path):
    out = tmp_path / "r"
    r = _invoke("run", rec, "--out", out, "--use-rig", "--crop", "-1,-1,0,1,1,2", "--format", "glb", "--frames", "0:1")
    assert r.exit_code == 0, r.output
    (g,) = trimesh.load(out / "clouds" / "000000.glb").geometry.values()
    assert len(g.vertices) > 100
    assert (np.abs(g.vertices[:, :2]) <= 1).all() and (g.vertices[:, 2] >= 0).all() and (g.vertices[:, 2] <= 2).all()
    seq = json.loads((out / "manifest.json").read_text())["sequence"]
    assert seq["frames"][0]["cloud"] == "clouds/000000.glb" and seq["crop"]["kind"] == "explicit"
    log = [json.loads(x) for x in (out / "frames.jsonl").read_text().splitlines()]
    assert log[0]["points"] == len(g.vertices)
    for bad in ("1,2,3", "0,0,0,1,1,nan", "0,0,5,1,1,1"):
        r = _invoke("fuse", rec, "--out", tmp_path / "bad", "--crop", bad)
        assert r.exit_code == 2 and "--crop" in r.output and len(r.output.strip().splitlines()) == 1, r.output
    r = _invoke("fuse", rec, "--out", tmp_path / "bad", "--format", "obj")
    assert r.exit_code == 2 and "--format" in r.output
