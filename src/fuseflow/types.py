"""The data model of FuseFlow (docs/design.md section 1): Camera, Rig, View, Frame, FusedCloud, Calibration.

Conventions, used everywhere in the package (docs/conventions.md says the same):

* Units are metres. Depth is float32 metres; 0 means "no measurement".
* Pinhole cameras with OpenCV axes: x right, y down, z forward. ``K`` is 3x3.
* ``T_cam_world`` (the paper's E_i) is **camera-from-world**: ``X_cam = T_cam_world @ X_world``.
  A pose (world-from-camera, ``T_world_cam``) is its inverse.
* Batched tensors put the camera axis first: depth (N, H, W), K (N, 3, 3), T_cam_world (N, 4, 4).

Camera and Rig are small metadata held in float64 numpy arrays (made read-only); Frame and
FusedCloud carry pixel and point data as torch tensors that move between devices with ``.to``,
or as numpy arrays (CPU only: the compiled FUSE path reads them without importing torch;
``.to(device)`` turns them into tensors). torch is imported only where a tensor is made.
This module imports nothing else from the package except the exception types.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from fuseflow.errors import ValidationError

if TYPE_CHECKING:
    import torch

__all__ = [
    "POSE_LANDMARKS",
    "Camera",
    "Rig",
    "View",
    "Frame",
    "FusedCloud",
    "Calibration",
    "check_rigid",
    "invert_rigid",
]

#: Tolerance on R^T R = I and det R = 1 when checking that a 4x4 matrix is a rigid transform.
RIGID_TOL = 1e-4


#: The 33 human-pose landmarks in MediaPipe Pose's order: what the person route of calibration
#: detects (``calib.people``) and what the simulator's walking person gives as ground truth
#: (``synth.person``).
POSE_LANDMARKS = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip


def _frozen_array(value: Any, shape: tuple[int, ...], what: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{what}: expected a numeric array of shape {shape}, got {value!r}") from exc
    if arr.shape != shape:
        raise ValidationError(f"{what}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValidationError(f"{what}: contains NaN or inf: {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def check_rigid(T: Any, what: str = "T_cam_world") -> np.ndarray:
    """Validate a 4x4 rigid transform and return it as a read-only float64 array.

    Raises ValidationError naming ``what`` when the matrix has the wrong shape, is not finite,
    has a last row other than [0, 0, 0, 1], or a rotation block that is not orthonormal with
    determinant +1 (to ``RIGID_TOL``).
    """
    arr = _frozen_array(T, (4, 4), what)
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ValidationError(f"{what}: last row must be [0, 0, 0, 1], got {arr[3].tolist()}")
    R = arr[:3, :3]
    ortho_err = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if ortho_err > RIGID_TOL or abs(det - 1.0) > RIGID_TOL:
        raise ValidationError(
            f"{what}: not a rigid transform (|R^T R - I| = {ortho_err:.2e}, det R = {det:.6f}); "
            "expected a rotation with det +1 and a translation in metres"
        )
    return arr


def invert_rigid(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform (R, t) -> (R^T, -R^T t), float64."""
    T = np.asarray(T, dtype=np.float64)
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


# A horizontal field of view outside this range is no depth camera's: a focal length in the wrong
# units, or a K written for another resolution, lands here.
HFOV_RANGE_DEG = (10.0, 170.0)
_ID_FORBIDDEN = frozenset('/\\:*?"<>|')


def _check_camera_id(cid: object) -> None:
    """A camera id names a folder of the recording: a plain name, never a path (an id of '..'
    would read the recording's parent folder)."""
    bad = None
    if not isinstance(cid, str) or not cid:
        bad = "must be a non-empty string"
    elif cid.startswith("."):
        bad = "must not start with '.'"
    elif cid != cid.strip():
        bad = "must not start or end with whitespace"
    elif any(ch in _ID_FORBIDDEN or ord(ch) < 32 for ch in cid):
        bad = 'must not contain / \\ : * ? " < > | or control characters'
    if bad:
        raise ValidationError(f"camera id {cid!r} is not a plain name: it {bad} (the id names the camera's folder)")


