"""`fuseflow run` and `fuseflow view` through the CLI."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from fuseflow.cli import app


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_run_then_view(static_rec, tmp_path):
    out = tmp_path / "out"
    res = _invoke("run", static_rec, "--out", out, "--use-rig", "--frames", "0:3")
    assert res.exit_code == 0, res.output
    assert "points per frame" in res.output and "rig.json" in res.output
    assert json.loads((out / "summary.json").read_text())["frames"] == 3
    res = _invoke("view", out, "--save-png", tmp_path / "png")
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "png").glob("*.png")) == [f"{t:06d}.png" for t in range(3)]
    pytest.importorskip("rerun")
    res = _invoke("view", out, "--rrd", tmp_path / "v.rrd")
    assert res.exit_code == 0, res.output
    assert (tmp_path / "v.rrd").stat().st_size > 10_000


def test_run_argument_errors_are_one_line(static_rec, tmp_path):
    res = _invoke("run", static_rec, "--out", tmp_path / "o", "--use-rig", "--calib", tmp_path / "c.json")
    assert res.exit_code == 2 and "pass one" in res.output
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "fuseflow", "run", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2 and "error:" in proc.stderr and "Traceback" not in proc.stderr
    res = _invoke("run", static_rec, "--out", tmp_path / "o", "--device", "tpu")
    assert res.exit_code == 2 and "--device" in res.output
    res = _invoke("run", static_rec, "--out", tmp_path / "o", "--use-rig", "--preset", "nope")
    assert res.exit_code == 2 and "no FUSE preset 'nope'" in res.output


def test_run_with_the_live_preset_fuses_fewer_points_and_will_not_resume_another_preset(static_rec, tmp_path):
    out, live = tmp_path / "default", tmp_path / "live"
    assert _invoke("run", static_rec, "--out", out, "--use-rig", "--frames", "0:2").exit_code == 0
    res = _invoke("run", static_rec, "--out", live, "--use-rig", "--frames", "0:2", "--preset", "live")
    assert res.exit_code == 0, res.output
    full = json.loads((out / "summary.json").read_text())["points_per_frame"]["mean"]
    fewer = json.loads((live / "summary.json").read_text())["points_per_frame"]["mean"]
    assert 0 < fewer < 0.6 * full
    # the preset is part of the run's settings: the default cannot resume the live run's output
    res = _invoke("run", static_rec, "--out", live, "--use-rig", "--frames", "0:2")
    assert res.exit_code == 2 and "settings" in res.output


def test_run_points_sets_the_density_and_the_run_settings(static_rec, tmp_path):
    """`fuseflow run --points N`: about N points per frame (within 10 %); the budget is part of the
    run's settings, so another budget does not resume it; a budget below 1 is a one-line error."""
    out = tmp_path / "o"
    res = _invoke("run", static_rec, "--out", out, "--use-rig", "--frames", "0:2", "--points", "5000")
    assert res.exit_code == 0, res.output
    ppf = json.loads((out / "summary.json").read_text())["points_per_frame"]
    assert abs(ppf["min"] - 5000) <= 500 and abs(ppf["max"] - 5000) <= 500, ppf
    res = _invoke("run", static_rec, "--out", out, "--use-rig", "--frames", "0:2", "--points", "8000")
    assert res.exit_code == 2 and "settings" in res.output
    res = _invoke("run", static_rec, "--out", tmp_path / "p", "--use-rig", "--points", "0")
    assert res.exit_code == 2 and "--points" in res.output


def test_run_use_rig_without_extrinsics_refuses(static_rec, tmp_path):
    """As `fuse` does: --use-rig on a rig.json without extrinsics is one error line (exit 2),
    not GMAC run in its place."""
    import shutil

    rec = tmp_path / "bare"
    shutil.copytree(static_rec, rec)
    doc = json.loads((rec / "rig.json").read_text())
    for cam in doc["cameras"]:
        cam.pop("T_cam_world", None)
    (rec / "rig.json").write_text(json.dumps(doc))
    res = _invoke("run", rec, "--out", tmp_path / "o", "--use-rig", "--frames", "0:1")
    assert res.exit_code == 2 and "rig.json has no extrinsics" in " ".join(res.output.split()), res.output
    assert not (tmp_path / "o" / "calib.json").exists()


def test_run_prints_the_verdict_table_and_writes_the_report_picture(static_rec, tmp_path):
    """GMAC ran: the per-camera verdict table and OUT/calib.png, as `calibrate` prints and writes."""
    out = tmp_path / "out"
    res = _invoke("run", static_rec, "--out", out, "--frames", "0:1", "--calib-frame", "0")
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "verdict" in text and "verdicts:" in text and "good" in text, res.output
    assert (out / "calib.png").stat().st_size > 1000
