"""`fuseflow calibrate`: --backbone rgbd (metric, scale check), --frames A:B[:step], bad specs."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

import fuseflow
from fuseflow.cli import app as cli_app


@pytest.fixture(scope="module")
def ring_rec(tmp_path_factory):
    """A 3-camera room ring, 320x240 (rgbd needs the floor texture this resolution keeps)."""
    from fuseflow.synth import SimConfig, simulate_recording

    out = tmp_path_factory.mktemp("ring") / "rec"
    simulate_recording(out, SimConfig(cameras=3, frames=3, scene="room", resolution=(320, 240), seed=2))
    return out


def test_calibrate_rgbd_over_frames(ring_rec, tmp_path):
    out = tmp_path / "c.json"
    args = ["calibrate", str(ring_rec), "--out", str(out), "--backbone", "rgbd", "--frames", "0:4:2"]
    res = CliRunner().invoke(cli_app, args)
    assert res.exit_code == 0, res.output
    assert "2 frames (0..2)" in res.output and "backbone rgbd" in res.output
    assert "(check)" in res.output
    assert "time per stage: backbone " in res.output and "(prepare " in res.output, res.output
    cal = fuseflow.read_calibration(out)
    assert cal.report["backbone"] == "rgbd" and cal.report["scale"] == 1.0 and cal.report["scale_check"] > 0
    assert cal.report["backbone_info"]["frames"] == 2
    assert set(cal.report["placed_by"]) == set(cal.T_cam_world)


def test_bad_frames_spec_fails_in_one_line(static_rec, tmp_path):
    out = tmp_path / "c.json"
    for spec, msg in (("3", "expected A:B"), ("a:b", "expected A:B"), ("10:20", "selects no frame"), ("0:4:0", "step")):
        res = CliRunner().invoke(cli_app, ["calibrate", str(static_rec), "--out", str(out), "--frames", spec])
        assert res.exit_code == 2 and msg in res.output, (spec, res.output)
    assert not out.exists()


def test_calibrate_prints_verdicts_progress_reference_and_writes_the_picture(ring_rec, tmp_path):
    """Piped (CliRunner): progress as plain lines; the verdict table; --reference rig.json (the
    simulator's truth) as a per-camera table stored in the report; <stem>.png beside calib.json."""
    import cv2

    from fuseflow.viz.calib_picture import PICTURE_SIZE

    out = tmp_path / "c.json"
    args = [
        "calibrate",
        str(ring_rec),
        "--out",
        str(out),
        "--backbone",
        "rgbd",
        "--reference",
        str(ring_rec / "rig.json"),
    ]
    res = CliRunner().invoke(cli_app, args)
    assert res.exit_code == 0, res.output
    assert "calibrate: rgbd: cameras: 3/3" in res.output and "calibrate: rgbd: pairs: 3/3" in res.output
    assert "calibrate: report" in res.output
    assert "verdicts: 3 good, 0 check it, 0 unplaced" in res.output, res.output
    r = fuseflow.read_calibration(out).report
    assert set(r["camera_verdicts"]) == {"cam00", "cam01", "cam02"}
    assert all(v["verdict"] == "good" and v["cycles"] == 1 for v in r["camera_verdicts"].values())
    ref = r["reference"]
    assert ref["source"] == str(ring_rec / "rig.json") and set(ref["cameras"]) == {"cam00", "cam01", "cam02"}
    assert ref["max_rotation_deg"] < 1.0 and ref["max_position_mm"] < 30.0, ref  # the truth, aligned
    assert "difference to the reference" in res.output and "position (mm)" in res.output
    png = out.with_suffix(".png")
    assert f"wrote {out} and {png}" in res.output.replace("\n", "")
    img = cv2.imread(str(png))
    assert img.shape[:2] == (PICTURE_SIZE[1], PICTURE_SIZE[0]) and img.std() > 20


def _write_ref(path, T, fingerprint_rig=None):
    fuseflow.write_calibration(path, fuseflow.Calibration(T, {}), rig=fingerprint_rig)
    return path


@pytest.mark.parametrize(
    "case", ["absent", "not-json", "other-format", "other-rig", "missing", "intrinsics", "no-extrinsics"]
)
def test_bad_reference_fails_in_one_line_before_gmac(static_rec, tmp_path, case):
    import dataclasses
    import json

    import numpy as np

    rig = fuseflow.read_rig(static_rec / "rig.json")
    T = {c.id: c.T_cam_world for c in rig.cameras}
    ref = tmp_path / "ref.json"
    if case == "not-json":
        ref.write_text("{not json")
    elif case == "other-format":
        ref.write_text(json.dumps({"format": "vendor/2", "cameras": {}}))
    elif case == "other-rig":
        _write_ref(ref, {f"x{k}": np.eye(4) for k in range(3)})
    elif case == "missing":
        _write_ref(ref, {c: T[c] for c in list(T)[:2]})
    elif case == "intrinsics":
        scaled = np.diag([1.2, 1.2, 1.0])  # another camera model: fx, fy, cx, cy 20 % off
        cams = tuple(dataclasses.replace(c, K=scaled @ c.K) for c in rig.cameras)
        _write_ref(ref, T, fuseflow.Rig(cams))
    elif case == "no-extrinsics":
        fuseflow.write_rig(tmp_path, fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rig.cameras)))
        ref = tmp_path / "rig.json"
    out = tmp_path / "c.json"
    res = CliRunner().invoke(cli_app, ["calibrate", str(static_rec), "--out", str(out), "--reference", str(ref)])
    expect = {
        "absent": "ref.json",
        "not-json": "invalid JSON",
        "other-format": "not a calibration",
        "other-rig": "another rig",
        "missing": "missing from it",
        "intrinsics": "made for another rig",
        "no-extrinsics": "no 'T_cam_world'",
    }[case]
    assert res.exit_code == 2 and expect in res.output, res.output
    assert "Traceback" not in res.output and "calibrate: " not in res.output  # before GMAC started
    assert not out.exists()