def _check_intrinsics(K: np.ndarray, width: int, height: int, where: str) -> None:
    """Principal point inside the image and a plausible field of view for this image size."""
    fx, fy, cx, cy = (float(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    if not (0 <= cx <= width and 0 <= cy <= height):
        raise ValidationError(
            f"{where}: principal point (cx, cy) = ({cx:g}, {cy:g}) lies outside the {width}x{height} image; "
            f"expected 0 <= cx <= {width}, 0 <= cy <= {height} (K written for another resolution?)"
        )
    lo, hi = HFOV_RANGE_DEG
    hfov = math.degrees(2 * math.atan(width / (2 * fx)))
    vfov = math.degrees(2 * math.atan(height / (2 * fy)))
    # the vertical lower bound follows the aspect ratio, so a narrow wide-screen camera still passes
    vlo = math.degrees(2 * math.atan(height / width * math.tan(math.radians(lo) / 2)))
    if not (lo <= hfov <= hi and vlo <= vfov <= hi):
        f_min = width / (2 * math.tan(math.radians(hi) / 2))
        f_max = width / (2 * math.tan(math.radians(lo) / 2))
        raise ValidationError(
            f"{where}: fx = {fx:g}, fy = {fy:g} give a {hfov:.1f} x {vfov:.1f} degree field of view at "
            f"{width}x{height}; expected {lo:g}-{hi:g} degrees horizontally (fx between {f_min:.1f} and "
            f"{f_max:.1f} pixels; focal length in pixels, for this resolution?)"
        )


@dataclass(frozen=True)
class Camera:
    """One calibrated-intrinsics depth camera.

    Attributes:
        id: unique camera name, also its directory name in a recording (no '/').
        width, height: image size in pixels (colour and depth are registered, same size).
        K: (3, 3) float64 pinhole intrinsics in pixels, OpenCV axes.
        depth_scale: stored depth units per metre in the recording's uint16 PNGs (1000 = mm).
        depth_range: (min, max) metres of trustworthy depth; values outside are treated as missing.
        T_cam_world: (4, 4) float64 camera-from-world rigid transform in metres, or None when
            the camera is not calibrated.
        sensor: name of the camera's depth-noise preset (``fuseflow.geometry.noise.SENSOR_NOISE``,
            e.g. "realsense_d4xx"), or None: the algorithms' global choice.
    """

    id: str
    width: int
    height: int
    K: np.ndarray
    depth_scale: float = 1000.0
    depth_range: tuple[float, float] = (0.1, 10.0)
    T_cam_world: np.ndarray | None = None
    sensor: str | None = None

    def __post_init__(self) -> None:
        where = f"camera {self.id!r}"
        _check_camera_id(self.id)
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v <= 0:
                raise ValidationError(f"{where}: {name} must be a positive integer, got {v!r}")
            object.__setattr__(self, name, int(v))
        K = _frozen_array(self.K, (3, 3), f"{where}: K")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise ValidationError(
                f"{where}: K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}"
            )
        _check_intrinsics(K, self.width, self.height, where)
        object.__setattr__(self, "K", K)
        ds = self.depth_scale
        if isinstance(ds, bool) or not isinstance(ds, (int, float, np.number)) or not math.isfinite(ds) or ds <= 0:
            raise ValidationError(f"{where}: depth_scale must be a positive number (units per metre), got {ds!r}")
        object.__setattr__(self, "depth_scale", float(ds))
        try:
            lo, hi = (float(x) for x in self.depth_range)
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"{where}: depth_range must be [min, max] metres, got {self.depth_range!r}") from exc
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi):
            raise ValidationError(f"{where}: depth_range must satisfy 0 <= min < max, got [{lo}, {hi}]")
        object.__setattr__(self, "depth_range", (lo, hi))
        if self.T_cam_world is not None:
            object.__setattr__(self, "T_cam_world", check_rigid(self.T_cam_world, f"{where}: T_cam_world"))
        if self.sensor is not None and (not isinstance(self.sensor, str) or not self.sensor):
            raise ValidationError(f"{where}: sensor must be a sensor preset name or None, got {self.sensor!r}")

    @property
    def is_calibrated(self) -> bool:
        return self.T_cam_world is not None

    @property
    def T_world_cam(self) -> np.ndarray | None:
        """(4, 4) world-from-camera pose, the inverse of T_cam_world, or None."""
        return None if self.T_cam_world is None else invert_rigid(self.T_cam_world)

    def with_extrinsics(self, T_cam_world: np.ndarray | None) -> Camera:
        return replace(self, T_cam_world=T_cam_world)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        same_T = (self.T_cam_world is None and other.T_cam_world is None) or (
            self.T_cam_world is not None
            and other.T_cam_world is not None
            and np.array_equal(self.T_cam_world, other.T_cam_world)
        )
        return (
            self.id == other.id
            and (self.width, self.height) == (other.width, other.height)
            and np.array_equal(self.K, other.K)
            and self.depth_scale == other.depth_scale
            and self.depth_range == other.depth_range
            and self.sensor == other.sensor
            and same_T
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class Rig:
    """The camera set of a recording: N cameras in a fixed order (the camera axis of Frame)."""

    cameras: tuple[Camera, ...]

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        if not cams:
            raise ValidationError("a rig needs at least one camera, got none")
        for c in cams:
            if not isinstance(c, Camera):
                raise ValidationError(f"rig cameras must be Camera objects, got {type(c).__name__}")
        ids = [c.id for c in cams]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValidationError(f"camera ids must be unique, duplicated: {dup}")
        object.__setattr__(self, "cameras", cams)

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self):
        return iter(self.cameras)

    def __getitem__(self, key: int | str) -> Camera:
        if isinstance(key, str):
            return self.cameras[self.index(key)]
        return self.cameras[key]

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(c.id for c in self.cameras)

    def index(self, camera_id: str) -> int:
        try:
            return self.ids.index(camera_id)
        except ValueError:
            raise ValidationError(f"no camera {camera_id!r} in the rig; cameras are {list(self.ids)}") from None

    @property
    def is_calibrated(self) -> bool:
        """True when every camera has T_cam_world."""
        return all(c.is_calibrated for c in self.cameras)

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height) shared by all cameras; ValidationError when they differ."""
        sizes = {(c.width, c.height) for c in self.cameras}
        if len(sizes) != 1:
            raise ValidationError(
                "cameras have different resolutions "
                f"{sorted(sizes)}; batched frames need one resolution (resize when converting)"
            )
        return next(iter(sizes))

    def K(self, device: torch.device | str = "cpu", dtype: torch.dtype | None = None) -> torch.Tensor:
        """(N, 3, 3) intrinsics tensor (float32 unless ``dtype``)."""
        import torch

        return torch.as_tensor(np.stack([c.K for c in self.cameras]), dtype=dtype or torch.float32, device=device)

    def T_cam_world(self, device: torch.device | str = "cpu", dtype: torch.dtype | None = None) -> torch.Tensor:
        """(N, 4, 4) camera-from-world tensor (float32 unless ``dtype``); ValidationError naming
        the uncalibrated cameras."""
        import torch

        missing = [c.id for c in self.cameras if c.T_cam_world is None]
        if missing:
            raise ValidationError(f"cameras without extrinsics (T_cam_world is null): {missing}")
        T = np.stack([c.T_cam_world for c in self.cameras])
        return torch.as_tensor(T, dtype=dtype or torch.float32, device=device)

    def depth_range(self, device: torch.device | str = "cpu") -> torch.Tensor:
        """(N, 2) float32 [min, max] metres."""
        import torch

        return torch.tensor([c.depth_range for c in self.cameras], dtype=torch.float32, device=device)

    def with_extrinsics(self, T_cam_world: Mapping[str, np.ndarray] | Sequence[np.ndarray] | np.ndarray) -> Rig:
        """New rig with extrinsics replaced: a mapping id -> (4, 4), or an (N, 4, 4) array in rig order.

        With a mapping, cameras absent from it keep their current extrinsics.
        """
        if isinstance(T_cam_world, Mapping):
            unknown = sorted(set(T_cam_world) - set(self.ids))
            if unknown:
                raise ValidationError(f"extrinsics given for cameras not in the rig: {unknown}")
            return Rig(tuple(c.with_extrinsics(T_cam_world.get(c.id, c.T_cam_world)) for c in self.cameras))
        arr = np.asarray(T_cam_world, dtype=np.float64)
        if arr.shape != (len(self), 4, 4):
            raise ValidationError(f"extrinsics: expected shape ({len(self)}, 4, 4), got {arr.shape}")
        return Rig(tuple(c.with_extrinsics(arr[i]) for i, c in enumerate(self.cameras)))

    def subset(self, indices: Iterable[int]) -> Rig:
        return Rig(tuple(self.cameras[i] for i in indices))


def is_tensor(x: Any) -> bool:
    """Whether ``x`` is a torch tensor (False without importing torch when nothing imported it)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def to_numpy(x: Any) -> np.ndarray:
    """A numpy view (or CPU copy) of a tensor or array of Frame / FusedCloud."""
    return x.detach().cpu().numpy() if is_tensor(x) else np.asarray(x)


