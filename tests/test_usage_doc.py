"""docs/usage.md's walk-through (sections 1-5) run as written, on small data, so that the docs
cannot drift from the CLI: every `fuseflow ...` line of those sections' bash blocks is run in
order with /tmp/ moved to a temporary folder and `simulate` made small (4 cameras, 3 frames,
320x240: the commands and every other option stay as the doc gives them). The demo of section 0
has its own test (tests/pipeline/test_demo.py). Also: every option named in a command's
``--help`` examples exists."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fuseflow.cli import COMMANDS, app

USAGE = Path(__file__).resolve().parents[1] / "docs" / "usage.md"
SMALL = {"--cameras": "4", "--frames": "3", "--resolution": "320x240"}


def walkthrough(text: str) -> list[list[str]]:
    """The `fuseflow` command lines of the bash blocks in sections 1-5, split into arguments."""
    body = text[text.index("\n## 1. ") : text.index("\n## 6. ")]
    out = []
    for block in re.findall(r"```bash\n(.*?)```", body, flags=re.S):
        for line in block.splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("fuseflow "):
                out.append(shlex.split(line)[1:])
    return out


def _small(args: list[str], tmp: Path) -> list[str]:
    args = [a.replace("/tmp/", f"{tmp}/") for a in args]
    if args[0] != "simulate":
        return args
    for opt, value in SMALL.items():
        if opt in args:
            args[args.index(opt) + 1] = value
        else:
            args += [opt, value]
    return args


def test_the_walkthrough_names_every_step():
    names = [a[0] for a in walkthrough(USAGE.read_text())]
    assert names[:7] == ["simulate", "info", "calibrate", "calibrate", "fuse", "run", "view"], names


def test_usage_walkthrough_runs_as_written(tmp_path, monkeypatch):
    from fuseflow.cli import view

    monkeypatch.delenv("DISPLAY", raising=False)  # CI is headless: the doc says what view does then
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(view, "VIEWER_PORT", 1)  # nothing listens there
    runner = CliRunner()
    for args in walkthrough(USAGE.read_text()):
        args = _small(args, tmp_path)
        res = runner.invoke(app, args)
        if args[0] == "view" and len(args) == 2:  # the viewer form, without a display
            assert res.exit_code == 2 and "--rrd" in res.output and "--save-png" in res.output, res.output
            continue
        assert res.exit_code == 0, f"fuseflow {' '.join(args)} -> exit {res.exit_code}:\n{res.output}"
        assert "Traceback" not in res.output
    assert len(list((tmp_path / "studio-run" / "clouds").glob("*.ply"))) == 3
    assert len(list((tmp_path / "png").glob("*.png"))) == 3
    assert (tmp_path / "run.rrd").stat().st_size > 0


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_examples_use_real_options(name):
    examples = getattr(COMMANDS[name], "EXAMPLES", "")
    assert f"fuseflow {name}" in examples, f"{name}: no --help examples"
    res = CliRunner().invoke(app, [name, "--help"])
    assert res.exit_code == 0 and "Examples:" in res.output
    for opt in set(re.findall(r"\s(--[a-z][a-z-]*)", examples)):
        assert opt in res.output, f"{name} --help examples use {opt}, which it does not have"
