"""The capture volume: the region a rig's cameras look at together, as a box.

A ``CaptureVolume`` is an axis-aligned box ``[lo, hi]`` (metres) in its own frame, placed in the
world by ``T_box_world`` (box-from-world, rigid; the identity for a box given in world
coordinates, e.g. ``--crop xmin,ymin,zmin,xmax,ymax,zmax``). ``capture_volume(rig)`` computes it
from the calibrated cameras:

- **ring / dome** (the cameras surround a common aim point): the aim point ``p`` is the
  least-squares closest point to every optical axis. The cameras surround it when the largest
  gap between their azimuths around ``p`` (in the plane across the rig's least-spread axis ``n``,
  the ring's axis) is under 150 degrees. The box is centred on ``p``, oriented along ``n`` (its
  +z towards the cameras' side), with half-width ``RING_SHARE`` (0.7) of the median distance of
  the cameras from the axis in all three directions: the space inside the ring, so walls,
  the floor beyond the stage and rig stands (under the cameras) fall outside.
- **one side** (otherwise, or fewer than 3 cameras): where the frusta overlap within each
  camera's depth range: a grid of rays x depths of every frustum, the samples that at least
  ``min(2, N)`` cameras see in front of them within their depth range, their 1st-99th
  percentile box in world axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import FusedCloud, Rig, as_tensor, to_numpy

__all__ = [
    "CaptureVolume",
    "capture_volume",
    "covisible_points",
    "seen_count",
    "seen_volume",
    "aim_point",
    "parse_crop",
    "crop_cloud",
    "RING_SHARE",
    "HEADROOM_M",
]

RING_SHARE = 0.7
"""Half-width of a ring's box as a share of the cameras' median distance from the ring axis
(0.7: the box's horizontal corners, at 0.99 of that distance, stay inside the ring)."""

_MAX_GAP_DEG = 150.0


#: calib.json's ``capture_volume`` ``units`` and their size in metres (``from_json`` converts).
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass(frozen=True)
class CaptureVolume:
    """A box ``lo <= T_box_world @ X <= hi`` (metres); ``kind`` says how it was made."""

    lo: np.ndarray
    hi: np.ndarray
    T_box_world: np.ndarray = field(default_factory=lambda: np.eye(4))
    kind: str = "explicit"
    """"explicit" (given), "seen" / "seen-ring" (what the cameras see together, ``seen_volume``),
    "ring" (cameras around an aim point) or "frusta" (overlap of frusta)."""
    radius: float | None = None
    """When set, the box is also cut to the vertical cylinder (along the box frame's z) of this
    radius around ``axis`` (metres)."""
    axis: tuple[float, float] | None = None
    """(x, y) of the cylinder's axis in the box frame (with ``radius``)."""

    def __post_init__(self) -> None:
        lo, hi = np.asarray(self.lo, np.float64).reshape(-1), np.asarray(self.hi, np.float64).reshape(-1)
        T = np.asarray(self.T_box_world, np.float64)
        if lo.shape != (3,) or hi.shape != (3,):
            raise ValidationError(f"capture volume: lo and hi must be 3 numbers each, got {lo.size} and {hi.size}")
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            raise ValidationError(f"capture volume: bounds must be finite numbers, got {lo.tolist()} {hi.tolist()}")
        bad = [a for a, lo_a, hi_a in zip("xyz", lo, hi) if lo_a >= hi_a]
        if bad:
            raise ValidationError(
                f"capture volume: min must be below max on every axis ({', '.join(bad)} is not): "
                f"min {lo.tolist()}, max {hi.tolist()}"
            )
        if (
            T.shape != (4, 4)
            or not np.isfinite(T).all()
            or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-5)
        ):
            raise ValidationError("capture volume: T_box_world must be a 4x4 rigid transform")
        if self.radius is not None and not (math.isfinite(self.radius) and self.radius > 0 and self.axis is not None):
            raise ValidationError(f"capture volume: radius must be a positive number with an axis, got {self.radius!r}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "T_box_world", T)
        if self.axis is not None:
            object.__setattr__(self, "axis", (float(self.axis[0]), float(self.axis[1])))

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """(M,) bool: which world points (M, 3) lie inside the box."""
        xyz = np.asarray(xyz, np.float64).reshape(-1, 3)
        p = xyz @ self.T_box_world[:3, :3].T + self.T_box_world[:3, 3]
        inside = np.all((p >= self.lo) & (p <= self.hi), axis=1)
        if self.radius is not None:
            inside &= np.hypot(p[:, 0] - self.axis[0], p[:, 1] - self.axis[1]) <= self.radius
        return inside

    def corners(self) -> np.ndarray:
        """(8, 3) world coordinates of the box's corners."""
        c = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float64)
        box = self.lo + c * (self.hi - self.lo)
        R, t = self.T_box_world[:3, :3], self.T_box_world[:3, 3]
        return (box - t) @ R

    def centre(self) -> np.ndarray:
        """(3,) world coordinates of the box's centre."""
        return self.corners().mean(axis=0)

    def to_json(self) -> dict[str, Any]:
        """calib.json's ``capture_volume`` entry (io.calibration writes it)."""
        doc = {
            "min": [round(float(v), 6) for v in self.lo],
            "max": [round(float(v), 6) for v in self.hi],
            "T_box_world": np.round(self.T_box_world, 9).tolist(),
            "kind": self.kind,
            "units": "m",
        }
        if self.radius is not None:
            doc["radius"] = round(float(self.radius), 6)
            doc["axis"] = [round(v, 6) for v in self.axis]
        return doc

    @classmethod
    def from_json(cls, doc: Any, where: str = "capture_volume") -> CaptureVolume:
        """Inverse of ``to_json``; ``T_box_world`` optional (identity: world axes); ``units`` "m"
        (default), "cm" or "mm" (bounds and the box's translation converted to metres).
        ValidationError naming ``where`` on a malformed entry or other units."""
        if not isinstance(doc, dict) or "min" not in doc or "max" not in doc:
            raise ValidationError(f"{where}: expected an object with 'min' and 'max' (3 numbers each, metres)")
        try:
            lo = np.array(doc["min"], dtype=np.float64)
            hi = np.array(doc["max"], dtype=np.float64)
            T = np.array(doc.get("T_box_world", np.eye(4)), dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"{where}: min, max and T_box_world must be numbers ({exc})") from None
        units = doc.get("units", "m")
        if units not in UNITS:
            raise ValidationError(f"{where}: units must be one of {sorted(UNITS)} (default m), got {units!r}")
        lo, hi = lo * UNITS[units], hi * UNITS[units]
        T = np.array(T)
        if T.shape == (4, 4):
            T[:3, 3] *= UNITS[units]
        try:
            radius = None if doc.get("radius") is None else float(doc["radius"])
            axis = None if doc.get("axis") is None else tuple(float(v) for v in doc["axis"])[:2]
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"{where}: radius and axis must be numbers ({exc})") from None
        try:
            return cls(lo, hi, T, str(doc.get("kind", "explicit")), radius, axis)
        except ValidationError as exc:
            raise ValidationError(f"{where}: {exc}") from None


