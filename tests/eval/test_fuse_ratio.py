"""`fuseflow bench fuse-ratio`'s function: interleaved FUSE / VoxelBlockGrid rounds on a small recording."""

from __future__ import annotations

import pytest

from fuseflow.eval.bench.fuse_ratio import run_fuse_ratio

pytest.importorskip("open3d")


def test_fuse_ratio_reports_the_median_of_its_rounds(static_rec):
    lines = []
    (row,) = run_fuse_ratio([static_rec], preset="auto", rounds=2, log=lines.append)
    assert row["rounds"] == 2 and row["points"] > 1000
    assert row["ratio_min"] <= row["ratio"] <= row["ratio_max"]
    assert row["fuse_ms"] > 0 and row["vbg_ms"] > 0
    assert row["grid"].startswith("auto: stride 1")  # 4 cameras at 200x150: every pixel
    assert len(lines) == 1 and "VBG / FUSE median" in lines[0]
    assert row["valid_pixels"] > 0 and row["core_ms"] > 0
    assert row["core_ms_per_mpx"] == pytest.approx(row["core_ms"] * 1e6 / row["valid_pixels"])
    assert "per million valid depth pixels" in lines[0]
