"""The CLI's console: text printed verbatim (no rich markup eaten), native libraries' stderr noise
kept off the terminal, commands registered in one list."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from typer.testing import CliRunner

from fuseflow.cli import app


def test_help_and_errors_keep_square_brackets(tmp_path):
    res = CliRunner().invoke(app, ["run", "--help"])
    assert "pip install 'fuseflow[ray]'" in " ".join(res.output.split())  # help wraps at the terminal width
    res = CliRunner().invoke(app, ["info", str(tmp_path / "no[pe]")])
    assert res.exit_code == 2 and "no[pe]" in res.output


def test_native_stderr_goes_to_the_log_not_the_terminal(tmp_path):
    script = textwrap.dedent(
        """
        import functools, os, sys
        sys.argv = ["fuseflow", "info", "/nonexistent-recording"]
        import fuseflow.cli as c
        orig = c.info.command
        @functools.wraps(orig)
        def noisy(*a, **k):
            os.write(2, b"libpng warning: iCCP: known incorrect sRGB profile\\n")
            return orig(*a, **k)
        [x for x in c.app.registered_commands if x.name == "info"][0].callback = c.guarded(noisy)
        c.main()
        """
    )
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    env.pop("FUSEFLOW_VERBOSE", None)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip() == "error: /nonexistent-recording: no such file or directory"
    assert "libpng" in (tmp_path / "fuseflow-native.log").read_text()
    env["FUSEFLOW_VERBOSE"] = "1"
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert "libpng warning" in proc.stderr and "error: /nonexistent-recording" in proc.stderr


def test_stage_progress_plain_lines_when_piped_and_a_bar_on_a_terminal(monkeypatch):
    import importlib
    import io

    from rich.console import Console

    app_mod = importlib.import_module("fuseflow.cli.app")

    def feed(cb):
        cb("rgbd: backbone", 0, 0)
        for k in range(1, 21):
            cb("rgbd: pairs", k, 20)
        cb("report", 0, 0)

    piped = io.StringIO()
    monkeypatch.setattr(app_mod, "console", Console(file=piped, width=100))
    with app_mod.StageProgress("calibrate: ") as cb:
        feed(cb)
    lines = piped.getvalue().splitlines()
    assert lines[0] == "calibrate: rgbd: backbone" and lines[-1] == "calibrate: report"
    pairs = [x for x in lines if "pairs" in x]
    assert pairs[0] == "calibrate: rgbd: pairs: 0/20" and pairs[-1] == "calibrate: rgbd: pairs: 20/20"
    assert len(pairs) <= 12  # about every 10 %, not one line per pair
    tty = io.StringIO()
    monkeypatch.setattr(app_mod, "console", Console(file=tty, width=100, force_terminal=True))
    with app_mod.StageProgress("calibrate: ") as cb:
        feed(cb)
    assert "\x1b[" in tty.getvalue() and "calibrate: rgbd: pairs: 0/20\n" not in tty.getvalue()
