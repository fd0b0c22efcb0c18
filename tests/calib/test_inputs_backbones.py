"""Bad input, unconnected cameras, and the colmap backbone (incl. the N = 2 two-view fallback)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

import fuseflow
from fuseflow import ValidationError
from fuseflow.calib import BackboneResult, CalibConfig, CalibrationError, calibrate


def test_one_camera_is_rejected(scene5, backbone_builder):
    frame, rig, T = scene5
    with pytest.raises(ValidationError, match="at least two cameras"):
        calibrate(frame.subset([0]), rig.subset([0]), backbone_result=backbone_builder(T[:1], 2.0))


def test_camera_without_depth_is_named(scene5, backbone_builder):
    frame, rig, T = scene5
    depth = frame.depth.clone()
    depth[2] = 0
    with pytest.raises(CalibrationError, match="c2"):
        calibrate(replace(frame, depth=depth), rig, backbone_result=backbone_builder(T, 2.0))


def test_camera_without_overlap_is_reported_unconnected(scene_builder, backbone_builder):
    frame, rig, T = scene_builder(6, seed=1)
    depth = frame.depth.clone()
    depth[5] = 0.5  # a camera covered by a board 0.5 m away: nothing it sees matches the others
    cal = calibrate(replace(frame, depth=depth), rig, backbone_result=backbone_builder(T, 3.0))
    assert cal.report["unconnected_cameras"] == ["c5"]
    assert "c5" not in cal.T_cam_world
    assert set(cal.T_cam_world) == {"c0", "c1", "c2", "c3", "c4"}
    assert any("not placed" in w for w in cal.report["warnings"])


def test_backbone_result_validation():
    with pytest.raises(CalibrationError, match="poses must be"):
        BackboneResult(np.eye(4), np.ones(1, bool), name="x")
    with pytest.raises(CalibrationError, match="overlap"):
        BackboneResult(np.tile(np.eye(4), (2, 1, 1)), np.ones(2, bool), overlap=np.eye(3), name="x")


def test_config_validation_and_presets():
    with pytest.raises(ValidationError, match="closed_form"):
        CalibConfig(closed_form="nope")
    with pytest.raises(ValidationError, match="depth_tau"):
        CalibConfig(depth_tau=2.0)
    assert CalibConfig.preset("paper").closed_form == "zonly" and not CalibConfig.preset("paper").refine
    assert CalibConfig.preset("wo_rc").random_correspondences
    with pytest.raises(ValidationError, match="unknown GMAC preset"):
        CalibConfig.preset("bogus")


def test_textureless_images_give_clear_error(scene5):
    frame, rig, _ = scene5
    flat = replace(frame, color=torch.full_like(frame.color, 128))
    with pytest.raises(CalibrationError, match="textureless"):
        calibrate(flat, rig, CalibConfig(backbone="colmap"))


def test_unknown_backbone():
    from fuseflow.calib import get_backbone

    with pytest.raises(CalibrationError, match="unknown backbone"):
        get_backbone("nope")


@pytest.fixture(scope="module")
def icl2(icl_path, tmp_path_factory):
    from typer.testing import CliRunner

    from fuseflow.cli import app as cli_app

    out = tmp_path_factory.mktemp("icl2")

    res = CliRunner().invoke(
        cli_app, ["convert", str(icl_path), str(out / "rec"), "--cameras", "2", "--every", "15", "--force"]
    )
    assert res.exit_code == 0, res.output
    return out / "rec"


def test_colmap_two_cameras_end_to_end(icl2):
    """N = 2: COLMAP's mappers refuse 2-image models; the two-view relative pose is used."""
    from fuseflow.eval.metrics import pose_errors

    icl2 = fuseflow.open_recording(icl2)
    rig = icl2.rig
    bare = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rig))
    cal = calibrate(icl2[0], bare, CalibConfig(backbone="colmap"))
    assert cal.report["backbone_info"]["mode"] == "two-view"
    assert set(cal.T_cam_world) == set(rig.ids)
    assert cal.report["cycle_mode"] == "single"
    err = pose_errors(cal.T_cam_world, {c.id: c.T_cam_world for c in rig})
    # reference poses are ~1 cm accurate; the notes measured 0.28 deg on this pair
    assert err.rotation_deg < 1.0
    assert err.translation_mm < 30.0


def test_cli_calibrate_writes_calibration(icl2, tmp_path):
    from typer.testing import CliRunner

    from fuseflow.cli import app as cli_app

    out = tmp_path / "calib.json"
    res = CliRunner().invoke(cli_app, ["calibrate", str(icl2), "--out", str(out), "--preset", "paper"])
    assert res.exit_code == 0, res.output
    cal = fuseflow.read_calibration(out)
    assert set(cal.T_cam_world) == {"cam00", "cam01"}
    assert cal.report["closed_form"] == "zonly" and "s* =" in res.output
    assert "verdicts:" in res.output and "0 unplaced" in res.output
    bad = CliRunner().invoke(cli_app, ["calibrate", str(icl2), "--out", str(out), "--frame", "5"])
    assert bad.exit_code != 0 and "out of range" in bad.output


def test_wrong_backbone_pose_is_never_placed_silently(scene_builder, backbone_builder):
    """A backbone that registers a camera 40 deg off (what COLMAP did on a simulated studio
    seed): GMAC either leaves it out or names it in suspect_cameras with a warning; a right
    calibration of the same scene has no suspect and agreement above the threshold."""
    from scipy.spatial.transform import Rotation

    frame, rig, T = scene_builder(6, seed=1)
    good = calibrate(frame, rig, backbone_result=backbone_builder(T, 3.0))
    assert good.report["suspect_cameras"] == []
    assert min(v for v in good.report["depth_agreement"].values() if v is not None) > 0.8
    bb = backbone_builder(T, 3.0)
    T0 = bb.T_cam_world.copy()
    C = -T0[2, :3, :3].T @ T0[2, :3, 3]
    T0[2, :3, :3] = Rotation.from_euler("y", 40, degrees=True).as_matrix() @ T0[2, :3, :3]
    T0[2, :3, 3] = -T0[2, :3, :3] @ C
    cal = calibrate(frame, rig, backbone_result=BackboneResult(T0, bb.registered, name="wrong"))
    placed_silently = "c2" in cal.T_cam_world and "c2" not in cal.report["suspect_cameras"]
    assert not placed_silently, cal.report["depth_agreement"]
    if "c2" in cal.T_cam_world:
        assert any("disagree with their neighbours' depth" in w for w in cal.report["warnings"])
    with pytest.raises(ValidationError, match="min_depth_agreement"):
        CalibConfig(min_depth_agreement=1.5)


def test_scale_warnings_name_edges_by_camera_id():
    from fuseflow.calib.report import edge_names

    ids = ("left", "mid", "right", "top", "cam4")
    assert (
        edge_names("edges [(0, 4), (2, 3)] have fewer than 50", ids)
        == "edges [left-cam4, right-top] have fewer than 50"
    )
    assert edge_names("no edge here (scale 1.5)", ids) == "no edge here (scale 1.5)"