def parse_crop(text: str) -> CaptureVolume:
    """``"xmin,ymin,zmin,xmax,ymax,zmax"`` (metres, world frame) -> an explicit CaptureVolume;
    ValidationError in one line for a wrong count, a non-number, NaN or min >= max."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 6:
        raise ValidationError(
            f"--crop: expected 'auto' or 6 numbers xmin,ymin,zmin,xmax,ymax,zmax (metres), got {len(parts)}: {text!r}"
        )
    try:
        v = [float(p) for p in parts]
    except ValueError:
        raise ValidationError(f"--crop: not numbers: {text!r} (expected xmin,ymin,zmin,xmax,ymax,zmax)") from None
    if not all(math.isfinite(x) for x in v):
        raise ValidationError(f"--crop: bounds must be finite, got {text!r}")
    try:
        return CaptureVolume(np.array(v[:3]), np.array(v[3:]))
    except ValidationError as exc:
        raise ValidationError(f"--crop {text!r}: {str(exc).removeprefix('capture volume: ')}") from None


def crop_cloud(cloud: FusedCloud, volume: CaptureVolume | None) -> FusedCloud:
    """The points of ``cloud`` inside ``volume`` (all of them when ``volume`` is None)."""
    if volume is None or len(cloud) == 0:
        return cloud
    keep = volume.contains(to_numpy(cloud.xyz))
    if not cloud.is_numpy:
        keep = as_tensor(keep, cloud.xyz.device)
    sup = None if cloud.support is None else cloud.support[keep]
    return FusedCloud(cloud.xyz[keep], cloud.rgb[keep], cloud.weight[keep], cloud.camera[keep], sup)


def aim_point(centres: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares closest point to the lines ``centres[i] + s axes[i]`` and the conditioning
    of the problem (smallest eigenvalue of sum(I - a a^T) / N: 0 for parallel axes)."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, a in zip(centres, axes):
        P = np.eye(3) - np.outer(a, a)
        A += P
        b += P @ c
    cond = float(np.linalg.eigvalsh(A / max(len(centres), 1))[0])
    return np.linalg.lstsq(A, b, rcond=None)[0], cond


def _ring_volume(centres: np.ndarray, axes: np.ndarray) -> CaptureVolume | None:
    """The box inside a ring or dome of cameras around their aim point, or None when the cameras
    do not surround it (largest azimuth gap >= 150 degrees, or the axes nearly parallel)."""
    if len(centres) < 3:
        return None
    p, cond = aim_point(centres, axes)
    if cond < 0.05:
        return None
    d = centres - p
    in_front = np.einsum("ij,ij->i", -d, axes) > 0  # the aim point lies ahead of each camera
    if not in_front.all():
        return None
    n = np.linalg.eigh(np.cov((d - d.mean(axis=0)).T))[1][:, 0]  # least-spread axis: the ring's axis
    if d.mean(axis=0) @ n < 0:
        n = -n
    a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    az = np.sort(np.degrees(np.arctan2(d @ b, d @ a)))
    gaps = np.diff(np.concatenate([az, az[:1] + 360.0]))
    if gaps.max() >= _MAX_GAP_DEG:
        return None
    radial = np.linalg.norm(d - np.outer(d @ n, n), axis=1)
    h = RING_SHARE * float(np.median(radial))
    R = np.stack([a, b, n])  # box-from-world rotation
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ p
    return CaptureVolume(np.full(3, -h), np.full(3, h), T, "ring")


def _frusta_volume(rig: Rig, grid: int = 12, depths: int = 16) -> CaptureVolume:
    """The world box (1st-99th percentile) of the frustum samples that at least min(2, N)
    cameras see within their depth range."""
    samples = []
    for cam in rig:
        u, v = np.meshgrid(np.linspace(0, cam.width - 1, grid), np.linspace(0, cam.height - 1, grid))
        rays = np.linalg.solve(cam.K, np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
        z = np.linspace(cam.depth_range[0], cam.depth_range[1], depths)
        Xc = (rays[:, :, None] * z).reshape(3, -1).T
        R, t = cam.T_cam_world[:3, :3], cam.T_cam_world[:3, 3]
        samples.append((Xc - t) @ R)
    pts = np.concatenate(samples)
    seen = np.zeros(len(pts), np.int64)
    for cam in rig:
        Xc = pts @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (Xc @ cam.K.T)[:, :2] / z[:, None]
        ok = (z >= cam.depth_range[0]) & (z <= cam.depth_range[1])
        ok &= (uv[:, 0] >= -0.5) & (uv[:, 0] <= cam.width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cam.height - 0.5)
        seen += ok
    keep = pts[seen >= min(2, len(rig))]
    if len(keep) < 8:  # no overlap: the frusta's union
        keep = pts
    lo, hi = np.percentile(keep, 1, axis=0), np.percentile(keep, 99, axis=0)
    hi = np.maximum(hi, lo + 1e-3)
    return CaptureVolume(lo, hi, np.eye(4), "frusta")


def capture_volume(rig: Rig) -> CaptureVolume:
    """The capture volume of a calibrated rig (see the module docstring); ValidationError when a
    camera has no extrinsics."""
    missing = [c.id for c in rig if not c.is_calibrated]
    if missing:
        raise ValidationError(f"capture volume: cameras {missing} have no extrinsics")
    poses = [c.T_world_cam for c in rig]
    centres = np.array([T[:3, 3] for T in poses])
    axes = np.array([T[:3, 2] / np.linalg.norm(T[:3, 2]) for T in poses])
    ring = _ring_volume(centres, axes)
    return ring if ring is not None else _frusta_volume(rig)


HEADROOM_M = 2.2
"""The seen volume reaches at most this far above the floor, or 0.3 m above the highest
camera when that is higher (metres): a standing person's head is kept, a ceiling is not."""
COVISIBLE_TOL_M = 0.02
"""Another camera agrees with a point when its depth at the point's pixel is within this ..."""
COVISIBLE_TOL_REL = 0.03
"""... plus this share of the depth."""
SEEN_MARGIN_M = 0.05
"""Margin added around the seen points on every side (metres)."""


