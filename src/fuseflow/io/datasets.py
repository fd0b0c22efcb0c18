"""Readers for public RGB-D dataset layouts, the virtual-rig builder, and ``open_recording``.

Each reader states units and conventions, and converts to the library's at the boundary
(metres, OpenCV axes, camera-from-world extrinsics):

* **Open3D / Redwood / ICL-NUIM** (``color/``, ``depth/``, optional ``intrinsic.json``, optional
  ``*.log`` trajectory): depth uint16 millimetres (scale 1000). ``intrinsic.json`` is Open3D's
  PinholeCameraIntrinsic with a *column-major* ``intrinsic_matrix``; without it, Open3D's
  PrimeSense default (fx = fy = 525, cx = 319.5, cy = 239.5) is used. A ``.log`` file stores
  per frame a line ``i j n`` and a 4x4 **world-from-camera** matrix; it is inverted here.
* **TUM RGB-D** (``rgb.txt``, ``depth.txt``, optional ``groundtruth.txt``): depth uint16 with
  scale 5000; ``groundtruth.txt`` lines are ``timestamp tx ty tz qx qy qz qw``, the
  **world-from-camera** pose (Hamilton quaternion, scalar last). Colour, depth and pose are
  associated by nearest timestamp within ``max_dt`` seconds (TUM's ``associate.py`` rule).
* **SUN RGB-D** and **NYU Depth v2** single pairs: see ``fuseflow.io.images``.

A single moving camera loads as a one-camera recording whose rig is uncalibrated and whose
per-frame poses are in ``SequenceRecording.T_world_cam``. ``make_virtual_rig`` turns K frames of
such a sequence (static scene) into a K-camera recording with reference extrinsics.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError, RecordingError, ValidationError
from fuseflow.io.images import (
    decode_nyu_disparity,
    decode_sun_depth,
    read_color,
    read_depth,
    read_depth_raw,
    read_pgm16,
    write_color,
    write_depth,
)
from fuseflow.io.recording import COLOR_EXTS, FuseFlowRecording, Recording, frame_path, list_frames, write_rig
from fuseflow.types import Camera, Rig, check_rigid, invert_rigid

__all__ = [
    "SequenceRecording",
    "open_recording",
    "read_open3d_intrinsic",
    "read_log_trajectory",
    "write_log_trajectory",
    "read_tum_groundtruth",
    "quaternion_to_matrix",
    "read_rgbd_pair",
    "make_virtual_rig",
    "convert_sequence",
    "TUM_INTRINSICS",
]

#: Open3D's PinholeCameraIntrinsicParameters.PrimeSenseDefault (640x480).
PRIMESENSE_K = np.array([[525.0, 0.0, 319.5], [0.0, 525.0, 239.5], [0.0, 0.0, 1.0]])

#: TUM RGB-D calibrated intrinsics per sensor (fx, fy, cx, cy); "ros" is the default ROS calibration.
TUM_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
    "ros": (525.0, 525.0, 319.5, 239.5),
}


def read_open3d_intrinsic(path: str | Path) -> tuple[np.ndarray, int, int]:
    """Open3D PinholeCameraIntrinsic JSON -> (K 3x3, width, height); the matrix is column-major."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc})") from None
    try:
        m = np.array(doc["intrinsic_matrix"], dtype=np.float64)
        w, h = int(doc["width"]), int(doc["height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"{path}: expected fields 'width', 'height', 'intrinsic_matrix' (9 numbers): {exc}") from None
    if m.shape != (9,):
        raise FormatError(f"{path}: 'intrinsic_matrix' must have 9 numbers, got {m.size}")
    return m.reshape(3, 3).T.copy(), w, h


def read_log_trajectory(path: str | Path) -> list[np.ndarray]:
    """Read an Open3D / Redwood ``.log`` trajectory: a list of 4x4 **world-from-camera** matrices."""
    path = Path(path)
    try:
        lines = [ln.split() for ln in path.read_text().splitlines() if ln.strip()]
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc})") from None
    if len(lines) % 5:
        raise FormatError(f"{path}: expected blocks of 5 lines (metadata + 4x4 matrix), got {len(lines)} lines")
    poses = []
    for b in range(0, len(lines), 5):
        try:
            T = np.array([[float(x) for x in row] for row in lines[b + 1 : b + 5]])
        except ValueError:
            raise FormatError(f"{path}: non-numeric matrix in block starting at line {b + 1}") from None
        if T.shape != (4, 4):
            raise FormatError(f"{path}: block starting at line {b + 1} is not a 4x4 matrix")
        poses.append(np.asarray(check_rigid(T, f"{path}: pose {b // 5}")).copy())
    return poses


