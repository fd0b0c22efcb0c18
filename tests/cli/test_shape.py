"""One CLI shape: one --frames grammar, fuse and run digest FuseConfig alike, the API shares the
CLI's defaults, and a resume mismatch names the settings that differ."""

from __future__ import annotations

import inspect
import json

import pytest
from typer.testing import CliRunner

from fuseflow.cli import app
from fuseflow.errors import OutputError, ValidationError
from fuseflow.fuse import PRESETS
from fuseflow.fuse.presets import preset_config
from fuseflow.io.convert import parse_frame_range
from fuseflow.pipeline import PipelineConfig


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def rec(tmp_path_factory):
    from fuseflow.synth import SimConfig, simulate_recording

    out = tmp_path_factory.mktemp("shape") / "rec"
    simulate_recording(out, SimConfig(cameras=3, frames=3, resolution=(96, 72), seed=2))
    return out


@pytest.mark.parametrize(
    ("spec", "want"),
    [
        (None, [0, 1, 2, 3, 4, 5]),
        ("1:4", [1, 2, 3]),
        ("0:6:2", [0, 2, 4]),
        ("-2:", [4, 5]),
        (":-4", [0, 1]),
        ("::3", [0, 3]),
    ],
)
def test_one_frames_grammar(spec, want):
    assert list(parse_frame_range(spec, 6)) == want


@pytest.mark.parametrize(
    ("spec", "msg"), [("3", "expected A:B"), ("a:b", "expected A:B"), ("0:4:0", "step must be positive")]
)
def test_bad_frames_spec_is_one_clear_error(spec, msg):
    with pytest.raises(ValidationError, match=msg):
        parse_frame_range(spec, 6)


def test_frames_step_and_empty_selection_on_the_cli(rec, tmp_path):
    r = _invoke("fuse", rec, "--out", tmp_path / "a", "--frames", "0:3:2", "--preset", "live")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "a" / "clouds").glob("*.ply")) == ["000000.ply", "000002.ply"]
    r = _invoke("run", rec, "--out", tmp_path / "b", "--use-rig", "--frames", "5:9")
    assert r.exit_code == 2 and "selects no frame" in r.output


def test_api_and_cli_share_run_defaults():
    from fuseflow.cli import run as run_cli

    params = inspect.signature(run_cli.command).parameters
    cfg = PipelineConfig()
    assert params["sync_offsets"].default.default == cfg.sync == "check"
    assert params["recalibrate"].default.default == cfg.recalibrate
    assert params["device"].default.default == cfg.device
    assert preset_config(params["preset"].default.default, params["points"].default.default) == cfg.fuse_config()


def test_fuse_and_run_digest_the_same_fuse_config(rec):
    from fuseflow.io import open_recording
    from fuseflow.pipeline.config import OutputOptions
    from fuseflow.pipeline.fuse_only import _manifest
    from fuseflow.pipeline.runner import run_manifest

    recording = open_recording(rec)
    cfg = preset_config("live", 1000)
    f = _manifest(recording, recording.rig, cfg, OutputOptions())
    r = run_manifest(recording, None, PipelineConfig(fuse=cfg), None, True)
    assert f.settings["fuse"] == r.settings["fuse"]
    assert json.loads(json.dumps(f.settings["fuse"])) == json.loads(json.dumps(r.settings["fuse"]))


def test_resume_mismatch_names_the_settings_that_differ(rec, tmp_path):
    out = tmp_path / "out"
    assert _invoke("fuse", rec, "--out", out, "--frames", "0:1").exit_code == 0
    r = _invoke("fuse", rec, "--out", out, "--frames", "0:1", "--preset", "live")
    assert r.exit_code == 2
    text = " ".join(r.output.split())
    assert "fuse.pixel_stride was 1, now 2" in text and "fuse.s0 was 5.0, now 1.0" in text, text


def test_mismatch_with_an_old_manifest_falls_back_to_digests(tmp_path):
    from fuseflow.pipeline.outputs import OutputManifest, open_output

    old = dict(
        command="fuse", recording="r", recording_fingerprint="f", calibration="c", config="aaaa", fuseflow_version="v"
    )
    (tmp_path / "manifest.json").write_text(json.dumps(old))
    new = OutputManifest(**{**old, "config": "bbbb"}, settings={"fuse": {"s0": 1.0}})
    with pytest.raises(OutputError, match="settings: was aaaa, now bbbb"):
        open_output(tmp_path, new)


def test_count_options_are_num_frames_and_the_old_spelling_warns(tmp_path):
    r = _invoke("simulate", tmp_path / "a", "--cameras", "2", "--num-frames", "1", "--resolution", "32x24")
    assert r.exit_code == 0, r.output
    r = _invoke("simulate", tmp_path / "b", "--cameras", "2", "--frames", "2", "--resolution", "32x24")
    assert r.exit_code == 0, r.output
    assert "--frames 2 as a count is deprecated: use --num-frames 2" in " ".join(r.output.split())
    assert len(list((tmp_path / "b").rglob("depth/*.png"))) > len(list((tmp_path / "a").rglob("depth/*.png")))


def test_the_api_fuses_with_the_cli_default_preset():
    assert preset_config("auto") == PRESETS["auto"] == PipelineConfig().fuse_config()
    assert PRESETS["auto"].auto_grid and not PRESETS["default"].auto_grid
