"""Camera-sync check (issue 19, part 3): re-timing views exactly, and no false alarm where no
shift is consistently better."""

from __future__ import annotations

import pytest
import torch

from fuseflow.errors import ValidationError
from fuseflow.io import open_recording
from fuseflow.io.timesync import shift_views
from fuseflow.pipeline import PipelineConfig
from fuseflow.pipeline.sync import check_sync


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


def test_sync_config_validates():
    with pytest.raises(ValidationError, match="sync"):
        PipelineConfig(sync="maybe")
    with pytest.raises(ValidationError, match="sync_max_shift"):
        PipelineConfig(sync_max_shift=0)
