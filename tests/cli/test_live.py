"""`fuseflow live`: a replay recorded to files with a summary; clear errors for a port in use, a
source without extrinsics and bad options; a warning for a non-loopback host."""

from __future__ import annotations

import json
import socket

import pytest
from typer.testing import CliRunner

from fuseflow.cli import app


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_replay_to_files_with_summary(dynamic_rec, tmp_path):
    out = tmp_path / "out"
    res = _invoke("live", dynamic_rec, "--rate", "20", "--preload", "--record", out, "--rerun", tmp_path / "l.rrd")
    assert res.exit_code == 0, res.output
    assert "end of source" in res.output and "5 in" in res.output
    lines = [json.loads(x) for x in (out / "frames.jsonl").read_text().splitlines()]
    assert lines and len(list((out / "clouds").glob("*.ply"))) == len(lines)
    assert (tmp_path / "l.rrd").stat().st_size > 1000


def test_port_in_use_and_bad_options(dynamic_rec, tmp_path):
    pytest.importorskip("websockets")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        res = _invoke("live", dynamic_rec, "--serve", s.getsockname()[1], "--num-frames", "2")
    assert res.exit_code == 2 and "is in use" in res.output and "Traceback" not in res.output
    res = _invoke("live", dynamic_rec, "--serve", "nohost:port")
    assert res.exit_code == 2 and "--serve expects" in res.output
    res = _invoke("live", dynamic_rec, "--num-frames", "0")
    assert res.exit_code == 2 and "--num-frames must be positive" in res.output
    res = _invoke("live", dynamic_rec, "--frames", "0")  # the deprecated count spelling
    assert res.exit_code == 2 and "deprecated" in res.output and "--num-frames must be positive" in res.output
    res = _invoke("live", dynamic_rec, "--rate", "-1")
    assert res.exit_code == 2 and "--rate" in res.output
    res = _invoke("live", dynamic_rec, "--codec", "draco")
    assert res.exit_code == 2 and "--codec must be one of compact, raw" in res.output
    res = _invoke("live", dynamic_rec, "--grid-mm", "0")
    assert res.exit_code == 2 and "--grid-mm" in res.output and "Traceback" not in res.output


def test_no_extrinsics_and_open_host_warning(tmp_path, dynamic_rec):
    pytest.importorskip("websockets")
    res = _invoke("live", dynamic_rec, "--serve", "0.0.0.0:0", "--num-frames", "1", "--rate", "20")
    assert res.exit_code == 0, res.output
    assert "serving on 0.0.0.0" in res.output and "token" in res.output
    (tmp_path / "rec").mkdir()
    import shutil

    shutil.copytree(dynamic_rec, tmp_path / "rec", dirs_exist_ok=True)
    doc = json.loads((tmp_path / "rec" / "rig.json").read_text())
    for c in doc["cameras"]:
        c["T_cam_world"] = None
    (tmp_path / "rec" / "rig.json").write_text(json.dumps(doc))
    res = _invoke("live", tmp_path / "rec", "--num-frames", "1")
    assert res.exit_code == 2 and "pass --calib" in res.output
