"""The benchmark studies (benchmarks/studies: calib_wide, fuse_ablations, calib_reference, ...)
and their programs (``python -m benchmarks.NAME``), on tiny inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from benchmarks import calib_wide, fuse_ablations, sync_check
from benchmarks.studies.calib_reference import into_reference
from benchmarks.studies.calib_verdicts import verdict_summary
from benchmarks.studies.calib_wide import summary_lines
from benchmarks.studies.fuse_ablations import run_fuse_ablations
from benchmarks.studies.sync_check import run_sync_check

from fuseflow.errors import ValidationError


def _wide_rows(path):
    base = {"data": "sim", "scene": "room", "n": 3, "frames": 1, "res": "640x480", "cameras": 3, "time_s": 2.0}
    rows = [
        {**base, "placed": 3, "rot_deg": 0.1, "trans_mm": 2.0, "worst_cam_deg": 0.2, "worst_cam_mm": 3.0,
         "wrong_edges": 0, "wrong_cameras": 0, "wrong_unflagged": 0},
        {**base, "placed": 2, "rot_deg": 0.3, "trans_mm": 4.0, "worst_cam_deg": 1.5, "worst_cam_mm": 60.0,
         "wrong_edges": 1, "wrong_cameras": 1, "wrong_unflagged": 1, "time_s": 4.0},
        {**base, "backbone": "auto", "placed": 0, "error": "CalibrationError: no pair"},
    ]  # fmt: skip
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))


def test_calib_wide_summary_groups_runs(tmp_path):
    out = tmp_path / "wide.jsonl"
    _wide_rows(out)
    lines = summary_lines(out)
    assert lines[0].startswith("| data | scene | N |") and len(lines) == 4
    raw = next(x for x in lines[2:] if x.startswith("| sim | room"))
    cells = [c.strip() for c in raw.strip("|").split("|")]
    assert cells[4:8] == ["2", "1/2", "2.5", "0.200 / 0.300"]  # runs, all placed, placed, rot mean / max
    assert cells[10:13] == ["1", "1 (1)", "3.0"]  # wrong edges, wrong cams (unflagged), median time
    assert any(x.startswith("| sim [auto] | room") and "| 0/1 |" in x for x in lines)


def test_calib_wide_program_summary_and_bad_run(tmp_path, capsys):
    out = tmp_path / "wide.jsonl"
    _wide_rows(out)
    calib_wide.main(["summary", "--out", str(out)])
    assert capsys.readouterr().out.splitlines() == summary_lines(out)
    with pytest.raises(SystemExit) as exc:
        calib_wide.main(["sideways", "--out", str(out)])
    assert exc.value.code == 2 and "'sim', 'hocap', 'icl', 'pairs', 'summary'" in capsys.readouterr().err


def test_fuse_ablations_rows_on_a_tiny_ring():
    # the two baselines without compiled kernels: the rows, scores and log of the table's machinery
    lines: list[str] = []
    only = ["naive", "naive + voxel 1 cm"]
    out = run_fuse_ablations(1, 1, 3, (80, 60), 3, density=False, only=only, log=lines.append)
    assert [(r["rig"], r["method"]) for r in out["rows"]] == [(k, m) for k in ("static", "dynamic") for m in only]
    assert out["density"] == [] and out["meta"]["resolution"] == [80, 60]
    for r in out["rows"]:
        assert r["points"] > 0 and 0 <= r["f_1cm"] <= 1 and 0 <= r["or_5mm"] <= 1
    pts = {(r["rig"], r["method"]): r["points"] for r in out["rows"]}
    assert all(pts[k, "naive + voxel 1 cm"] < pts[k, "naive"] for k in ("static", "dynamic"))
    assert sum("frame 0 done" in x for x in lines) == 2


def test_fuse_ablations_unknown_row_is_a_clear_error():
    with pytest.raises(ValidationError, match="unknown methods"):
        run_fuse_ablations(only=["FUSE", "nope"])


def test_fuse_ablations_program_unknown_row_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        fuse_ablations.main(["--only", "nope"])
    assert exc.value.code == 2 and "unknown methods ['nope']" in capsys.readouterr().err


def test_into_reference_undoes_a_change_of_world():
    rng = np.random.default_rng(0)
    T_ref = {f"c{k}": _rigid(rng) for k in range(4)}
    G = _rigid(rng)  # the calibration's world -> the reference's world
    T = {c: t @ G for c, t in T_ref.items()}
    for c in T:
        assert np.allclose(into_reference(T, T_ref, c), T_ref[c], atol=1e-9)


def _rigid(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    T = np.eye(4)
    T[:3, :3] = q * np.sign(np.linalg.det(q))
    T[:3, 3] = rng.normal(size=3)
    return T


def test_verdict_summary_counts_cameras_within_twice_the_expected():
    rows = [
        {"verdict": "good", "accuracy_deg": 0.1, "error_deg": 0.05, "accuracy_mm": 2.0, "error_mm": 1.0},
        {"verdict": "good", "accuracy_deg": 0.1, "error_deg": 0.3, "accuracy_mm": 2.0, "error_mm": 5.0},
        {"verdict": "unplaced", "accuracy_deg": None, "error_deg": None, "accuracy_mm": None, "error_mm": None},
    ]
    line = verdict_summary(rows)
    assert line.startswith("3 cameras, verdicts ['good', 'unplaced']")
    assert "true <= 2x expected: 1/2 (deg), 1/2 (mm)" in line
    assert verdict_summary(rows[2:]) is None


def test_bad_names_are_clear_errors(tmp_path, capsys):
    with pytest.raises(ValidationError, match="unknown configs"):
        run_sync_check(tmp_path, configs=["c4_160_late2", "nope"])
    with pytest.raises(SystemExit) as exc:
        sync_check.main([str(tmp_path), "--method", "psychic"])
    assert exc.value.code == 2 and "'psychic'" in capsys.readouterr().err


def test_bit_identity_compares_clouds_by_bytes_and_calib_without_its_times(tmp_path):
    from benchmarks.studies.bit_identity import compare

    calib = {"format": "fuseflow-calib/1", "cameras": {"c0": {"T_cam_world": [[1.0, 0, 0, 0]]}},
             "report": {"timings_s": {"total": 1.5}, "backbone_info": {"time_s": 0.2, "name": "rgbd",
                                                                       "colmap": {"seconds": {"match": 7.5}}}}}  # fmt: skip
    for name, t, x in (("a", 1.5, b"ply 1"), ("b", 9.0, b"ply 1")):
        (tmp_path / name / "fuse" / "clouds").mkdir(parents=True)
        (tmp_path / name / "fuse" / "clouds" / "000000.ply").write_bytes(x)
        calib["report"]["timings_s"]["total"] = t
        (tmp_path / name / "calib.json").write_text(json.dumps(calib))
    row = compare(tmp_path / "a", tmp_path / "b")
    assert row["identical"] and row["clouds"] == 1
    assert row["calib_fields_ignored"] == [
        "report.backbone_info.colmap.seconds",
        "report.backbone_info.time_s",
        "report.timings_s",
    ]
    (tmp_path / "b" / "fuse" / "clouds" / "000000.ply").write_bytes(b"ply 2")
    calib["cameras"]["c0"]["T_cam_world"][0][3] = 1e-12
    (tmp_path / "b" / "calib.json").write_text(json.dumps(calib))
    row = compare(tmp_path / "a", tmp_path / "b")
    assert not row["identical"] and row["different_clouds"] == ["fuse/clouds/000000.ply"]
    assert not row["calib_identical"]