def as_tensor(x: Any, device: Any = None) -> torch.Tensor:
    """A torch tensor of ``x`` (a numpy array shares its memory), on ``device`` when given."""
    import torch

    t = x if isinstance(x, torch.Tensor) else torch.from_numpy(x)
    return t if device is None else t.to(device)


def _check_tensor(t: Any, name: str, dtype: str, shape: tuple[int | None, ...]) -> Any:
    """``t`` if it is a torch tensor or numpy array of ``dtype`` (a numpy dtype name) and ``shape``."""
    if isinstance(t, np.ndarray):
        got, want_dtype = str(t.dtype), dtype
    elif is_tensor(t):
        got, want_dtype = str(t.dtype), f"torch.{dtype}"
    else:
        raise ValidationError(f"{name}: expected a torch.Tensor or numpy array, got {type(t).__name__}")
    if got != want_dtype:
        raise ValidationError(f"{name}: expected dtype {want_dtype}, got {got}")
    if t.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, t.shape)):
        want = "(" + ", ".join("?" if s is None else str(s) for s in shape) + ")"
        raise ValidationError(f"{name}: expected shape {want}, got {tuple(t.shape)}")
    return t


def _device(t: Any) -> Any:
    """A tensor's device; "cpu" for a numpy array."""
    return "cpu" if isinstance(t, np.ndarray) else t.device


