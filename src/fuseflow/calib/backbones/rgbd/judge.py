"""The subject's judge of a pair: a person's head tracked through the rig (route (e),
:mod:`fuseflow.calib.subject`) refutes the candidates that move one head track from the other,
and a verified pose the other camera sees the subject through is rejected."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fuseflow.calib.backbones.rgbd.config import RGBDConfig
from fuseflow.calib.backbones.rgbd.evidence import CameraEvidence, verify_pose
from fuseflow.calib.symmetry import SUBJECT_MAX_FREE_SPACE, SUBJECT_MIN_POINTS, subject_free_space

#: A candidate whose head tracks stay further apart than this (metres, median) is refuted, or
#: than the subject's own pose leaves them plus SUBJECT_MARGIN_M, whichever is smaller: at
#: 3.5-4 m a pose 0.5 deg off moves the head 3 cm; a right pose of another route (a textured
#: near-range studio: 0.05 deg / 3 mm where the subject's was 0.2 deg / 12 mm) stays within it.
SUBJECT_REFUTE_M, SUBJECT_MARGIN_M = 0.08, 0.03


@dataclass(frozen=True)
class _SubjectJudge:
    """The subject's judge of one pair: pose -> median head-track residual (metres) over the
    subject pose's inlier frames; a candidate beyond ``limit`` is refuted."""

    route: object
    i: int
    j: int
    frames: np.ndarray
    limit: float

    def __call__(self, T_ba: np.ndarray) -> float | None:
        got = self.route.judge(self.i, self.j, T_ba, self.frames)
        return None if got is None else got[0]


def subject_judge(a: CameraEvidence, b: CameraEvidence, cands: list[dict], cfg: RGBDConfig, subject, i: int, j: int):
    """The subject's judge of pair (i, j) (``_SubjectJudge``), or None: no subject candidate, or
    it fails the depth checks on the static scene (agreement, free space), so the two views may
    have tracked different things."""
    own = [c for c in cands if c["route"] == "subject"]
    if subject is None or not own:
        return None
    chk = verify_pose(a, b, own[0]["T_ba"], cfg.tau)
    if chk.agreement < cfg.min_agreement or chk.free_space > cfg.max_free_space or chk.agree < cfg.min_agree_points:
        return None
    judge = _SubjectJudge(subject, i, j, own[0]["inliers_mask"], SUBJECT_REFUTE_M)
    base = judge(own[0]["T_ba"])
    if base is None:
        return None
    return _SubjectJudge(subject, i, j, judge.frames, min(SUBJECT_REFUTE_M, base + SUBJECT_MARGIN_M))


def subject_ok(a: CameraEvidence, b: CameraEvidence, T_ba: np.ndarray, cfg: RGBDConfig, row: dict) -> bool:
    """The subject check of a verified pose (``symmetry.subject_free_space``, at tau): False
    (``row`` marked rejected) when the other camera sees through more than SUBJECT_MAX_FREE_SPACE
    of the subject points it sees, with at least SUBJECT_MIN_POINTS of them."""
    share, seen = subject_free_space(a, b, T_ba, cfg.tau)
    if seen < SUBJECT_MIN_POINTS:
        return True
    row["subject_free_space"] = round(share, 4)
    if share > SUBJECT_MAX_FREE_SPACE:
        row.update(ok=False, rejected="subject seen through")
        return False
    return True
