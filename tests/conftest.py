"""Shared test fixtures: paths to ../shared/data and small synthetic rigs built by hand."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from fuseflow.io import read_rig, write_rig
from fuseflow.synth import SimConfig, simulate_recording

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
ICL = SHARED_DATA / "icl-livingroom1"
FORMAT_SAMPLES = SHARED_DATA / "format-samples"


def look_at(eye, target, up=(0.0, -1.0, 0.0)) -> np.ndarray:
    """Camera-from-world 4x4 of an OpenCV camera at ``eye`` looking at ``target``.

    ``up`` is the world direction that should appear up in the image (OpenCV y is down, so
    the camera's -y axis is aligned with it as far as possible).
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up), z)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T


@pytest.fixture(scope="session")
def icl_path() -> Path:
    if not ICL.is_dir():
        pytest.skip(f"shared data not found at {ICL}")
    return ICL


@pytest.fixture(scope="session")
def format_samples() -> Path:
    if not FORMAT_SAMPLES.is_dir():
        pytest.skip(f"shared data not found at {FORMAT_SAMPLES}")
    return FORMAT_SAMPLES


# --- small simulated recordings (GT extrinsics in rig.json), shared by pipeline, cli and faults tests
RES = (200, 150)


def simulate(out: Path, frames: int = 6, cameras: int = 4, rig: str = "auto", seed: int = 3, dynamic: bool = False):
    cfg = SimConfig(cameras=cameras, frames=frames, scene="studio", dynamic=dynamic, resolution=RES, seed=seed, rig=rig)
    simulate_recording(out, cfg)
    return out


@pytest.fixture(scope="session")
def static_rec(tmp_path_factory) -> Path:
    return simulate(tmp_path_factory.mktemp("pipe") / "static", frames=6)


@pytest.fixture(scope="session")
def dynamic_rec(tmp_path_factory) -> Path:
    return simulate(tmp_path_factory.mktemp("pipe") / "dynamic", frames=5, dynamic=True)


def rotate_camera(T_cam_world: np.ndarray, deg: float) -> np.ndarray:
    """The camera turned by ``deg`` about its own y axis (a bump), same centre."""
    a = np.radians(deg)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    out = np.eye(4)
    out[:3, :3] = R @ T_cam_world[:3, :3]
    c = -T_cam_world[:3, :3].T @ T_cam_world[:3, 3]
    out[:3, 3] = -out[:3, :3] @ c
    return out


@pytest.fixture(scope="session")
def bumped_rec(tmp_path_factory) -> tuple[Path, str, int, np.ndarray]:
    """8 frames; camera cam01 is turned by 6 degrees from frame 4 on (rig.json keeps the old pose).

    Returns (recording, bumped id, first bumped frame, the bumped camera's true new T_cam_world).
    """
    base = tmp_path_factory.mktemp("bump")
    rec = simulate(base / "rec", frames=8)
    rig = read_rig(rec / "rig.json")
    T_new = rotate_camera(rig["cam01"].T_cam_world, 6.0)
    moved = rig.with_extrinsics({"cam01": T_new})
    (base / "moved").mkdir()
    write_rig(base / "moved", moved)
    other = simulate(base / "other", frames=8, rig=str(base / "moved" / "rig.json"))
    for kind in ("color", "depth"):
        for t in range(4, 8):
            src = sorted((other / "cam01" / kind).glob(f"{t:06d}.*"))[0]
            dst_dir = rec / "cam01" / kind
            for old in dst_dir.glob(f"{t:06d}.*"):
                old.unlink()
            shutil.copy(src, dst_dir / src.name)
    return rec, "cam01", 4, T_new


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """One `fuseflow demo --cameras 8 --num-frames 2 --seed 1` (the README's first command on 2 of
    its 10 frames, 640x480) shared by the tests that need a demo run: (output folder, CLI result)."""
    from typer.testing import CliRunner

    from fuseflow.cli import app

    out = tmp_path_factory.mktemp("demo") / "demo"
    res = CliRunner().invoke(app, ["demo", "--out", str(out), "--cameras", "8", "--num-frames", "2", "--seed", "1"])
    return out, res