def _backproject(depth: np.ndarray, cam, stride: int) -> np.ndarray:
    """(M, 3) world points of every ``stride``-th pixel of ``depth`` within the depth range."""
    d = np.asarray(depth, np.float64)[::stride, ::stride]
    v, u = np.nonzero((d >= cam.depth_range[0]) & (d <= cam.depth_range[1]))
    z = d[v, u]
    K = cam.K
    Xc = np.stack([(u * stride - K[0, 2]) / K[0, 0] * z, (v * stride - K[1, 2]) / K[1, 1] * z, z], axis=1)
    R, t = cam.T_cam_world[:3, :3], cam.T_cam_world[:3, 3]
    return (Xc - t) @ R


def _agrees(X: np.ndarray, depth: np.ndarray, cam) -> np.ndarray:
    """(M,) bool: ``cam`` sees the world points X where its depth says a surface is."""
    Xc = X @ cam.T_cam_world[:3, :3].T + cam.T_cam_world[:3, 3]
    z = Xc[:, 2]
    ok = (z >= cam.depth_range[0]) & (z <= cam.depth_range[1])
    zs = np.where(ok, z, 1.0)
    u = np.rint(cam.K[0, 0] * Xc[:, 0] / zs + cam.K[0, 1] * Xc[:, 1] / zs + cam.K[0, 2]).astype(np.int64)
    v = np.rint(cam.K[1, 1] * Xc[:, 1] / zs + cam.K[1, 2]).astype(np.int64)
    h, w = depth.shape
    ok &= (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = np.where(ok, depth[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)], 0.0)
    return ok & (d > 0) & (np.abs(d - z) < COVISIBLE_TOL_M + COVISIBLE_TOL_REL * z)


