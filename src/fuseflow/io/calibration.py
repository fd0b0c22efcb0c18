"""The calibration file, calib.json.

Schema::

    {"format": "fuseflow-calib/1",
     "cameras": {"<camera id>": {"T_cam_world": [[4x4 row-major]]}, ...},
     "report": {...},          # free-form JSON: how the extrinsics were obtained (GMAC writes
                               # fuseflow.calib.CalibReport.to_json() here)
     "rig_fingerprint": {"<camera id>": {"width": W, "height": H, "K": [[3x3]]}, ...},  # optional
     "capture_volume": {"min": [x, y, z], "max": [x, y, z], "T_box_world": [[4x4]],   # optional
                        "kind": "seen" | "seen-ring" | "ring" | "frusta" | "explicit", "units": "m"},
     "world": {"name": ..., "T_out_world": [[4x4]], "up": [3], "units": "m", "floor": {...}}}  # optional

rig_fingerprint (optional; files without it are read as before) records the intrinsics and
resolution of every camera of the rig the calibration was made for. Read back, it is in
``Calibration.report["rig_fingerprint"]``; ``fuseflow.pipeline.placed_rig`` refuses to apply the
calibration to a rig whose cameras of the same ids differ (a calibration of another rig).

capture_volume (optional) is the box ``--crop auto`` crops fused clouds to
(``fuseflow.geometry.volume.CaptureVolume``: points X with min <= T_box_world X <= max, metres;
T_box_world box-from-world, identity or absent for a box in world axes). ``run`` and ``fuse``
write the one they used; edit it to move the crop. Read back, it is in
``Calibration.report["capture_volume"]`` (validated).

world (optional) is the frame ``run`` and ``fuse`` wrote their clouds in (``--world``,
``fuseflow.geometry.world.World``): ``{"name": "floor" | "camera:<id>" | "calib", "T_out_world":
[[4x4]] (output-from-world), "up": [x, y, z] (in the output frame), "units": "m", "floor":
{"normal", "offset", "cameras"} | null}``. The cameras' poses in the output frame are
``T_cam_world @ inv(T_out_world)``. Read back, it is in ``Calibration.report["world"]``.

T_cam_world is camera-from-world in metres (the same as rig.json). Cameras that a calibration
could not place are simply absent from "cameras" (and named in the report).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FormatError, ValidationError
from fuseflow.geometry.volume import CaptureVolume
from fuseflow.geometry.world import World
from fuseflow.io.files import load_json, write_json_atomic
from fuseflow.io.recording import RIG_FORMAT, parse_matrix, rig_from_json
from fuseflow.types import Calibration, Rig

__all__ = [
    "CALIB_FORMAT",
    "FINGERPRINT_KEY",
    "VOLUME_KEY",
    "WORLD_KEY",
    "read_calibration",
    "write_calibration",
    "calibration_to_json",
    "rig_fingerprint",
    "read_reference",
]

CALIB_FORMAT = "fuseflow-calib/1"
FINGERPRINT_KEY = "rig_fingerprint"
VOLUME_KEY = "capture_volume"
WORLD_KEY = "world"


def _jsonable(obj: Any) -> Any:
    if hasattr(obj, "to_json"):  # a typed report (fuseflow.calib.CalibReport); io does not import calib
        return _jsonable(obj.to_json())
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if hasattr(obj, "tolist"):  # torch tensors, without importing torch here
        return obj.tolist()
    return obj


def rig_fingerprint(rig: Rig) -> dict[str, Any]:
    """Camera id -> {"width", "height", "K"} (pixels) and, when the camera names one, "sensor"
    (its noise preset) of every camera of ``rig``: what calib.json records of the rig it was
    made for."""
    return {
        c.id: {"width": c.width, "height": c.height, "K": c.K.tolist(), **({"sensor": c.sensor} if c.sensor else {})}
        for c in rig.cameras
    }


def calibration_to_json(calib: Calibration, rig: Rig | None = None) -> dict[str, Any]:
    """calib.json's document for ``calib``; a typed report is written as its ``to_json()``.

    ``rig``: the rig the calibration was made for; its fingerprint is written (else the one a
    read-back calibration carries in its report, if any)."""
    report = _jsonable(calib.report)
    fingerprint = report.pop(FINGERPRINT_KEY, None) if isinstance(report, dict) else None
    volume = report.pop(VOLUME_KEY, None) if isinstance(report, dict) else None
    world = report.pop(WORLD_KEY, None) if isinstance(report, dict) else None
    if rig is not None:
        fingerprint = rig_fingerprint(rig)
    doc = {
        "format": CALIB_FORMAT,
        "cameras": {cid: {"T_cam_world": T.tolist()} for cid, T in calib.T_cam_world.items()},
        "report": report,
    }
    if fingerprint is not None:
        doc[FINGERPRINT_KEY] = fingerprint
    if volume is not None:
        doc[VOLUME_KEY] = volume.to_json() if isinstance(volume, CaptureVolume) else volume
    if world is not None:
        doc[WORLD_KEY] = world.to_json() if isinstance(world, World) else world
    return doc


def write_calibration(path: str | Path, calib: Calibration, rig: Rig | None = None) -> Path:
    """Write calib.json (atomically); with ``rig``, its fingerprint (intrinsics and resolution)."""
    path = Path(path)
    write_json_atomic(path, calibration_to_json(calib, rig))
    return path


def _read_fingerprint(value: Any, path: Path) -> dict[str, dict[str, Any]]:
    if not isinstance(value, dict):
        raise FormatError(f"{path}: field {FINGERPRINT_KEY!r} must be an object mapping camera id to intrinsics")
    out = {}
    for cid, entry in value.items():
        where = f"{path}: {FINGERPRINT_KEY} camera {cid!r}"
        if not isinstance(entry, dict) or not all(k in entry for k in ("width", "height", "K")):
            raise FormatError(f"{where}: expected an object with 'width', 'height' and 'K'")
        w, h = entry["width"], entry["height"]
        if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in (w, h)):
            raise FormatError(f"{where}: width and height must be positive integers, got {w!r}, {h!r}")
        out[cid] = {"width": w, "height": h, "K": parse_matrix(entry["K"], 3, f"{where}: field 'K'").tolist()}
    return out


def read_calibration(path: str | Path) -> Calibration:
    """Read and validate calib.json; errors name the field and camera."""
    path = Path(path)
    doc = load_json(path)
    if not isinstance(doc, dict):
        raise FormatError(f"{path}: top level must be an object")
    if doc.get("format") != CALIB_FORMAT:
        raise FormatError(f"{path}: field 'format' must be {CALIB_FORMAT!r}, got {doc.get('format')!r}")
    cams = doc.get("cameras")
    if not isinstance(cams, dict):
        raise FormatError(f"{path}: field 'cameras' must be an object mapping camera id to extrinsics")
    T = {}
    for cid, entry in cams.items():
        if not isinstance(entry, dict) or "T_cam_world" not in entry:
            raise FormatError(f"{path}: camera {cid!r}: missing field 'T_cam_world'")
        T[cid] = parse_matrix(entry["T_cam_world"], 4, f"{path}: camera {cid!r}: field 'T_cam_world'")
    report = doc.get("report", {})
    if not isinstance(report, dict):
        raise FormatError(f"{path}: field 'report' must be an object")
    if FINGERPRINT_KEY in doc:
        report = {**report, FINGERPRINT_KEY: _read_fingerprint(doc[FINGERPRINT_KEY], path)}
    for key, kind in ((VOLUME_KEY, CaptureVolume), (WORLD_KEY, World)):
        if key in doc:
            try:
                value = kind.from_json(doc[key], f"{path}: field {key!r}")
            except ValidationError as exc:
                raise FormatError(str(exc)) from None
            report = {**report, key: value.to_json()}
    try:
        return Calibration(T, report)
    except ValidationError as exc:
        raise FormatError(f"{path}: {exc}") from None


def read_reference(path: str | Path) -> Calibration:
    """Extrinsics to compare a calibration with: calib.json (``fuseflow-calib/1``), rig.json
    (``fuseflow-rig/1``; a recording directory reads its rig.json) whose cameras have
    ``T_cam_world``, or a simulated recording's gt.json (``fuseflow-gt/1``: the true extrinsics).
    A rig.json's intrinsics become the calibration's ``rig_fingerprint``.

    Raises:
        RecordingError / FormatError: unreadable, not JSON, another format, a rig.json without
            extrinsics.
    """
    path = Path(path)
    if path.is_dir():
        path = path / "rig.json"
    doc = load_json(path)
    fmt = doc.get("format") if isinstance(doc, dict) else None
    if fmt == CALIB_FORMAT:
        return read_calibration(path)
    if fmt == GT_FORMAT:
        return _gt_reference(doc, path)
    if fmt != RIG_FORMAT:
        raise FormatError(
            f"{path}: not a calibration: field 'format' must be {CALIB_FORMAT!r} (calib.json), "
            f"{RIG_FORMAT!r} (rig.json) or {GT_FORMAT!r} (a simulated recording's gt.json), got {fmt!r}"
        )
    rig = rig_from_json(doc, str(path))
    without = [c.id for c in rig.cameras if c.T_cam_world is None]
    if without:
        raise FormatError(f"{path}: cameras {without} have no 'T_cam_world': a rig.json reference needs extrinsics")
    return Calibration({c.id: c.T_cam_world for c in rig.cameras}, {FINGERPRINT_KEY: rig_fingerprint(rig)})


#: The simulator's ground-truth file (``synth.recording``: OUT/gt.json).
GT_FORMAT = "fuseflow-gt/1"


def _gt_reference(doc: dict, path: Path) -> Calibration:
    """The true extrinsics of a simulated recording's gt.json; FormatError naming the field."""
    cams = doc.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise FormatError(f"{path}: field 'cameras' must be an object id -> {{T_cam_world, K}}")
    out = {}
    for cid, c in cams.items():
        T = np.asarray(c.get("T_cam_world") if isinstance(c, dict) else None, dtype=np.float64)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise FormatError(f"{path}: camera {cid!r}: 'T_cam_world' must be a finite 4x4 matrix")
        out[str(cid)] = T
    return Calibration(out, {})
