"""`fuseflow demo` end to end (the README's first command), on a short run: 8 cameras, 2 frames."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np

from fuseflow.io import read_calibration
from fuseflow.io.exchange import read_cloud


def test_demo_writes_its_scores_pictures_and_clouds(demo_run):
    out, res = demo_run  # tests/conftest.py: one demo run shared with tests/test_usage_doc.py
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["recording"] == "(temporary, removed)"  # not a path that no longer exists
    assert "GMAC rotation error" in res.output and "F-score" in res.output
    d = json.loads((out / "demo.json").read_text())
    assert d["cameras"] == 8 and d["frames"] == 2 and 2 <= d["cameras_placed"] <= 8
    for k in ("rotation_error_deg", "translation_error_mm", "chamfer_mm", "fscore_1cm", "outlier_share_2cm"):
        assert math.isfinite(d[k]) and d[k] >= 0, k
    assert 0 <= d["fscore_1cm"] <= 1 and 0 <= d["outlier_share_2cm"] <= 1
    calib = read_calibration(out / "calib.json")
    assert len(calib.camera_ids) == d["cameras_placed"]
    for t in range(2):
        cloud = read_cloud(out / "clouds" / f"{t:06d}.drc")  # the demo writes Draco (its size)
        assert len(cloud) == 0 or np.isfinite(cloud.xyz.numpy()).all()
    assert calib.report["world"]["name"] == "floor"  # the clouds stand on the simulated floor, z up
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    assert size < 150e6 * 2 / 10  # 150 MB for the default 10 frames
    assert d["points_per_frame"] > 1000
    for png in d["png"]:
        img = cv2.imread(png)
        assert img is not None and (img < 250).any(), f"{png} is blank"
