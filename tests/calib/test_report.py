"""CalibReport: typed GMAC report whose JSON is calib.json's "report" object, unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fuseflow import Calibration
from fuseflow.calib import CalibConfig, CalibReport, calibrate
from fuseflow.errors import ValidationError
from fuseflow.io.calibration import read_calibration, write_calibration

#: The keys (and their order) of calib.json's GMAC report before the report was typed: users'
#: files and code depend on them.
REPORT_KEYS = [
    "method",
    "backbone",
    "backbone_info",
    "config",
    "scale",
    "scale_before_pruning",
    "scale_coarse",
    "scale_naive_median_depth_ratio",
    "scale_std_error",
    "closed_form",
    "fixed_point",
    "coarse_peak_spread",
    "edge_scales",
    "correspondence_counts",
    "edges",
    "kept_edges",
    "scale_edges",
    "pruned_edges",
    "cycle_mode",
    "cycle_residuals_relative",
    "cycle_residuals_relative_before_pruning",
    "cycle_residuals_mm",
    "unconnected_cameras",
    "unregistered_cameras",
    "depth_agreement",
    "suspect_cameras",
    "warnings",
    "ill_conditioned",
    "refinement",
    "timings_s",
    "world_anchor",  # the camera whose frame is the world
    "scale_check",  # GMAC's s* on a metric backbone's poses
    "placed_by",  # which source placed each camera
    "unplaced_reasons",  # auto, why a camera is not placed
    "joint_refinement",  # the depth-aware joint refinement's summary
    "pair_agreement",  # per-pair depth agreement under the result
    "camera_verdicts",  # good / check it / unplaced per camera, with the evidence
    "reference",  # calibrate --reference's per-camera differences
    "room",  # the repeating room found by calib.turns (None: none)
]


@pytest.fixture(scope="module")
def gmac(scene5, backbone_builder):
    frame, rig, T = scene5
    return calibrate(frame, rig, CalibConfig(), backbone_result=backbone_builder(T, 3.7))


def test_calibrate_returns_typed_report_with_the_old_keys(gmac):
    r = gmac.report
    assert isinstance(r, CalibReport)
    assert list(r.to_json()) == REPORT_KEYS
    assert r.method == "GMAC" and r.backbone == "truth" and r.closed_form == "plane"
    assert abs(r.scale - 3.7) / 3.7 < 2e-3
    assert r.fixed_point["converged"] is True
    assert set(r.kept_edges) <= set(r.edges) and r.unconnected_cameras == []


def test_key_access_still_works(gmac):
    r = gmac.report
    assert r["scale"] == r.scale and r["kept_edges"] is r.kept_edges
    assert r.get("warnings", ["x"]) == r.warnings and r.get("no such key", 7) == 7
    assert "scale" in r and "no such key" not in r
    assert list(r) == REPORT_KEYS and len(r) == len(REPORT_KEYS)
    assert dict(r) == r.to_json() and r == r.to_json()
    with pytest.raises(KeyError):
        r["no such key"]


def test_json_round_trip_through_calib_json(gmac, tmp_path):
    path = write_calibration(tmp_path / "calib.json", gmac)
    back = read_calibration(path)
    assert isinstance(back.report, dict)  # io does not know CalibReport
    typed = CalibReport.from_json(back.report)
    assert typed == json.loads(json.dumps(gmac.report.to_json()))
    assert typed.scale == gmac.report.scale and typed.edge_scales == gmac.report.edge_scales
    # writing the read-back report (plain dict) or the typed one gives the same bytes
    again = write_calibration(tmp_path / "again.json", Calibration(back.T_cam_world, typed))
    assert again.read_bytes() == path.read_bytes()
    plain = write_calibration(tmp_path / "plain.json", Calibration(back.T_cam_world, back.report))
    assert plain.read_bytes() == path.read_bytes()
    for cid, T in gmac.T_cam_world.items():
        np.testing.assert_array_equal(back.T_cam_world[cid], T)


def test_typed_report_nested_in_a_plain_report_is_written(gmac, tmp_path):
    """The pipeline stores a recalibration's GMAC report under "gmac" of its own report."""
    cal = Calibration(dict(gmac.T_cam_world), {"source": "recalibrated", "gmac": gmac.report})
    doc = json.loads(write_calibration(tmp_path / "c.json", cal).read_text())
    assert list(doc["report"]["gmac"]) == REPORT_KEYS
    assert doc["report"]["gmac"]["scale"] == gmac.report.scale


def test_from_json_rejects_other_objects(gmac):
    d = dict(gmac.report.to_json())
    del d["scale"]
    with pytest.raises(ValidationError, match=r"missing keys \['scale'\]"):
        CalibReport.from_json(d)
    with pytest.raises(ValidationError, match=r"unknown keys \['extra'\]"):
        CalibReport.from_json({**gmac.report.to_json(), "extra": 1})
    with pytest.raises(ValidationError, match="JSON object"):
        CalibReport.from_json([1, 2])
