"""Camera-sync check accuracy over a grid of simulated recordings.

    python -m benchmarks.sync_check /tmp/sync-grid --seeds 5 --fps 30 --num-frames 90 --configs c4_160_late2,c4_160_sync

For each config (:data:`CONFIGS`) and seed: simulate a dynamic (or static) studio, desynchronise
the listed cameras with ``synth.desync.apply_desync``, run ``pipeline.sync.check_sync`` with the
ground-truth rig and compare the offsets found with the truth (a static scene must report
nothing). One line per recording and a table per config: exact / of seeds, false alarms, seconds
per check.

Recordings are kept in the folder and reused on a second run (their ground-truth surface files
are sampled at 100 points per m^2, not 10000: a 90-frame dynamic recording would hold 1.9 GB of
them; depth and colour do not depend on it).
"""

from __future__ import annotations

import json
import platform
import shutil
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from fuseflow.errors import ValidationError
from fuseflow.io import open_recording
from fuseflow.pipeline.sync import check_sync
from fuseflow.synth import SimConfig, simulate_recording
from fuseflow.synth.desync import apply_desync

__all__ = ["CONFIGS", "METHODS", "make", "run_sync_check"]

METHODS = ("auto", "covisible", "agreement")
"""The methods of ``check_sync``."""

# name: (cameras, (W, H), dynamic, desync)
CONFIGS = {
    "c4_160_late2": (4, (160, 120), True, "cam03:2"),
    "c3_160_early1": (3, (160, 120), True, "cam01:-1"),
    "c4_160_sync": (4, (160, 120), True, ""),
    "c8_160_mixed": (8, (160, 120), True, "cam02:1,cam05:-2"),
    "c4_160_static": (4, (160, 120), False, "cam03:2"),
    "c4_320_late2": (4, (320, 240), True, "cam03:2"),
    "c4_320_sync": (4, (320, 240), True, ""),
    "c4_320_two": (4, (320, 240), True, "cam00:-2,cam02:1"),
}


def make(root: Path, name: str, seed: int, fps: float, frames: int) -> Path:
    """The recording of config ``name`` and ``seed`` under ``root``, simulated (and desynchronised)
    unless a finished one is there."""
    n, res, dynamic, desync = CONFIGS[name]
    out = root / f"{name}_fps{fps:g}_f{frames}_s{seed}"
    if not (out / "gt.json").exists() or (desync and "desync" not in json.loads((out / "gt.json").read_text())):
        shutil.rmtree(out, ignore_errors=True)  # an unfinished one (interrupted run)
        simulate_recording(out, SimConfig(cameras=n, frames=frames, scene="studio", dynamic=dynamic, resolution=res,
                                          seed=seed, fps=fps, surface_density=100.0))  # fmt: skip
        if desync:
            apply_desync(out, desync)
    return out


def _torch_version() -> str:
    import torch

    return torch.__version__


def run_sync_check(
    root: Path,
    seeds: int = 5,
    fps: float = 30.0,
    frames: int = 20,
    configs: Sequence[str] = tuple(CONFIGS),
    method: str = "auto",
    first_seed: int = 0,
    log: Callable[[str], None] = lambda line: None,
) -> dict[str, list[tuple[bool, bool, float]]]:
    """Per config the (exact, false alarm, seconds) of each seed; the lines and the table go to
    ``log``. Recordings are made under ``root`` (:func:`make`)."""
    unknown = sorted(set(configs) - set(CONFIGS))
    if unknown or method not in METHODS:
        raise ValidationError(
            f"unknown configs {unknown} or method {method!r}: configs {sorted(CONFIGS)}, methods {METHODS}"
        )
    log(
        f"# {platform.processor() or platform.machine()}, torch {_torch_version()}, fps {fps:g}, {frames} frames, "
        f"method {method}"
    )
    rows: dict[str, list[tuple[bool, bool, float]]] = {}
    for name in configs:
        for seed in range(first_seed, first_seed + seeds):
            rec_dir = make(root, name, seed, fps, frames)
            gt = json.loads((rec_dir / "gt.json").read_text())
            dynamic = CONFIGS[name][2]
            truth = {c: k for c, k in gt.get("desync", {}).items() if k} if dynamic else {}
            rec = open_recording(rec_dir)
            t0 = time.perf_counter()
            report = check_sync(rec, rec.rig, list(range(len(rec.rig))), method=method)
            dt = time.perf_counter() - t0
            found = report.late()
            false_alarm = any(c not in truth for c in found)
            rows.setdefault(name, []).append((found == truth, false_alarm, dt))
            sub = {c: round(v, 2) for c, v in (report.sub_frame or {}).items()}  # co-visible: sub-frame solve
            log(f"{name:14s} seed {seed}: truth {truth} found {found} {'OK' if found == truth else 'WRONG'} "
                f"({dt:.1f} s, {report.method}{f', sub-frame {sub}' if sub else ''})")  # fmt: skip
    log("\n| config | exact | false alarm | s / check (median) |\n|---|---|---|---|")
    for name, r in rows.items():
        ok, fa, dt = zip(*r, strict=True)
        log(f"| {name} | {sum(ok)}/{len(r)} | {sum(fa)}/{len(r)} | {np.median(dt):.1f} |")
    return rows