def write_log_trajectory(path: str | Path, T_world_cam: Sequence[np.ndarray]) -> None:
    """Write world-from-camera poses as an Open3D ``.log`` trajectory."""
    with open(path, "w") as f:
        for i, T in enumerate(T_world_cam):
            f.write(f"{i} {i} {i + 1}\n")
            for row in np.asarray(T):
                f.write(" ".join(f"{v:.8f}" for v in row) + "\n")


def quaternion_to_matrix(q_xyzw: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), Hamilton convention, to a 3x3 rotation (normalised first)."""
    q = np.asarray(q_xyzw, dtype=np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < 1e-12:
        raise ValidationError(f"quaternion {q.tolist()} has zero or non-finite norm")
    x, y, z, w = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _read_tum_list(path: Path, need: int = 0) -> list[tuple[float, list[str]]]:
    """(timestamp, the other fields) per line of a TUM list; FormatError naming the line when a
    line has fewer than ``need`` fields after its timestamp (rgb.txt / depth.txt: a file name)."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc})") from None
    out = []
    for k, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.replace(",", " ").split()
        try:
            out.append((float(parts[0]), parts[1:]))
        except ValueError:
            raise FormatError(f"{path}:{k}: expected 'timestamp ...', got {line!r}") from None
        if len(parts) - 1 < need:
            raise FormatError(f"{path}:{k}: expected 'timestamp filename', got {line!r} (no file name)")
    return out


