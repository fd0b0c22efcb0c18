"""The frame outputs are written in (``--world``): a level floor frame, or one camera's frame.

A calibration's world is whatever its extrinsics say (the first camera's frame for GMAC, the
recording's for rig.json). Content tools want "up": a ``World`` maps the calibration's world
into the output frame with ``T_out_world`` (output-from-calibration-world, rigid).

- **floor** (``floor_frame``): origin on the floor plane under a given centre (the capture
  volume's), z up along the floor normal, x along the direction from that origin towards the
  first camera's centre projected onto the floor, y = z x x. Metres, right-handed.
- **camera:ID** (``camera_frame``): the camera's own frame (OpenCV axes: x right, y down, z
  forward), the frame of that camera's depth.
- **calib**: the calibration's world, unchanged (the identity).

The floor itself is the consensus of planes measured by several cameras (``floor_consensus``):
each camera's floor plane carried into the calibration's world (``n . X + d = 0``, n up).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError

__all__ = ["World", "floor_consensus", "floor_frame", "camera_frame", "GLTF_FROM_Z_UP", "GLTF_FROM_OPENCV"]

FLOOR_AGREE_DEG = 5.0
"""Two cameras' floor planes agree when their normals are within this angle ..."""
FLOOR_AGREE_M = 0.05
"""... and their offsets within this distance (metres)."""

GLTF_FROM_Z_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64)
"""glTF axes (+y up) from a z-up frame: (x, y, z) -> (x, z, -y) (a rotation)."""
GLTF_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
"""glTF axes (+y up, camera looking along -z) from OpenCV camera axes (y down, z forward)."""


@dataclass(frozen=True)
class World:
    """The output frame: ``name`` ("floor", "camera:<id>" or "calib") and ``T_out_world``
    (output-from-calibration-world). ``floor``: the floor plane in the calibration's world
    (``{"normal": [3], "offset": d, "cameras": [...]}``) when one was found, else None."""

    name: str
    T_out_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    floor: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        T = np.asarray(self.T_out_world, np.float64)
        if (
            T.shape != (4, 4)
            or not np.isfinite(T).all()
            or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6)
        ):
            raise ValidationError("world: T_out_world must be a 4x4 rigid transform")
        object.__setattr__(self, "T_out_world", T)

    @property
    def up(self) -> list[float]:
        """The output frame's up axis: +z for the floor frame; for the others the floor normal
        carried into it when known, else -y (the first camera's image up)."""
        if self.name == "floor":
            return [0.0, 0.0, 1.0]
        if self.floor is not None:
            n = self.T_out_world[:3, :3] @ np.asarray(self.floor["normal"], np.float64)
            return np.round(n / np.linalg.norm(n), 6).tolist()
        return [0.0, -1.0, 0.0]

    @property
    def gltf_from_out(self) -> np.ndarray:
        """(4, 4) glTF axes from the output frame: z-up frames rotate z to +y; a camera frame
        (OpenCV) turns to glTF's camera axes; the calibration's world is rotated so that its up
        (``up``) becomes +y when a floor is known."""
        if self.name == "floor":
            return GLTF_FROM_Z_UP
        if self.name.startswith("camera:") and self.floor is None:
            return GLTF_FROM_OPENCV
        return _rotation_to_y(np.asarray(self.up, np.float64))

    def apply(self, xyz: np.ndarray) -> np.ndarray:
        """(M, 3) float32 points of the calibration's world in the output frame."""
        if self.name == "calib":
            return np.asarray(xyz)
        T = self.T_out_world
        return (np.asarray(xyz, np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)

    def rotate(self, vectors: np.ndarray) -> np.ndarray:
        """(M, 3) float32 directions (normals) in the output frame."""
        return (np.asarray(vectors, np.float64) @ self.T_out_world[:3, :3].T).astype(np.float32)

    def to_json(self) -> dict[str, Any]:
        """calib.json's and manifest.json's ``world`` entry."""
        return {
            "name": self.name,
            "T_out_world": np.round(self.T_out_world, 9).tolist(),
            "up": self.up,
            "units": "m",
            "floor": self.floor,
        }

    @classmethod
    def from_json(cls, doc: Any, where: str = "world") -> World:
        """Inverse of ``to_json``; ValidationError naming ``where`` on a malformed entry."""
        if not isinstance(doc, dict) or not isinstance(doc.get("name"), str) or "T_out_world" not in doc:
            raise ValidationError(f"{where}: expected an object with 'name' and 'T_out_world'")
        try:
            T = np.array(doc["T_out_world"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"{where}: T_out_world must be a 4x4 matrix of numbers ({exc})") from None
        floor = doc.get("floor")
        try:
            return cls(doc["name"], T, floor if isinstance(floor, dict) else None)
        except ValidationError as exc:
            raise ValidationError(f"{where}: {exc}") from None


def _rotation_to_y(up: np.ndarray) -> np.ndarray:
    """(4, 4) a rotation taking unit ``up`` to +y (the smallest one)."""
    y = np.array([0.0, 1.0, 0.0])
    u = up / max(np.linalg.norm(up), 1e-12)
    v, c = np.cross(u, y), float(u @ y)
    T = np.eye(4)
    if c < -1 + 1e-9:  # up is -y: half a turn about x
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])
        return T
    V = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    T[:3, :3] = np.eye(3) + V + V @ V / (1 + c)
    return T


