"""The per-camera verdicts and expected accuracy of ``calibrate`` against the truth.

    python -m benchmarks.calib_verdicts --cameras 4,6 --seeds 1,2 --json /tmp/verdicts.json

Simulated room rings (``fuseflow.synth``, 320x240, one frame, default config: auto backbone and
joint refinement); per camera the verdict, the expected accuracy the report gives
(``report.camera_verdicts``) and the true error (``fuseflow.calib.reference.compare_to_reference``
against the recording's rig.json: robust rigid alignment of the worlds, then deg / mm per camera).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

import fuseflow
from fuseflow.calib import CalibConfig, calibrate
from fuseflow.calib.reference import compare_to_reference
from fuseflow.synth import SimConfig, simulate_recording

__all__ = ["run_calib_verdicts", "verdict_rows", "verdict_summary"]


def verdict_rows(n: int, seed: int, work: Path) -> list[dict]:
    """One simulated room ring of ``n`` cameras (made under ``work``) calibrated: per camera its
    verdict, expected accuracy, true error and the calibration time."""
    out = work / f"ring{n}_{seed}"
    simulate_recording(out, SimConfig(cameras=n, frames=1, scene="room", resolution=(320, 240), seed=seed))
    rec = fuseflow.open_recording(out)
    rig = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in rec.rig))
    t = time.perf_counter()
    cal = calibrate(rec[0], rig, CalibConfig())
    dt = time.perf_counter() - t
    truth = {c.id: c.T_cam_world for c in rec.rig.cameras}
    err = compare_to_reference(cal.T_cam_world, truth, rig.ids)["cameras"]
    return [
        {"cameras": n, "seed": seed, "camera": c, "verdict": v["verdict"], "accuracy_deg": v.get("accuracy_deg"),
         "accuracy_mm": v.get("accuracy_mm"), "error_deg": err[c].get("rotation_deg"),
         "error_mm": err[c].get("position_mm"), "cycles": v.get("cycles"), "time_s": round(dt, 1)}
        for c, v in cal.report.camera_verdicts.items()
    ]  # fmt: skip


def run_calib_verdicts(
    cameras: Sequence[int] = (4, 6), seeds: Sequence[int] = (1, 2), log: Callable[[dict], None] = lambda row: None
) -> list[dict]:
    """:func:`verdict_rows` of every camera count and seed (recordings in a temporary folder);
    each row also to ``log``."""
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for n in cameras:
            for seed in seeds:
                for r in verdict_rows(n, seed, Path(work)):
                    log(r)
                    rows.append(r)
    return rows


def verdict_summary(rows: Sequence[dict]) -> str | None:
    """One line: verdicts, expected and true error ranges, and how often the true error is within
    twice the expected; None when no camera has both."""
    placed = [r for r in rows if r["error_deg"] is not None and r["accuracy_deg"] is not None]
    if not placed:
        return None
    d = np.array([[r["accuracy_deg"], r["error_deg"], r["accuracy_mm"], r["error_mm"]] for r in placed])
    return (f"{len(rows)} cameras, verdicts {sorted({r['verdict'] for r in rows})}; expected "
            f"{d[:, 0].min():.3f}-{d[:, 0].max():.3f} deg / {d[:, 2].min():.1f}-{d[:, 2].max():.1f} mm, true "
            f"{d[:, 1].min():.3f}-{d[:, 1].max():.3f} deg / {d[:, 3].min():.2f}-{d[:, 3].max():.2f} mm; true <= 2x "
            f"expected: {(d[:, 1] <= 2 * d[:, 0]).sum()}/{len(d)} (deg), {(d[:, 3] <= 2 * d[:, 2]).sum()}/{len(d)} (mm)")  # fmt: skip
