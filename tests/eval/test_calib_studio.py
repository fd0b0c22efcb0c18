"""The studio benchmark's scoring (eval.bench.calib_studio.camera_errors): the calibrated world is
tied to the truth through the best anchor; a wrong camera stays wrong whatever the anchor."""

from __future__ import annotations

import math

import numpy as np
from benchmarks.studies.calib_studio import camera_errors

from fuseflow.synth.rigs import look_at


def _rz(deg: float) -> np.ndarray:
    a = math.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    return T


def test_camera_errors_ignore_the_world_frame_and_find_the_wrong_camera():
    true = {f"cam{k}": look_at([2.6 * math.cos(k), 2.6 * math.sin(k), 1.5], [0, 0, 1]) for k in range(5)}
    W = _rz(33.0)
    W[:3, 3] = [0.4, -1.0, 0.2]  # any world frame: est = T_true @ W
    est = {c: T @ W for c, T in true.items()}
    est["cam3"] = true["cam3"] @ _rz(72.0) @ W  # one camera one period of a 5-fold room off
    errs = camera_errors(est, true)
    for c in ("cam0", "cam1", "cam2", "cam4"):
        assert errs[c][0] < 1e-6 and errs[c][1] < 1e-9
    assert abs(errs["cam3"][0] - 72.0) < 1e-6 and errs["cam3"][1] > 1.0


def test_a_camera_whose_verdict_is_check_it_counts_as_flagged():
    from types import SimpleNamespace

    from benchmarks.studies.calib_studio import flagged_cameras

    report = SimpleNamespace(
        suspect_cameras=["cam0"],
        backbone_info={"sources": {"rgbd": {"cameras": {"cam1": {"placed": True, "cycle_checked": False}}}}},
        camera_verdicts={"cam2": {"verdict": "check it"}, "cam3": {"verdict": "good"}, "cam4": {"verdict": "unplaced"}},
    )
    assert flagged_cameras(report) == {"cam0", "cam1", "cam2", "cam4"}
