"""How far a calibration is from a reference one (a vendor calibration, an earlier calib.json, a
rig.json's extrinsics), per camera, in degrees and millimetres.

GMAC's world is the first placed camera's frame, a reference's world is its own, so the two are
aligned first: a rigid transform (no scale: both are metric) of the estimate's world onto the
reference's, fitted over every camera both place, on orientations and centres together. The fit
is iteratively reweighted (each camera weighted by the inverse of its current error, rotation and
position separately: a least-absolute-deviations fit), so one or two wrong cameras show their own
error instead of spreading it over the others. With one common camera the worlds are aligned on
that camera exactly.

Per camera: ``rotation_deg``, the angle of R_ref^T R_aligned (the difference of the two camera
orientations); ``position_mm``, the distance between the two camera centres after alignment.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.types import invert_rigid

__all__ = ["compare_to_reference", "check_reference", "align_worlds", "ALIGNMENT"]

ALIGNMENT = (
    "rigid fit of the estimate's world onto the reference's over the cameras both place "
    "(orientations and centres, iteratively reweighted: least absolute deviations)"
)


def _project_so3(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _errors(Rw_est, Rw_ref, C_est, C_ref, R, t) -> tuple[np.ndarray, np.ndarray]:
    """(rotation deg, position m) per camera under world alignment (R, t)."""
    D = np.einsum("nji,jk,nkl->nil", Rw_ref, R, Rw_est)  # R_ref^T R R_est
    ang = np.degrees(np.arccos(np.clip((np.trace(D, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    pos = np.linalg.norm(C_ref - (C_est @ R.T + t), axis=1)
    return ang, pos


def align_worlds(
    T_est: Mapping[str, np.ndarray], T_ref: Mapping[str, np.ndarray], cams: Sequence[str], iterations: int = 50
) -> np.ndarray:
    """(4, 4) ref-world-from-estimate-world over ``cams`` (module docstring)."""
    W_est = np.stack([invert_rigid(np.asarray(T_est[c], dtype=np.float64)) for c in cams])
    W_ref = np.stack([invert_rigid(np.asarray(T_ref[c], dtype=np.float64)) for c in cams])
    Rw_est, Rw_ref, C_est, C_ref = W_est[:, :3, :3], W_ref[:, :3, :3], W_est[:, :3, 3], W_ref[:, :3, 3]
    wr = np.ones(len(cams))
    wt = np.ones(len(cams))
    for _ in range(iterations):
        R = _project_so3(np.einsum("n,nij,nkj->ik", wr, Rw_ref, Rw_est))  # sum w R_ref R_est^T
        t = (wt[:, None] * (C_ref - C_est @ R.T)).sum(0) / wt.sum()
        ang, pos = _errors(Rw_est, Rw_ref, C_est, C_ref, R, t)
        wr, wt = 1.0 / np.maximum(ang, 1e-3), 1.0 / np.maximum(pos, 1e-5)
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, t
    return M


def check_reference(T_ref: Mapping[str, np.ndarray], ids: Sequence[str], source: str = "") -> None:
    """ValidationError unless the reference ``T_ref`` places every camera of ``ids``: one naming
    none of them is a calibration of another rig; one lacking some names them."""
    where = f"--reference {source}: " if source else "reference: "
    ids = list(ids)
    if not any(c in T_ref for c in ids):
        raise ValidationError(
            f"{where}it places none of this rig's cameras {ids} (it has {sorted(T_ref)}): a calibration of another rig"
        )
    missing = [c for c in ids if c not in T_ref]
    if missing:
        raise ValidationError(f"{where}cameras {missing} of this rig are missing from it (it has {sorted(T_ref)})")


def compare_to_reference(
    T_est: Mapping[str, np.ndarray], T_ref: Mapping[str, np.ndarray], ids: Sequence[str], source: str = ""
) -> dict[str, Any]:
    """Per-camera rotation (deg) and position (mm) differences of ``T_est`` to ``T_ref``
    (camera id -> camera-from-world, metres) after aligning their worlds (module docstring).

    Args:
        ids: the rig's camera ids; every one must be in ``T_ref``.
        source: where the reference came from (stored as is).

    Returns:
        {"source", "alignment", "common": [ids], "cameras": {id: {"rotation_deg",
        "position_mm"} or {"unplaced": True}}, "median_rotation_deg", "max_rotation_deg",
        "median_position_mm", "max_position_mm"} (plain JSON data).

    Raises:
        ValidationError: the reference places none of ``ids`` (another rig), lacks some of them,
            or shares no placed camera with the estimate.
    """
    where = f"reference {source}: " if source else "reference: "
    ids = list(ids)
    check_reference(T_ref, ids, source)
    common = [c for c in ids if c in T_est]
    if not common:
        raise ValidationError(f"{where}the calibration placed no camera to compare")
    M_inv = invert_rigid(align_worlds(T_est, T_ref, common))
    cams: dict[str, Any] = {}
    for c in ids:
        if c not in T_est:
            cams[c] = {"unplaced": True}
            continue
        T_al = np.asarray(T_est[c], dtype=np.float64) @ M_inv  # camera-from-reference-world
        W_al, W_ref = invert_rigid(T_al), invert_rigid(np.asarray(T_ref[c], dtype=np.float64))
        D = W_ref[:3, :3].T @ W_al[:3, :3]
        ang = float(np.degrees(np.arccos(np.clip((np.trace(D) - 1) / 2, -1, 1))))
        cams[c] = {
            "rotation_deg": round(ang, 4),
            "position_mm": round(float(np.linalg.norm(W_al[:3, 3] - W_ref[:3, 3]) * 1000), 2),
        }
    rot = [v["rotation_deg"] for v in cams.values() if "rotation_deg" in v]
    pos = [v["position_mm"] for v in cams.values() if "position_mm" in v]
    return {
        "source": source,
        "alignment": ALIGNMENT if len(common) > 1 else f"the worlds aligned on {common[0]}, the only common camera",
        "common": common,
        "cameras": cams,
        "median_rotation_deg": round(float(np.median(rot)), 4),
        "max_rotation_deg": round(float(np.max(rot)), 4),
        "median_position_mm": round(float(np.median(pos)), 2),
        "max_position_mm": round(float(np.max(pos)), 2),
    }
