"""Per-camera verdicts: how each camera was placed, what checks it, how accurate it probably is,
and one word for a user: "good", "check it" or "unplaced" (with the reason).

Evidence read from the report and the final extrinsics (nothing is re-measured but the floor):

- **route**: the source that placed the camera (``placed_by``) and, for the metric ``rgbd``
  backbone, the routes of the pair poses that link it ("floor": top-down floor texture; "image":
  image keypoints lifted by depth; "image+floor": both; "geometric": shape alone; "... turned":
  that route's pose turned by whole periods of a repeating room, ``symmetry.room_orbits``).
- **pairs**: the measured pair poses (edges) that link the camera. Each is compared with the
  relative pose of the final extrinsics; it *agrees* within ``AGREE_DEG`` / ``AGREE_MM`` (wide
  enough for the noise of real pair poses, which the pose graph and the joint refinement
  average out: on hocap-8rs correct cameras' pairs are up to 3.9 deg / 38 mm off; far too
  narrow for a symmetric alias, tens of degrees).
- **cycles**: triangles of agreeing edges through the camera (each closes a loop: an
  independent check of its pose). Scale-free backbones (colmap, ...): the kept triangles of the
  scale stage's cycle check.
- **floor**: the camera's own floor plane, carried into the world by its pose, against the
  median of every floor-seeing camera's: a check when within ``FLOOR_DEG`` / ``FLOOR_MM``. A
  camera whose dominant plane is another surface (a table top) simply has no floor check.
- **accuracy**: ``rgbd``: :func:`fuseflow.calib.accuracy.camera_accuracy`: the larger of the
  fit covariance of its agreeing pair poses (from their correspondences) and RMS / sqrt(n) of
  their disagreement with the final extrinsics; for a camera an accepted joint refinement moved,
  the larger of that refinement's covariance of its refined pose and half the larger of the
  pair poses' estimate and its motion (``calib.accuracy``, 3); in a repeating room the position at
  least their RMS / sqrt(n) (``calib.accuracy``, 4). Scale-free backbones: the position error the standard error of s* causes at the camera's distance from
  the world camera (the scale part only; no angle). That is the *estimate* the verdict judges
  ("estimate_deg" / "estimate_mm"); what is printed ("accuracy_deg" / "accuracy_mm", the table,
  the reasons) is ``calib.accuracy.printed_bound`` of it, a bound that covered the error of 90 %
  of the cameras it was fitted on.
- **plausibility**: two camera centres closer than ``STACKED_M`` (a device's width) cannot both
  be right.

The verdict: "unplaced" (not in the extrinsics; the reason the report gives), "check it" (the
first failing reason: stacked, depth agreement below the threshold (after a joint refinement or
a room turn moved it: ``drop_unconfirmed`` has left every camera below it unplaced before),
placed by a backbone's own poses alone (``FALLBACK_ALONE``: no metric pair pose measures it;
every camera of ``colmap``, ``vggt``, ``mapanything``, ``precomputed``, and ``auto``'s
fallback), fewer than half of its pairs
agree, no cycle through it (a floor check alone leaves its heading and horizontal position
unchecked), the estimate beyond ``GOOD_DEG`` / ``GOOD_MM``), else "good" unless the room
repeats: then a whole-period turn about the room's axis keeps every cycle, the floor and the
background, so only the subject can check the turn (``TurnEvidence`` from ``calib.turns``):
"ambiguous" when its margin is below ``TURN_MIN_MARGIN`` or nothing of the subject is seen,
"check it" when the subject prefers another turn, "good" otherwise; "check it" when the subject
turned other cameras and its position relative to most of them rests on the room's axis alone
(``_across_turns``); "ambiguous" too when the
backbone's pairs say the room repeats (a period, or at least ``ALIASED_PAIRS`` pairs with verified
poses that alias, ``room_aliases``) but ``calib.turns`` found no axis. When frames are pooled
(``calib.pooling``), ``cross_check`` makes "check it" a good camera that the other attempt's
extrinsics contradict. This module is the one place that decides (docs/gmac-trust.md, "Verdict
policy").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from itertools import combinations
from typing import Any

import numpy as np

from fuseflow.calib.accuracy import camera_accuracy, printed_bound
from fuseflow.geometry import depth_agreement, pair_agreement
from fuseflow.types import Frame, Rig, invert_rigid

__all__ = [
    "TurnEvidence",
    "TURN_MIN_MARGIN",
    "AMBIGUOUS_ACTION",
    "FALLBACK_ALONE",
    "camera_verdicts",
    "cross_check",
    "drop_unconfirmed",
    "pair_agreements",
    "drop_answered_scale_warning",
    "SCALE_CHECK_WARNING",
    "edge_residual",
    "AGREE_DEG",
    "AGREE_MM",
    "GOOD_DEG",
    "GOOD_MM",
    "FLOOR_DEG",
    "FLOOR_MM",
    "STACKED_M",
]

#: A measured pair pose agrees with the final extrinsics within these (module docstring).
AGREE_DEG, AGREE_MM = 5.0, 100.0
#: Expected accuracy within these reads "good" (its calibration against the truth:
#: docs/gmac-trust.md, "Expected accuracy").
GOOD_DEG, GOOD_MM = 2.0, 50.0
#: The floor check: tilt and height of a camera's floor against the rig's median floor.
FLOOR_DEG, FLOOR_MM = 2.0, 50.0
#: Two camera centres closer than this (metres; a depth camera is 10-25 cm wide) are stacked.
STACKED_M = 0.10

#: The subject's margin between a camera's chosen room turn and its runner-up below which the
#: turn is "ambiguous" (``TurnEvidence.margin``; docs/gmac-trust.md, "Room turns").
TURN_MIN_MARGIN = 0.05
#: The verdict reason of a camera no metric pair pose measures, whichever backbone placed it
#: (``colmap``, ``vggt``, ``mapanything``, ``precomputed``, or ``auto``'s fallback): the scale
#: stage's cycles rebuild relative poses from that backbone's own poses, so they close by
#: construction and check its scale, not its pose (symstudio at 320x240: COLMAP folded 5- and
#: 7-camera rings onto one wall, 33-163 deg off, every cycle closed).
FALLBACK_ALONE = (
    "placed by {src} alone, as no metric pair pose measures it: its cycles check the scale, not the pose "
    "(in a repeating room image matching folds cameras onto each other); calibrate with the rgbd or auto "
    "backbone, record more frames, or check it by eye"
)
#: With at least this many pairs whose verified poses alias (the subject sees through one, or the
#: rgbd backbone's consistent solution refutes one), the room repeats: the backbone leaves every
#: camera outside its solution's main cycle-checked group ambiguous (``symmetry.main_block``;
#: its geometry-only route places none of them), ``auto`` runs no other source, and with no room
#: axis found no camera is "good".
ALIASED_PAIRS = 2
#: What a user can do about an ambiguous room turn.
AMBIGUOUS_ACTION = "put a person or one asymmetric object in the middle, or record a few frames of them moving"
#: How well a repeating room's axis is known (mm). A camera the subject turned by an angle a about
#: that axis moves with the axis' error, so its position is known to no better than 2 sin(a / 2)
#: times this, whatever its pair poses say: more than ``GOOD_MM`` for every turn of 30 deg or more,
#: so a turned camera is never "good". Measured on independently rendered 6-12-sided studios
#: (``python -m benchmarks.calib_independent --seeds 300-307 --resolution 320x240``): cameras turned
#: by 30-180 deg ended 3.3-7 cm from the truth while their pair poses' estimate printed 3-26 mm
#: (a 30-deg turn 7 cm off: an axis about 13 cm off).
TURN_AXIS_MM = 100.0


@dataclass(frozen=True)
class TurnEvidence:
    """What the subject says about a camera's turn in a room that repeats every 360/sides deg
    (``calib.turns``): its chosen turn (whole periods, 0 = as placed), the subject score there
    and at the best other turn (minus the share of its subject points and its neighbours' that
    the other side sees through, both directions), the margin between the two (how much more of
    the subject the best other turn puts in seen free space), the points seen at the chosen
    turn, how many other turns are physically possible (not stacked on another camera)."""

    sides: int
    turn: int
    score: float | None
    runner_up: int | None
    runner_up_score: float | None
    margin: float | None
    seen: int
    alternatives: int
    subject_radius_m: float
    moved: int = 0
    """The turn (whole periods) the subject made the calibration apply to this camera (0: none)."""

    def to_json(self) -> dict[str, Any]:
        return {**asdict(self), "period_deg": round(360.0 / self.sides, 2)}


ROUTE_NAMES = {"floor": "floor", "sift4": "image+floor", "sift3d": "image", "geometric": "geometric"}
ROUTE_NAMES["subject"] = "subject"  # route (e), calib.subject


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def edge_residual(T_ba_measured: np.ndarray, T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(deg, mm) between a measured pair pose (camera b from camera a) and the one the final
    camera-from-world extrinsics ``T_a``, ``T_b`` give: the rotation of their difference and the
    distance between where each puts camera a's centre in camera b's frame."""
    T_final = T_b @ invert_rigid(T_a)
    D = np.asarray(T_ba_measured) @ invert_rigid(T_final)
    return _angle_deg(D[:3, :3]), float(np.linalg.norm(np.asarray(T_ba_measured)[:3, 3] - T_final[:3, 3]) * 1000)


