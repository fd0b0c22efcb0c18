"""The simulated 4-camera 320x240 ring calibrated by the CLI and by the Python API
(benchmarks.calib_ring_api says what is measured)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np

from benchmarks import common

WITHIN_DEG, WITHIN_CM = 1.0, 3.0
WRONG_DEG, WRONG_CM = 2.0, 5.0


def _cli(*args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "fuseflow", *args]
    return subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ))


def _api(rec: Path) -> tuple[dict, dict, list[str]]:
    """(T by camera, verdict by camera, warning lines) of ``fuseflow.calibrate`` on the recording."""
    import fuseflow

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        calib = fuseflow.calibrate(fuseflow.open_recording(rec))
    verdicts = {c: v["verdict"] for c, v in calib.report.camera_verdicts.items()}
    return dict(calib.T_cam_world), verdicts, [str(w.message) for w in caught]


def _cli_result(path: Path) -> tuple[dict, dict]:
    doc = json.loads(path.read_text())
    T = {c: np.asarray(v["T_cam_world"]) for c, v in doc["cameras"].items()}
    verdicts = {c: v["verdict"] for c, v in doc["report"]["camera_verdicts"].items()}
    return T, verdicts


def _rows(seed: int, how: str, T: dict, verdicts: dict, truth: dict) -> list[dict]:
    from fuseflow.calib.reference import compare_to_reference

    cmp = compare_to_reference(T, truth, sorted(truth)) if len(T) >= 1 else {"cameras": {}}
    rows = []
    for cam in sorted(truth):
        e = cmp["cameras"].get(cam, {"unplaced": True})
        placed = "rotation_deg" in e
        deg, cm = (e["rotation_deg"], e["position_mm"] / 10) if placed else (None, None)
        within = placed and deg <= WITHIN_DEG and cm <= WITHIN_CM
        verdict = verdicts.get(cam, "unplaced")
        rows.append({
            "seed": seed, "route": how, "camera": cam, "placed": placed, "verdict": verdict,
            "rot_deg": deg, "pos_cm": cm, "within": within,
            "silently_wrong": placed and verdict == "good" and (deg > WRONG_DEG or cm > WRONG_CM),
            "wrong_unflagged": placed and not within and verdict == "good",
        })  # fmt: skip
    return rows


def run_seed(seed: int, work: Path) -> tuple[list[dict], dict]:
    from fuseflow.io.calibration import read_reference

    rec, out = work / f"ring{seed}", work / f"ring{seed}.json"
    if not (rec / "gt.json").exists():
        made = _cli("simulate", str(rec), "--cameras", "4", "--num-frames", "6", "--resolution", "320x240",
                    "--dynamic", "--uncalibrated", "--seed", str(seed))  # fmt: skip
        if made.returncode:
            raise SystemExit(f"simulate seed {seed} failed: {made.stderr.strip()[-400:]}")
    truth = dict(read_reference(rec / "gt.json").T_cam_world)
    cli = _cli("calibrate", str(rec), "--out", str(out))
    T_cli, v_cli = _cli_result(out) if cli.returncode == 0 else ({}, {})
    T_api, v_api, warned = _api(rec)
    same_poses = sorted(T_cli) == sorted(T_api) and all(np.allclose(T_cli[c], T_api[c], atol=1e-6) for c in T_cli)
    rows = _rows(seed, "cli", T_cli, v_cli, truth) + _rows(seed, "api", T_api, v_api, truth)
    not_good = [c for c, v in v_api.items() if v != "good"]
    agree = {
        "seed": seed, "cli_exit": cli.returncode, "same_poses": same_poses, "same_verdicts": v_cli == v_api,
        "api_warnings_name": all(any(c in w for w in warned) for c in not_good),
    }  # fmt: skip
    return rows, agree


def run_ring_api(seeds: list[int], work: Path) -> tuple[list[dict], list[dict]]:
    """Every seed's camera rows (CLI and API) and its agreement line; prints as it goes."""
    work.mkdir(parents=True, exist_ok=True)
    rows, agreement = [], []
    for seed in seeds:
        r, agree = run_seed(seed, work)
        rows += r
        agreement.append(agree)
        for x in r:
            if x["route"] == "api":
                err = f"{x['rot_deg']:.2f} deg / {x['pos_cm']:.1f} cm" if x["placed"] else "unplaced"
                common.log(f"seed {seed} {x['camera']}: {x['verdict']:9s} {err}{'' if x['within'] else '  NOT WITHIN'}")
        common.log(f"seed {seed}: CLI and API same poses {agree['same_poses']}, same verdicts {agree['same_verdicts']}, "
                   f"API warns every camera not good {agree['api_warnings_name']}")  # fmt: skip
    for how in ("cli", "api"):
        sub = [x for x in rows if x["route"] == how]
        common.log(
            f"{how}: {len(sub)} cameras, {sum(x['placed'] for x in sub)} placed, {sum(x['within'] for x in sub)} within "
            f"1 deg / 3 cm, {sum(x['verdict'] == 'good' for x in sub)} good, "
            f"{sum(x['wrong_unflagged'] for x in sub)} not within and good, {sum(x['silently_wrong'] for x in sub)} silently wrong"
        )
    return rows, agreement
