"""The FuseFlow recording format: a directory a user can also write with a short script.

Layout (docs/formats.md has the full schema)::

    REC/rig.json                          {"format": "fuseflow-rig/1", "cameras": [...]}
    REC/<camera id>/color/<frame:06d>.png  (or .jpg / .jpeg)   8-bit RGB
    REC/<camera id>/depth/<frame:06d>.png  uint16, value / depth_scale = metres, 0 = none

Frames align by index across cameras. A camera without a colour or depth image at a frame index
that other cameras have is a *dropped view*: the frame still loads, with that camera marked not
present (zeros in its slot). A file that exists but cannot be decoded is an error naming it.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fuseflow.errors import FormatError, FuseFlowError, RecordingError, ValidationError
from fuseflow.geometry.noise import sensor_noise
from fuseflow.io.files import load_json, write_json_atomic
from fuseflow.io.images import clean_depth, read_color, read_depth, write_color, write_depth
from fuseflow.types import Camera, Frame, Rig, to_numpy

if TYPE_CHECKING:
    import torch

__all__ = [
    "RIG_FORMAT",
    "Recording",
    "FuseFlowRecording",
    "rig_to_json",
    "rig_from_json",
    "read_rig",
    "write_rig",
    "write_frame",
    "frame_path",
]

RIG_FORMAT = "fuseflow-rig/1"
COLOR_EXTS = (".png", ".jpg", ".jpeg")
_FRAME_RE = re.compile(r"^(\d+)\.(png|jpg|jpeg)$", re.IGNORECASE)


# --------------------------------------------------------------------------- rig.json


def rig_to_json(rig: Rig) -> dict[str, Any]:
    """The rig as the rig.json document (K and T_cam_world as nested row-major lists)."""
    return {
        "format": RIG_FORMAT,
        "cameras": [
            {
                "id": c.id,
                "width": c.width,
                "height": c.height,
                "K": c.K.tolist(),
                "depth_scale": c.depth_scale,
                "depth_range": list(c.depth_range),
                "T_cam_world": None if c.T_cam_world is None else c.T_cam_world.tolist(),
                **({} if c.sensor is None else {"sensor": c.sensor}),
            }
            for c in rig.cameras
        ],
    }


def parse_matrix(value: Any, n: int, where: str) -> np.ndarray:
    """Accept an n x n nested list or a flat row-major list of n*n numbers."""
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"{where}: expected a {n}x{n} matrix of numbers, got {value!r}") from None
    if arr.shape == (n * n,):
        arr = arr.reshape(n, n)
    if arr.shape != (n, n):
        raise FormatError(f"{where}: expected a {n}x{n} matrix (row-major), got shape {arr.shape}")
    return arr


def rig_from_json(doc: Any, source: str = "rig.json") -> Rig:
    """Parse and validate a rig.json document; errors name the field and the camera."""
    if not isinstance(doc, dict):
        raise FormatError(f"{source}: top level must be an object, got {type(doc).__name__}")
    fmt = doc.get("format")
    if fmt != RIG_FORMAT:
        raise FormatError(f"{source}: field 'format' must be {RIG_FORMAT!r}, got {fmt!r}")
    cams = doc.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise FormatError(f"{source}: field 'cameras' must be a non-empty list")
    out = []
    for k, c in enumerate(cams):
        if not isinstance(c, dict):
            raise FormatError(f"{source}: cameras[{k}] must be an object")
        cid = c.get("id")
        where = f"{source}: camera {cid!r} (cameras[{k}])"
        if not isinstance(cid, str) or not cid:
            raise FormatError(f"{source}: cameras[{k}]: field 'id' must be a non-empty string, got {cid!r}")
        for key in ("width", "height", "K"):
            if key not in c:
                raise FormatError(f"{where}: missing field '{key}'")
        T = c.get("T_cam_world")
        sensor = c.get("sensor")
        if sensor is not None:
            if not isinstance(sensor, str):
                raise FormatError(f"{where}: field 'sensor' must be a sensor preset name, got {sensor!r}")
            try:
                sensor_noise(sensor)
            except ValidationError as exc:
                raise FormatError(f"{where}: field 'sensor': {exc}") from None
        try:
            out.append(
                Camera(
                    id=cid,
                    width=c["width"],
                    height=c["height"],
                    K=parse_matrix(c["K"], 3, f"{where}: field 'K'"),
                    depth_scale=c.get("depth_scale", 1000.0),
                    depth_range=tuple(c.get("depth_range", (0.1, 10.0))),
                    T_cam_world=None if T is None else parse_matrix(T, 4, f"{where}: field 'T_cam_world'"),
                    sensor=sensor,
                )
            )
        except ValidationError as exc:
            raise FormatError(f"{source}: {exc}") from None
        except TypeError:
            raise FormatError(f"{where}: field 'depth_range' must be [min, max] metres") from None
    try:
        return Rig(tuple(out))
    except ValidationError as exc:
        raise FormatError(f"{source}: {exc}") from None


def read_rig(path: str | Path) -> Rig:
    """Read rig.json (a file, or a recording directory containing one)."""
    path = Path(path)
    if path.is_dir():
        path = path / "rig.json"
    return rig_from_json(load_json(path), str(path))


def write_rig(path: str | Path, rig: Rig) -> Path:
    """Write rig.json into recording directory ``path`` (created if needed); returns the file."""
    out = Path(path) / "rig.json"
    write_json_atomic(out, rig_to_json(rig))
    return out


def frame_path(root: str | Path, camera_id: str, kind: str, index: int, ext: str = ".png") -> Path:
    """REC/<camera id>/<kind>/<index:06d><ext>, kind in {'color', 'depth'}."""
    return Path(root) / camera_id / kind / f"{index:06d}{ext}"


def write_frame(
    root: str | Path,
    rig: Rig,
    index: int,
    color: np.ndarray | torch.Tensor,
    depth_m: np.ndarray | torch.Tensor,
    present: Sequence[bool] | None = None,
    color_ext: str = ".png",
) -> None:
    """Write one frame of a recording.

    Args:
        color: (N, H, W, 3) uint8 RGB, rig order.
        depth_m: (N, H, W) float32 metres; written as uint16 with each camera's depth_scale.
        present: (N,) bool; views marked False are not written (dropped views).
    """
    color = to_numpy(color)
    depth_m = to_numpy(depth_m)
    n = len(rig)
    if color.shape[0] != n or depth_m.shape[0] != n:
        raise ValidationError(f"write_frame: expected {n} views, got color {color.shape}, depth {depth_m.shape}")
    for i, cam in enumerate(rig.cameras):
        if present is not None and not present[i]:
            continue
        if depth_m[i].shape != (cam.height, cam.width) or color[i].shape != (cam.height, cam.width, 3):
            raise ValidationError(
                f"write_frame: camera {cam.id!r} expects {cam.width}x{cam.height}, "
                f"got color {color[i].shape}, depth {depth_m[i].shape}"
            )
        write_color(frame_path(root, cam.id, "color", index, color_ext), color[i])
        write_depth(frame_path(root, cam.id, "depth", index), depth_m[i], cam.depth_scale)


# --------------------------------------------------------------------------- recordings


class Recording:
    """A sequence of multi-view RGB-D frames with a rig: ``len(rec)``, ``rec[t]``, ``rec.rig``.

    ``rec[t]`` is the t-th frame (0 <= t < len(rec)); ``Frame.index`` keeps the frame number the
    files carry. Subclasses implement ``_load_view``.
    """

    rig: Rig
    path: Path
    frame_numbers: tuple[int, ...]

    def __len__(self) -> int:
        return len(self.frame_numbers)

    def __iter__(self) -> Iterator[Frame]:
        for t in range(len(self)):
            yield self[t]

    def __getitem__(self, t: int) -> Frame:
        return self.frame(t)

    def frame(self, t: int, numpy: bool = False) -> Frame:
        """The frame at position ``t`` (negative counts from the end): torch tensors, or with
        ``numpy`` numpy arrays (then torch is not imported)."""
        if not isinstance(t, (int, np.integer)):
            raise TypeError(f"frames are indexed by int, got {type(t).__name__}")
        n = len(self)
        if t < 0:
            t += n
        if not 0 <= t < n:
            raise IndexError(f"frame {t} out of range: the recording has {n} frames")
        number = self.frame_numbers[t]
        w, h = self.rig.resolution
        N = len(self.rig)
        with ThreadPoolExecutor(max_workers=min(N, 4)) as pool:  # cv2 decoding releases the GIL
            views = list(pool.map(lambda i: self._load_view(i, number), range(N)))
        color = np.zeros((N, h, w, 3), dtype=np.uint8)
        depth = np.zeros((N, h, w), dtype=np.float32)
        present = np.zeros(N, dtype=bool)
        invalid = np.zeros(N, dtype=np.int64)
        timestamp = None
        for i, v in enumerate(views):
            if v is None:
                continue
            c, d, ts = v
            d, invalid[i] = clean_depth(d)
            color[i], depth[i], present[i] = c, d, True
            timestamp = ts if timestamp is None else timestamp
        frame = Frame(number, self.rig.ids, color, depth, present, invalid, timestamp)
        return frame if numpy else frame.to("cpu")

    def _load_view(self, cam_index: int, number: int) -> tuple[np.ndarray, np.ndarray, float | None] | None:
        raise NotImplementedError

    def missing_views(self) -> dict[str, list[int]]:
        """Camera id -> frame numbers at which that camera has no view (from file listings)."""
        raise NotImplementedError

    def check_files(self) -> list[str]:
        """Read every view of every frame; one line per problem (file and what is wrong with it),
        empty when all decode. Readers with per-file listings override this to name every bad
        file; this default names the first bad view of each frame."""
        problems = []
        for t in range(len(self)):
            try:
                self[t]
            except (FuseFlowError, OSError, ValueError) as exc:
                problems.append(f"frame {self.frame_numbers[t]}: {exc}")
        return problems

    def _check_view(self, cam: Camera, color: np.ndarray, depth: np.ndarray, cpath: Path, dpath: Path) -> None:
        want = (cam.height, cam.width)
        if color.shape[:2] != want:
            raise ValidationError(
                f"{cpath}: colour is {color.shape[1]}x{color.shape[0]}, camera {cam.id!r} is {cam.width}x{cam.height}"
            )
        if depth.shape != want:
            raise ValidationError(
                f"{dpath}: depth is {depth.shape[1]}x{depth.shape[0]}, camera {cam.id!r} is {cam.width}x{cam.height}"
            )


def list_frames(directory: Path, exts: tuple[str, ...]) -> dict[int, Path]:
    out: dict[int, Path] = {}
    if not directory.is_dir():
        return out
    # sorted: the error below names the same pair whatever order the directory lists
    for entry in sorted(os.scandir(directory), key=lambda e: e.name):
        m = _FRAME_RE.match(entry.name)
        if m and ("." + m.group(2).lower()) in exts:
            number = int(m.group(1))
            if number in out:  # 000000.png beside 000000.jpg (or 0.png beside 000000.png)
                raise RecordingError(
                    f"{directory}: two images for frame {number}: {out[number].name} and {entry.name}; "
                    "keep one (which one is meant cannot be guessed)"
                )
            out[number] = Path(entry.path)
    return out


def _view_stamps(root: Path) -> dict[str, dict[int, float]]:
    """Device timestamps of a converted recording (``timestamps.json``, docs/formats.md):
    camera id -> frame number -> seconds; {} without the file. Read here rather than through
    ``io.timesync.read_timestamps`` (which validates it) because timesync imports this module."""
    path = root / "timestamps.json"
    if not path.is_file():
        return {}
    doc = load_json(path)
    frames = [int(n) for n in doc.get("frames", [])]
    return {
        c: {n: float(x) for n, x in zip(frames, v.get("timestamp", [])) if x is not None}
        for c, v in doc.get("cameras", {}).items()
    }


class FuseFlowRecording(Recording):
    """A recording in FuseFlow's own format (rig.json + per-camera colour/depth folders)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_dir():
            raise RecordingError(f"{self.path}: not a directory")
        self.rig = read_rig(self.path)
        self.rig.resolution  # noqa: B018 - raises a clear error for mixed resolutions
        self._color: list[dict[int, Path]] = []
        self._depth: list[dict[int, Path]] = []
        for cam in self.rig.cameras:
            if not (self.path / cam.id).is_dir():
                raise RecordingError(f"{self.path}: rig.json lists camera {cam.id!r} but there is no folder {cam.id}/")
            self._color.append(list_frames(self.path / cam.id / "color", COLOR_EXTS))
            self._depth.append(list_frames(self.path / cam.id / "depth", (".png",)))
        numbers: set[int] = set()
        for c, d in zip(self._color, self._depth):
            numbers |= set(c) | set(d)
        if not numbers:
            raise RecordingError(f"{self.path}: no frames found (expected <camera>/color/000000.png and depth/)")
        self.frame_numbers = tuple(sorted(numbers))
        self._stamps = _view_stamps(self.path)

    def _load_view(self, cam_index: int, number: int):
        cpath = self._color[cam_index].get(number)
        dpath = self._depth[cam_index].get(number)
        if cpath is None or dpath is None:
            return None
        cam = self.rig.cameras[cam_index]
        color = read_color(cpath)
        depth = read_depth(dpath, cam.depth_scale)
        self._check_view(cam, color, depth, cpath, dpath)
        return color, depth, self._stamps.get(cam.id, {}).get(number)

    def check_files(self) -> list[str]:
        """Decode every colour and depth file of every camera (``fuseflow info --check``); one line
        per file that is corrupt, truncated, of the wrong size or bit depth, naming the file."""

        def check(job):
            cam, kind, path = job
            try:
                img = read_color(path) if kind == "color" else read_depth(path, cam.depth_scale)
            except (FuseFlowError, OSError) as exc:
                return str(exc)
            if img.shape[:2] != (cam.height, cam.width):
                return f"{path}: {'colour' if kind == 'color' else kind} is {img.shape[1]}x{img.shape[0]}, camera {cam.id!r} is {cam.width}x{cam.height}"
            return None

        jobs = [
            (cam, kind, path)
            for cam, c, d in zip(self.rig.cameras, self._color, self._depth)
            for kind, files in (("color", c), ("depth", d))
            for _, path in sorted(files.items())
        ]
        with ThreadPoolExecutor(max_workers=4) as pool:  # cv2 decoding releases the GIL
            return [p for p in pool.map(check, jobs) if p is not None]

    def missing_views(self) -> dict[str, list[int]]:
        out = {}
        for cam, c, d in zip(self.rig.cameras, self._color, self._depth):
            miss = [n for n in self.frame_numbers if n not in c or n not in d]
            if miss:
                out[cam.id] = miss
        return out
