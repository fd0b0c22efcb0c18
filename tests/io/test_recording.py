"""The recording format: rig.json round trip and validation, frames, dropped views, bad files."""

import json

import numpy as np
import pytest
import torch

import fuseflow
from fuseflow import Camera, FormatError, RecordingError, Rig, ValidationError
from fuseflow.io.recording import frame_path, rig_from_json, rig_to_json

K = [[100.0, 0, 15.5], [0, 100.0, 11.5], [0, 0, 1]]


def small_rig(n=3, calibrated=True):
    cams = []
    for i in range(n):
        T = np.eye(4)
        T[0, 3] = 0.1 * i
        cams.append(Camera(f"cam{i}", 32, 24, K, 1000.0, (0.2, 5.0), T if calibrated else None))
    return Rig(tuple(cams))


def write_small(tmp_path, n=3, frames=2):
    rig = small_rig(n)
    rng = np.random.default_rng(0)
    data = []
    for t in range(frames):
        color = rng.integers(0, 255, (n, 24, 32, 3), dtype=np.uint8)
        depth = rng.uniform(0.5, 3.0, (n, 24, 32)).astype(np.float32)
        fuseflow.write_frame(tmp_path, rig, t, color, depth)
        data.append((color, depth))
    fuseflow.write_rig(tmp_path, rig)
    return rig, data


def test_rig_json_roundtrip_identical(tmp_path):
    rig = small_rig()
    fuseflow.write_rig(tmp_path, rig)
    assert fuseflow.read_rig(tmp_path) == rig
    assert fuseflow.read_rig(tmp_path / "rig.json") == rig
    uncal = small_rig(calibrated=False)
    assert rig_from_json(rig_to_json(uncal)) == uncal


def test_frames_load_with_metric_depth(tmp_path):
    rig, data = write_small(tmp_path)
    rec = fuseflow.open_recording(tmp_path)
    assert len(rec) == 2 and rec.rig == rig
    f = rec[1]
    assert f.index == 1 and f.depth.shape == (3, 24, 32) and f.color.dtype == torch.uint8
    assert torch.equal(f.color, torch.from_numpy(data[1][0]))
    # uint16 millimetres: quantisation error at most half a millimetre
    assert np.abs(f.depth.numpy() - data[1][1]).max() <= 0.0005 + 1e-6
    assert bool(f.present.all())
    assert [fr.index for fr in rec] == [0, 1]
    with pytest.raises(IndexError, match="2 frames"):
        rec[2]


def test_dropped_view_loads_marked_missing(tmp_path):
    write_small(tmp_path)
    frame_path(tmp_path, "cam1", "depth", 1).unlink()
    rec = fuseflow.open_recording(tmp_path)
    f = rec[1]
    assert f.missing == ("cam1",)
    assert float(f.depth[1].abs().sum()) == 0.0
    assert rec.missing_views() == {"cam1": [1]}
    assert rec[0].missing == ()


def test_nan_negative_depth_zeroed_and_counted(tmp_path):
    from fuseflow.io.images import clean_depth

    d = np.array([[1.0, np.nan], [-2.0, np.inf]], dtype=np.float32)
    out, n = clean_depth(d)
    assert n == 3 and out.tolist() == [[1.0, 0.0], [0.0, 0.0]]