def test_default_frame_is_the_first_with_every_camera(ring_rec, tmp_path):
    """A camera whose stream starts late (no view in frame 0): the default calibrates on the first
    frame with every camera and places all three; an explicit --frame 0 names the absent camera
    and the frame to use before GMAC runs."""
    import shutil

    rec = tmp_path / "rec"
    shutil.copytree(ring_rec, rec)
    for kind in ("color", "depth"):
        next((rec / "cam02" / kind).glob("000000.*")).unlink()
    out = tmp_path / "c.json"
    res = CliRunner().invoke(cli_app, ["calibrate", str(rec), "--out", str(out), "--backbone", "rgbd"])
    assert res.exit_code == 0, res.output
    assert "calibrating on frame 1, the first with every camera present" in " ".join(res.output.split())
    assert len(fuseflow.read_calibration(out).T_cam_world) == 3
    res = CliRunner().invoke(cli_app, ["calibrate", str(rec), "--out", str(out), "--frame", "0"])
    text = " ".join(res.output.split())
    assert "cameras ['cam02'] have no view in the frames to calibrate from" in text, res.output
    assert "(--frame 1)" in text
    assert "not 'good' from one frame; --frames 0:3 pools 3 frames" in text  # cam02 is left unplaced


def test_default_pools_frames_when_one_frame_places_too_few(ring_rec, tmp_path, monkeypatch):
    """No --frame/--frames: a first frame that places too few cameras (here: a GMAC that fails on
    any single frame) makes calibrate pool the recording's frames, spread over it, and say so;
    an explicit --frame does not pool and fails as GMAC does."""
    import fuseflow.calib as calib_mod
    from fuseflow.calib import CalibrationError

    real, calls = calib_mod.calibrate, []

    def one_frame_fails(views, rig, config, progress=None):
        calls.append([v.index for v in views])
        if len(views) == 1:
            raise CalibrationError("the backbone placed fewer than two cameras")
        return real(views, rig, config, progress=progress)

    monkeypatch.setattr(calib_mod, "calibrate", one_frame_fails)
    out = tmp_path / "c.json"
    args = ["calibrate", str(ring_rec), "--out", str(out), "--backbone", "rgbd"]
    res = CliRunner().invoke(cli_app, args)
    assert res.exit_code == 0, res.output
    assert calls == [[0], [0, 1, 2]], calls
    assert (
        "one frame placed too few cameras" in res.output
        and "pooling 3 frames spread over the recording (0..2)" in res.output
    )
    assert fuseflow.read_calibration(out).report["backbone_info"]["frames"] == 3
    calls.clear()
    res = CliRunner().invoke(cli_app, [*args, "--frame", "1"])
    assert res.exit_code == 2 and "fewer than two cameras" in res.output and calls == [[1]], res.output


def test_default_pooling_that_also_fails_names_both_attempts(ring_rec, tmp_path, monkeypatch):
    """No --frame/--frames: when the one frame raises and the pooled frames raise too, the one
    error line says that pooling ran and why each attempt failed (exit 2, no traceback)."""
    import fuseflow.calib as calib_mod
    from fuseflow.calib import CalibrationError

    calls = []

    def always_fails(views, rig, config, progress=None):
        calls.append(len(views))
        raise CalibrationError(f"nothing placed from {len(views)} frame(s)")

    monkeypatch.setattr(calib_mod, "calibrate", always_fails)
    res = CliRunner().invoke(cli_app, ["calibrate", str(ring_rec), "--out", str(tmp_path / "c.json")])
    text = " ".join(res.output.split())
    assert res.exit_code == 2 and calls == [1, 3], (calls, res.output)
    assert "nothing placed from 1 frame(s)" in text and "3 pooled frames also failed: nothing placed from 3" in text
    assert "Traceback" not in res.output
