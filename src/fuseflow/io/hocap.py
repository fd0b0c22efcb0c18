"""HO-Cap recordings (the hand-object capture dataset of UT Dallas, as laid out by its loader
``lib/SequenceLoader.py`` in goldPig888/utd_cv and in ``../shared/data/hocap-8rs``) into a
FuseFlow recording.

Layout read::

    SEQ/meta.json                               {"realsense": {"serials": [...], "width", "height"},
                                                 "calibration": {"extrinsics": "<name>"}}
    SEQ/<serial>/color_<frame:06d>.jpg          8-bit colour
    SEQ/<serial>/depth_<frame:06d>.png          uint16 millimetres, registered to colour
    CAL/intrinsics/<serial>_<W>x<H>.json        RealSense factory intrinsics: {"color": {fx, fy, ppx, ppy,
                                                 width, height, coeffs}, "depth": {...}, "depth2color": [12]}
    CAL/extrinsics/<name>.json                  (or <name>/extrinsics.json) {"extrinsics": {<serial>: [12]},
                                                 "rs_master": <serial>}

SEQ is the directory given, or its ``frames/`` folder; CAL is ``calibration/`` beside SEQ or
beside its parent. Conventions at the boundary: depth is registered to colour, so each camera
gets the *colour* intrinsics (distortion, small, is ignored as the source loader does); depth
scale 1000 (millimetres). The extrinsics are row-major 3x4 [R | t] **camera -> master**
(X_master = R X_cam + t, metres), so with the master camera as the world frame
T_cam_world = inv([R | t]). Colour and depth files are copied bit-exactly.
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError, RecordingError
from fuseflow.io.recording import frame_path, write_rig
from fuseflow.types import Calibration, Camera, Rig, check_rigid, invert_rigid

__all__ = ["HOCAP_DEPTH_RANGE", "is_hocap", "HoCapSequence", "read_hocap", "convert_hocap"]

#: Trustworthy depth range of the HO-Cap D400 cameras, metres (depth is truncated at ~1.5 m in the data).
HOCAP_DEPTH_RANGE = (0.1, 1.6)
_FRAME_RE = re.compile(r"^(color|depth)_(\d+)\.(jpg|jpeg|png)$", re.IGNORECASE)


def _sequence_dir(path: Path) -> Path | None:
    for cand in (path, path / "frames"):
        if (cand / "meta.json").is_file():
            try:
                doc = json.loads((cand / "meta.json").read_text())
            except (OSError, json.JSONDecodeError):
                continue
            if isinstance(doc, dict) and isinstance(doc.get("realsense"), dict):
                return cand
    return None


def is_hocap(path: str | Path) -> bool:
    """True when ``path`` (or its ``frames/``) holds an HO-Cap meta.json with a "realsense" entry."""
    return Path(path).is_dir() and _sequence_dir(Path(path)) is not None


def _load(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise RecordingError(f"{path}: file not found") from None
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: invalid JSON at line {exc.lineno}: {exc.msg}") from None


@dataclass(frozen=True)
class HoCapSequence:
    """An HO-Cap sequence: the rig (colour intrinsics, uncalibrated), frame files and reference extrinsics.

    Attributes:
        rig: cameras in ``meta.json`` order, ids = serials, no extrinsics.
        files: serial -> frame number -> (colour path, depth path).
        reference: serial -> (4, 4) T_cam_world with the master as world, or empty without extrinsics.
        master: the master camera's serial, or None. extrinsics_file: where the reference came from.
    """

    path: Path
    rig: Rig
    files: dict[str, dict[int, tuple[Path, Path]]]
    reference: dict[str, np.ndarray]
    master: str | None
    extrinsics_file: Path | None


def read_hocap(path: str | Path) -> HoCapSequence:
    """Read an HO-Cap sequence's metadata (no images). Errors name the file and the field."""
    path = Path(path)
    seq = _sequence_dir(path)
    if seq is None:
        raise RecordingError(f"{path}: not an HO-Cap sequence (expected meta.json with a 'realsense' entry)")
    meta = _load(seq / "meta.json")
    try:
        serials = [str(s) for s in meta["realsense"]["serials"]]
        W, H = int(meta["realsense"]["width"]), int(meta["realsense"]["height"])
    except (KeyError, TypeError, ValueError):
        raise FormatError(
            f"{seq / 'meta.json'}: expected realsense.serials, realsense.width, realsense.height"
        ) from None
    cal = next((c for c in (seq / "calibration", seq.parent / "calibration", seq.parent.parent / "calibration")
                if (c / "intrinsics").is_dir()), None)  # fmt: skip
    if cal is None:
        raise RecordingError(f"{seq}: no calibration/intrinsics/ folder beside the sequence or its parent")
    cams, files = [], {}
    for s in serials:
        ipath = cal / "intrinsics" / f"{s}_{W}x{H}.json"
        doc = _load(ipath)
        try:
            c = doc["color"]
            K = np.array([[c["fx"], 0.0, c["ppx"]], [0.0, c["fy"], c["ppy"]], [0.0, 0.0, 1.0]], dtype=np.float64)
            cw, ch = int(c["width"]), int(c["height"])
        except (KeyError, TypeError, ValueError):
            raise FormatError(f"{ipath}: field 'color' needs fx, fy, ppx, ppy, width, height") from None
        if (cw, ch) != (W, H):
            raise FormatError(f"{ipath}: colour intrinsics are for {cw}x{ch}, meta.json says {W}x{H}")
        cams.append(Camera(s, W, H, K, depth_scale=1000.0, depth_range=HOCAP_DEPTH_RANGE))
        found: dict[int, dict[str, Path]] = {}
        if not (seq / s).is_dir():
            raise RecordingError(f"{seq}: meta.json lists camera {s} but there is no folder {s}/")
        for f in (seq / s).iterdir():
            m = _FRAME_RE.match(f.name)
            if m:
                found.setdefault(int(m.group(2)), {})[m.group(1).lower()] = f
        files[s] = {n: (d["color"], d["depth"]) for n, d in found.items() if "color" in d and "depth" in d}
    reference, master, ext_file = {}, None, None
    name = (meta.get("calibration") or {}).get("extrinsics")
    cands = [cal / "extrinsics" / f"{name}.json", cal / "extrinsics" / name / "extrinsics.json"] if name else []
    cands += sorted((cal / "extrinsics").glob("*.json")) if (cal / "extrinsics").is_dir() else []
    ext_file = next((c for c in cands if c.is_file()), None)
    if ext_file is not None:
        doc = _load(ext_file)
        master = doc.get("rs_master")
        for s in serials:
            try:
                M = np.eye(4)
                M[:3, :] = np.asarray(doc["extrinsics"][s], dtype=np.float64).reshape(3, 4)
            except (KeyError, TypeError, ValueError):
                raise FormatError(
                    f"{ext_file}: extrinsics[{s!r}] must be 12 numbers (row-major 3x4 camera -> master)"
                ) from None
            T_master_cam = check_rigid(M, f"{ext_file}: extrinsics[{s!r}]")
            reference[s] = invert_rigid(T_master_cam)
    return HoCapSequence(seq, Rig(tuple(cams)), files, reference, master, ext_file)


