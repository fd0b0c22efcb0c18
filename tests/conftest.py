"""Shared test fixtures: paths to ../shared/data and small synthetic rigs built by hand."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

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
