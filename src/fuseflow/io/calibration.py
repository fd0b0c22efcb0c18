"""The calibration file, calib.json.

Schema::

    {"format": "fuseflow-calib/1",
     "cameras": {"<camera id>": {"T_cam_world": [[4x4 row-major]]}, ...},
     "report": {...}}          # free-form JSON: how the extrinsics were obtained (GMAC writes
                               # fuseflow.calib.CalibReport.to_json() here)

T_cam_world is camera-from-world in metres (the same as rig.json). Cameras that a calibration
could not place are simply absent from "cameras" (and named in the report).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import FormatError, ValidationError
from fuseflow.io.files import load_json, write_json_atomic
from fuseflow.io.recording import parse_matrix
from fuseflow.types import Calibration

__all__ = ["CALIB_FORMAT", "read_calibration", "write_calibration", "calibration_to_json"]

CALIB_FORMAT = "fuseflow-calib/1"


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


def calibration_to_json(calib: Calibration) -> dict[str, Any]:
    """calib.json's document for ``calib``; a typed report is written as its ``to_json()``."""
    return {
        "format": CALIB_FORMAT,
        "cameras": {cid: {"T_cam_world": T.tolist()} for cid, T in calib.T_cam_world.items()},
        "report": _jsonable(calib.report),
    }


def write_calibration(path: str | Path, calib: Calibration) -> Path:
    """Write calib.json (atomically)."""
    path = Path(path)
    write_json_atomic(path, calibration_to_json(calib))
    return path


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
    try:
        return Calibration(T, report)
    except ValidationError as exc:
        raise FormatError(f"{path}: {exc}") from None