@pytest.mark.parametrize(
    "mutate, err, msg",
    [
        (lambda d: d.update(format="other/1"), FormatError, "field 'format'"),
        (lambda d: d["cameras"][1].pop("K"), FormatError, "camera 'cam1'.*missing field 'K'"),
        (lambda d: d["cameras"][0].update(K=[[1, 2], [3, 4]]), FormatError, "camera 'cam0'.*field 'K'"),
        (
            lambda d: d["cameras"][2].update(T_cam_world=[[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),
            FormatError,
            "cam2.*not a rigid",
        ),
        (lambda d: d["cameras"][2].update(T_cam_world=[[float("nan")] * 4] * 4), FormatError, "cam2.*NaN"),
        (lambda d: d["cameras"][0].update(depth_scale=0), FormatError, "cam0.*depth_scale"),
        (lambda d: d["cameras"][1].update(id="cam0"), FormatError, "unique"),
        (lambda d: d.update(cameras=[]), FormatError, "'cameras'"),
    ],
)
def test_rig_json_validation_names_field_and_camera(tmp_path, mutate, err, msg):
    write_small(tmp_path)
    doc = json.loads((tmp_path / "rig.json").read_text())
    mutate(doc)
    (tmp_path / "rig.json").write_text(json.dumps(doc))
    with pytest.raises(err, match=msg):
        fuseflow.open_recording(tmp_path)


def test_invalid_json_reports_line(tmp_path):
    (tmp_path / "rig.json").write_text('{"format": "fuseflow-rig/1",\n "cameras": [}')
    with pytest.raises(FormatError, match="invalid JSON at line 2"):
        fuseflow.open_recording(tmp_path)


def test_size_mismatch_names_file(tmp_path):
    write_small(tmp_path)
    import cv2

    cv2.imwrite(str(frame_path(tmp_path, "cam2", "depth", 0)), np.zeros((10, 10), np.uint16))
    with pytest.raises(ValidationError, match=r"cam2/depth/000000.png: depth is 10x10, camera 'cam2' is 32x24"):
        fuseflow.open_recording(tmp_path)[0]


@pytest.mark.parametrize(
    "cam, kind, index, damage, msg",
    [
        ("cam0", "color", 0, lambda b: b"", "file is empty"),
        ("cam1", "depth", 1, lambda b: b[:-30], "truncated"),
        ("cam2", "color", 1, lambda b: b[: len(b) // 2], "truncated"),
        ("cam2", "color", 1, lambda b: b"this is not an image at all", "not a readable image"),
    ],
)
def test_empty_truncated_and_corrupt_images_name_the_file(tmp_path, cam, kind, index, damage, msg):
    write_small(tmp_path)
    p = frame_path(tmp_path, cam, kind, index)
    p.write_bytes(damage(p.read_bytes()))
    with pytest.raises(RecordingError, match=f"{cam}/{kind}/{index:06d}.png: .*{msg}"):
        fuseflow.open_recording(tmp_path)[index]


def test_not_a_recording(tmp_path):
    with pytest.raises(RecordingError, match="not a recording"):
        fuseflow.open_recording(tmp_path)
    with pytest.raises(RecordingError, match="no such file"):
        fuseflow.open_recording(tmp_path / "nope")
    fuseflow.write_rig(tmp_path, small_rig())
    with pytest.raises(RecordingError, match="no folder cam0"):
        fuseflow.open_recording(tmp_path)


def test_write_depth_never_wraps(tmp_path):
    from fuseflow.io.images import read_depth, write_depth

    write_depth(tmp_path / "d.png", np.array([[70.0, 1.0]], np.float32), 1000.0)
    assert read_depth(tmp_path / "d.png", 1000.0).tolist() == [[0.0, 1.0]]


def test_shared_file_helpers_write_atomically_and_name_the_file(tmp_path):
    from fuseflow.io.files import load_json, read_bytes, write_bytes_atomic, write_json_atomic

    out = write_bytes_atomic(tmp_path / "a" / "b.bin", b"ab", b"cd")
    assert out.read_bytes() == b"abcd" and sorted(p.name for p in out.parent.iterdir()) == ["b.bin"]
    write_json_atomic(tmp_path / "d.json", {"x": [1, 2]})
    assert load_json(tmp_path / "d.json") == {"x": [1, 2]}
    assert (tmp_path / "d.json").read_text() == json.dumps({"x": [1, 2]}, indent=2) + "\n"
    with pytest.raises(RecordingError, match="missing.json: file not found"):
        load_json(tmp_path / "missing.json")
    with pytest.raises(RecordingError, match="cannot read"):
        read_bytes(tmp_path)  # a directory
    (tmp_path / "bad.json").write_bytes(b'{"x": 1,\n}')
    with pytest.raises(FormatError, match="bad.json: invalid JSON at line 2 column 1"):
        load_json(tmp_path / "bad.json")
    (tmp_path / "latin.json").write_bytes(b'{"x": "\xe9"}')
    with pytest.raises(FormatError, match="latin.json: not UTF-8"):
        load_json(tmp_path / "latin.json")
