"""Calibration in the scenes that break it: ``python -m benchmarks.calib_accuracy --data symstudio,far3``.

``symstudio``: the simulator's symmetric studio (``synth.studios``): a regular 8-12-sided room
that repeats exactly, a small figure at the centre, 5-10 cameras (5 + seed % 6) on one ring (even
seeds) or two rings (odd seeds), one frame, Kinect v2-class depth (``noise='kinect2'``) at 512x424,
70 deg field of view. ``far3``: the far-range room, 3 cameras 120 deg apart 3.5-4 m from a person
walking across a low-texture room, 10 frames at 5 fps, the same sensor.

Per camera: placed or not, flagged or not (a suspect camera, or one the report marks ambiguous or
not cycle-checked), and its error against the ground truth. The calibrated world is tied to the
truth by the placed camera that makes the most cameras right (a calibration is defined up to one
rigid transform; choosing the best anchor never makes a wrong camera look right alone; the
anchor itself counts as right only when another camera is right with it).
Counted: "silently wrong" (placed, not flagged, more than 5 deg or 10 cm off) and "within 1 deg /
3 cm". ``run_studio_bench`` hands Markdown lines to a ``log`` callback.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from fuseflow.calib import CalibConfig, calibrate
from fuseflow.calib.errors import CalibrationError
from fuseflow.types import Rig, invert_rigid

__all__ = ["STUDIO_DATA", "studio_config", "camera_errors", "flagged_cameras", "run_studio_seed", "run_studio_bench"]

STUDIO_DATA = ("symstudio", "far3")
WRONG_DEG, WRONG_M = 5.0, 0.10
GOOD_DEG, GOOD_M = 1.0, 0.03


def studio_config(name: str, seed: int):
    """The SimConfig of data set ``name`` ('symstudio' or 'far3') for ``seed`` (module docstring)."""
    from fuseflow.synth import SimConfig

    common = dict(resolution=(512, 424), hfov_deg=70.0, noise="kinect2", seed=seed)
    if name == "symstudio":
        return SimConfig(cameras=5 + seed % 6, frames=1, scene="symstudio", rig="ring" if seed % 2 == 0 else "dome",
                         **common)  # fmt: skip
    if name == "far3":
        return SimConfig(cameras=3, frames=10, scene="farroom", fps=5.0, **common)
    raise ValueError(f"unknown studio data set {name!r}; expected one of {STUDIO_DATA}")


def _rel_err(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    D = A @ invert_rigid(B)
    c = np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0)
    return float(np.degrees(np.arccos(c))), float(np.linalg.norm(invert_rigid(A)[:3, 3] - invert_rigid(B)[:3, 3]))


def camera_errors(T_est: dict[str, np.ndarray], T_true: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """Camera -> (rotation deg, centre distance m) of the estimated camera-from-world poses against
    the truth, the estimated world tied to the true one through the anchor camera that puts the
    most cameras within GOOD_DEG / GOOD_M (ties: the smaller summed rotation error)."""
    best, best_key = {}, None
    for a in sorted(T_est):
        W = invert_rigid(T_est[a]) @ T_true[a]  # estimated world <- true world, through camera a
        errs = {c: _rel_err(T_est[c] @ W, T_true[c]) for c in T_est}
        good = sum(r <= GOOD_DEG and t <= GOOD_M for r, t in errs.values())
        key = (good, -sum(r for r, _ in errs.values()))
        if best_key is None or key > best_key:
            best, best_key = errs, key
    return best


def flagged_cameras(report) -> set[str]:
    """Cameras the report marks: suspect (low depth agreement), placed by rgbd edges that close no
    cycle (no independent check: the report's warning), or a per-camera verdict other than good
    (``report.camera_verdicts``: "check it")."""
    out = set(report.suspect_cameras)
    info = report.backbone_info
    cams = info.get("sources", {}).get("rgbd", info).get("cameras", {})
    out |= {c for c, v in cams.items() if v.get("placed") and not v.get("cycle_checked", True)}
    for c, ev in (report.camera_verdicts or {}).items():
        if ev.get("verdict", "good") != "good":
            out.add(c)
    return out


def run_studio_seed(name: str, seed: int, config: CalibConfig | None = None) -> dict:
    """Simulate data set ``name`` for ``seed``, calibrate, and score every camera (module docstring)."""
    from fuseflow.synth import Simulator

    cfg = studio_config(name, seed)
    sim = Simulator(cfg)
    frames = [sim.render(t).frame for t in range(cfg.frames)]
    rig = Rig(tuple(c.with_extrinsics(None) for c in sim.rig.cameras))
    T_true = {c.id: c.T_cam_world for c in sim.rig.cameras}
    t0 = time.perf_counter()
    try:
        calib = calibrate(frames, rig, config or CalibConfig())
        T_est, flagged, error = dict(calib.T_cam_world), flagged_cameras(calib.report), None
        reasons = dict(calib.report.unplaced_reasons)
        verdicts = {c: v.get("verdict") for c, v in (calib.report.camera_verdicts or {}).items()}
    except CalibrationError as e:
        T_est, flagged, error, reasons, verdicts = {}, set(), str(e), {}, {}
    seconds = time.perf_counter() - t0
    errs = camera_errors(T_est, T_true) if T_est else {}
    # the anchor camera is right by construction: one right camera alone is no evidence
    lone = sum(r <= GOOD_DEG and t <= GOOD_M for r, t in errs.values()) < 2
    cams = {}
    for c in T_true:
        r, t = errs.get(c, (None, None))
        placed = c in T_est
        wrong = placed and (r > WRONG_DEG or t > WRONG_M)
        cams[c] = {"placed": placed, "flagged": c in flagged, "rot_deg": r, "pos_m": t,
                   "silently_wrong": bool(wrong and c not in flagged),
                   "good": bool(placed and not lone and r <= GOOD_DEG and t <= GOOD_M),
                   "reason": reasons.get(c), "verdict": verdicts.get(c)}  # fmt: skip
    return {"data": name, "seed": seed, "cameras": len(T_true), "frames": cfg.frames, "rig": cfg.rig,
            "sides": getattr(sim.scene, "symmetry", 1), "seconds": round(seconds, 2), "error": error,
            "per_camera": cams}  # fmt: skip


def _summary(rows: list[dict]) -> str:
    n = sum(r["cameras"] for r in rows)
    pc = [c for r in rows for c in r["per_camera"].values()]
    placed = sum(c["placed"] for c in pc)
    flagged = sum(c["placed"] and c["flagged"] for c in pc)
    silent = sum(c["silently_wrong"] for c in pc)
    good = sum(c["good"] for c in pc)
    all3 = sum(all(c["good"] for c in r["per_camera"].values()) for r in rows)
    secs = [r["seconds"] for r in rows]
    return (f"| {rows[0]['data']} | {len(rows)} | {n} | {placed} | {flagged} | {silent} | {good} ({100 * good / n:.0f} %) "
            f"| {all3} | {np.median(secs):.1f} ({max(secs):.1f}) |")  # fmt: skip


def run_studio_bench(
    names: Sequence[str], seeds: int, json_path: Path | None = None, log: Callable[[str], None] = print,
    progress: Callable[[str], None] | None = None, config: CalibConfig | None = None, seed_start: int = 0,
) -> list[dict]:  # fmt: skip
    """Seeds ``seed_start`` .. ``seed_start + seeds - 1`` of every data set in ``names``; per-seed
    lines then one summary row per data set through ``log``; all rows to ``json_path`` when
    given. Returns the rows."""
    rows_all = []
    for name in names:
        rows = []
        for seed in range(seed_start, seed_start + seeds):
            row = run_studio_seed(name, seed, config)
            rows.append(row)
            pc = row["per_camera"].values()
            line = (f"{name} seed {seed} ({row['cameras']} cams, {row['sides']}-fold, {row['rig']}): "
                    f"placed {sum(c['placed'] for c in pc)}, good {sum(c['good'] for c in pc)}, "
                    f"flagged {sum(c['flagged'] for c in pc)}, silently wrong {sum(c['silently_wrong'] for c in pc)}, "
                    f"{row['seconds']:.1f} s" + (f" [{row['error'][:80]}]" if row["error"] else ""))  # fmt: skip
            (progress or log)(line)
        rows_all += rows
        log("")
        log("| data | seeds | cameras | placed | placed+flagged | silently wrong | within 1 deg / 3 cm | "
            "seeds all within | s median (max) |")  # fmt: skip
        log("|---|---|---|---|---|---|---|---|---|")
        log(_summary(rows))
    if json_path is not None:
        Path(json_path).write_text(json.dumps(rows_all, indent=1))
    return rows_all
