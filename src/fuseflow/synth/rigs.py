"""Camera rigs around the capture volume: ring, dome, or a rig.json; and pairwise overlap.

All cameras look at the scene's target point; extrinsics are camera-from-world with OpenCV axes
(x right, y down, z forward), world z up.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import Camera, Rig

__all__ = ["look_at", "intrinsics", "make_rig", "camera_centres", "with_sensor", "SIM_SENSOR"]


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) camera-from-world of an OpenCV camera at ``eye`` looking at ``target`` with world
    ``up`` appearing up in the image."""
    eye = np.asarray(eye, float)
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K with square pixels, principal point at the image centre ((W-1)/2, (H-1)/2)."""
    f = (width / 2) / math.tan(math.radians(hfov_deg) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])


def _ring_eyes(n: int, target: np.ndarray, radius: float, height: float, phase: float) -> list[np.ndarray]:
    return [
        np.array([target[0] + radius * math.cos(a), target[1] + radius * math.sin(a), height])
        for a in (phase + 2 * math.pi * k / n for k in range(n))
    ]


def _dome_eyes(n: int, target: np.ndarray, radius: float, elev: tuple[float, float]) -> list[np.ndarray]:
    rings = max(2, min(5, round(math.sqrt(n / 4))))
    els = np.radians(np.linspace(elev[0], elev[1], rings))
    w = np.cos(els)
    counts = np.floor(n * w / w.sum()).astype(int)
    counts[0] += n - counts.sum()
    eyes = []
    for k, (e, c) in enumerate(zip(els, counts)):
        r = radius * math.cos(e)
        eyes += _ring_eyes(int(c), target, r, target[2] + radius * math.sin(e), phase=0.5 * k * 2 * math.pi / max(c, 1))
    return eyes


def make_rig(
    layout: str, n: int, width: int, height: int, hfov_deg: float, depth_scale: float,
    depth_range: tuple[float, float], scene, rng: np.random.Generator,
) -> Rig:  # fmt: skip
    """The rig of a config: ``layout`` 'auto' | 'ring' | 'dome' | path to a rig.json.

    Camera positions get a small seeded jitter (+-5 cm, +-2 deg of ring angle) so that no two
    rigs of different seeds are identical and no symmetry is exact.
    """
    if layout not in ("auto", "ring", "dome"):
        path = Path(layout)
        if not path.exists():
            raise ValidationError(f"SimConfig.rig: expected 'auto', 'ring', 'dome' or a rig.json path, got {layout!r}")
        from fuseflow.io import read_rig

        rig = read_rig(path)
        if not rig.is_calibrated:
            raise ValidationError(f"{path}: a rig file for the simulator needs T_cam_world for every camera")
        if len(rig) != n:
            raise ValidationError(f"{path}: holds {len(rig)} cameras but {n} were asked for (--cameras)")
        return rig
    K = intrinsics(width, height, hfov_deg)
    target = scene.target
    if scene.name in ("symstudio", "farroom"):
        from fuseflow.synth.studios import far_eyes, studio_eyes

        pairs = studio_eyes(n, layout != "ring", scene.symmetry) if scene.name == "symstudio" else far_eyes(n, rng)
        eyes, targets = [e for e, _ in pairs], [t for _, t in pairs]
        jitter = True
    elif scene.name == "wall":
        # a row of cameras 2 m in front of the wall, 0.3 m apart, looking straight at it
        eyes = [np.array([0.0, 0.3 * (k - (n - 1) / 2), 1.0]) for k in range(n)]
        targets = [e + np.array([2.0, 0, 0]) for e in eyes]
        jitter = False
    else:
        if layout == "ring" or (layout == "auto" and n <= 16):
            eyes = _ring_eyes(n, target, scene.ring_radius, scene.ring_height, phase=0.3)
        else:
            eyes = _dome_eyes(n, target, scene.dome_radius, scene.dome_elevations)
        targets = [target] * n
        jitter = True
    cams = []
    for k, (eye, tgt) in enumerate(zip(eyes, targets)):
        if jitter:
            eye = eye + rng.uniform(-0.05, 0.05, 3)
            tgt = tgt + rng.uniform(-0.1, 0.1, 3)
        cams.append(
            Camera(
                f"cam{k:02d}",
                width,
                height,
                K,
                depth_scale=depth_scale,
                depth_range=depth_range,
                T_cam_world=look_at(eye, tgt),
            )  # fmt: skip
        )
    return Rig(tuple(cams))


#: SimConfig.noise -> the fuseflow.geometry.noise preset its rig.json names per camera
#: ("none": no sensor, the global choice).
SIM_SENSOR: dict[str, str | None] = {"kinect": "kinect_v1", "realsense": "realsense_d4xx", "kinect2": "kinect_v2",
                                     "azure": "azure_kinect", "none": None}  # fmt: skip


def with_sensor(rig: Rig, sensor: str | None) -> Rig:
    """``rig`` with ``sensor`` (a noise preset name) on every camera that names none."""
    if sensor is None:
        return rig
    return Rig(tuple(c if c.sensor is not None else replace(c, sensor=sensor) for c in rig.cameras))


def camera_centres(rig: Rig) -> np.ndarray:
    """(N, 3) camera centres in world metres."""
    return np.stack([c.T_world_cam[:3, 3] for c in rig.cameras])