def convert_hocap(src: str | Path, out: str | Path, with_extrinsics: bool = False) -> tuple[Rig, HoCapSequence]:
    """Write an HO-Cap sequence as a FuseFlow recording (files copied bit-exactly).

    Frames are numbered as in the source. The reference extrinsics always go to
    ``out/reference_calib.json`` (calib.json format, master camera = world); with
    ``with_extrinsics`` they are also written into rig.json. Returns (rig written, sequence).
    """
    from fuseflow.io.calibration import write_calibration

    seq = read_hocap(src)
    out = Path(out)
    for cam in seq.rig.cameras:
        for n, (c, d) in sorted(seq.files[cam.id].items()):
            for kind, p in (("color", c), ("depth", d)):
                dst = frame_path(out, cam.id, kind, n, p.suffix.lower())
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(p, dst)
    rig = seq.rig
    if with_extrinsics:
        if not seq.reference:
            raise RecordingError(f"{seq.path}: --with-extrinsics, but no calibration/extrinsics/*.json was found")
        rig = rig.with_extrinsics(seq.reference)
    write_rig(out, rig)
    if seq.reference:
        write_calibration(out / "reference_calib.json", Calibration(seq.reference, {
            "source": "HO-Cap reference extrinsics (target-based), camera -> master inverted; world = master camera",
            "file": str(seq.extrinsics_file), "master": seq.master}))  # fmt: skip
    ext = str(Path(seq.extrinsics_file).resolve()) if seq.extrinsics_file else None
    (out / "source.json").write_text(json.dumps({"hocap": str(Path(seq.path).resolve()), "extrinsics": ext,
                                                 "master": seq.master}, indent=2) + "\n")  # fmt: skip
    return rig, seq
