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
