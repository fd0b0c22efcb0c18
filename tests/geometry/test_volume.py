"""The capture volume (geometry.volume): ring and one-sided rigs, --crop parsing, calib.json."""

from __future__ import annotations

import json

import numpy as np
import pytest
from tests.conftest import look_at

from fuseflow.errors import FormatError, ValidationError
from fuseflow.geometry.volume import CaptureVolume, aim_point, capture_volume, crop_cloud, parse_crop
from fuseflow.io import read_calibration, write_calibration
from fuseflow.types import Calibration, Camera, FusedCloud, Rig

K = np.array([[200.0, 0, 159.5], [0, 200.0, 119.5], [0, 0, 1]])


def _ring(n=8, radius=2.6, height=1.8, target=(0.0, 0.0, 0.9)) -> Rig:
    cams = []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = (radius * np.cos(a), radius * np.sin(a), height)
        cams.append(Camera(f"c{k}", 320, 240, K, depth_range=(0.3, 6.0), T_cam_world=look_at(eye, target, (0, 0, 1))))
    return Rig(tuple(cams))


def test_ring_volume_keeps_the_stage_and_drops_walls_and_stands():
    rig = _ring()
    vol = capture_volume(rig)
    assert vol.kind == "ring"
    stage = np.array([[0, 0, 0.9], [0.5, -0.4, 1.7], [-0.6, 0.3, 0.0], [0.3, 0.3, 0.2]])
    assert vol.contains(stage).all()
    walls = np.array([[4.0, 0, 1.5], [0, -4.0, 0.5], [-3.0, -3.0, 1.0]])
    stands = np.array([[2.6 * np.cos(a), 2.6 * np.sin(a), z] for a in np.linspace(0, 6, 5) for z in (0.2, 1.0)])
    assert not vol.contains(walls).any()
    assert not vol.contains(stands).any()
    p, cond = aim_point(np.array([c.T_world_cam[:3, 3] for c in rig]), np.array([c.T_world_cam[:3, 2] for c in rig]))
    assert np.allclose(p, [0, 0, 0.9], atol=1e-6) and cond > 0.05


def test_one_sided_rig_gets_the_frusta_overlap_within_depth_range():
    cams = [
        Camera(f"c{k}", 320, 240, K, depth_range=(0.5, 3.0), T_cam_world=look_at((x, 0, 0), (x, 0, 2.0)))
        for k, x in enumerate((-0.3, 0.0, 0.3))
    ]
    vol = capture_volume(Rig(tuple(cams)))
    assert vol.kind == "frusta"
    assert vol.contains(np.array([[0, 0, 1.5], [0.2, 0.1, 2.5]])).all()
    assert not vol.contains(np.array([[0, 0, 0.2], [0, 0, 3.5], [0, 0, -1.0], [3.0, 0, 1.0]])).any()


@pytest.mark.parametrize(
    "text, words",
    [
        ("1,2,3", "got 3"),
        ("0,0,0,1,1,nan", "finite"),
        ("0,0,0,1,a,1", "not numbers"),
        ("0,0,2,1,1,1", "z is not"),
        ("", "got 1"),
    ],
)
def test_bad_crop_boxes_are_one_line_errors(text, words):
    with pytest.raises(ValidationError) as e:
        parse_crop(text)
    assert words in str(e.value) and "\n" not in str(e.value)


def test_explicit_crop_and_crop_cloud():
    vol = parse_crop("-1,-1,0,1,1,2")
    xyz = np.array([[0, 0, 1], [2, 0, 1], [0, 0, -0.1], [0.99, -0.99, 1.99]], np.float32)
    cloud = FusedCloud.from_numpy(xyz, np.zeros((4, 3)), np.ones(4), np.arange(4), np.arange(4))
    kept = crop_cloud(cloud, vol)
    assert kept.xyz.numpy().tolist() == xyz[[0, 3]].tolist()
    assert kept.camera.tolist() == [0, 3] and kept.support.tolist() == [0, 3]
    assert len(crop_cloud(FusedCloud.from_numpy(xyz[:0], np.zeros((0, 3)), [], []), vol)) == 0
    assert crop_cloud(cloud, None) is cloud


def test_volume_round_trips_through_calib_json(tmp_path):
    vol = capture_volume(_ring())
    path = tmp_path / "calib.json"
    cal = Calibration({"c0": np.eye(4)}, {"source": "x", "capture_volume": vol.to_json()})
    write_calibration(path, cal)
    doc = json.loads(path.read_text())
    assert "capture_volume" in doc and "capture_volume" not in doc["report"]
    back = CaptureVolume.from_json(read_calibration(path).report["capture_volume"])
    assert np.allclose(back.corners(), vol.corners(), atol=1e-5)
    # an older file without the key reads as before; an edited box with min > max is refused
    del doc["capture_volume"]
    path.write_text(json.dumps(doc))
    assert "capture_volume" not in read_calibration(path).report
    doc["capture_volume"] = {"min": [0, 0, 0], "max": [1, -1, 1]}
    path.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="capture_volume.*y is not"):
        read_calibration(path)
