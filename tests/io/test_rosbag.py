"""RealSense .bag files (written here in librealsense's layout with rosbags) -> FuseFlow recording."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

pytest.importorskip("rosbags")

import fuseflow.cli  # noqa: E402, F401  (registers the commands)
from fuseflow.cli.app import app  # noqa: E402
from fuseflow.errors import FormatError, RecordingError  # noqa: E402
from fuseflow.io import open_recording  # noqa: E402
from fuseflow.io.convert import convert  # noqa: E402
from fuseflow.io.images import read_color, read_depth_raw  # noqa: E402
from fuseflow.io.rosbag import RealSenseBag  # noqa: E402
from fuseflow.io.timesync import read_timestamps  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from recording_writers import write_realsense_bag  # noqa: E402

runner = CliRunner()
K = np.array([[80.0, 0.0, 47.5], [0.0, 80.0, 35.5], [0.0, 0.0, 1.0]])
T, H, W = 6, 72, 96


def _frames(seed: int):
    rng = np.random.default_rng(seed)
    color = rng.integers(0, 256, (T, H, W, 3), dtype=np.uint8)
    depth = rng.integers(0, 8000, (T, H, W), dtype=np.uint16)
    depth[:, :4] = 0  # no-measurement pixels survive as 0
    return color, depth


def _stamps_ns(base_ns: int, jitter_seed: int | None = None) -> np.ndarray:
    ns = base_ns + np.arange(T, dtype=np.int64) * 33_333_333
    if jitter_seed is not None:
        ns += np.random.default_rng(jitter_seed).integers(-2_000_000, 2_000_000, T)
    return ns


@pytest.mark.parametrize("trailer, compress", [(True, False), (False, True)])
def test_bag_round_trip_is_exact(tmp_path, trailer, compress):
    """Depth (z16 raw), colour, intrinsics, depth scale, serial and device timestamps come back exactly,
    with and without librealsense's trailing depth_units, uncompressed and LZ4-compressed."""
    color, depth = _frames(1)
    ns = _stamps_ns(1_700_000_000_000_000_000 // 1000, 5)  # device ms clock ~ 1.7e9 s: ns precision kept
    bag = write_realsense_bag(tmp_path / "a.bag", "831612070001", color, depth, ns / 1e9, K, depth_units=0.0001,
                              depth_units_trailer=trailer, compress=compress)  # fmt: skip
    b = RealSenseBag(bag)
    assert b.id == "831612070001" and (b.width, b.height) == (W, H) and b.file_version == 3
    assert np.array_equal(b.K, K) and b.aligned_in_file and b.depth_scale == pytest.approx(10000.0, rel=1e-6)
    assert np.array_equal(np.round(b.timestamps * 1e9).astype(np.int64), ns)
    assert np.array_equal(b.device_frames, np.arange(1, T + 1))
    out = tmp_path / "rec"
    s = convert([bag], out)
    assert s.kind == "realsense" and s.frames == T
    rec = open_recording(out)
    assert rec.rig.ids == ("831612070001",) and np.array_equal(rec.rig.cameras[0].K, K)
    for t in range(T):
        assert np.array_equal(read_color(out / "831612070001" / "color" / f"{t:06d}.png"), color[t])
        assert np.array_equal(read_depth_raw(out / "831612070001" / "depth" / f"{t:06d}.png"), depth[t])
    ts = read_timestamps(out)
    assert np.array_equal(np.round(ts.view["831612070001"] * 1e9).astype(np.int64), ns)


def _plane_depth(Kx, size, n, d, R=np.eye(3), t=np.zeros(3)):
    """Depth (metres) of the plane n . X = d (given in frame A) seen by a camera X_B = R X_A + t."""
    w, h = size
    nb = R @ n
    db = d + nb @ t
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rx, ry = (u - Kx[0, 2]) / Kx[0, 0], (v - Kx[1, 2]) / Kx[1, 1]
    return db / (nb[0] * rx + nb[1] * ry + nb[2])


def test_unaligned_depth_is_aligned_to_colour(tmp_path):
    """A bag with depth in its own camera (other intrinsics and resolution, 15 mm baseline) is
    registered to colour: on a tilted plane, >= 97 % of the colour pixels the depth camera sees get
    a depth, within one pixel's depth step of the analytic depth (a depth pixel's footprint
    carries its centre depth, as in rs2::align), median within 1.5 mm."""
    K_d = np.array([[70.0, 0.0, 40.5], [0.0, 70.0, 30.5], [0.0, 0.0, 1.0]])
    ang = np.deg2rad(1.0)
    R = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    T_cd = np.eye(4)
    T_cd[:3, :3], T_cd[:3, 3] = R, [0.015, 0.0005, 0.001]
    n, d = np.array([-0.3, 0.1, 1.0]), 1.2
    dep_m = _plane_depth(K_d, (82, 62), n, d)
    depth = np.rint(dep_m / 0.001).astype(np.uint16)[None].repeat(2, 0)
    color = np.zeros((2, H, W, 3), np.uint8)
    bag = write_realsense_bag(tmp_path / "u.bag", "1", color, depth, np.array([1.0, 1.0333]), K, K_depth=K_d,
                              T_color_depth=T_cd)  # fmt: skip
    b = RealSenseBag(bag)
    assert not b.aligned_in_file and np.allclose(b.T_color_depth, T_cd, atol=1e-6)
    (_, _, raw), _ = list(b.views({0, 1}))
    truth = _plane_depth(K, (W, H), n, d, R, T_cd[:3, 3])
    got = raw.astype(np.float64) / 1000
    seen = np.zeros((H, W), bool)
    seen[2:-2, 6:-6] = True  # well inside the depth camera's field of view (checked below)
    assert (got[seen] > 0).mean() >= 0.97
    ok = seen & (got > 0)
    err = np.abs(got[ok] - truth[ok])
    step = max(np.abs(np.diff(truth, axis=0)).max(), np.abs(np.diff(truth, axis=1)).max())
    assert np.median(err) < 0.0015 and err.max() < 1.5 * step + 0.001, (np.median(err), err.max(), step)


def test_two_cameras_pair_with_a_dropped_view_and_info(tmp_path):
    """Two bags, 3 ms apart with jitter; camera B misses its 4th frame: it becomes a dropped view,
    and `fuseflow info` shows fps, the gap and the pairing spread."""
    ca, da = _frames(2)
    cb, db = _frames(3)
    ns_a = _stamps_ns(10_000_000_000, 1)
    ns_b = _stamps_ns(10_003_000_000, 2)
    keep = np.arange(T) != 3
    (tmp_path / "in").mkdir()
    write_realsense_bag(tmp_path / "in" / "a.bag", "A", ca, da, ns_a / 1e9, K)
    write_realsense_bag(tmp_path / "in" / "b.bag", "B", cb[keep], db[keep], ns_b[keep] / 1e9, K)
    res = runner.invoke(app, ["convert", str(tmp_path / "in"), str(tmp_path / "rec")])
    assert res.exit_code == 0, res.output
    assert "1 dropped views" in res.output
    rec = open_recording(tmp_path / "rec")
    assert len(rec) == T and rec.missing_views() == {"B": [3]}
    assert not bool(rec[3].present[1]) and bool(rec[4].present[1])
    assert np.array_equal(read_depth_raw(tmp_path / "rec" / "B" / "depth" / "000004.png"), db[4])
    s = json.loads(runner.invoke(app, ["info", str(tmp_path / "rec"), "--json"]).output)
    tm = s["timing"]
    assert tm["cameras"]["A"]["fps"] == pytest.approx(30.0, rel=0.15) and tm["cameras"]["A"]["gaps"] == 0
    assert tm["cameras"]["B"]["gaps"] == 1 and tm["cameras"]["B"]["dropped_views"] == 1
    assert tm["cameras"]["B"]["longest_gap_ms"] > 60
    spread = np.abs((ns_b - ns_a)[keep]) / 1e6
    assert tm["spread_ms"]["max"] == pytest.approx(spread.max(), abs=1e-3)
    table = runner.invoke(app, ["info", str(tmp_path / "rec")])
    assert table.exit_code == 0 and "spread per frame" in table.output


def test_bad_bags_give_one_line_errors_naming_file_and_stream(tmp_path):
    color, depth = _frames(4)
    st = np.arange(T) / 30 + 5.0
    good = write_realsense_bag(tmp_path / "good.bag", "G", color, depth, st, K)
    trunc = tmp_path / "trunc.bag"
    trunc.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(FormatError, match=r"trunc\.bag: not a readable ROS1 bag"):
        RealSenseBag(trunc)
    nodepth = write_realsense_bag(tmp_path / "nodepth.bag", "N", color, depth, st, K, write_depth=False)
    with pytest.raises(
        FormatError,
        match=r"nodepth\.bag: no depth stream \(expected a topic like /device_0/sensor_N/Depth_0/image/data\)",
    ):
        RealSenseBag(nodepth)
    small = write_realsense_bag(tmp_path / "small.bag", "S", color[:, :48, :64], depth[:, :48, :64], st, K)
    with pytest.raises(RecordingError, match=r"small\.bag: colour stream is 64x48, but .*good\.bag is 96x72"):
        convert([good, small], tmp_path / "out")
    res = runner.invoke(app, ["convert", str(nodepth), str(tmp_path / "o2")])
    assert res.exit_code == 2 and "nodepth.bag: no depth stream" in res.output and "Traceback" not in res.output
    notbag = tmp_path / "x.bag"
    notbag.write_bytes(b"#ROSBAG V2.0\nrubbish")
    with pytest.raises(FormatError, match=r"x\.bag"):
        RealSenseBag(notbag)


def test_missing_extra_is_named(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(RecordingError, match=r"pip install 'fuseflow\[recordings\]'"):
        RealSenseBag(tmp_path / "any.bag")