def seen_count(xyz: np.ndarray, depths, rig: Rig) -> np.ndarray:
    """(M,) how many cameras of ``rig`` see the world points ``xyz`` (M, 3): the point lies in
    the camera's frustum within its depth range and the camera's depth at its pixel agrees
    (within ``COVISIBLE_TOL_M`` + ``COVISIBLE_TOL_REL`` of the depth). ``depths``: one (H, W)
    depth image (metres, 0 = none) per camera, or None for a camera without a view."""
    X = np.asarray(xyz, np.float64).reshape(-1, 3)
    n = np.zeros(len(X), np.int64)
    for d, cam in zip(depths, rig):
        if d is not None and cam.is_calibrated:
            n += _agrees(X, np.asarray(d, np.float64), cam)
    return n


def covisible_points(depths, rig: Rig, stride: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Every ``stride``-th depth pixel of each camera as a world point (M, 3), and (M,) how many
    cameras see it: 1 (its own) plus the others that see it (``seen_count``). ``depths``: one
    (H, W) depth image (metres, 0 = none) per camera of ``rig``, or None for a camera without a
    view."""
    pts, counts = [], []
    for i, cam in enumerate(rig):
        if depths[i] is None or not cam.is_calibrated:
            continue
        X = _backproject(depths[i], cam, stride)
        others = [None if j == i else d for j, d in enumerate(depths)]
        pts.append(X)
        counts.append(1 + seen_count(X, others, rig))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(pts), np.concatenate(counts)


def _surrounded(centres_xy: np.ndarray, middle: np.ndarray) -> bool:
    """Whether cameras (xy on the floor) surround ``middle``: their largest azimuth gap is under
    150 degrees."""
    if len(centres_xy) < 3:
        return False
    d = centres_xy - middle
    az = np.sort(np.degrees(np.arctan2(d[:, 1], d[:, 0])))
    gaps = np.diff(np.concatenate([az, az[:1] + 360.0]))
    return bool(gaps.max() < _MAX_GAP_DEG)


RING_REACH_M = 0.5
"""A ring's seen volume reaches this far beyond its farthest camera from the middle of what the
cameras see (metres): a subject leaning in between the cameras is kept (HO-Cap's seated
person reaches 0.3 m beyond them), a studio's walls, a metre or more behind the cameras, are
not. Measured with ``python -m benchmarks.outputs_world_crop`` (docs/formats.md, "Crop")."""


def _ring(P: np.ndarray, cams: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(middle, radius) of the cylinder a ring keeps (``seen_volume``), or None when the cameras
    (floor-frame centres) do not surround the middle of the points P."""
    if len(P) < 100 or len(cams) < 3:
        return None
    middle = np.median(P[:, :2], axis=0)
    if not _surrounded(cams[:, :2], middle):
        return None
    return middle, float(np.linalg.norm(cams[:, :2] - middle, axis=1).max()) + RING_REACH_M


def seen_volume(
    xyz: np.ndarray, count: np.ndarray, rig: Rig, T_floor_world: np.ndarray | None, min_cameras: int | None = None
) -> CaptureVolume | None:
    """The box of what several cameras see together (``covisible_points``): at least
    ``min_cameras`` (default: 2 in a ring, half the placed cameras, at least 2, on one side).

    With a floor frame ``T_floor_world`` (floor-from-world, z up), the box is in that frame:
    only the seen points above the floor (z > ``SEEN_MARGIN_M``) and below the head-room
    (``HEADROOM_M``, or 0.3 m over the highest camera) count. When the cameras surround the
    middle of those points on the floor (their median; largest azimuth gap of the cameras
    around it < 150 degrees: a ring), each part of the subject is seen by the cameras on its
    side only, so points 2 cameras see count, within ``RING_REACH_M`` beyond the farthest
    camera's distance from that middle, and the box is also cut to that vertical cylinder
    (walls stand farther out); across, the box is that cylinder's square, and up, the seen
    points' extent. On one side, every camera looks at the subject: the points half of them see
    count (the edges of what fewer see move with the cameras' spacing), and the box is their
    extent. An extent is the 0.1-99.9 percentile range plus ``SEEN_MARGIN_M``; the box starts at
    the floor (z = -``SEEN_MARGIN_M``). Without a floor frame: the same extent in world axes, no head-room.
    None when fewer than 100 points are seen together."""
    count = np.asarray(count)
    T = np.eye(4) if T_floor_world is None else np.asarray(T_floor_world, np.float64)
    P = np.asarray(xyz, np.float64) @ T[:3, :3].T + T[:3, 3]
    placed = [c for c in rig if c.is_calibrated]
    cams = np.array([T[:3, :3] @ c.T_world_cam[:3, 3] + T[:3, 3] for c in placed]).reshape(-1, 3)
    keep = np.ones(len(P), bool)
    if T_floor_world is not None:
        headroom = max(HEADROOM_M, float(cams[:, 2].max(initial=0.0)) + 0.3)
        keep = (P[:, 2] > SEEN_MARGIN_M) & (P[:, 2] < headroom)
    ring = _ring(P[keep & (count >= 2)], cams) if T_floor_world is not None else None
    if min_cameras is None:
        min_cameras = 2 if ring is not None else max(2, int(np.ceil(len(placed) / 2)))
    keep &= count >= min_cameras
    if ring is not None:
        keep &= np.linalg.norm(P[:, :2] - ring[0], axis=1) <= ring[1]
    P = P[keep]
    if len(P) < 100:
        return None
    lo = np.percentile(P, 0.1, axis=0) - SEEN_MARGIN_M
    hi = np.percentile(P, 99.9, axis=0) + SEEN_MARGIN_M
    if T_floor_world is None:
        return CaptureVolume(lo, hi, T, "seen")
    lo[2] = -SEEN_MARGIN_M
    if ring is None:
        return CaptureVolume(lo, hi, T, "seen")
    lo[:2], hi[:2] = ring[0] - ring[1], ring[0] + ring[1]  # across: the cylinder, set by the cameras
    axis = (float(ring[0][0]), float(ring[0][1]))
    return CaptureVolume(lo, hi, T, "seen-ring", ring[1], axis)
