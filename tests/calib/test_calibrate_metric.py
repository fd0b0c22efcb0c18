"""calibrate() with a metric backbone (scale 1, GMAC's closed form as a check), several frames,
and frames whose views are all dropped."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from fuseflow.calib import BackboneResult, CalibConfig, CalibrationError, CalibReport, calibrate
from fuseflow.errors import ValidationError
from fuseflow.eval.metrics import pose_errors
from fuseflow.types import Rig


def _metric(T_true: np.ndarray, factor: float = 1.0) -> BackboneResult:
    T0 = T_true.copy()
    T0[:, :3, 3] *= factor
    return BackboneResult(T0, np.ones(len(T0), bool), name="metric-test", metric=True)


def test_metric_backbone_is_used_at_scale_one(scene5):
    frame, rig, T = scene5
    cal = calibrate(frame, rig, CalibConfig(joint_refine=False), backbone_result=_metric(T))
    r = cal.report
    assert r.scale == 1.0 and r.scale_check is not None and abs(r.scale_check - 1) < 0.02, r.scale_check
    assert not any("closed-form scale" in w for w in r.warnings)
    assert set(cal.T_cam_world) == set(rig.ids) and r.placed_by == dict.fromkeys(rig.ids, "metric-test")
    e = pose_errors(cal.T_cam_world, {c: T[k] for k, c in enumerate(rig.ids)})
    assert e.rotation_deg < 1e-6 and e.translation_mm < 1e-6, e  # the poses as given, s = 1


def test_metric_backbone_with_wrong_scale_warns_but_keeps_scale_one(scene5):
    """A 'metric' backbone 25 % too long (wrong depth units): GMAC's check finds ~1/1.25 and warns;
    the poses stay as given. A check 2-10 % off (its bias on correct rings) does not warn."""
    frame, rig, T = scene5
    # no depth-agreement rule: it would leave the cameras the too-long poses misplace unplaced
    cal = calibrate(
        frame, rig, CalibConfig(joint_refine=False, min_depth_agreement=0.0), backbone_result=_metric(T, 1.25)
    )
    r = cal.report
    assert r.scale == 1.0 and abs(r.scale_check - 1 / 1.25) < 0.02, r.scale_check
    assert any("more than 15% from 1" in w for w in r.warnings), r.warnings
    c1 = -cal.T_cam_world["c1"][:3, :3].T @ cal.T_cam_world["c1"][:3, 3]
    c1_true = -(T[1, :3, :3].T @ T[1, :3, 3]) + T[0, :3, :3].T @ T[0, :3, 3]  # c0 is the world
    assert np.linalg.norm(T[0, :3, :3] @ c1_true * 1.25 - c1) < 1e-6
    r = calibrate(frame, rig, CalibConfig(joint_refine=False), backbone_result=_metric(T, 1.1)).report
    assert abs(r.scale_check - 1 / 1.1) < 0.02 and not any("closed-form scale" in w for w in r.warnings), r.warnings


@pytest.fixture(scope="module")
def ring4():
    from fuseflow.synth.config import SimConfig
    from fuseflow.synth.simulator import Simulator

    sim = Simulator(SimConfig(cameras=4, frames=2, scene="room", resolution=(320, 240), seed=1))
    frames = [sim.render(t).frame for t in range(2)]
    T_true = np.stack([c.T_cam_world for c in sim.rig])
    return frames, Rig(tuple(c.with_extrinsics(None) for c in sim.rig)), T_true


def test_rgbd_backbone_through_calibrate_one_and_two_frames(ring4):
    """The 4-camera ring COLMAP half-places: rgbd places all four on one frame, metric;
    pooled over two frames the backbone gets both (its median floor image over these two frames
    loses cam01's floor matches: 3 of 4 placed, measured) and what it places is right."""
    frames, rig, T_true = ring4
    truth = {c: T_true[k] for k, c in enumerate(rig.ids)}
    one = calibrate(frames[0], rig, CalibConfig(backbone="rgbd"))
    two = calibrate(frames, rig, CalibConfig(backbone="rgbd"))
    assert set(one.T_cam_world) == set(rig.ids)
    assert one.report.backbone_info["frames"] == 1 and two.report.backbone_info["frames"] == 2
    for cal in (one, two):
        r = cal.report
        assert r.backbone == "rgbd" and r.scale == 1.0 and r.scale_check is not None
        assert len(cal.T_cam_world) >= 3 and set(r.placed_by) == set(cal.T_cam_world)
        assert set(r.placed_by.values()) == {"rgbd"}
        e = pose_errors(cal.T_cam_world, {c: truth[c] for c in cal.T_cam_world})
        assert e.rotation_deg < 0.3 and e.translation_mm < 10.0, e


def test_frames_of_different_rigs_are_rejected(scene5, ring4):
    with pytest.raises(ValidationError, match="one static rig"):
        calibrate([scene5[0], ring4[0][0]], scene5[1])
    with pytest.raises(ValidationError, match="non-empty"):
        calibrate([], scene5[1])


def test_all_views_dropped_says_missing(scene5):
    """Every view dropped (present False, images zero): the error names missing views, not texture."""
    frame, rig, _ = scene5
    dropped = replace(
        frame,
        color=torch.zeros_like(frame.color),
        depth=torch.zeros_like(frame.depth),
        present=torch.zeros_like(frame.present),
    )
    with pytest.raises(CalibrationError, match="missing") as err:
        calibrate(dropped, rig, CalibConfig(backbone="colmap"))
    assert "textureless" not in str(err.value)
    one_left = replace(dropped, present=torch.tensor([True, False, False, False, False]))
    with pytest.raises(CalibrationError, match="1 present"):
        calibrate(one_left, rig)


def test_old_report_without_new_fields_reads(scene5):
    frame, rig, T = scene5
    d = dict(calibrate(frame, rig, backbone_result=_metric(T)).report.to_json())
    for k in ("scale_check", "placed_by", "unplaced_reasons"):
        d.pop(k)
    r = CalibReport.from_json(d)
    assert r.placed_by == {} and r.scale_check is None and r.unplaced_reasons == {}


def test_scale_check_warning_is_dropped_only_when_every_verdict_is_good():
    """The check's warning is for poses the verdicts cannot vouch for: with every camera "good"
    it goes (the value stays in scale_check); one camera "check it" keeps it, as do other warnings."""
    from types import SimpleNamespace

    from fuseflow.calib.verdicts import SCALE_CHECK_WARNING, drop_answered_scale_warning

    scale = f"{SCALE_CHECK_WARNING} 0.7584, more than 15% from 1"
    for verdicts, kept in (
        ({"a": {"verdict": "good"}, "b": {"verdict": "good"}}, ["other"]),
        ({"a": {"verdict": "good"}, "b": {"verdict": "check it"}}, [scale, "other"]),
        ({}, [scale, "other"]),
    ):
        report = SimpleNamespace(camera_verdicts=verdicts, warnings=[scale, "other"], scale_check=0.7584)
        drop_answered_scale_warning(report)
        assert report.warnings == kept and report.scale_check == 0.7584
