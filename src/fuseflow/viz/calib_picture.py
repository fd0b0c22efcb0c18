"""The calibration report picture (``fuseflow calibrate`` writes it beside calib.json, same stem,
``.png``): a top-down map of the rig and the pair-agreement matrix, drawn with OpenCV.

Left, the map: the placed cameras' depth (every ``stride``-th pixel of the first frame) carried
into the world by the calibration and seen from above as a grey density splat (darker: more
points), each camera a dot at its centre with its viewing direction (a wedge of its horizontal
field of view) and its id (ids longer than 6 characters: its number in the list beside the
matrix); green = verdict "good", red = "check it". "Up" is the rig's floor
normal when the rgbd backbone measured one, else the mean of the cameras' "up" image axes (else
the normal of the plane through the camera centres). Unplaced cameras are listed under the map.

Right, the matrix: each pair's depth agreement under the calibration (``report.pair_agreement``:
the share of overlapping depth within 5 %), white (0) to dark green (1), "-" where the pair does
not overlap; camera ids in red where the verdict is not "good".
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fuseflow.errors import FuseFlowError
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = ["calibration_picture", "PICTURE_SIZE", "up_direction"]

#: (width, height) pixels of the picture: two square panels side by side.
PICTURE_SIZE = (1400, 760)
GREEN, RED, GREY, BLACK = (40, 150, 40), (30, 30, 210), (150, 150, 150), (20, 20, 20)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def up_direction(T_cam_world: Mapping[str, np.ndarray], report: Any = None) -> np.ndarray:
    """(3,) unit "up" in the world (module docstring)."""
    normals = []
    info = getattr(report, "backbone_info", None) or {}
    rgbd = info if info.get("cameras") else (info.get("sources", {}) or {}).get("rgbd", {}) or {}
    for c, ci in (rgbd.get("cameras") or {}).items():
        fl = ci.get("floor") if isinstance(ci, dict) else None
        if c in T_cam_world and fl and "normal" in fl:
            normals.append(T_cam_world[c][:3, :3].T @ np.asarray(fl["normal"], dtype=np.float64))
    if normals:
        n = np.median(np.stack(normals), axis=0)
        return n / max(np.linalg.norm(n), 1e-12)
    W = [invert_rigid(T) for T in T_cam_world.values()]
    up = -np.mean([w[:3, 1] for w in W], axis=0)  # image y points down
    if np.linalg.norm(up) > 0.5 or len(W) < 3:
        return up / max(np.linalg.norm(up), 1e-12)
    C = np.stack([w[:3, 3] for w in W])
    n = np.linalg.svd(C - C.mean(0))[2][2]
    return n if n @ up >= 0 else -n


def _scene_points(frame: Frame, rig: Rig, T: Mapping[str, np.ndarray], stride: int) -> np.ndarray:
    """(M, 3) world points of the placed cameras' depth, every ``stride``-th pixel."""
    depth = frame.depth.detach().cpu().numpy()
    out = []
    for k, c in enumerate(frame.camera_ids):
        if c not in T:
            continue
        z = depth[k, ::stride, ::stride]
        v, u = np.nonzero(z > 0)
        K = rig[c].K
        zz = z[v, u].astype(np.float64)
        X = np.stack([(u * stride - K[0, 2]) / K[0, 0] * zz, (v * stride - K[1, 2]) / K[1, 1] * zz, zz], 1)
        W = invert_rigid(T[c])
        out.append(X @ W[:3, :3].T + W[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _basis(up: np.ndarray, T: Mapping[str, np.ndarray]) -> np.ndarray:
    """(2, 3) map axes (x right, y down on the picture) perpendicular to ``up``; x along the
    first camera's horizontal viewing direction so the map's orientation is reproducible."""
    first = invert_rigid(next(iter(T.values())))[:3, 2]
    e1 = first - (first @ up) * up
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(up, [1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.cross(up, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)  # right-handed seen from above
    return np.stack([e1, -e2])


def _draw_map(img, box, frame, rig, T, verdicts, report, stride) -> None:
    """The top-down map into ``img`` within ``box`` (x0, y0, size)."""
    x0, y0, size = box
    up = up_direction(T, report)
    B = _basis(up, T)
    C = {c: invert_rigid(M)[:3, 3] for c, M in T.items()}
    cam2 = np.stack([B @ C[c] for c in T])
    P = _scene_points(frame, rig, T, stride)
    p2 = P @ B.T if len(P) else np.zeros((0, 2))
    lo, hi = cam2.min(0), cam2.max(0)
    if len(p2) > 50:
        lo = np.minimum(lo, np.percentile(p2, 2, axis=0))
        hi = np.maximum(hi, np.percentile(p2, 98, axis=0))
    span = float(max(hi - lo)) * 1.15 + 0.5
    mid = (lo + hi) / 2
    scale = size / span

    def px(xy):
        q = (np.asarray(xy) - mid) * scale + size / 2
        return q[..., 0] + x0, q[..., 1] + y0

    if len(p2):
        qx, qy = px(p2)
        ok = (qx >= x0) & (qx < x0 + size) & (qy >= y0) & (qy < y0 + size)
        hist = np.zeros((size, size))
        np.add.at(hist, ((qy[ok] - y0).astype(int), (qx[ok] - x0).astype(int)), 1.0)
        hist = cv2.GaussianBlur(hist, (0, 0), 1.0)
        dens = np.log1p(hist) / max(np.log1p(hist).max(), 1e-9)
        grey = (255 - 215 * dens**0.7).astype(np.uint8)
        img[y0 : y0 + size, x0 : x0 + size] = grey[..., None]
    _scale_bar(img, x0 + 15, y0 + size - 20, scale)
    taken: list[tuple[int, int, int, int]] = []
    for c in T:
        label = c if len(c) <= 6 else str(frame.camera_ids.index(c))  # long ids: the legend's number
        colour = GREEN if verdicts.get(c, {}).get("verdict") == "good" else RED
        _draw_camera(img, px(B @ C[c]), T[c], rig[c], B, 0.12 * size, label, colour, taken)


def _draw_camera(img, centre, T: np.ndarray, cam, B: np.ndarray, L: float, label: str, colour, taken: list) -> None:
    """One camera on the map: dot, viewing arrow, field-of-view wedge, label behind it (moved
    down while it would overlap a label in ``taken``, which it joins)."""
    cx, cy = centre
    W = invert_rigid(T)
    half = np.arctan2(cam.width / 2, cam.K[0, 0])
    for a in (-half, half):  # the field-of-view wedge: rays at the image's left and right edges
        d = B @ (W[:3, :3] @ np.array([np.tan(a), 0.0, 1.0]))
        d = d / max(np.linalg.norm(d), 1e-9)
        cv2.line(img, (int(cx), int(cy)), (int(cx + L * d[0]), int(cy + L * d[1])), colour, 1, cv2.LINE_AA)
    d = B @ W[:3, 2]
    d = d / max(np.linalg.norm(d), 1e-9)
    tip = (int(cx + L * d[0]), int(cy + L * d[1]))
    cv2.arrowedLine(img, (int(cx), int(cy)), tip, colour, 2, cv2.LINE_AA, tipLength=0.25)
    cv2.circle(img, (int(cx), int(cy)), 7, colour, -1, cv2.LINE_AA)
    (tw, th), _ = cv2.getTextSize(label, FONT, 0.55, 2)
    back = 14 + abs(d[0]) * tw / 2 + abs(d[1]) * th / 2  # behind the camera, clear of the dot
    x, y = int(cx - back * d[0] - tw / 2), int(cy - back * d[1] + th / 2)
    while any(x < r[2] and r[0] < x + tw and y - th < r[3] and r[1] < y for r in taken):
        y += th + 6
    taken.append((x, y - th, x + tw, y))
    cv2.putText(img, label, (x, y), FONT, 0.55, colour, 2, cv2.LINE_AA)


def _scale_bar(img, x: int, y: int, px_per_m: float) -> None:
    metres = next((m for m in (0.1, 0.2, 0.5, 1, 2, 5, 10, 20) if m * px_per_m >= 60), 50)
    cv2.line(img, (x, y), (int(x + metres * px_per_m), y), BLACK, 2)
    cv2.putText(img, f"{metres:g} m", (x, y - 6), FONT, 0.5, BLACK, 1, cv2.LINE_AA)


def _draw_matrix(img, box, ids, pairs: Mapping[str, float], verdicts) -> None:
    """The pair-agreement matrix into ``img`` within ``box`` (x0, y0, size)."""
    x0, y0, size = box
    n = len(ids)
    margin = 70
    cell = (size - margin) / max(n, 1)
    S = np.full((n, n), np.nan)
    for key, v in pairs.items():
        a, b = _split_pair(key, ids)
        if a in ids and b in ids:
            S[ids.index(a), ids.index(b)] = S[ids.index(b), ids.index(a)] = v
    font = min(0.5, 0.045 * cell)
    for i in range(n):
        for j in range(n):
            p0 = (int(x0 + margin + j * cell), int(y0 + margin + i * cell))
            p1 = (int(x0 + margin + (j + 1) * cell) - 1, int(y0 + margin + (i + 1) * cell) - 1)
            v = S[i, j]
            if i == j:
                colour = (225, 225, 225)
            elif np.isfinite(v):
                g = float(np.clip(v, 0, 1))
                colour = (int(255 - 215 * g), int(255 - 105 * g), int(255 - 215 * g))
            else:
                colour = (245, 245, 245)
            cv2.rectangle(img, p0, p1, colour, -1)
            if i != j and cell >= 28:
                text = f"{v:.2f}" if np.isfinite(v) else "-"
                ink = (255, 255, 255) if np.isfinite(v) and v > 0.6 else BLACK
                cv2.putText(img, text, (p0[0] + 4, (p0[1] + p1[1]) // 2 + 5), FONT, font, ink, 1, cv2.LINE_AA)
    for k, c in enumerate(ids):  # rows and columns numbered; the ids listed to the right
        v = verdicts.get(c, {}).get("verdict", "unplaced")
        colour = GREEN if v == "good" else RED
        bold = 1 + (colour == RED)
        yc = int(y0 + margin + (k + 0.5) * cell) + 5
        cv2.putText(img, str(k), (x0 + margin - 26, yc), FONT, 0.5, colour, bold, cv2.LINE_AA)
        xc = int(x0 + margin + (k + 0.5) * cell)
        cv2.putText(img, str(k), (xc - 6, y0 + margin - 8), FONT, 0.5, colour, bold, cv2.LINE_AA)
        ly = y0 + margin + 10 + k * 24
        cv2.putText(img, f"{k}  {c}  {v}", (x0 + size + 15, ly), FONT, 0.5, colour, bold, cv2.LINE_AA)


def _draw_reasons(img, x0: int, y0: int, width: int, ids, verdicts) -> None:
    """ "k id verdict: reason" of every camera whose verdict is not "good", wrapped to ``width``
    pixels, without a trailing parenthesis (advice the printed table gives); what does not fit
    ends in "... N more (calib.json's camera_verdicts)"."""
    flagged = [(k, c, verdicts[c]) for k, c in enumerate(ids) if verdicts.get(c, {}).get("verdict", "good") != "good"]
    chars, bottom, y = max(20, width // 9), img.shape[0] - 16, y0
    for n, (k, c, v) in enumerate(flagged):
        reason = re.sub(r"\s*\([^()]*\)$", "", v.get("reason", ""))
        lines, text = [], f"{k} {c} {v['verdict']}: {reason}"
        while text:
            cut = text if len(text) <= chars else text[:chars].rsplit(" ", 1)[0]
            lines.append(cut)
            text = text[len(cut) :].lstrip()
        if y + 20 * len(lines) > bottom - (20 if n < len(flagged) - 1 else 0):
            cv2.putText(
                img,
                f"... {len(flagged) - n} more (calib.json's camera_verdicts)",
                (x0, y),
                FONT,
                0.45,
                RED,
                1,
                cv2.LINE_AA,
            )
            return
        for line in lines:
            cv2.putText(img, line, (x0, y), FONT, 0.45, RED, 1, cv2.LINE_AA)
            y += 20
        y += 6


def _split_pair(key: str, ids) -> tuple[str, str]:
    """ "a-b" where camera ids may contain "-": the split whose both halves are ids."""
    for k in range(1, len(key)):
        if key[k] == "-" and key[:k] in ids and key[k + 1 :] in ids:
            return key[:k], key[k + 1 :]
    return key, ""


def calibration_picture(
    path: str | Path,
    frame: Frame,
    rig: Rig,
    T_cam_world: Mapping[str, np.ndarray],
    report: Any,
    stride: int = 4,
) -> Path:
    """Draw the report picture (module docstring) and write it to ``path`` (PNG).

    Args:
        frame: the calibrated frame (its depth is the map's scene). rig: its cameras'
            intrinsics. T_cam_world: camera id -> (4, 4) camera-from-world, metres (placed only).
        report: the :class:`~fuseflow.calib.CalibReport` (verdicts, pair agreement, floor).

    Raises:
        FuseFlowError: the PNG could not be written.
    """
    W, H = PICTURE_SIZE
    img = np.full((H, W, 3), 255, np.uint8)
    verdicts = getattr(report, "camera_verdicts", {}) or {}
    ids = list(frame.camera_ids)
    good = sum(v.get("verdict") == "good" for v in verdicts.values())
    check = sum(v.get("verdict") == "check it" for v in verdicts.values())
    title = f"{len(T_cam_world)}/{len(ids)} cameras placed: {good} good, {check} check it"
    cv2.putText(img, title, (20, 32), FONT, 0.8, BLACK, 2, cv2.LINE_AA)
    panel = H - 110
    cv2.putText(img, "rig seen from above (green: good, red: check it)", (20, 66), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    if T_cam_world:
        _draw_map(img, (20, 80, panel), frame, rig, dict(T_cam_world), verdicts, report, stride)
    cv2.rectangle(img, (20, 80), (20 + panel, 80 + panel), GREY, 1)
    x1 = 40 + panel
    cv2.putText(img, "pair depth agreement (share within 5 %)", (x1, 66), FONT, 0.55, BLACK, 1, cv2.LINE_AA)
    _draw_matrix(img, (x1, 80, min(panel, W - x1 - 250)), ids, getattr(report, "pair_agreement", {}) or {}, verdicts)
    _draw_reasons(img, x1, 80 + min(panel, W - x1 - 250) + 30, W - x1 - 20, ids, verdicts)
    unplaced = [c for c in ids if c not in T_cam_world]
    if unplaced:
        cv2.putText(img, "unplaced: " + ", ".join(unplaced), (20, H - 12), FONT, 0.6, RED, 2, cv2.LINE_AA)
    path = Path(path)
    ok, buf = cv2.imencode(".png", img)
    try:
        if not ok:
            raise OSError("PNG encoding failed")
        path.write_bytes(buf.tobytes())
    except OSError as exc:
        raise FuseFlowError(f"{path}: could not write the report picture: {exc}") from None
    return path