@dataclass(frozen=True)
class View:
    """One camera's RGB-D image at one instant.

    Attributes:
        camera: the Camera (intrinsics, extrinsics if known).
        color: (H, W, 3) uint8 RGB.
        depth: (H, W) float32 metres, 0 = no measurement.
        timestamp: seconds, or None when unknown.
    """

    camera: Camera
    color: torch.Tensor
    depth: torch.Tensor
    timestamp: float | None = None

    def __post_init__(self) -> None:
        h, w = self.camera.height, self.camera.width
        _check_tensor(self.color, f"camera {self.camera.id!r} color", "uint8", (h, w, 3))
        _check_tensor(self.depth, f"camera {self.camera.id!r} depth", "float32", (h, w))


@dataclass(frozen=True)
class Frame:
    """The N views of one instant, batched with the camera axis first.

    Attributes:
        index: frame number in its recording.
        camera_ids: (N,) ids, in rig order.
        color: (N, H, W, 3) uint8 RGB.
        depth: (N, H, W) float32 metres; 0 = no measurement. Cleaned at the input boundary:
            NaN, inf and negative values are 0 (and counted in ``invalid_depth``). Values
            outside a camera's depth_range are kept; the algorithms gate on the range.
        present: (N,) bool; False marks a dropped view (its color and depth are all zero).
        invalid_depth: (N,) int64 count of NaN/inf/negative depth values zeroed on input.
        timestamp: seconds, or None.
    """

    index: int
    camera_ids: tuple[str, ...]
    color: torch.Tensor
    depth: torch.Tensor
    present: torch.Tensor
    invalid_depth: torch.Tensor = field(default=None)  # type: ignore[assignment]
    timestamp: float | None = None

    def __post_init__(self) -> None:
        n = len(self.camera_ids)
        if n == 0:
            raise ValidationError("a frame needs at least one view")
        _check_tensor(self.depth, "frame depth", "float32", (n, None, None))
        h, w = self.depth.shape[1:]
        _check_tensor(self.color, "frame color", "uint8", (n, h, w, 3))
        _check_tensor(self.present, "frame present", "bool", (n,))
        if self.invalid_depth is None:
            zeros = np.zeros(n, dtype=np.int64)
            object.__setattr__(self, "invalid_depth", zeros if self.is_numpy else as_tensor(zeros))
        _check_tensor(self.invalid_depth, "frame invalid_depth", "int64", (n,))
        if len({isinstance(t, np.ndarray) for t in (self.color, self.depth, self.present)}) != 1:
            raise ValidationError("frame color, depth and present mix numpy arrays and torch tensors")
        devices = {_device(t) for t in (self.color, self.depth, self.present)}
        if len(devices) != 1:
            raise ValidationError(f"frame tensors are on different devices: {sorted(map(str, devices))}")

    @property
    def num_views(self) -> int:
        return len(self.camera_ids)

    @property
    def device(self) -> torch.device | str:
        """The tensors' device; "cpu" when the frame holds numpy arrays."""
        return _device(self.depth)

    @property
    def is_numpy(self) -> bool:
        """Whether the frame holds numpy arrays (CPU) rather than torch tensors."""
        return isinstance(self.depth, np.ndarray)

    @property
    def resolution(self) -> tuple[int, int]:
        """(width, height)."""
        return int(self.depth.shape[2]), int(self.depth.shape[1])

    @property
    def missing(self) -> tuple[str, ...]:
        """Ids of cameras whose view was dropped at this instant."""
        return tuple(cid for cid, p in zip(self.camera_ids, self.present.tolist()) if not p)

    def to(self, device: torch.device | str) -> Frame:
        """The frame as torch tensors on ``device`` (numpy arrays are shared, not copied, on CPU)."""
        return replace(
            self,
            color=as_tensor(self.color, device),
            depth=as_tensor(self.depth, device),
            present=as_tensor(self.present, device),
            invalid_depth=as_tensor(self.invalid_depth),
        )

    def view(self, i: int, rig: Rig) -> View:
        """The i-th view as a View with its Camera from ``rig``."""
        cam = rig[self.camera_ids[i]]
        return View(cam, self.color[i], self.depth[i], self.timestamp)

    def subset(self, indices: Sequence[int]) -> Frame:
        if self.is_numpy:
            idx_np = np.asarray(list(indices), dtype=np.int64)
            return replace(
                self,
                camera_ids=tuple(self.camera_ids[i] for i in indices),
                color=self.color[idx_np],
                depth=self.depth[idx_np],
                present=self.present[idx_np],
                invalid_depth=to_numpy(self.invalid_depth)[idx_np],
            )
        import torch

        idx = torch.as_tensor(list(indices), dtype=torch.long)
        return replace(
            self,
            camera_ids=tuple(self.camera_ids[i] for i in indices),
            color=self.color[idx.to(self.color.device)],
            depth=self.depth[idx.to(self.depth.device)],
            present=self.present[idx.to(self.present.device)],
            invalid_depth=as_tensor(self.invalid_depth)[idx],
        )

    @staticmethod
    def from_views(index: int, views: Sequence[View]) -> Frame:
        if not views:
            raise ValidationError("a frame needs at least one view")
        sizes = {(v.camera.width, v.camera.height) for v in views}
        if len(sizes) != 1:
            raise ValidationError(f"views have different resolutions {sorted(sizes)}")
        if all(isinstance(v.depth, np.ndarray) for v in views):
            return Frame(
                index,
                tuple(v.camera.id for v in views),
                np.stack([to_numpy(v.color) for v in views]),
                np.stack([v.depth for v in views]),
                np.ones(len(views), dtype=bool),
                timestamp=views[0].timestamp,
            )
        import torch

        return Frame(
            index=index,
            camera_ids=tuple(v.camera.id for v in views),
            color=torch.stack([v.color for v in views]),
            depth=torch.stack([v.depth for v in views]),
            present=torch.ones(len(views), dtype=torch.bool, device=views[0].depth.device),
            timestamp=views[0].timestamp,
        )


