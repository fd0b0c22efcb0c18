"""Fault injection: each test breaks one thing a user can break, runs the CLI as a user would,
and checks the exit code, that no traceback is printed, and the key words of the message."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from fuseflow.synth import SimConfig, simulate_recording

RES = (160, 120)


def make_recording(out: Path, cameras: int = 3, frames: int = 2, seed: int = 4, resolution=RES, **kw) -> Path:
    """A small simulated studio recording with ground-truth extrinsics in rig.json."""
    cfg = SimConfig(cameras=cameras, frames=frames, scene="studio", resolution=resolution, seed=seed, **kw)
    simulate_recording(out, cfg)
    return out


@pytest.fixture(scope="session")
def small_rec(tmp_path_factory) -> Path:
    """Read-only for tests: copy it (``copy_rec``) before breaking anything."""
    return make_recording(tmp_path_factory.mktemp("faults") / "rec")


def invoke(*args):
    """Run the CLI in-process; returns typer's Result."""
    from fuseflow.cli import app

    return CliRunner().invoke(app, [str(a) for a in args])


def expect(res, code: int, *words: str) -> None:
    """Exit code ``code``, no traceback, every word in the output."""
    out = res.output
    assert res.exit_code == code, f"exit {res.exit_code}, expected {code}:\n{out}\n{res.exception!r}"
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "Traceback" not in out, out
    flat = " ".join(out.split())  # rich wraps long lines at the terminal width
    for w in words:
        assert w in out or w in flat, f"{w!r} not in:\n{out}"


@pytest.fixture(name="invoke")
def _invoke_fixture():
    return invoke


@pytest.fixture(name="expect")
def _expect_fixture():
    return expect


@pytest.fixture(name="make_recording", scope="session")
def _make_recording_fixture():
    return make_recording
