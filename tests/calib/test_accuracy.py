"""The expected accuracy of a placed camera (calib.accuracy) against the true error of fits
whose noise is known, and the verdict of a camera whose expected accuracy is poor."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from fuseflow.calib.accuracy import (
    REFINED_SHARE,
    SYSTEMATIC_DEG,
    SYSTEMATIC_MM,
    camera_accuracy,
    combine_pair_accuracies,
    pair_pose_accuracy,
)
from fuseflow.calib.geometric import kabsch
from fuseflow.calib.verdicts import GOOD_DEG, GOOD_MM, _judge
from fuseflow.types import invert_rigid


def _errors(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    D = T_est @ invert_rigid(T_true)
    deg = float(np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))))
    return deg, float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]) * 1000)


def _trials(points: np.ndarray, sigma: float, n: int = 150, seed: int = 0):
    """(expected, true) (deg, mm) of Kabsch fits to ``points`` (camera a) seen by camera b with
    isotropic noise ``sigma`` metres on both sides."""
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", 120, degrees=True).as_matrix()
    T[:3, 3] = [2.5, 0.1, 3.0]
    exp, true = [], []
    for _ in range(n):
        A = points + rng.normal(0, sigma, points.shape)
        B = points @ T[:3, :3].T + T[:3, 3] + rng.normal(0, sigma, points.shape)
        Tf = kabsch(A, B)
        acc = pair_pose_accuracy(Tf, A, B)
        exp.append(acc[:2])
        true.append(_errors(Tf, T))
    return np.array(exp), np.array(true)


def test_far_short_track_is_expected_as_poor_as_it_is():
    """A ball track 1 m long 4 m away (20 frames, 2 cm noise): the rotation and the camera's
    position are poorly fixed (lever arm); the RMS expected error tracks the RMS true error."""
    rng = np.random.default_rng(1)
    track = np.c_[rng.uniform(-0.5, 0.5, 20), rng.uniform(-0.2, 0.2, 20), 4.0 + rng.uniform(-0.3, 0.3, 20)]
    exp, true = _trials(track, 0.02)
    rms = lambda x: np.sqrt((x**2).mean(axis=0))  # noqa: E731
    ratio = rms(exp) / rms(true)
    assert np.all((ratio > 0.6) & (ratio < 1.7)), ratio
    assert rms(exp)[0] > 0.5 and rms(exp)[1] > 25  # not the 0.1-deg, few-mm kind


def test_many_correlated_points_count_as_cells_not_points():
    """3000 matches on six 6-cm patches (each inside one cell) are six measurements: the
    estimate does not shrink by sqrt(3000), and it tracks the true error over trials."""
    rng = np.random.default_rng(2)
    centres = np.array([[-0.95, 0.55, 3.05], [1.05, 0.45, 3.55], [0.05, -0.75, 2.55], [0.35, 0.95, 4.05],
                        [-1.45, -0.35, 3.85], [1.55, -0.55, 2.95]])  # fmt: skip
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.0, 0.2]
    exp, true = [], []
    for _ in range(60):
        pts = (centres[:, None] + rng.uniform(-0.03, 0.03, (6, 500, 3))).reshape(-1, 3)
        offset = np.repeat(rng.normal(0, 0.01, (6, 3)), 500, axis=0)  # each patch's shared depth error
        B = pts @ T[:3, :3].T + T[:3, 3] + offset
        Tf = kabsch(pts, B)
        deg, mm, cells = pair_pose_accuracy(Tf, pts, B)
        assert cells == 6
        exp.append((deg, mm))
        true.append(_errors(Tf, T))
    ratio = np.sqrt((np.array(exp) ** 2).mean(axis=0) / (np.array(true) ** 2).mean(axis=0))
    assert np.all((ratio > 0.5) & (ratio < 2.0)), ratio


def test_floor_and_combination():
    pts = np.random.default_rng(3).uniform(-2, 2, (400, 3)) + [0, 0, 4]
    deg, mm, _ = pair_pose_accuracy(np.eye(4), pts, pts)  # exact: only the systematic floor is left
    assert (deg, mm) == (SYSTEMATIC_DEG, SYSTEMATIC_MM)
    d, m = combine_pair_accuracies([(1.0, 20.0), (1.0, 20.0)])
    assert np.isclose(d, 1 / np.sqrt(2)) and np.isclose(m, 20 / np.sqrt(2))
    deg, mm, how = camera_accuracy([(0.1, 2.0)], [(0.8, 30.0, "sift3d")])  # one residual: the fit alone
    assert (deg, mm) == (0.8, 30.0) and "covariance" in how
    assert camera_accuracy([], [])[0] is None


def test_camera_expected_beyond_the_limit_is_not_good():
    """A camera with cycles, agreeing pairs and its floor, but an expected accuracy worse than
    GOOD_DEG / GOOD_MM, is "check it"."""
    base = {"depth_agreement": 0.95, "disagreeing": {}, "pairs": 2, "pairs_agreeing": 2, "cycles": 1,
            "floor_ok": True, "accuracy_from": "test"}  # fmt: skip
    assert _judge({**base, "accuracy_deg": 0.5, "accuracy_mm": 20.0}, None, None, 0.5)[0] == "good"
    assert _judge({**base, "accuracy_deg": GOOD_DEG * 1.1, "accuracy_mm": 20.0}, None, None, 0.5)[0] == "check it"
    assert _judge({**base, "accuracy_deg": 0.5, "accuracy_mm": GOOD_MM * 1.1}, None, None, 0.5)[0] == "check it"


def test_track_pair_poses_are_not_combined():
    """Pair poses of one moving-object track share each camera's track: the worst one counts;
    independent pair poses combine."""
    track = [(0.5, 20.0, "sphere+floor"), (1.5, 60.0, "sphere+floor+refit")]
    assert camera_accuracy([], track)[:2] == (1.5, 60.0)
    d, m, _ = camera_accuracy([], [(1.5, 60.0, "sift3d"), (1.5, 60.0, "floor+refit")])
    assert np.isclose(d, 1.5 / np.sqrt(2), atol=1e-3) and np.isclose(m, 60 / np.sqrt(2), atol=0.1)


def test_after_the_joint_refinement_the_pair_poses_scatter_is_theirs():
    """Pair poses 3 deg off a refined result say how wrong they were, not the result: with a fit
    covariance at hand the residual estimate no longer counts; without one it still does."""
    res, fits = [(3.0, 40.0), (3.0, 40.0)], [(0.4, 6.0, "sift3d"), (0.4, 6.0, "sift3d")]
    assert camera_accuracy(res, fits)[0] > 2.0
    assert camera_accuracy(res, fits, refined=True)[0] < 0.3
    assert camera_accuracy(res, [], refined=True)[0] > 2.0


def test_a_refined_camera_reads_the_larger_of_the_covariance_and_half_the_disagreement():
    """Two weak pair poses say 3.82 deg / 51.6 mm; the joint refinement moved the camera 3.2 deg /
    48 mm and its covariance says 0.3 deg / 5.1 mm. The covariance sees depth noise only (on a
    real rig it was 3-5x below the error against the reference), so the printed value is at least
    half the larger of the pair poses' estimate and the motion; the covariance wins when it is
    larger; the systematic floor holds; the verdict reads the same."""
    fits = [(5.4, 73.0, "floor"), (5.4, 73.0, "sift3d")]
    assert camera_accuracy([], fits, refined=True)[0] > 3.5
    d, m, how = camera_accuracy([], fits, refined=True, refinement=(0.3, 5.1), moved=(3.2, 48.0))
    assert np.isclose(d, REFINED_SHARE * 5.4 / np.sqrt(2), atol=1e-3), d
    assert np.isclose(m, REFINED_SHARE * 73.0 / np.sqrt(2), atol=0.1) and "joint refinement" in how
    d, m, _ = camera_accuracy([], fits, refined=True, refinement=(0.3, 5.1), moved=(9.0, 120.0))
    assert (d, m) == (REFINED_SHARE * 9.0, REFINED_SHARE * 120.0)  # moved beyond the pair poses' estimate
    d, m, _ = camera_accuracy([], [], refined=True, refinement=(0.3, 5.1), moved=(0.2, 4.0))
    assert (d, m) == (0.3, 5.1)  # no pair pose estimate, a small motion: the covariance
    low = camera_accuracy([], [(0.01, 0.1, "sift3d")], refined=True, refinement=(0.001, 0.1), moved=(0.0, 0.0))
    assert low[:2] == (SYSTEMATIC_DEG, SYSTEMATIC_MM)

    from types import SimpleNamespace

    from fuseflow.calib.verdicts import camera_verdicts

    T = {c: np.eye(4) for c in "abc"}
    for k, c in enumerate("abc"):
        T[c][:3, 3] = [k * 1.0, 0.0, 0.0]
    exp = {"deg": 0.2, "mm": 3.0, "cells": 5}
    pairs = [{"cameras": [x, y], "edge": {"T_ji": (T[y] @ invert_rigid(T[x])).tolist(), "route": "floor",
                                          "expected": exp}} for x, y in ("ab", "ac", "bc")]  # fmt: skip
    info = {"pairs": pairs, "cameras": {c: {"edges": [o for o in T if o != c]} for c in T}}
    jr = {"accepted": True, "expected_deg_mm": {"b": [0.3, 5.1], "c": [0.4, 6.0]},
          "moved_deg_mm": {"b": [0.1, 1.0], "c": [1.6, 30.0]}}  # fmt: skip
    rep = SimpleNamespace(backbone="rgbd", backbone_info=info, config={}, placed_by=dict.fromkeys(T, "rgbd"),
                          depth_agreement=dict.fromkeys(T, 0.95), unplaced_reasons={}, unregistered_cameras=[],
                          joint_refinement=jr)  # fmt: skip
    v = camera_verdicts(rep, T, list(T))
    assert (v["b"]["estimate_deg"], v["b"]["estimate_mm"]) == (0.3, 5.1) and v["b"]["verdict"] == "good", v["b"]
    assert (v["c"]["estimate_deg"], v["c"]["estimate_mm"]) == (0.8, 15.0), v["c"]  # half its motion
    assert np.isclose(v["a"]["estimate_deg"], 0.2 / np.sqrt(2), atol=1e-3)  # held: its pair poses still say
    rep.joint_refinement = {**jr, "accepted": False}
    assert camera_verdicts(rep, T, list(T))["c"]["estimate_deg"] < 0.2


def test_in_a_repeating_room_the_pair_poses_scatter_still_counts_after_the_refinement():
    """Four pair poses turned back by whole periods of a repeating room scatter 20 mm about the
    refined result while their fits and the refinement's covariance say 3 mm: the refinement saw
    the same repeating walls (an independent 10-sided studio: cameras 17-32 mm off printed
    2-5 mm), so the position reads RMS / sqrt(4) = 10 mm; the rotation keeps its estimate.
    Unturned pair poses after the refinement: the scatter is theirs, as before."""
    res = [(0.2, 20.0)] * 4
    fits = [(0.1, 3.0, "sift4+turn+refit")] * 4
    d, m, how = camera_accuracy(res, fits, refined=True, refinement=(0.05, 3.0), moved=(0.05, 3.0))
    assert m == 10.0 and "repeating room" in how
    assert d == SYSTEMATIC_DEG
    assert camera_accuracy(res, fits)[1] == 10.0  # not refined: the residual estimate, as before
    plain = [(0.1, 3.0, "sift4+refit")] * 4
    assert camera_accuracy(res, plain, refined=True, refinement=(0.05, 3.0), moved=(0.05, 3.0))[1] == 3.0
    assert camera_accuracy([(0.2, 120.0)] * 2, fits[:2], refined=True, refinement=(0.05, 3.0))[1] > GOOD_MM


def test_the_printed_accuracy_is_the_bound_and_the_verdict_judges_the_estimate():
    """The verdict table prints the bound (the estimate times the fitted factors; for a camera the
    subject turned, combined with the room axis' error over its chord) while the verdict judges
    the estimate: a camera whose estimate is within GOOD_MM stays "good" though its bound is not."""
    from types import SimpleNamespace

    from fuseflow.calib.accuracy import BOUND_AXIS_MM, BOUND_DEG_FACTOR, BOUND_MM_FACTOR, printed_bound
    from fuseflow.calib.verdicts import camera_verdicts

    assert printed_bound(0.2, 10.0) == (round(0.2 * BOUND_DEG_FACTOR, 3), 10.0 * BOUND_MM_FACTOR)
    assert printed_bound(None, None) == (None, None)
    turned = printed_bound(0.2, 10.0, turned_deg=-180.0)[1]
    assert turned == round(float(np.hypot(10.0 * BOUND_MM_FACTOR, 2 * BOUND_AXIS_MM)), 1)
    T = {c: np.eye(4) for c in "abc"}
    for k, c in enumerate("abc"):
        T[c][:3, 3] = [k * 1.0, 0.0, 0.0]
    exp = {"deg": 0.2, "mm": 0.9 * GOOD_MM, "cells": 5}
    pairs = [{"cameras": [x, y], "edge": {"T_ji": (T[y] @ invert_rigid(T[x])).tolist(), "route": "floor",
                                          "expected": exp}} for x, y in ("ab", "ac", "bc")]  # fmt: skip
    info = {"pairs": pairs, "cameras": {c: {"edges": [o for o in T if o != c]} for c in T}}
    rep = SimpleNamespace(backbone="rgbd", backbone_info=info, config={}, placed_by=dict.fromkeys(T, "rgbd"),
                          depth_agreement=dict.fromkeys(T, 0.95), unplaced_reasons={}, unregistered_cameras=[],
                          joint_refinement=None)  # fmt: skip
    v = camera_verdicts(rep, T, list(T))["b"]
    assert v["verdict"] == "good" and v["estimate_mm"] < GOOD_MM < v["accuracy_mm"], v
    assert (v["accuracy_deg"], v["accuracy_mm"]) == printed_bound(v["estimate_deg"], v["estimate_mm"])
    assert f"{v['accuracy_mm']:.0f} mm" in v["reason"]