@dataclass(frozen=True)
class FusedCloud:
    """A fused point cloud in world coordinates (docs/design.md section 1).

    Attributes:
        xyz: (M, 3) float32 metres, world frame.
        rgb: (M, 3) uint8.
        weight: (M,) float32 in [0, 1], the joint fusion weight of eq. (22).
        camera: (M,) int16 index (rig order) of the camera each point came from.
        support: optional (M,) int16, how many cameras measured the point's surface (FUSE's
            multi-view consensus, ``FuseConfig.rps.consensus``); None when not computed.
    """

    xyz: torch.Tensor
    rgb: torch.Tensor
    weight: torch.Tensor
    camera: torch.Tensor
    support: torch.Tensor | None = None

    def __post_init__(self) -> None:
        _check_tensor(self.xyz, "cloud xyz", "float32", (None, 3))
        m = self.xyz.shape[0]
        _check_tensor(self.rgb, "cloud rgb", "uint8", (m, 3))
        _check_tensor(self.weight, "cloud weight", "float32", (m,))
        _check_tensor(self.camera, "cloud camera", "int16", (m,))
        if self.support is not None:
            _check_tensor(self.support, "cloud support", "int16", (m,))

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def device(self) -> torch.device | str:
        """The tensors' device; "cpu" when the cloud holds numpy arrays."""
        return _device(self.xyz)

    @property
    def is_numpy(self) -> bool:
        """Whether the cloud holds numpy arrays (CPU) rather than torch tensors."""
        return isinstance(self.xyz, np.ndarray)

    def to(self, device: torch.device | str) -> FusedCloud:
        """The cloud as torch tensors on ``device`` (numpy arrays are shared, not copied, on CPU)."""
        sup = None if self.support is None else as_tensor(self.support, device)
        xyz, rgb, w, cam = (as_tensor(a, device) for a in (self.xyz, self.rgb, self.weight, self.camera))
        return FusedCloud(xyz, rgb, w, cam, sup)

    def numpy(self) -> FusedCloud:
        """The cloud as numpy arrays (CPU)."""
        sup = None if self.support is None else to_numpy(self.support)
        return FusedCloud(*(to_numpy(a) for a in (self.xyz, self.rgb, self.weight, self.camera)), sup)

    @staticmethod
    def empty(device: torch.device | str = "cpu") -> FusedCloud:
        import torch

        return FusedCloud(
            torch.zeros((0, 3), dtype=torch.float32, device=device),
            torch.zeros((0, 3), dtype=torch.uint8, device=device),
            torch.zeros((0,), dtype=torch.float32, device=device),
            torch.zeros((0,), dtype=torch.int16, device=device),
        )

    @staticmethod
    def from_numpy(
        xyz: np.ndarray, rgb: np.ndarray, weight: np.ndarray, camera: np.ndarray, support: np.ndarray | None = None
    ) -> FusedCloud:
        """A cloud of torch tensors holding copies of the arrays."""
        import torch

        sup = None if support is None else torch.from_numpy(np.array(support, dtype=np.int16, order="C", copy=True))
        return FusedCloud(
            torch.from_numpy(np.array(xyz, dtype=np.float32, order="C", copy=True)),
            torch.from_numpy(np.array(rgb, dtype=np.uint8, order="C", copy=True)),
            torch.from_numpy(np.array(weight, dtype=np.float32, order="C", copy=True)),
            torch.from_numpy(np.array(camera, dtype=np.int16, order="C", copy=True)),
            sup,
        )


