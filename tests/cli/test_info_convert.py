"""`fuseflow info` and `fuseflow convert` through typer's CliRunner."""

import json

from typer.testing import CliRunner

import fuseflow.cli  # noqa: F401  (registers commands)
from fuseflow.cli.app import app

runner = CliRunner()


def test_help_on_every_command():
    res = runner.invoke(app, ["--help"])
    assert res.exit_code == 0
    for cmd in ("info", "convert"):
        r = runner.invoke(app, [cmd, "--help"])
        assert r.exit_code == 0 and "Usage" in r.output


def test_info_icl_json(icl_path):
    res = runner.invoke(app, ["info", str(icl_path), "--json"])
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    assert s["frames"] == 211 and s["cameras"] == 1 and s["resolution"] == [640, 480]
    assert s["calibrated"] is False and s["poses"] is True


def test_convert_virtual_rig_then_info(icl_path, tmp_path):
    out = tmp_path / "rig8"
    res = runner.invoke(app, ["convert", str(icl_path), str(out), "--cameras", "8", "--every", "30"])
    assert res.exit_code == 0, res.output
    s = json.loads(runner.invoke(app, ["info", str(out), "--json"]).output)
    assert s["cameras"] == 8 and s["calibrated"] is True and s["frames"] == 1
    # refusing to overwrite
    res = runner.invoke(app, ["convert", str(icl_path), str(out), "--cameras", "2"])
    assert res.exit_code != 0 and "not empty" in res.output


def test_convert_plain_sequence_keeps_poses(icl_path, tmp_path):
    out = tmp_path / "seq"
    res = runner.invoke(app, ["convert", str(icl_path), str(out), "--frames", "10:13"])
    assert res.exit_code == 0, res.output
    s = json.loads(runner.invoke(app, ["info", str(out), "--json"]).output)
    assert s["frames"] == 3 and s["cameras"] == 1
    assert (out / "trajectory.log").exists()


def test_convert_too_many_cameras_is_clear(icl_path, tmp_path):
    res = runner.invoke(app, ["convert", str(icl_path), str(tmp_path / "x"), "--cameras", "20", "--every", "30"])
    assert res.exit_code == 2 and "dataset has 211" in res.output


def test_info_on_bad_path_is_one_line_error(tmp_path):
    import subprocess
    import sys

    p = subprocess.run([sys.executable, "-m", "fuseflow", "info", str(tmp_path)], capture_output=True, text=True)
    assert p.returncode == 2
    assert "not a recording" in p.stderr and "Traceback" not in p.stderr


def test_warnings_and_errors_print_brackets_verbatim(capsys):
    """rich reads "[cam00-cam04, ...]" as a markup tag and drops it; messages are escaped."""
    import typer

    from fuseflow.cli.app import fail, warn

    warn("edges [cam00-cam04, cam01-cam05] have fewer than 50 correspondences")
    assert "[cam00-cam04, cam01-cam05]" in capsys.readouterr().out
    try:
        fail("cameras [bold] and [cam02-cam03] are odd")
    except typer.Exit:
        pass
    assert "[bold] and [cam02-cam03]" in capsys.readouterr().err
