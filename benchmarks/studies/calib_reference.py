"""Which extrinsics fit the images better: the calibration's or the data set's reference?

    python -m benchmarks.calib_reference_check /tmp/fuseflow-calib-wide/icl8_every26 hocap
    python -m benchmarks.calib_reference_check hocap --per-camera

On real data the "error" of a calibration is its distance to a reference that has errors of its
own (ICL-NUIM: Open3D's trajectory estimate; hocap-8rs: a target-based calibration, ~1 cm). This
calibrates (``fuseflow.calibrate``, default config) and scores both pose sets on the same frame
with two measures the calibration does not optimise jointly:

* depth: share of depth samples within 1 cm (point to plane) of an overlapping neighbour's
  surface and the median point-to-plane residual (mm), :func:`fuseflow.calib.joint_refine.depth_fit`
  (the joint refinement's own check);
* colour: median absolute grey-level difference (0-255) between a textured pixel (Sobel
  magnitude > 40) and the pixel it projects to in each other camera where the depths agree
  within 3 % (median over camera pairs). Depth cannot see a camera sliding along a wall; colour
  can. Exposure differences between real cameras add a constant to both pose sets.

A data name is ``hocap`` (``hocap-8rs`` under the shared data folder) or a recording's path
(frame 0; reference: its rig.json extrinsics).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from fuseflow.calib import calibrate
from fuseflow.calib.joint_refine import depth_fit
from fuseflow.calib.posegraph import rotation_angle_deg
from fuseflow.eval.metrics import pose_errors
from fuseflow.types import Rig, invert_rigid

__all__ = ["colour_fit", "into_reference", "per_camera_table", "reference_table"]

Log = Callable[[str], None]


def _load(name: str, shared: Path):
    if name == "hocap":
        from benchmarks.studies.calib_refine import load_hocap

        frame, rig, T_ref = load_hocap(shared / "hocap-8rs")
        return frame, rig, dict(zip(rig.ids, T_ref))
    from fuseflow.io import open_recording

    rec = open_recording(name)
    return rec[0], Rig(tuple(c.with_extrinsics(None) for c in rec.rig)), {c.id: c.T_cam_world for c in rec.rig}


def _bilinear(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """img sampled at float pixel coordinates (u, v), bilinear (all inside the image)."""
    u0, v0 = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * img[v0, u0] + a * (1 - b) * img[v0, u0 + 1]
            + (1 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])  # fmt: skip


def colour_fit(frame, rig, T: dict, only: str | None = None) -> float:
    """Median over camera pairs of the median absolute grey-level difference (0-255) between a
    textured pixel and the pixel it projects to where the depths agree within 3 % (module
    docstring); ``only``: the pairs of that camera."""
    ids = [c for c in frame.camera_ids if c in T]
    depth, col = frame.depth.numpy(), frame.color.numpy()
    grey = {
        c: cv2.GaussianBlur(cv2.cvtColor(col[frame.camera_ids.index(c)], cv2.COLOR_RGB2GRAY), (3, 3), 0).astype(
            np.float32
        )
        for c in ids
    }
    out = []
    for ci in ids:
        z = depth[frame.camera_ids.index(ci)]
        K = rig[ci].K
        mag = np.hypot(cv2.Sobel(grey[ci], cv2.CV_32F, 1, 0), cv2.Sobel(grey[ci], cv2.CV_32F, 0, 1))
        v, u = np.nonzero((z > 0) & (mag > 40))
        keep = np.arange(0, len(v), max(1, len(v) // 20000))
        v, u = v[keep], u[keep]
        zz = z[v, u].astype(np.float64)
        P = np.stack([(u - K[0, 2]) / K[0, 0] * zz, (v - K[1, 2]) / K[1, 1] * zz, zz], 1)
        for cj in ids:
            if cj == ci or (only is not None and only not in (ci, cj)):
                continue
            M = T[cj] @ invert_rigid(T[ci])
            X = P @ M[:3, :3].T + M[:3, 3]
            Kj, dj = rig[cj].K, depth[frame.camera_ids.index(cj)]
            h, w = dj.shape
            with np.errstate(divide="ignore", invalid="ignore"):
                uu = Kj[0, 0] * X[:, 0] / X[:, 2] + Kj[0, 2]
                vv = Kj[1, 1] * X[:, 1] / X[:, 2] + Kj[1, 2]
            ok = (X[:, 2] > 0.1) & (uu >= 1) & (uu < w - 2) & (vv >= 1) & (vv < h - 2)
            ui, vi = np.rint(uu[ok]).astype(int), np.rint(vv[ok]).astype(int)
            d = dj[vi, ui]
            agree = (d > 0) & (np.abs(d - X[ok, 2]) < 0.03 * X[ok, 2])
            if agree.sum() < 200:
                continue
            src = grey[ci][v[ok][agree], u[ok][agree]]
            dst = _bilinear(grey[cj], uu[ok][agree], vv[ok][agree])
            out.append(float(np.median(np.abs(dst - src))))
    return float(np.median(out))


def into_reference(T: dict, T_ref: dict, cam: str) -> np.ndarray:
    """Camera ``cam``'s calibrated pose moved into the reference's world by the rigid transform
    that best maps the calibration's world onto the reference's over the *other* cameras
    (A_j = inv(T_ref_j) T_j, rotations averaged by SVD, translations by the mean)."""
    A = [np.linalg.inv(T_ref[j]) @ T[j] for j in T if j != cam]
    u, _, vt = np.linalg.svd(sum(a[:3, :3] for a in A))
    M = np.eye(4)
    M[:3, :3] = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    M[:3, 3] = np.mean([a[:3, 3] for a in A], axis=0)
    return T[cam] @ np.linalg.inv(M)


def per_camera_table(name: str, shared: Path, log: Log) -> None:
    """Per camera c: the reference's other cameras with c at the reference's pose against c at
    the calibration's pose (moved into the reference's world over the other cameras): which
    pose of c fits the reference's other cameras better, by depth and by colour; a markdown
    table to ``log``."""
    frame, rig, T_ref = _load(name, shared)
    T = dict(calibrate(frame, rig).T_cam_world)
    log(
        "| camera | c vs reference deg / mm | share within 1 cm: calib c / ref c | median residual mm: calib c / ref c | colour diff: calib c / ref c |"
    )
    log("|---|---|---|---|---|")
    for c in T:
        hyb = {j: T_ref[j] for j in T}
        hyb[c] = into_reference(T, T_ref, c)
        ref = {j: T_ref[j] for j in T}
        d = hyb[c] @ np.linalg.inv(ref[c])
        deg = rotation_angle_deg(d[:3, :3])
        mm = 1000 * np.linalg.norm(invert_rigid(hyb[c])[:3, 3] - invert_rigid(ref[c])[:3, 3])
        (s_h, m_h), (s_r, m_r) = depth_fit(frame, rig, hyb, only=c), depth_fit(frame, rig, ref, only=c)
        p_h, p_r = colour_fit(frame, rig, hyb, only=c), colour_fit(frame, rig, ref, only=c)
        log(f"| {c} | {deg:.2f} / {mm:.1f} | {s_h:.3f} / {s_r:.3f} | {m_h:.2f} / {m_r:.2f} | {p_h:.2f} / {p_r:.2f} |")


def reference_table(
    names: list[str], shared: Path, log: Log, record: Callable[[dict], None] = lambda row: None
) -> list[dict]:
    """Per data name: calibration vs reference (placed, pose difference, depth and colour fit of
    both pose sets); a markdown table to ``log``, each row as a dict to ``record`` and returned."""
    log(
        "| data | placed | calibration vs reference deg / mm | share within 1 cm: calib / ref | median residual mm: calib / ref | colour diff: calib / ref |"
    )
    log("|---|---|---|---|---|---|")
    rows = []
    for name in names:
        frame, rig, T_ref = _load(name, shared)
        cal = calibrate(frame, rig)
        T = dict(cal.T_cam_world)
        ref = {c: T_ref[c] for c in T}
        e = pose_errors(T, ref)
        s_c, m_c = depth_fit(frame, rig, T)
        s_r, m_r = depth_fit(frame, rig, ref)
        p_c, p_r = colour_fit(frame, rig, T), colour_fit(frame, rig, ref)
        log(
            f"| {Path(name).name} | {len(T)}/{len(rig)} | {e.rotation_deg:.3f} / {e.translation_mm:.1f} | {s_c:.3f} / {s_r:.3f} | {m_c:.2f} / {m_r:.2f} | {p_c:.2f} / {p_r:.2f} |"
        )
        rows.append(
            {
                "data": Path(name).name,
                "rot_deg": e.rotation_deg,
                "trans_mm": e.translation_mm,
                "share": [s_c, s_r],
                "median_mm": [m_c, m_r],
                "colour": [p_c, p_r],
            }
        )
        record(rows[-1])
    return rows