def _rgbd_info(report) -> dict[str, Any] | None:
    """The rgbd backbone's info (its own run or the ``auto`` source), None without one."""
    info = report.backbone_info or {}
    if report.backbone == "rgbd":
        return info
    src = info.get("sources", {}).get("rgbd") if isinstance(info.get("sources"), dict) else None
    return src if src and "pairs" in src else None


def room_aliases(info: Mapping[str, Any] | None) -> tuple[int, int]:
    """The rgbd backbone's evidence that the room repeats: (pairs with a verified pose whose
    subject the other camera sees through, ``symmetry.subject_free_space``; pairs with a
    verified pose its consistent solution refutes, ``backbones.rgbd.choice``)."""
    info = info or {}
    seen_through = sum(
        any(c.get("rejected") == "subject seen through" for c in p.get("candidates", [])) for p in info.get("pairs", [])
    )
    return seen_through, int((info.get("joint_choice") or {}).get("refuted_pairs", 0))


def _repeats(info: Mapping[str, Any] | None) -> int:
    """The room period the rgbd backbone's pairs read (sides), -1 when they only saw that the
    room repeats (``room_aliases``: at least ``ALIASED_PAIRS`` of either kind), 0 otherwise."""
    sides = int(((info or {}).get("room") or {}).get("sides") or 0)
    if sides or not info:
        return sides
    return -1 if max(room_aliases(info)) >= ALIASED_PAIRS else 0


