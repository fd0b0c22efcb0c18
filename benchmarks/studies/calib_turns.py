"""Calibration in repeating rooms from ONE frame (``benchmarks/calib_room_turns.py``): is any
camera placed a whole room period off with verdict "good"?

Two separately written studio families of the simulator: ``symstudio`` (``synth.studios``: an
8-12-sided room, a small figure, 5-10 cameras on one ring (even seeds) or two rings (odd seeds),
Kinect v2-class noise, 70 deg) and ``polyroom`` (``synth.studio_b``: a 6-12-sided room with its
own textures, a seated figure of boxes and cylinders, Kinect v2 or Azure Kinect time-of-flight
noise, 5-10 cameras on one or two rings 2.5-4 m out). Cameras: 5 + seed % 6. ``fuseflow.calibrate``
with its defaults on the first ``frames`` frames (``dynamic``: the figure moves between frames).

Per camera: placed, verdict, rotation / centre error against the truth (the calibrated world tied
to the true one through the placed camera that puts the most cameras within 1 deg / 3 cm; a lone
right camera does not count as right), the room turn evidence (``camera_verdicts``' "turn").
Counted: "silently wrong" (placed, verdict "good", more than 2 deg or 5 cm off) and "within
1 deg / 3 cm" (of all cameras).

``run_planted_bench`` measures the subject's evidence alone on true poses with cameras turned by
planted whole periods (no calibration), with the polyroom's control subjects.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

__all__ = [
    "FAMILIES",
    "run_seed",
    "seed_line",
    "summary",
    "run_turn_bench",
    "planted_turns_seed",
    "run_planted_bench",
]

FAMILIES = ("symstudio", "polyroom")
WRONG_DEG, WRONG_M = 2.0, 0.05
GOOD_DEG, GOOD_M = 1.0, 0.03


def sim_config(family: str, seed: int, resolution: tuple[int, int], frames: int, dynamic: bool):
    from fuseflow.synth import SimConfig

    n = 5 + seed % 6
    if family == "symstudio":
        return SimConfig(cameras=n, frames=frames, scene="symstudio", rig="ring" if seed % 2 == 0 else "dome",
                         resolution=resolution, hfov_deg=70.0, noise="kinect2", seed=seed, dynamic=dynamic)  # fmt: skip
    return SimConfig(cameras=n, frames=frames, scene="polyroom", resolution=resolution, seed=seed, dynamic=dynamic)


def simulate(family: str, seed: int, resolution: tuple[int, int], frames: int, dynamic: bool):
    """(frames, true rig, room sides) of one seed."""
    from fuseflow.synth import Simulator
    from fuseflow.synth.studio_b import PolyroomSimulator

    cfg = sim_config(family, seed, resolution, frames, dynamic)
    sim = PolyroomSimulator(cfg) if family == "polyroom" else Simulator(cfg)
    sides = sim.symmetry if family == "polyroom" else sim.scene.symmetry
    return [sim.render(t).frame for t in range(frames)], sim.rig, sides


def _err(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    from fuseflow.types import invert_rigid

    D = A @ invert_rigid(B)
    c = np.clip((np.trace(D[:3, :3]) - 1) / 2, -1.0, 1.0)
    return float(np.degrees(np.arccos(c))), float(np.linalg.norm(invert_rigid(A)[:3, 3] - invert_rigid(B)[:3, 3]))


def camera_errors(T_est: dict, T_true: dict) -> tuple[dict, bool]:
    """(camera -> (deg, m), lone): errors with the best anchor; lone when fewer than two are right."""
    from fuseflow.types import invert_rigid

    best, key_best = {}, None
    for a in sorted(T_est):
        W = invert_rigid(T_est[a]) @ T_true[a]
        errs = {c: _err(T_est[c] @ W, T_true[c]) for c in T_est}
        good = sum(r <= GOOD_DEG and t <= GOOD_M for r, t in errs.values())
        key = (good, -sum(r for r, _ in errs.values()))
        if key_best is None or key > key_best:
            best, key_best = errs, key
    return best, (key_best or (0,))[0] < 2


def run_seed(family: str, seed: int, resolution, frames: int, dynamic: bool) -> dict:
    from fuseflow.calib import calibrate
    from fuseflow.calib.errors import CalibrationError
    from fuseflow.types import Rig

    fr, rig_true, sides = simulate(family, seed, resolution, frames, dynamic)
    rig = Rig(tuple(c.with_extrinsics(None) for c in rig_true.cameras))
    T_true = {c.id: c.T_cam_world for c in rig_true.cameras}
    t0 = time.perf_counter()
    try:
        cal = calibrate(fr, rig)
        T_est, verdicts, error = dict(cal.T_cam_world), cal.report.camera_verdicts or {}, None
        room = (cal.report.backbone_info or {}).get("sources", {}).get("rgbd", cal.report.backbone_info).get("room")
    except CalibrationError as e:
        T_est, verdicts, error, room = {}, {}, str(e), None
    secs = time.perf_counter() - t0
    errs, lone = camera_errors(T_est, T_true) if T_est else ({}, True)
    cams = {}
    for c in T_true:
        r, t = errs.get(c, (None, None))
        v = verdicts.get(c, {})
        placed = c in T_est
        off = placed and (r > WRONG_DEG or t > WRONG_M)
        cams[c] = {"placed": placed, "verdict": v.get("verdict"), "reason": v.get("reason"), "rot_deg": r, "pos_m": t,
                   "turn": v.get("turn"), "silently_wrong": bool(off and v.get("verdict") == "good"),
                   "within": bool(placed and not lone and r <= GOOD_DEG and t <= GOOD_M)}  # fmt: skip
    return {"family": family, "seed": seed, "cameras": len(T_true), "sides": sides, "frames": frames,
            "seconds": round(secs, 1), "error": error, "room": room, "per_camera": cams}  # fmt: skip


def seed_line(row: dict) -> str:
    pc = row["per_camera"].values()
    bad = [f"{c} {v['rot_deg']:.1f}deg/{v['pos_m'] * 100:.0f}cm {v['verdict']}" for c, v in row["per_camera"].items()
           if v["placed"] and (v["rot_deg"] > WRONG_DEG or v["pos_m"] > WRONG_M)]  # fmt: skip
    return (f"{row['family']} seed {row['seed']} ({row['cameras']} cams, {row['sides']}-fold): placed "
            f"{sum(c['placed'] for c in pc)}, good {sum(c['verdict'] == 'good' for c in pc)}, within "
            f"{sum(c['within'] for c in pc)}, silently wrong {sum(c['silently_wrong'] for c in pc)}, "
            f"{row['seconds']} s{'; error: ' + row['error'] if row['error'] else ''}"
            f"{'; off: ' + ', '.join(bad) if bad else ''}")  # fmt: skip


def summary(rows: list[dict]) -> list[str]:
    out = ["| family | seeds | cameras | placed | good | silently wrong | within 1 deg / 3 cm | s per seed (median, max) |",
           "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for fam in FAMILIES:
        rs = [r for r in rows if r["family"] == fam]
        if not rs:
            continue
        pc = [c for r in rs for c in r["per_camera"].values()]
        n = len(pc)
        within = sum(c["within"] for c in pc)
        secs = [r["seconds"] for r in rs]
        out.append(f"| {fam} | {len(rs)} | {n} | {sum(c['placed'] for c in pc)} | "
                   f"{sum(c['verdict'] == 'good' for c in pc)} | {sum(c['silently_wrong'] for c in pc)} | "
                   f"{within} ({100 * within / n:.0f} %) | {np.median(secs):.1f}, {max(secs):.1f} |")  # fmt: skip
    return out


def run_turn_bench(families, seeds, resolution=(320, 240), frames: int = 1, dynamic: bool = False,
                   json_path=None, log=print) -> list[dict]:  # fmt: skip
    """Every seed, each over every family: a line per seed, then the summary table, through
    ``log``; all rows to ``json_path`` (rewritten after each seed) when given. ``resolution``:
    (w, h) or family -> (w, h). Returns the rows."""
    rows = []
    for seed in seeds:
        for fam in families:
            res = resolution[fam] if isinstance(resolution, dict) else resolution
            rows.append(run_seed(fam, seed, res, frames, dynamic))
            rows[-1]["resolution"] = f"{res[0]}x{res[1]}"
            log(seed_line(rows[-1]))
            if json_path:
                Path(json_path).write_text(json.dumps(rows, indent=1, default=str))
    log("\n".join(summary(rows)))
    return rows


def planted_turns_seed(family: str, seed: int, resolution=(320, 240), subject: str = "figure") -> list[dict]:
    """The subject's turn evidence alone (no calibration): the true poses (world = the first
    camera), 0-3 cameras other than the first turned by a random whole number of room periods,
    then ``calib.turns.camera_turns``. Per camera: the planted turn (the one that puts it back),
    the chosen turn, whether they match, the margin. ``subject`` (polyroom only): 'figure', or the
    controls 'column' and 'none' (``synth.studio_b.SUBJECTS``)."""
    from types import SimpleNamespace

    from fuseflow.calib.turns import RoomAxis, camera_turns
    from fuseflow.synth import Simulator
    from fuseflow.synth.studio_b import PolyroomSimulator
    from fuseflow.types import invert_rigid

    cfg = sim_config(family, seed, resolution, 1, False)
    sim = PolyroomSimulator(cfg, subject=subject) if family == "polyroom" else Simulator(cfg)
    sides = sim.symmetry if family == "polyroom" else sim.scene.symmetry
    frame, ids = sim.render(0).frame, list(sim.rig.ids)
    T0 = sim.rig.cameras[0].T_cam_world
    T = {c.id: c.T_cam_world @ invert_rigid(T0) for c in sim.rig.cameras}
    true_room = RoomAxis(sides, (T0 @ np.r_[0.0, 0.0, 0.0, 1.0])[:3], T0[:3, 2], 1.0, 0.0)
    rng = np.random.default_rng(seed)
    planted = {}
    for c in rng.choice(ids[1:], size=min(len(ids) - 1, int(rng.integers(0, 4))), replace=False):
        k = int(rng.integers(1, sides))
        T[str(c)] = T[str(c)] @ invert_rigid(true_room.turn(-k))
        planted[str(c)] = k if k <= sides // 2 else k - sides
    room, ev = camera_turns(frame, sim.rig, T, SimpleNamespace(backbone_info={}))
    if room is None:
        return [{"family": family, "seed": seed, "subject": subject, "sides": sides, "room": None}]
    return [{"family": family, "seed": seed, "subject": subject, "sides": sides, "room": room.sides, "camera": c,
             "planted": planted.get(c, 0), "chosen": ev[c].turn, "right": ev[c].turn == planted.get(c, 0),
             "margin": ev[c].margin} for c in ids]  # fmt: skip


def run_planted_bench(families, seeds, resolution=(320, 240), subject: str = "figure", json_path=None,
                      log=print) -> list[dict]:  # fmt: skip
    """``planted_turns_seed`` over seeds and families; one line per seed, then per family: rooms
    found, cameras, right turns, and the margins of right and wrong choices."""
    rows = []
    for fam in families:
        for seed in seeds:
            r = planted_turns_seed(fam, seed, resolution, subject)
            rows += r
            ok = [x for x in r if x.get("camera")]
            log(f"{fam} {subject} seed {seed} ({r[0]['sides']}-fold): room {r[0].get('room')}, "
                f"right {sum(x['right'] for x in ok)} of {len(ok)}, margins {[x['margin'] for x in ok]}")  # fmt: skip
            if json_path:
                Path(json_path).write_text(json.dumps(rows, indent=1, default=str))
    for fam in families:
        cams = [x for x in rows if x["family"] == fam and x.get("camera")]
        rooms = len({x["seed"] for x in cams})
        right = [x["margin"] for x in cams if x["right"] and x["margin"] is not None]
        wrong = [x["margin"] for x in cams if not x["right"] and x["margin"] is not None]
        log(f"{fam} {subject}: {len(cams)} cameras in {rooms} seeds with a room, {sum(x['right'] for x in cams)} right; "
            f"margins right {min(right, default=None)}-{max(right, default=None)} (median "
            f"{np.median(right) if right else None}), wrong {min(wrong, default=None)}-{max(wrong, default=None)}, "
            f"no margin {sum(x['margin'] is None for x in cams)}")  # fmt: skip
    return rows
