"""Pairing views by timestamp, the timestamps file and stream statistics."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.errors import FormatError, ValidationError
from fuseflow.io.timesync import pair_by_timestamp, read_timestamps, stream_stats, write_timestamps

P = 1 / 30


def test_pairing_jitter_drop_and_late_start():
    rng = np.random.default_rng(0)
    a = np.arange(20) * P + rng.uniform(-0.003, 0.003, 20)
    b = np.delete(np.arange(20) * P + 0.004 + rng.uniform(-0.003, 0.003, 20), [5, 6])  # B misses two frames
    c = np.arange(3, 23) * P  # C starts 3 frames later and runs 3 longer
    p = pair_by_timestamp([a, b, c])
    assert p.tolerance == pytest.approx(P / 2, rel=0.05)
    assert len(p.index) == 23  # union of the instants
    assert list(np.flatnonzero(p.index[:, 1] < 0)) == [5, 6, 20, 21, 22]
    assert list(np.flatnonzero(p.index[:, 2] < 0)) == [0, 1, 2]
    assert list(p.index[:20, 0]) == list(range(20)) and list(p.index[3:, 2]) == list(range(20))
    both = (p.index >= 0).all(axis=1)
    assert p.spread[both].max() < 0.011
    assert list(p.dropped) == [3, 5, 3]


def test_pairing_tolerance_and_bad_input():
    a = np.arange(5) * P
    b = a + 0.010
    assert (pair_by_timestamp([a, b], tolerance=0.012).index >= 0).all()
    tight = pair_by_timestamp([a, b], tolerance=0.005)
    assert len(tight.index) == 10 and (tight.index < 0).sum() == 10  # nothing pairs: every view alone
    with pytest.raises(ValidationError, match="cam B: timestamps must increase"):
        pair_by_timestamp([a, a[::-1]], names=["cam A", "cam B"])
    with pytest.raises(ValidationError, match="no timestamps"):
        pair_by_timestamp([a, []])


def test_stream_stats_counts_gaps():
    s = np.delete(np.arange(30) * P, [10, 20, 21])
    st = stream_stats(s)
    assert st.fps == pytest.approx(30.0) and st.gaps == 2 and st.longest_gap_s == pytest.approx(3 * P)


def test_timestamps_file_round_trip(tmp_path):
    view = {"a": np.array([0.0, 0.0333, np.nan]), "b": np.array([0.001, np.nan, 0.068])}
    write_timestamps(tmp_path, [0, 1, 2], view, {"a": np.array([0.0, 0.0333]), "b": np.array([0.001, 0.068])}, 0.0167,
                     {"a": np.array([1, 2, np.nan]), "b": np.array([7, np.nan, 9])})  # fmt: skip
    ts = read_timestamps(tmp_path)
    assert np.array_equal(ts.view["a"], view["a"], equal_nan=True) and ts.device_frame["b"][2] == 9
    assert np.allclose(ts.spread(), [0.001, 0.0, 0.0])
    (tmp_path / "timestamps.json").write_text('{"format": "other"}')
    with pytest.raises(FormatError, match="timestamps.json: field 'format'"):
        read_timestamps(tmp_path)
    assert read_timestamps(tmp_path / "nothing") is None
