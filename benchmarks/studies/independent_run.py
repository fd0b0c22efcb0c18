"""Calibration with defaults on independently rendered repeating studios
(:mod:`benchmarks.studies.independent_scene`), scored camera by camera against the truth.

Per seed: the recording is written under a work folder, ``fuseflow calibrate REC -o
OUT/calib.json --reference REC/reference.json`` runs in a subprocess with the Python and
``PYTHONPATH`` of this process (the calibration a new user gets from the CLI, whatever source
tree is first on the path), and calib.json is read back.

Scoring (:func:`score`): the calibrated world is tied to the true one through one placed camera,
the anchor that puts the most cameras within 1 deg / 3 cm (ties: the smaller median error); when
no anchor puts a second camera within, no camera counts as within (a lone right camera is not a
calibration). Per camera: rotation error (deg) and centre error (cm) under that anchor;
"within" = within 1 deg and 3 cm; "silently wrong" = placed, verdict "good", more than 2 deg or
5 cm off; "flagged" = placed with another verdict; "unplaced" = absent from calib.json.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.common import log
from benchmarks.studies.independent_scene import make_studio, write_studio

WITHIN = (1.0, 3.0)  # deg, cm
WRONG = (2.0, 5.0)


def _rot_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def _centre(T: np.ndarray) -> np.ndarray:
    return -T[:3, :3].T @ T[:3, 3]


def errors_through(anchor: str, est: dict, true: dict) -> dict[str, tuple[float, float]]:
    """(rotation deg, centre cm) of every estimated camera when the calibrated world is tied to
    the true one through ``anchor`` (est: camera-from-calibrated-world, true: camera-from-world)."""
    M = np.linalg.inv(est[anchor]) @ true[anchor]  # calibrated-world-from-true-world
    Minv = np.linalg.inv(M)
    out = {}
    for c, T in est.items():
        rot = _rot_deg(T[:3, :3] @ M[:3, :3] @ true[c][:3, :3].T)
        centre = Minv[:3, :3] @ _centre(T) + Minv[:3, 3]
        out[c] = (rot, float(np.linalg.norm(centre - _centre(true[c])) * 100.0))
    return out


def score(
    est: dict, true: dict, good: set[str] | frozenset = frozenset()
) -> tuple[str | None, dict[str, tuple[float, float]], bool]:
    """The anchor, every placed camera's (deg, cm) through it, and whether at least two cameras
    are within 1 deg / 3 cm under it (else none counts as within). Ties in the count of cameras
    within go to the anchor that leaves the fewest cameras of ``good`` (verdict "good") more than
    2 deg / 5 cm off, then to the smaller median error: the count of silently wrong cameras is a
    lower bound."""
    best, best_key = None, None
    for a in sorted(est):
        errs = errors_through(a, est, true)
        n = sum(r <= WITHIN[0] and p <= WITHIN[1] for r, p in errs.values())
        wrong = sum(c in good and (r > WRONG[0] or p > WRONG[1]) for c, (r, p) in errs.items())
        med = float(np.median([r + p for r, p in errs.values()]))
        key = (-n, wrong, med)
        if best_key is None or key < best_key:
            best, best_key = a, key
    if best is None:
        return None, {}, False
    return best, errors_through(best, est, true), -best_key[0] >= 2


def _calibrate(rec: Path, out: Path) -> tuple[int, float, str]:
    """Run the CLI with defaults; (exit code, seconds, the last lines of its output)."""
    cmd = [sys.executable, "-m", "fuseflow", "calibrate", str(rec), "-o", str(out / "calib.json"),
           "--reference", str(rec / "reference.json")]  # fmt: skip
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))
    (out / "stdout.txt").write_text(res.stdout + res.stderr)
    return res.returncode, time.perf_counter() - t0, (res.stdout + res.stderr)[-600:]


def camera_rows(calib: dict | None, truth: dict, period: float) -> list[dict]:
    """One row per camera of the truth: placed, verdict, reason, errors, counted classes."""
    est = {c: np.asarray(v["T_cam_world"], float) for c, v in (calib or {}).get("cameras", {}).items()}
    verdicts = (calib or {}).get("report", {}).get("camera_verdicts", {}) or {}
    anchor, errs, enough = score(est, truth, {c for c, v in verdicts.items() if v.get("verdict") == "good"})
    rows = []
    for c in truth:
        v = verdicts.get(c, {})
        row = {"camera": c, "placed": c in est, "verdict": v.get("verdict", "unplaced" if c not in est else "?"),
               "reason": v.get("reason", ""), "anchor": c == anchor}  # fmt: skip
        turn = v.get("turn") if isinstance(v.get("turn"), dict) else None
        if turn:
            row["turn_margin"] = turn.get("margin")
        if c in est:
            r, p = errs[c]
            row.update(rot_deg=round(r, 3), pos_cm=round(p, 2), periods=round(r / period, 2))
            row["within"] = bool(enough and r <= WITHIN[0] and p <= WITHIN[1])
            row["silently_wrong"] = bool(row["verdict"] == "good" and (r > WRONG[0] or p > WRONG[1]))
            row["flagged"] = row["verdict"] != "good"
        else:
            row.update(within=False, silently_wrong=False, flagged=False)
        rows.append(row)
    return rows


def run_seed(seed: int, resolution: str, frames: int, moving: bool, work: Path) -> dict:
    """Write the studio of ``seed``, calibrate it with defaults, score it: one result row."""
    studio = make_studio(seed, resolution, frames, moving)
    rec = work / f"{resolution}-f{frames}{'m' if moving else ''}-{seed}"
    out = rec.with_name(rec.name + "-out")
    out.mkdir(parents=True, exist_ok=True)
    write_studio(rec, studio)
    code, secs, tail = _calibrate(rec, out)
    error = tail.strip().splitlines()[-1] if code != 0 and tail.strip() else ""
    (out / "run.json").write_text(json.dumps({"exit_code": code, "time_s": round(secs, 1), "error": error}))
    return score_outputs(rec, out, moving)


def score_outputs(rec: Path, out: Path, moving: bool) -> dict:
    """The result row of one calibrated studio from its files: REC/scene.json, REC/reference.json
    (the truth), OUT/calib.json and OUT/run.json (exit code, time)."""
    info = json.loads((rec / "scene.json").read_text())
    run = json.loads((out / "run.json").read_text())
    truth = {
        c: np.asarray(v["T_cam_world"], float)
        for c, v in json.loads((rec / "reference.json").read_text())["cameras"].items()
    }
    calib_path = out / "calib.json"
    calib = json.loads(calib_path.read_text()) if run["exit_code"] == 0 and calib_path.exists() else None
    cams = camera_rows(calib, truth, 360.0 / info["sides"])
    room = (calib or {}).get("report", {}).get("room") or {}
    row = {**info, "moving": moving, "exit_code": run["exit_code"], "time_s": run["time_s"],
           "room_detected": room.get("sides") if isinstance(room, dict) else None,
           "placed": sum(c["placed"] for c in cams), "within": sum(c["within"] for c in cams),
           "silently_wrong": sum(c["silently_wrong"] for c in cams), "flagged": sum(c["flagged"] for c in cams),
           "unplaced": sum(not c["placed"] for c in cams), "cameras_rows": cams}  # fmt: skip
    if run["exit_code"] != 0:
        row["error"] = run.get("error", "")
    return row


def rescore(work: Path, seeds: list[int], resolution: str, frames: int, moving: bool) -> list[dict]:
    """The rows of seeds already calibrated under ``work`` (scoring only)."""
    rows = []
    for s in seeds:
        rec = work / f"{resolution}-f{frames}{'m' if moving else ''}-{s}"
        rows.append(score_outputs(rec, rec.with_name(rec.name + "-out"), moving))
    return rows


def seed_line(r: dict) -> str:
    """One report line of a seed, then its failing cameras."""
    head = (f"seed {r['seed']} {r['sensor']} N={r['sides']} (found {r.get('room_detected')}) cams={r['cameras']}: within {r['within']}, "
            f"silently wrong {r['silently_wrong']}, flagged {r['flagged']}, unplaced {r['unplaced']}, "
            f"{r['time_s']} s" + (f", exit {r['exit_code']}: {r.get('error', '')}" if r["exit_code"] else ""))  # fmt: skip
    bad = [c for c in r["cameras_rows"] if not c["within"]]
    return "\n".join([head] + [_camera_line(c) for c in bad])


def _camera_line(c: dict) -> str:
    if not c["placed"]:
        return f"    {c['camera']}: unplaced {c['reason'][:160]}"
    tag = "SILENTLY WRONG" if c["silently_wrong"] else c["verdict"]
    return (f"    {c['camera']}: {tag} {c['rot_deg']:.2f} deg ({c['periods']} periods) / {c['pos_cm']:.1f} cm, "
            f"margin {c.get('turn_margin')}: {c['reason'][:200]}")  # fmt: skip


def totals(rows: list[dict]) -> dict:
    """Sums over seeds: cameras, placed, within (and its share), silently wrong, flagged, unplaced."""
    n = sum(r["cameras"] for r in rows)
    t = {k: sum(r[k] for r in rows) for k in ("placed", "within", "silently_wrong", "flagged", "unplaced")}
    return {"seeds": len(rows), "cameras": n, **t, "within_share": round(t["within"] / max(1, n), 3),
            "failed_runs": sum(r["exit_code"] != 0 for r in rows),
            "median_time_s": float(np.median([r["time_s"] for r in rows])) if rows else 0.0}  # fmt: skip


def run_bench(
    seeds: list[int], resolution: str, frames: int, moving: bool, work: Path, progress: Path | None, again: bool = False
):
    """Every seed in order (``again``: only score the outputs already under ``work``); logs each
    seed and the totals; returns (rows, totals)."""
    rows = []
    for s in seeds:
        rows.append(
            rescore(work, [s], resolution, frames, moving)[0]
            if again
            else run_seed(s, resolution, frames, moving, work)
        )
        log(seed_line(rows[-1]))
        if progress is not None:
            progress.write_text(json.dumps(rows, indent=1))
    t = totals(rows)
    log(f"totals {resolution} frames {frames}{' moving' if moving else ''}: {json.dumps(t)}")
    return rows, t