def read_tum_groundtruth(path: str | Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """TUM groundtruth.txt -> (timestamps (M,), list of 4x4 **world-from-camera** poses)."""
    path = Path(path)
    stamps, poses = [], []
    for ts, vals in _read_tum_list(path):
        if len(vals) != 7:
            raise FormatError(f"{path}: pose at t={ts} needs 7 values 'tx ty tz qx qy qz qw', got {len(vals)}")
        v = np.array([float(x) for x in vals])
        T = np.eye(4)
        T[:3, :3] = quaternion_to_matrix(v[3:])
        T[:3, 3] = v[:3]
        stamps.append(ts)
        poses.append(T)
    return np.array(stamps), poses


def _nearest(stamps: np.ndarray, t: float, max_dt: float) -> int | None:
    if stamps.size == 0:
        return None
    k = int(np.searchsorted(stamps, t))
    best = None
    for j in (k - 1, k):
        if 0 <= j < stamps.size and abs(stamps[j] - t) <= max_dt:
            if best is None or abs(stamps[j] - t) < abs(stamps[best] - t):
                best = j
    return best


@dataclass
class _SeqItem:
    color: Path
    depth: Path
    timestamp: float | None
    T_world_cam: np.ndarray | None


class SequenceRecording(Recording):
    """A single moving camera (Open3D/Redwood/ICL-NUIM or TUM layout) as a one-camera recording.

    ``rig`` has one uncalibrated camera (a moving camera has no fixed extrinsic);
    ``T_world_cam[t]`` is the pose of frame t from the dataset's trajectory, or None.
    """

    def __init__(self, path: Path, camera: Camera, items: list[_SeqItem], layout: str):
        self.path = Path(path)
        self.rig = Rig((camera,))
        self.layout = layout
        self._items = items
        self.frame_numbers = tuple(range(len(items)))
        self.T_world_cam = [it.T_world_cam for it in items]

    @property
    def has_poses(self) -> bool:
        return all(T is not None for T in self.T_world_cam)

    def _load_view(self, cam_index: int, number: int):
        it = self._items[number]
        cam = self.rig.cameras[0]
        color = read_color(it.color)
        depth = read_depth(it.depth, cam.depth_scale)
        self._check_view(cam, color, depth, it.color, it.depth)
        return color, depth, it.timestamp

    def missing_views(self) -> dict[str, list[int]]:
        return {}

    def files(self, t: int) -> tuple[Path, Path]:
        """(colour path, depth path) of frame t."""
        return self._items[t].color, self._items[t].depth

    # ---- constructors

    @classmethod
    def open3d(cls, path: str | Path, camera_id: str = "cam0") -> SequenceRecording:
        """Open3D / Redwood / ICL-NUIM layout; frames paired by number, .log poses by order."""
        path = Path(path)
        colors = list_frames(path / "color", COLOR_EXTS)
        depths = list_frames(path / "depth", (".png",))
        numbers = sorted(set(colors) & set(depths))
        if not numbers:
            raise RecordingError(f"{path}: no colour/depth pairs in color/ and depth/")
        intr = path / "intrinsic.json"
        if intr.exists():
            K, w, h = read_open3d_intrinsic(intr)
        else:
            K, w, h = PRIMESENSE_K, 640, 480
        logs = sorted(path.glob("*.log"))
        poses: list[np.ndarray | None] = [None] * len(numbers)
        if logs:
            traj = read_log_trajectory(logs[0])
            if len(traj) != len(numbers):
                raise FormatError(f"{logs[0]}: {len(traj)} poses but {len(numbers)} colour/depth pairs in {path}")
            poses = list(traj)
        items = [_SeqItem(colors[n], depths[n], None, poses[k]) for k, n in enumerate(numbers)]
        cam = Camera(camera_id, w, h, K, depth_scale=1000.0, depth_range=(0.1, 10.0))
        return cls(path, cam, items, "open3d")

    @classmethod
    def tum(
        cls, path: str | Path, intrinsics: str | None = None, max_dt: float = 0.02, camera_id: str = "cam0"
    ) -> SequenceRecording:
        """TUM RGB-D layout; ``intrinsics`` is a TUM_INTRINSICS key, guessed from the folder name."""
        path = Path(path)
        rgb = _read_tum_list(path / "rgb.txt", need=1)
        depth = _read_tum_list(path / "depth.txt", need=1)
        if intrinsics is None:
            intrinsics = next((k for k in TUM_INTRINSICS if k in path.name), "ros")
        if intrinsics not in TUM_INTRINSICS:
            raise ValidationError(f"unknown TUM intrinsics {intrinsics!r}; choose from {sorted(TUM_INTRINSICS)}")
        fx, fy, cx, cy = TUM_INTRINSICS[intrinsics]
        gt_stamps, gt_poses = np.zeros(0), []
        if (path / "groundtruth.txt").exists():
            gt_stamps, gt_poses = read_tum_groundtruth(path / "groundtruth.txt")
        rgb_stamps = np.array([t for t, _ in rgb])
        items = []
        for ts, vals in depth:
            j = _nearest(rgb_stamps, ts, max_dt)
            if j is None:
                continue
            g = _nearest(gt_stamps, ts, max_dt)
            if gt_poses and g is None:
                continue  # TUM's evaluation uses only frames with a pose
            items.append(_SeqItem(path / rgb[j][1][0], path / vals[0], ts, None if g is None else gt_poses[g]))
        if not items:
            raise RecordingError(f"{path}: no depth frame has a colour frame within {max_dt} s")
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
        cam = Camera(camera_id, 640, 480, K, depth_scale=5000.0, depth_range=(0.1, 10.0))
        return cls(path, cam, items, "tum")


def open_recording(path: str | Path) -> Recording:
    """Open a recording: FuseFlow format (rig.json), Open3D/Redwood/ICL layout, or TUM RGB-D."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file or directory")
    if not path.is_dir():
        raise RecordingError(f"{path}: a recording is a directory")
    if (path / "rig.json").exists():
        return FuseFlowRecording(path)
    if (path / "rgb.txt").exists() and (path / "depth.txt").exists():
        return SequenceRecording.tum(path)
    if (path / "color").is_dir() and (path / "depth").is_dir():
        return SequenceRecording.open3d(path)
    raise RecordingError(
        f"{path}: not a recording: expected rig.json (FuseFlow), rgb.txt + depth.txt (TUM), "
        "or color/ + depth/ folders (Open3D / Redwood / ICL-NUIM)"
    )


def read_rgbd_pair(color_path: str | Path, depth_path: str | Path, fmt: str) -> tuple[np.ndarray, np.ndarray]:
    """Read one RGB-D pair of a known dataset format -> (rgb (H, W, 3) uint8, depth (H, W) float32 m).

    fmt: 'tum' (uint16 / 5000), 'redwood' or 'icl' (uint16 / 1000), 'sun' (bit-rotated mm),
    'nyu' (big-endian PGM disparity, colour in PPM).
    """
    fmt = fmt.lower()
    rgb = read_color(color_path)
    if fmt == "tum":
        depth = read_depth(depth_path, 5000.0)
    elif fmt in ("redwood", "icl", "open3d"):
        depth = read_depth(depth_path, 1000.0)
    elif fmt == "sun":
        depth = decode_sun_depth(read_depth_raw(depth_path))
    elif fmt == "nyu":
        depth = decode_nyu_disparity(read_pgm16(depth_path))
    else:
        raise ValidationError(f"unknown RGB-D format {fmt!r}; expected tum, redwood, icl, sun or nyu")
    if rgb.shape[:2] != depth.shape:
        raise ValidationError(
            f"{color_path} is {rgb.shape[1]}x{rgb.shape[0]} but {depth_path} is {depth.shape[1]}x{depth.shape[0]}"
        )
    return rgb, depth


def _copy_or_write_view(seq: SequenceRecording, t: int, out: Path, cam: Camera, index: int) -> None:
    """Copy frame t's files into a recording (bit-exact when formats allow, else re-encode)."""
    cpath, dpath = seq.files(t)
    ext = cpath.suffix.lower() if cpath.suffix.lower() in COLOR_EXTS else ".png"
    cdst = frame_path(out, cam.id, "color", index, ext)
    ddst = frame_path(out, cam.id, "depth", index)
    cdst.parent.mkdir(parents=True, exist_ok=True)
    ddst.parent.mkdir(parents=True, exist_ok=True)
    src_cam = seq.rig.cameras[0]
    # Decode both once: validates the files (a corrupt source fails here, naming it).
    color = read_color(cpath)
    depth = read_depth(dpath, src_cam.depth_scale)
    seq._check_view(src_cam, color, depth, cpath, dpath)
    if ext == cpath.suffix.lower():
        shutil.copyfile(cpath, cdst)
    else:
        write_color(cdst, color)
    if src_cam.depth_scale == cam.depth_scale:
        shutil.copyfile(dpath, ddst)
    else:
        write_depth(ddst, depth, cam.depth_scale)


def make_virtual_rig(
    seq: SequenceRecording,
    indices: Sequence[int],
    out: str | Path,
    camera_prefix: str = "cam",
) -> Rig:
    """Make a K-camera static recording (one frame) from frames ``indices`` of a posed sequence.

    Camera k is frame ``indices[k]`` with extrinsic T_cam_world = inverse(T_world_cam of that
    frame), in the trajectory's world frame. The scene must be static for this to be a rig
    (ICL-NUIM living room: it is). Returns the rig written to ``out/rig.json``.
    """
    if not seq.has_poses:
        raise ValidationError(f"{seq.path}: a virtual rig needs per-frame poses (a .log or groundtruth.txt)")
    indices = [int(i) for i in indices]
    if len(indices) < 1:
        raise ValidationError("a virtual rig needs at least one frame index")
    if len(set(indices)) != len(indices):
        raise ValidationError(f"virtual rig frame indices must be distinct, got {indices}")
    bad = [i for i in indices if not 0 <= i < len(seq)]
    if bad:
        raise ValidationError(f"virtual rig frame indices {bad} out of range 0..{len(seq) - 1}")
    out = Path(out)
    src = seq.rig.cameras[0]
    width = max(2, len(str(max(len(indices) - 1, 1))))
    cams = []
    for k, t in enumerate(indices):
        cam = Camera(
            f"{camera_prefix}{k:0{width}d}",
            src.width,
            src.height,
            src.K,
            depth_scale=src.depth_scale,
            depth_range=src.depth_range,
            T_cam_world=invert_rigid(seq.T_world_cam[t]),
        )
        cams.append(cam)
        _copy_or_write_view(seq, t, out, cam, 0)
    rig = Rig(tuple(cams))
    write_rig(out, rig)
    (out / "source.json").write_text(
        json.dumps({"virtual_rig_of": str(Path(seq.path).resolve()), "layout": seq.layout, "frames": indices}, indent=2)
        + "\n"
    )
    return rig


def convert_sequence(seq: SequenceRecording, out: str | Path, frames: Sequence[int] | None = None) -> Rig:
    """Write a single-camera sequence (or the frames listed) as a one-camera FuseFlow recording.

    Poses, when the dataset has them, go to ``out/trajectory.log`` (world-from-camera, Open3D
    format); the rig stays uncalibrated since a moving camera has no fixed extrinsic.
    """
    out = Path(out)
    frames = list(range(len(seq))) if frames is None else [int(f) for f in frames]
    bad = [i for i in frames if not 0 <= i < len(seq)]
    if bad:
        raise ValidationError(f"frames {bad[:5]} out of range 0..{len(seq) - 1}")
    cam = seq.rig.cameras[0]
    for k, t in enumerate(frames):
        _copy_or_write_view(seq, t, out, cam, k)
    write_rig(out, seq.rig)
    if seq.has_poses:
        write_log_trajectory(out / "trajectory.log", [seq.T_world_cam[t] for t in frames])
    return seq.rig
