"""The verdict policy in a repeating room where the subject turned some cameras about the room's
axis (calib.verdicts): a camera whose position relative to most of the rig rests on that axis is
not "good", whatever its cycles say."""

from __future__ import annotations

from itertools import combinations
from types import SimpleNamespace

import numpy as np
import pytest

from fuseflow.calib.turns import RoomAxis
from fuseflow.calib.verdicts import TurnEvidence, camera_verdicts
from fuseflow.types import invert_rigid


def _report(n: int):
    """n cameras 1 m apart whose pair poses all agree with the extrinsics (every check passes)."""
    T = {}
    for i in range(n):
        T[f"c{i}"] = np.eye(4)
        T[f"c{i}"][:3, 3] = [i * 1.0, 0.3 * (i % 2), 0]
    pairs = [
        {"cameras": [x, y], "edge": {"T_ji": (T[y] @ invert_rigid(T[x])).tolist(), "route": "floor"}}
        for x, y in combinations(T, 2)
    ]
    info = {"pairs": pairs, "cameras": {c: {"edges": [o for o in T if o != c]} for c in T}}
    rep = SimpleNamespace(backbone="rgbd", backbone_info=info, config={}, placed_by={}, depth_agreement={},
                          unplaced_reasons={}, unregistered_cameras=[])  # fmt: skip
    return rep, T


def _ev(moved: int) -> TurnEvidence:
    return TurnEvidence(sides=8, turn=0, score=0.3, runner_up=1, runner_up_score=0.1, margin=0.2, seen=5000,
                        alternatives=6, subject_radius_m=1.0, moved=moved)  # fmt: skip


ROOM = RoomAxis(8, np.zeros(3), np.array([0.0, 0.0, 1.0]), 0.8, 0.0)


def test_cameras_the_subject_left_while_it_turned_most_of_the_rig_are_not_good():
    """5 of 7 cameras turned by 90-180 deg (independent studio seeds 929, 933): the two left in
    place agree with each other and close cycles through the turned ones, yet their position
    relative to those rests on the room's axis."""
    rep, T = _report(7)
    turns = {c: _ev(m) for c, m in zip(T, (0, 0, 4, 4, 4, -2, -2))}
    v = camera_verdicts(rep, T, list(T), turns, ROOM)
    for c in ("c0", "c1"):
        assert v[c]["verdict"] == "check it", v[c]
        assert "5 of the 6 other cameras were turned" in v[c]["reason"]
    assert all(v[c]["verdict"] == "check it" for c in T)  # the turned ones by their own axis lever


def test_one_turned_camera_leaves_the_rest_good():
    rep, T = _report(7)
    turns = {c: _ev(m) for c, m in zip(T, (0, 0, 0, 0, 0, 0, 2))}
    v = camera_verdicts(rep, T, list(T), turns, ROOM)
    assert [v[c]["verdict"] for c in T] == ["good"] * 6 + ["check it"], v
    turned = v["c6"]  # its position rests on the axis (2 sin(90 deg / 2) x 100 mm), not on a fit
    assert turned["estimate_mm"] == pytest.approx(141.4, abs=0.1), turned
    assert "turn by +90 deg about the room's axis, known to 100 mm, checks its position to 141 mm" in turned["reason"]
    assert "expected accuracy" not in turned["reason"]  # the lever is no expected error
    same = {c: _ev(m) for c, m in zip(T, (0,) * 7)}
    assert all(x["verdict"] == "good" for x in camera_verdicts(rep, T, list(T), same, ROOM).values())


def test_a_turned_camera_turns_about_the_rooms_axis_as_found(scene5, backbone_builder, monkeypatch):
    """The placement turns a camera the subject turns by whole periods about the room's axis as
    ``turns.room_axis`` found it: no depth refinement moves the axis (it lets the turned cameras
    slide along the room's planes; docs/gmac-trust.md, "Apply")."""
    from fuseflow.calib import CalibConfig, calibrate, placement

    frame, rig, T = scene5
    last = rig.ids[-1]
    room = RoomAxis(8, np.array([0.1, 0.2, 0.0]), np.array([0.0, 1.0, 0.0]), 0.8, 0.0)
    seen = {}

    def fake_turns(frames, rig_, T_, report):
        seen.update(T_)
        return room, {c: TurnEvidence(sides=8, turn=2 if c == last else 0, score=0.3, runner_up=0 if c == last else 1,
                                      runner_up_score=0.1, margin=0.2, seen=5000, alternatives=6,
                                      subject_radius_m=1.0) for c in T_}  # fmt: skip

    monkeypatch.setattr(placement, "camera_turns", fake_turns)
    cal = calibrate(frame, rig, CalibConfig(), backbone_result=backbone_builder(T, 3.7))
    assert np.allclose(cal.T_cam_world[last], seen[last] @ invert_rigid(room.turn(2)))
    assert cal.report.camera_verdicts[last]["turn"]["moved"] == 2


def test_aliased_pair_poses_without_a_room_axis_leave_no_camera_good():
    """Two pairs whose verified pose the subject refutes say the room repeats (independent studio
    seed 304: no pair showed a period, no axis was found, three cameras 45-90 deg off passed their
    cycles and floor): then nothing checks a turn, so no camera is "good". One such pair is not
    enough."""
    rep, T = _report(5)
    rep.backbone_info["pairs"][0]["candidates"] = [{"rejected": "subject seen through"}]
    assert all(x["verdict"] == "good" for x in camera_verdicts(rep, T, list(T)).values())
    rep.backbone_info["pairs"][1]["candidates"] = [{"rejected": "subject seen through"}]
    v = camera_verdicts(rep, T, list(T))
    assert all(x["verdict"] == "ambiguous" for x in v.values()), v
    assert "verified pair poses alias" in v["c0"]["reason"]
