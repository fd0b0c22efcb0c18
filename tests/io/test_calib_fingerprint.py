"""calib.json's optional rig fingerprint and duplicate frame images."""

import json

import numpy as np
import pytest

from fuseflow import Camera, FormatError, RecordingError, Rig
from fuseflow.io import read_calibration, write_calibration
from fuseflow.io.recording import list_frames
from fuseflow.types import Calibration

K = [[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]]


def _rig():
    return Rig(tuple(Camera(f"c{i}", 32, 24, K, T_cam_world=np.eye(4)) for i in range(2)))


def test_fingerprint_round_trip_and_old_files(tmp_path):
    rig = _rig()
    cal = Calibration({c.id: c.T_cam_world for c in rig}, {"source": "test"})
    write_calibration(tmp_path / "new.json", cal, rig=rig)
    doc = json.loads((tmp_path / "new.json").read_text())
    assert doc["rig_fingerprint"]["c1"] == {"width": 32, "height": 24, "K": K}
    back = read_calibration(tmp_path / "new.json")
    assert back.report["rig_fingerprint"]["c0"]["K"] == K and back.report["source"] == "test"
    # written again without a rig: the fingerprint it carries stays a top-level field
    write_calibration(tmp_path / "again.json", back)
    again = json.loads((tmp_path / "again.json").read_text())
    assert again["rig_fingerprint"] == doc["rig_fingerprint"] and "rig_fingerprint" not in again["report"]
    # a file without the field (older versions) reads as before
    write_calibration(tmp_path / "old.json", cal)
    assert "rig_fingerprint" not in json.loads((tmp_path / "old.json").read_text())
    assert "rig_fingerprint" not in read_calibration(tmp_path / "old.json").report


@pytest.mark.parametrize(
    "value, msg",
    [
        ([], "must be an object"),
        ({"c0": {"width": 32}}, "camera 'c0'.*'width', 'height' and 'K'"),
        ({"c0": {"width": -1, "height": 24, "K": K}}, "positive integers"),
        ({"c0": {"width": 32, "height": 24, "K": [1, 2]}}, "camera 'c0'.*3x3"),
    ],
)
def test_malformed_fingerprint_is_named(tmp_path, value, msg):
    rig = _rig()
    write_calibration(tmp_path / "c.json", Calibration({c.id: c.T_cam_world for c in rig}, {}), rig=rig)
    doc = json.loads((tmp_path / "c.json").read_text())
    doc["rig_fingerprint"] = value
    (tmp_path / "c.json").write_text(json.dumps(doc))
    with pytest.raises(FormatError, match=msg):
        read_calibration(tmp_path / "c.json")


@pytest.mark.parametrize("other", ["000003.jpg", "3.png", "000003.JPEG"])
def test_two_images_for_one_frame_are_an_error_naming_both(tmp_path, other):
    (tmp_path / "000003.png").write_bytes(b"x")
    (tmp_path / other).write_bytes(b"x")
    (tmp_path / "000004.png").write_bytes(b"x")
    with pytest.raises(RecordingError, match="frame 3") as e:
        list_frames(tmp_path, (".png", ".jpg", ".jpeg"))
    assert "000003.png" in str(e.value) and other in str(e.value)


def test_a_jpg_beside_depth_only_pngs_is_no_duplicate(tmp_path):
    (tmp_path / "000003.png").write_bytes(b"x")
    (tmp_path / "000003.jpg").write_bytes(b"x")  # not a depth extension: ignored, not doubled
    assert list(list_frames(tmp_path, (".png",))) == [3]
