"""Camera-sync check: re-timing views exactly, and no false alarm where no
shift is consistently better."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import torch

from fuseflow.errors import ValidationError
from fuseflow.io import open_recording
from fuseflow.io.timesync import shift_views, write_timestamps
from fuseflow.pipeline import PipelineConfig
from fuseflow.pipeline.sync import check_sync
from fuseflow.synth import SimConfig, simulate_recording
from fuseflow.synth.desync import apply_desync


def test_shift_views_retimes_one_camera_and_drops_the_ends(dynamic_rec):
    rec = open_recording(dynamic_rec)
    cam = rec.rig.ids[1]
    shifted = shift_views(rec, {cam: 2})
    for t in range(len(rec)):
        f = shifted[t]
        if t + 2 < len(rec):
            assert torch.equal(f.depth[1], rec[t + 2].depth[1])
        else:
            assert not bool(f.present[1])  # shifted past the end: a dropped view
        assert torch.equal(f.depth[0], rec[t].depth[0])  # the others keep their time
    assert shifted.missing_views()[cam] == list(rec.frame_numbers[-2:])
    with pytest.raises(ValidationError, match="nope"):
        shift_views(rec, {"nope": 1})


def test_in_sync_static_rig_reports_no_offset(static_rec):
    rec = open_recording(static_rec)
    report = check_sync(rec, rec.rig, list(range(len(rec.rig))), max_shift=1, sample_frames=4)
    assert report.late() == {} and report.warnings() == []
    assert set(report.offsets) == set(rec.rig.ids)


def test_sync_check_method_is_validated(static_rec):
    rec = open_recording(static_rec)
    with pytest.raises(ValidationError, match="covisible"):
        check_sync(rec, rec.rig, list(range(len(rec.rig))), method="centroid")


def test_sync_config_validates():
    with pytest.raises(ValidationError, match="sync"):
        PipelineConfig(sync="maybe")
    with pytest.raises(ValidationError, match="sync_max_shift"):
        PipelineConfig(sync_max_shift=0)


# 30 fps: the walker moves ~3 cm a frame, less than a body's thickness (docs/formats.md
# "Camera-sync check"); 60 frames at 160x120 are the smallest recording measured to work.
@pytest.fixture(scope="module")
def walk30(tmp_path_factory):
    out = tmp_path_factory.mktemp("sync30") / "sync"
    # surface_density 100: the GT surface .ply files (not used here; 21 MB a frame at the
    # default) stay small; depth and colour do not depend on it
    simulate_recording(out, SimConfig(cameras=4, frames=60, scene="studio", dynamic=True, resolution=(160, 120),
                                      seed=0, fps=30.0, surface_density=100.0))  # fmt: skip
    late = out.with_name("late")
    shutil.copytree(out, late)
    apply_desync(late, "cam03:2")
    return out, late


def test_30fps_late_camera_found_exactly(walk30):
    rec = open_recording(walk30[1])
    report = check_sync(rec, rec.rig, list(range(len(rec.rig))))
    assert report.method == "covisible"
    assert report.late() == {"cam03": 2}
    assert report.sub_frame["cam03"] == pytest.approx(2.0, abs=0.3)
    (warning,) = report.warnings()
    assert warning.startswith("cam03 is about +2 frames late")
    kept = [p for p in report.pairs if p.kept]
    assert kept and all(3 in (p.i, p.j) or abs(p.lag) < 0.5 for p in kept)


def test_30fps_in_sync_rig_has_no_false_alarm(walk30):
    rec = open_recording(walk30[0])
    report = check_sync(rec, rec.rig, list(range(len(rec.rig))))
    assert report.late() == {} and report.warnings() == []
    sub = np.array([v for v in report.sub_frame.values() if np.isfinite(v)])
    assert sub.size >= 3 and np.abs(sub).max() < 0.5


def test_short_30fps_recording_says_the_check_is_blind(tmp_path):
    """12 frames at 30 fps: "auto" takes the agreement check, which cannot see a frame or two at
    this rate; the report says so (``run --sync-offsets auto`` passes it on as a warning) instead of
    a silent "nothing found". At 5 fps it has no such limit."""
    for fps, blind in ((30.0, True), (5.0, False)):
        out = tmp_path / f"r{fps:.0f}"
        simulate_recording(out, SimConfig(cameras=3, frames=6, scene="studio", dynamic=True, resolution=(160, 120),
                                          seed=1, fps=fps, surface_density=100.0))  # fmt: skip
        rec = open_recording(out)
        t = np.arange(len(rec)) / fps  # the stamps a .bag / .mkv conversion writes
        write_timestamps(out, rec.frame_numbers, {c: t for c in rec.rig.ids}, {c: t for c in rec.rig.ids}, 0.5 / fps)
        report = check_sync(rec, rec.rig, list(range(len(rec.rig))), max_shift=1, sample_frames=2)
        assert report.method == "agreement"
        if blind:
            assert "on 6 frames at 30 fps the sync check cannot see" in report.limit
            assert "at least 30 frames" in report.limit  # 24 positions + 2 (max_shift + 2)
        else:
            assert report.limit == ""