def _rgbd_edges(info: Mapping[str, Any]) -> dict[tuple[str, str], tuple[np.ndarray, str]]:
    """(a, b) -> (measured T_ba (4, 4), route name) of the rgbd edges kept after its cycle check."""
    cams = info.get("cameras", {})
    out = {}
    for p in info.get("pairs", []):
        e = p.get("edge")
        if not e or "T_ji" not in e:
            continue
        a, b = p["cameras"]
        if b not in cams.get(a, {}).get("edges", [b]):
            continue  # dropped by its cycle check
        parts = str(e.get("route", "?")).split("+")
        name = ROUTE_NAMES.get(parts[0], parts[0]) + (" turned" if "turn" in parts else "")
        x = e.get("expected")
        out[(a, b)] = (
            np.asarray(e["T_ji"], dtype=np.float64),
            name,
            None if not x else (x["deg"], x["mm"], e["route"]),
        )
    return out


def _floor_check(info: Mapping[str, Any] | None, T: Mapping[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """Camera -> (tilt deg, height mm) of its floor against the rig's median floor (>= 2 floors)."""
    planes = {}
    for c, ci in (info or {}).get("cameras", {}).items():
        fl = ci.get("floor")
        if c in T and fl and "normal" in fl:
            n = np.asarray(fl["normal"], dtype=np.float64)
            R, t = T[c][:3, :3], T[c][:3, 3]
            planes[c] = (R.T @ n, float(n @ t + fl["height_m"]))
    if len(planes) < 2:
        return {}
    n_med = np.median(np.stack([p[0] for p in planes.values()]), axis=0)
    n_med /= max(np.linalg.norm(n_med), 1e-12)
    d_med = float(np.median([p[1] for p in planes.values()]))
    return {
        c: (float(np.degrees(np.arccos(np.clip(n @ n_med, -1, 1)))), abs(d - d_med) * 1000)
        for c, (n, d) in planes.items()
    }


def _stacked(T: Mapping[str, np.ndarray]) -> dict[str, tuple[str, float]]:
    """Camera -> (nearest other camera, distance m) for centres closer than STACKED_M."""
    C = {c: invert_rigid(M)[:3, 3] for c, M in T.items()}
    out = {}
    for a, b in combinations(C, 2):
        d = float(np.linalg.norm(C[a] - C[b]))
        if d < STACKED_M:
            for x, y in ((a, b), (b, a)):
                if x not in out or d < out[x][1]:
                    out[x] = (y, d)
    return out


def _residual_up_to_turns(T_ba: np.ndarray, T_a: np.ndarray, T_b: np.ndarray, room) -> tuple[float, float]:
    """``edge_residual``, in a repeating room the smallest over camera a turned by whole periods."""
    best = edge_residual(T_ba, T_a, T_b)
    if room is None or (best[0] <= AGREE_DEG and best[1] <= AGREE_MM):
        return best
    for k in range(1, room.sides):
        r = edge_residual(T_ba, T_a @ room.turn(k), T_b)
        if r[0] <= AGREE_DEG and r[1] <= AGREE_MM:
            return r
    return best


def _evidence_rgbd(c: str, edges, T, room=None, refined: bool = False, refinement=None, moved=None) -> dict[str, Any]:
    """Pairs, agreeing pairs, cycles, routes and residual-based accuracy of an rgbd-placed camera."""
    mine = {(a, b): v for (a, b), v in edges.items() if c in (a, b) and a in T and b in T}
    res = {e: _residual_up_to_turns(v[0], T[e[0]], T[e[1]], room) for e, v in mine.items()}
    agree = {e for e, (d, mm) in res.items() if d <= AGREE_DEG and mm <= AGREE_MM}
    nb = {(b if a == c else a) for a, b in agree}
    good_edges = {frozenset(e) for e, v in edges.items() if e[0] in T and e[1] in T}
    cycles = sum(1 for x, y in combinations(sorted(nb), 2) if frozenset((x, y)) in good_edges)
    ev = {
        "routes": sorted({v[1] for v in mine.values()}),
        "pairs": len(mine),
        "pairs_agreeing": len(agree),
        "cycles": cycles,
        "disagreeing": {
            f"{a}-{b}": [round(d, 2), round(mm, 1)] for (a, b), (d, mm) in res.items() if (a, b) not in agree
        },
    }
    # a disagreeing pair is an outlier (reported in "disagreeing"), not noise: calib.accuracy
    fits = [mine[e][2] for e in agree if mine[e][2] is not None]
    ev["accuracy_deg"], ev["accuracy_mm"], ev["accuracy_from"] = camera_accuracy(
        [res[e] for e in agree],
        fits,
        refined,
        None if refinement is None else tuple(refinement),
        None if moved is None else tuple(moved),
    )
    return ev


def _subject_accuracy(ev: dict[str, Any], info: Mapping[str, Any], c: str) -> dict[str, Any]:
    """``ev`` with its expected accuracy raised to what the moving-subject edges of camera ``c``
    (route (e), :mod:`fuseflow.calib.subject`) can give: their pair poses share one head track
    per camera, so they agree around a cycle better than each is right. Position: the edge's
    "expected_m" (the tracks' RMS residual with the head-radius bias); rotation: that over half
    the track's extent, / sqrt(its frames)."""
    worst = None
    for p in info.get("pairs", []):
        e = p.get("edge") or {}
        if c in p.get("cameras", ()) and "expected_m" in e and e.get("spread_m"):
            n = max(int(e.get("track_frames", 1)), 1)
            acc = (float(np.degrees(e["expected_m"] / (e["spread_m"] / 2)) / np.sqrt(n)), e["expected_m"] * 1000)
            worst = acc if worst is None else (max(worst[0], acc[0]), max(worst[1], acc[1]))
    if worst is None:
        return ev
    deg, mm = float(max(ev["accuracy_deg"] or 0.0, worst[0])), float(max(ev["accuracy_mm"] or 0.0, worst[1]))
    return {**ev, "accuracy_deg": round(deg, 3), "accuracy_mm": round(mm, 1),
            "accuracy_from": ev["accuracy_from"] + "; at least its moving-subject tracks' residual"}  # fmt: skip


def _evidence_scale_free(c: str, report, T) -> dict[str, Any]:
    """Pairs and cycles of a camera placed by a scale-free backbone (the scale stage's kept
    edges); position accuracy from s*'s standard error at its distance from the world camera."""
    kept = [e.split("-") for e in report.kept_edges]
    mine = [e for e in kept if c in e and all(x in T for x in e)]
    tris = {k: v for k, v in report.cycle_residuals_mm.items() if c in k.split("-")}
    ev = {
        "routes": [],
        "pairs": len(mine),
        "pairs_agreeing": len(mine),
        "cycles": len(tris),
        "disagreeing": {},
        "accuracy_deg": None,
        "accuracy_mm": None,
        "accuracy_from": "no scale error estimate",
    }
    if report.scale and report.scale_std_error is not None and report.world_anchor in T:
        dist = np.linalg.norm(invert_rigid(T[c])[:3, 3] - invert_rigid(T[report.world_anchor])[:3, 3])
        ev["accuracy_mm"] = round(float(report.scale_std_error / report.scale * dist * 1000), 1)
        ev["accuracy_from"] = "standard error of s* at its distance from the world camera (scale part only)"
    return ev


def _unplaced_reason(c: str, report) -> str:
    if c in (report.unplaced_reasons or {}):
        return report.unplaced_reasons[c]
    if c in report.unregistered_cameras:
        return "the backbone could not register it"
    return "no usable pair links it to the other cameras"


def camera_verdicts(
    report,
    T_cam_world: Mapping[str, np.ndarray],
    ids,
    turns: Mapping[str, TurnEvidence] | None = None,
    room=None,
    min_agreement: float = 0.0,
) -> dict[str, dict[str, Any]]:
    """Camera id (rig order ``ids``) -> its verdict and evidence (module docstring), plain JSON.

    Keys: "verdict" ("good" | "check it" | "unplaced"), "reason", "placed_by", "routes", "pairs",
    "pairs_agreeing", "cycles", "floor" ([tilt deg, height mm] against the rig's floor, or None),
    "floor_ok" (within FLOOR_DEG / FLOOR_MM), "checks" (cycles + a passing floor check), "depth_agreement", "accuracy_deg", "accuracy_mm" (the printed
    bound, ``calib.accuracy.printed_bound``; None: unknown), "estimate_deg", "estimate_mm" (the
    estimate the verdict judges against GOOD_DEG / GOOD_MM), "accuracy_from" (how the estimate was made), "disagreeing" (edge -> [deg, mm] of pairs beyond AGREE_DEG / AGREE_MM),
    "turn" (``TurnEvidence.to_json`` in a repeating room, else None), "placed_alone" (the source,
    only for a camera ``auto``'s fallback placed with no metric pair pose); verdict "ambiguous" when
    the subject cannot tell the camera's room turn from another. ``room``: the repeating room
    (``calib.turns.RoomAxis``: ``sides`` and ``turn(k)``, the world rotation by k periods) or None;
    in one, a pair pose agrees when it agrees after whole turns of the room (it measures the pose
    up to the turn, which only the subject decides). ``min_agreement``: the depth agreement below
    which a camera is not "good" (``CalibConfig.min_depth_agreement``; 0 = not checked).
    """
    T = dict(T_cam_world)
    info = _rgbd_info(report)
    edges = _rgbd_edges(info) if info else {}
    floor = _floor_check(info, T)
    stacked = _stacked(T)
    backbone_room = _repeats(info)
    limit = float(min_agreement)
    out = {}
    for c in ids:
        if c not in T:
            out[c] = {"verdict": "unplaced", "reason": _unplaced_reason(c, report), "placed_by": None}
            continue
        src = (report.placed_by or {}).get(c, report.backbone)
        if any(c in e for e in edges):  # rgbd's pair poses measure it, whichever source placed it
            jr = getattr(report, "joint_refinement", None) or {}
            refined = bool(jr.get("accepted"))
            est = (jr.get("expected_deg_mm") or {}).get(c) if refined else None
            moved = (jr.get("moved_deg_mm") or {}).get(c) if refined else None
            ev = _subject_accuracy(_evidence_rgbd(c, edges, T, room, refined, est, moved), info, c)
        elif report.backbone != "auto":  # no metric pair pose measures it (FALLBACK_ALONE)
            ev = {**_evidence_scale_free(c, report, T), "placed_alone": src}
        else:  # auto's fallback: the scale stage reported is another source's
            ev = {**_evidence_scale_free(c, report, {}), "accuracy_from": f"{src} records no pair poses for it"}
            ev["placed_alone"] = src
        fl = floor.get(c)
        floor_ok = fl is not None and fl[0] <= FLOOR_DEG and fl[1] <= FLOOR_MM
        agreement = (report.depth_agreement or {}).get(c)
        entry = {
            "placed_by": src,
            **ev,
            "floor": None if fl is None else [round(fl[0], 2), round(fl[1], 1)],
            "checks": ev["cycles"] + int(floor_ok),
            "depth_agreement": None if agreement is None else round(float(agreement), 3),
        }
        entry["floor_ok"] = floor_ok
        turn = (turns or {}).get(c)
        entry["turn"] = None if turn is None else turn.to_json()
        turned_deg = turn.moved * 360.0 / turn.sides if turn is not None else 0.0
        entry["bound_deg"], entry["bound_mm"] = printed_bound(entry["accuracy_deg"], entry["accuracy_mm"], turned_deg)
        _raise_to_axis(entry, turn)
        entry["verdict"], entry["reason"] = _judge(entry, stacked.get(c), fl, limit)
        entry.pop("axis_floor", None)
        if room is not None and entry["verdict"] == "good":
            entry["verdict"], entry["reason"] = _judge_turn(turn, room.sides, entry["reason"])
        elif room is None and backbone_room and entry["verdict"] == "good":
            entry["verdict"], entry["reason"] = "ambiguous", _no_axis(backbone_room)
        elif room is None and stacked and entry["verdict"] == "good":  # a fold: the scene repeats
            entry["verdict"], entry["reason"] = "ambiguous", _folded(stacked)
        entry["verdict"], entry["reason"] = _across_turns(c, turns, T, entry["verdict"], entry["reason"])
        # printed: the bound; judged: the estimate (calib.accuracy, module docstring)
        entry["estimate_deg"], entry["estimate_mm"] = entry["accuracy_deg"], entry["accuracy_mm"]
        entry["accuracy_deg"], entry["accuracy_mm"] = entry.pop("bound_deg"), entry.pop("bound_mm")
        out[c] = {"verdict": entry.pop("verdict"), "reason": entry.pop("reason"), **entry}
    return out


def _raise_to_axis(entry: dict[str, Any], turn: TurnEvidence | None) -> None:
    """A camera turned about the room's axis, known to TURN_AXIS_MM: its position estimate is at
    least that axis' lever (``_axis_mm``), marked ``"axis_floor"`` for the reason to name it."""
    if turn is None or not turn.moved:
        return
    axis_mm = _axis_mm(turn.moved, turn.sides)
    if (entry["accuracy_mm"] or 0.0) < axis_mm:
        entry["accuracy_mm"] = round(axis_mm, 1)
        entry["accuracy_from"] = f"its turn by {turn.moved * 360.0 / turn.sides:+.0f} deg about the room's axis"
        entry["axis_floor"] = True


def _axis_mm(k: int, sides: int) -> float:
    """How far (mm) a turn by k periods of a room with ``sides`` moves a point when the room's
    axis is ``TURN_AXIS_MM`` off: 2 sin(k pi / sides) times it."""
    return 2.0 * abs(math.sin(math.pi * k / sides)) * TURN_AXIS_MM


def _across_turns(
    c: str, turns: Mapping[str, TurnEvidence] | None, T: Mapping[str, np.ndarray], verdict: str, reason: str
) -> tuple[str, str]:
    """(verdict, reason) of camera ``c`` given its ``verdict`` and ``reason`` so far: "check it"
    when it is "good" but its position is not checked against most of the rig. The subject
    turned cameras by whole periods about the room's axis, known to ``TURN_AXIS_MM``: camera c's
    position relative to a camera turned k periods more (or less) than c rests on that axis to
    2 sin(k pi / sides) x ``TURN_AXIS_MM``; its cycles through that camera hold up to the turn
    only. Not "good" when that is beyond ``GOOD_MM`` for more than half of the other placed cameras
    (independent studio seed 933: 5 of 7 cameras turned by 90-180 deg, the 2 left 4.6-5.8 cm from
    them and otherwise good)."""
    turns = turns or {}
    moved = {d: (turns[d].moved if d in turns else 0) for d in T}
    if verdict != "good" or not any(moved.values()) or c not in turns:
        return verdict, reason
    sides = turns[c].sides
    far = [d for d in T if d != c and _axis_mm(moved[d] - moved[c], sides) > GOOD_MM]
    if 2 * len(far) <= len(T) - 1:
        return verdict, reason
    return "check it", (
        f"{len(far)} of the {len(T) - 1} other cameras were turned by the subject about the room's axis "
        f"({', '.join(sorted(far))}), which is known to about {TURN_AXIS_MM:.0f} mm: its position relative to them "
        "is checked up to that axis only (cycles and the floor hold for any axis); " + AMBIGUOUS_ACTION
    )


def _no_axis(backbone_room: int) -> str:
    """Why a camera is "ambiguous" when the backbone's pairs say the room repeats (``_repeats``)
    and no room axis was found."""
    how = f"every {360.0 / backbone_room:.0f} deg" if backbone_room > 0 else "verified pair poses alias"
    return (
        f"the backbone's pairs say the room repeats ({how}) but its axis was not found in the calibrated "
        "cloud, so nothing checks its turn; " + AMBIGUOUS_ACTION
    )


def _folded(stacked: Mapping[str, tuple[str, float]]) -> str:
    """Why a camera is "ambiguous" when two cameras share a spot and no room axis was found."""
    first = min(stacked)
    return (
        f"{first} and {stacked[first][0]} share a spot: the scene repeats and folded them onto each other, "
        "but no room axis was found, so nothing checks this camera's turn; " + AMBIGUOUS_ACTION
    )


def _judge(e: dict[str, Any], stacked: tuple[str, float] | None, fl, limit: float) -> tuple[str, str]:
    """("good" | "check it", reason) of a placed camera's evidence ``e``."""
    if stacked is not None:
        return "check it", (
            f"its centre is {stacked[1] * 100:.0f} cm from {stacked[0]}'s: two cameras cannot share a spot "
            "(a symmetric scene can fold cameras onto each other)"
        )
    a = e["depth_agreement"]
    if a is not None and a < limit:
        return "check it", f"its neighbours confirm only {a:.2f} of its depth (below {limit:.2f})"
    if e.get("placed_alone"):
        return "check it", FALLBACK_ALONE.format(src=e["placed_alone"])
    if e["disagreeing"] and 2 * e["pairs_agreeing"] < e["pairs"]:
        edge, (d, mm) = next(iter(e["disagreeing"].items()))
        return "check it", (
            f"{e['pairs'] - e['pairs_agreeing']} of its {e['pairs']} measured pair poses disagree with the result "
            f"(pair {edge} by {d:.1f} deg / {mm:.0f} mm)"
        )
    if e["cycles"] == 0:
        floor = "only its floor (tilt and height) agrees" if e["floor_ok"] else "no floor check"
        if e["pairs"] == 0:
            return "check it", f"no independent check: {e['accuracy_from']}; {floor}"
        return "check it", (
            f"no independent check of its whole pose: placed by {e['pairs']} pair pose{'s' * (e['pairs'] != 1)} "
            f"that close{'s' * (e['pairs'] == 1)} no cycle; {floor} (add a camera that sees it and its neighbours, or more frames)"
        )
    deg, mm = e["accuracy_deg"], e["accuracy_mm"]
    bound = _acc(e.get("bound_deg", deg), e.get("bound_mm", mm))
    if e.get("axis_floor") and mm is not None and mm > GOOD_MM and (deg is None or deg <= GOOD_DEG):
        return "check it", (
            f"{e['accuracy_from']}, known to {TURN_AXIS_MM:g} mm, checks its position to {mm:.0f} mm at best, "
            f"beyond {GOOD_MM:g} mm (90 % bound {bound})"
        )
    if (deg is not None and deg > GOOD_DEG) or (mm is not None and mm > GOOD_MM):
        return "check it", (
            f"expected accuracy {_acc(deg, mm)} is beyond {GOOD_DEG:g} deg / {GOOD_MM:g} mm (90 % bound {bound})"
        )
    checks = [f"{e['cycles']} cycle{'s' * (e['cycles'] != 1)}"] + (["floor"] if e["floor_ok"] else [])
    return "good", f"checked by {' + '.join(checks)}; expected accuracy {_acc(deg, mm)} (90 % bound {bound})"


def _judge_turn(t: TurnEvidence | None, sides: int, reason: str) -> tuple[str, str]:
    """The verdict of a camera its other checks call good, in a room that repeats every 360/sides
    deg: cycles and the floor cannot tell its turn (a whole-period turn keeps both), only the
    subject can. Good when its chosen turn is the placed one with a margin of at least
    TURN_MIN_MARGIN over every other possible turn (or no other turn is possible)."""
    period = 360.0 / sides
    if t is None or t.score is None:
        return "ambiguous", (
            f"the room repeats every {period:.0f} deg and too little of the subject is seen to tell its turn; "
            + AMBIGUOUS_ACTION
        )
    moved = f"; turned by {t.moved * period:+.0f} deg about the room's axis by the subject" if t.moved else ""
    reason = reason + moved
    if t.turn != 0:
        return "check it", (
            f"the subject says it is turned by {t.turn * period:+.0f} deg about the room's axis "
            f"(score {t.score:.2f} there against {t.runner_up_score if t.runner_up_score is not None else float('nan'):.2f})"
        )
    if t.alternatives == 0:
        return "good", f"{reason}; room turn: every other turn puts it on another camera"
    if t.margin is None or t.margin < TURN_MIN_MARGIN:
        if t.margin is None:
            return (
                "ambiguous",
                f"the room repeats every {period:.0f} deg and the subject cannot score its other turns; "
                + AMBIGUOUS_ACTION,
            )
        return "ambiguous", (
            f"the room repeats every {period:.0f} deg and the subject prefers its turn by only {t.margin:.2f} "
            f"(score {t.score:.2f}) over {t.runner_up * period:+.0f} deg (below {TURN_MIN_MARGIN:.2f}); "
            + AMBIGUOUS_ACTION
        )
    return "good", f"{reason}; room turn checked by the subject (margin {t.margin:.2f})"


def cross_check(
    verdicts: Mapping[str, Mapping[str, Any]],
    T: Mapping[str, np.ndarray],
    T_other: Mapping[str, np.ndarray],
    other: str,
) -> dict[str, dict[str, Any]]:
    """``verdicts`` of the extrinsics ``T`` with every "good" camera that a second calibration of
    the same rig from other frames (``T_other``, described by ``other``) contradicts made "check
    it". Contradicted:

    - the other turns it: its rotation relative to more than half of the cameras both placed
      differs by more than ``GOOD_DEG``;
    - the other puts its centre's distance to a camera d more than ``GOOD_MM`` from this one's,
      where its rotation relative to d agrees within ``GOOD_DEG`` (a pair turned apart in one of
      them compares two room turns, which the rotation rule and the subject judge).

    A good camera is claimed within ``GOOD_MM``; two calibrations of one rig that disagree by more
    on its distance to another camera leave that claim unconfirmed, whichever of the two is off.
    Distances need no alignment of the two worlds, and they show what every pair pose of one
    frame shares: on independent studio seed 1639 (10-sided, 5 moving frames) one frame's joint
    room axis, about 20 mm off along every camera's view, left the ring 0.8 % small and cam0
    "good" 6.3 cm off; the five frames put it 72 mm further from cam3 (docs/gmac-trust.md,
    "Two calibrations of one rig")."""
    out = {c: dict(v) for c, v in verdicts.items()}
    common = [c for c in T if c in T_other]
    C = {c: invert_rigid(np.asarray(T[c]))[:3, 3] for c in common}
    C2 = {c: invert_rigid(np.asarray(T_other[c]))[:3, 3] for c in common}
    for c in common:
        v = out.get(c)
        if not v or v.get("verdict") != "good":
            continue
        others = [d for d in common if d != c]
        turned, gaps = 0, []
        for d in others:  # the other's pair pose c -> d, judged against T as a measured one would be
            if edge_residual(np.asarray(T_other[d]) @ invert_rigid(np.asarray(T_other[c])), T[c], T[d])[0] > GOOD_DEG:
                turned += 1
                continue
            dist, dist2 = float(np.linalg.norm(C[c] - C[d])), float(np.linalg.norm(C2[c] - C2[d]))
            gaps.append((abs(dist2 - dist), d, dist, dist2))
        if others and 2 * turned > len(others):
            reason = (
                f"{other} turned it by more than {GOOD_DEG:g} deg against {turned} of the {len(others)} other "
                "cameras: the two calibrations disagree on its pose; check it by eye or record more frames"
            )
            v.update(verdict="check it", reason=reason, cross_check={"other": other, "turned_against": turned})
        elif gaps and max(gaps)[0] * 1000 > GOOD_MM:
            _, d, dist, dist2 = max(gaps)
            side = "further from" if dist2 > dist else "nearer to"
            reason = (
                f"{other} put it {abs(dist2 - dist) * 1000:.0f} mm {side} {d} ({dist2:.3f} m against {dist:.3f} m): "
                f"the two calibrations disagree beyond {GOOD_MM:g} mm; check it by eye or record more frames"
            )
            check = {"other": other, "camera": d, "mm": round((dist2 - dist) * 1000, 1)}
            v.update(verdict="check it", reason=reason, cross_check=check)
    return out


def _acc(deg: float | None, mm: float | None) -> str:
    d = "? deg" if deg is None else f"{deg:.2f} deg"
    m = "? mm" if mm is None else f"{mm:.0f} mm"
    return f"{d} / {m}"


def drop_unconfirmed(
    T: Mapping[str, np.ndarray],
    frame: Frame,
    rig: Rig,
    min_agreement: float,
    under: Mapping[str, Mapping[str, float | None]],
    merged: bool = True,
    agreement: Mapping[str, float | None] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, float | None], dict[str, str]]:
    """The placement rule of every backbone: remove, one at a time, the camera with the lowest
    depth agreement under the extrinsics ``T`` while it is below ``min_agreement`` (a wrong camera
    also lowers its neighbours' agreement, so they are measured again without it). ``under``:
    source -> camera -> the agreement it had under that source's own poses (for the reason);
    ``merged`` False: ``T`` is the one source's own poses. ``agreement``: the depth agreement of
    ``T`` when already measured on ``frame``. Returns (extrinsics, agreement of the kept cameras,
    camera -> reason it is not placed)."""
    if min_agreement <= 0 or not T:
        return dict(T), {}, {}
    T = dict(T)
    reasons = {}
    agreement = dict(agreement) if agreement is not None else depth_agreement(frame, rig, T)
    while True:
        low = {c: a for c, a in agreement.items() if a is not None and a < min_agreement}
        if not low:
            return T, agreement, reasons
        c = min(low, key=lambda k: (low[k], k))
        if not merged:
            src = next(iter(under), "the backbone")
            reasons[c] = (
                f"depth agreement {low[c]:.3f} with its neighbours under {src}'s poses, below {min_agreement:.2f}: "
                "its pose is not confirmed"
            )
        else:
            each = ", ".join(f"{n} {a[c]:.2f}" for n, a in under.items() if a.get(c) is not None)
            reasons[c] = (
                f"depth agreement {low[c]:.3f} with its neighbours under the merged extrinsics "
                f"(under each source: {each or 'none'}), below {min_agreement:.2f}: no source's pose is confirmed"
            )
        del T[c]
        agreement = depth_agreement(frame, rig, T) if T else {}


SCALE_CHECK_WARNING = "GMAC's closed-form scale on the metric backbone's poses is"
"""How the scale check's warning (``scale_stage.placement_scale``) starts."""


def drop_answered_scale_warning(report) -> None:
    """Drop the scale check's warning when every camera's verdict is "good": the verdicts'
    depth-agreement and cycle evidence then shows the poses fit the sensor depth, and the check's
    own bias is the likelier cause (far-range rings with 120 deg between cameras read 0.76 on
    poses 0.1 deg / 12 mm from the truth). ``report.scale_check`` keeps the value."""
    verdicts = report.camera_verdicts or {}
    if verdicts and all(v.get("verdict") == "good" for v in verdicts.values()):
        report.warnings = [w for w in report.warnings if not w.startswith(SCALE_CHECK_WARNING)]


def pair_agreements(frame: Frame, rig: Rig, T_cam_world: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Edge "a-b" (frame order) -> share of the pair's overlapping depth that agrees under the
    extrinsics (``geometry.pair_agreement``, tau 5 %, each camera's 4 most-overlapping
    neighbours); pairs that cast no vote are left out."""
    placed = [c for c in frame.camera_ids if c in T_cam_world]
    if len(placed) < 2:
        return {}
    sub = frame.subset([frame.camera_ids.index(c) for c in placed])
    S = pair_agreement(sub, Rig(tuple(rig[c].with_extrinsics(T_cam_world[c]) for c in placed)))
    return {
        f"{placed[i]}-{placed[j]}": round(float(S[i, j]), 4)
        for i, j in combinations(range(len(placed)), 2)
        if np.isfinite(S[i, j])
    }