def floor_consensus(planes: dict[str, tuple[np.ndarray, float]], min_cameras: int = 2) -> dict[str, Any] | None:
    """The floor of a rig from its cameras' planes (camera id -> (unit normal n pointing up,
    offset d) with ``n . X + d = 0`` in the calibration's world).

    Planes agree when their normals are within ``FLOOR_AGREE_DEG`` and offsets within
    ``FLOOR_AGREE_M``; of the groups of at least ``min_cameras`` agreeing cameras (at least
    half as many as the largest group), the lowest one is the floor (a table top lies above it).
    Returns ``{"normal", "offset", "cameras"}`` (the median normal, renormalised, and the
    median offset of the group), or None when no group is large enough."""
    ids = sorted(planes)
    if len(ids) < min_cameras:
        return None
    n = np.array([np.asarray(planes[c][0], np.float64) / np.linalg.norm(planes[c][0]) for c in ids])
    d = np.array([float(planes[c][1]) for c in ids])
    agree = (n @ n.T > np.cos(np.radians(FLOOR_AGREE_DEG))) & (np.abs(d[:, None] - d[None, :]) < FLOOR_AGREE_M)
    sizes = agree.sum(axis=1)
    big = sizes >= max(min_cameras, int(np.ceil(sizes.max() / 2)))
    if not big.any():
        return None
    # lowest: the largest height of the rig's centre above the plane (n . X + d at a common X)
    centre = -np.mean(d[:, None] * n, axis=0)
    heights = np.where(big, n @ centre + d, -np.inf)
    members = agree[int(np.argmax(heights))]
    normal = np.median(n[members], axis=0)
    normal /= np.linalg.norm(normal)
    return {
        "normal": np.round(normal, 9).tolist(),
        "offset": round(float(np.median(d[members])), 9),
        "cameras": [c for c, m in zip(ids, members) if m],
    }


def floor_frame(floor: dict[str, Any], centre: np.ndarray, towards: np.ndarray) -> np.ndarray:
    """(4, 4) floor-from-world: origin at the foot of ``centre`` on the floor plane, z along
    its normal, x towards the foot of ``towards`` (the first camera's centre; any horizontal
    direction when it stands right above the origin), y = z x x."""
    z = np.asarray(floor["normal"], np.float64)
    z /= np.linalg.norm(z)
    d = float(floor["offset"])
    c = np.asarray(centre, np.float64)
    origin = c - (z @ c + d) * z
    x = np.asarray(towards, np.float64) - origin
    x -= (x @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: floor axes in world coordinates
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ origin
    return T


def camera_frame(T_cam_world: np.ndarray) -> np.ndarray:
    """(4, 4) the camera's frame: its camera-from-world."""
    return np.asarray(T_cam_world, np.float64).copy()