@dataclass(frozen=True)
class Calibration:
    """Extrinsics of a rig's cameras, and the report of how they were obtained.

    Attributes:
        T_cam_world: mapping camera id -> (4, 4) float64 camera-from-world, metres. Cameras the
            calibration could not place are absent (and named in ``report``).
        report: how they were obtained: a ``fuseflow.calib.CalibReport`` from GMAC (anything
            with a ``to_json()`` is kept as it is), or a plain JSON-serialisable dict (a calib.json
            read back, a given calibration). Both read by key: ``report["scale"]``.
    """

    T_cam_world: Mapping[str, np.ndarray]
    report: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        checked = {}
        for cid, T in self.T_cam_world.items():
            if not isinstance(cid, str) or not cid:
                raise ValidationError(f"calibration camera ids must be non-empty strings, got {cid!r}")
            checked[cid] = check_rigid(T, f"calibration camera {cid!r}: T_cam_world")
        object.__setattr__(self, "T_cam_world", checked)
        # A typed report (it has to_json, e.g. CalibReport) stays typed; types cannot import calib.
        if not hasattr(self.report, "to_json"):
            object.__setattr__(self, "report", dict(self.report))

    @property
    def camera_ids(self) -> tuple[str, ...]:
        return tuple(self.T_cam_world)

    def __repr__(self) -> str:
        """A few lines: the placed cameras, the report's kind, source, verdicts and warnings (the
        matrices: ``T_cam_world``; the whole report: ``report``)."""
        ids = list(self.T_cam_world)
        shown = ", ".join(ids[:8]) + (f", ... ({len(ids) - 8} more)" if len(ids) > 8 else "")
        rep = self.report
        lines = [f"Calibration of {len(ids)} cameras ({shown}): T_cam_world, camera-from-world, metres"]
        about = [f"report ({type(rep).__name__}, {len(list(rep))} entries)"]
        source = rep.get("source") if isinstance(rep, Mapping) else None
        if source:
            about.append(f"source: {source}")
        verdicts = getattr(rep, "camera_verdicts", None) or (
            rep.get("camera_verdicts") if isinstance(rep, Mapping) else None
        )
        if isinstance(verdicts, Mapping) and verdicts:
            counts: dict[str, int] = {}
            for v in verdicts.values():
                key = str(v.get("verdict", "?")) if isinstance(v, Mapping) else "?"
                counts[key] = counts.get(key, 0) + 1
            about.append("verdicts " + ", ".join(f"{n} {k}" for k, n in counts.items()))
        warned = getattr(rep, "warnings", None) if not isinstance(rep, Mapping) else rep.get("warnings")
        if warned:
            about.append(f"{len(warned)} warnings")
        return "\n".join([lines[0], "  " + "; ".join(about)])

    def apply(self, rig: Rig) -> Rig:
        """The rig with these extrinsics; cameras this calibration does not place keep theirs."""
        return rig.with_extrinsics(self.T_cam_world)
