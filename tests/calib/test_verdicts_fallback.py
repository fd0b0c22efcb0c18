"""The verdict of a camera ``auto`` placed by its fallback source alone (no metric pair pose
measures it): its scale-stage cycles rebuild relative poses from that source's own poses, so they
close whatever the pose is and never make it "good"."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from fuseflow.calib.verdicts import camera_verdicts


def _auto_report(rgbd_edges: bool):
    T = {}
    for i, c in enumerate(("a", "b", "c")):
        T[c] = np.eye(4)
        T[c][:3, 3] = [i * 1.0, 0, 0]
    sources = {"rgbd": {"failed": "the backbone placed fewer than two cameras ([])"}, "colmap": {"placed": list(T)}}
    if rgbd_edges:
        pairs = [{"cameras": [x, y], "edge": {"T_ji": (T[y] @ np.linalg.inv(T[x])).tolist(), "route": "floor"}}
                 for x, y in (("a", "b"), ("a", "c"), ("b", "c"))]  # fmt: skip
        sources["rgbd"] = {"pairs": pairs, "cameras": {c: {"edges": [o for o in T if o != c]} for c in T}}
    rep = SimpleNamespace(backbone="auto", backbone_info={"sources": sources}, config={},
                          placed_by=dict.fromkeys(T, "colmap"), depth_agreement=dict.fromkeys(T, 0.95),
                          unplaced_reasons={}, unregistered_cameras=[], kept_edges=["a-b", "a-c", "b-c"],
                          cycle_residuals_mm={"a-b-c": 1.0}, scale=1.0, scale_std_error=None,
                          world_anchor="a")  # fmt: skip
    return rep, T


def test_a_camera_the_fallback_places_alone_is_never_good_on_its_own_cycles():
    rep, T = _auto_report(rgbd_edges=False)
    v = camera_verdicts(rep, T, list(T))
    for c, e in v.items():
        assert e["verdict"] == "check it", (c, e)
        assert "placed by colmap alone" in e["reason"] and "check the scale, not the pose" in e["reason"]
        assert e["placed_alone"] == "colmap"


def test_metric_pair_poses_that_agree_still_check_a_fallback_camera():
    rep, T = _auto_report(rgbd_edges=True)
    v = camera_verdicts(rep, T, list(T))
    assert all(e["verdict"] == "good" and "placed_alone" not in e for e in v.values()), v


def test_an_explicit_scale_free_backbone_is_judged_by_the_same_rule():
    """``--backbone colmap`` (or a neural / precomputed backbone) chosen explicitly: its scale-stage
    cycles are rebuilt from its own poses too, so they never make a camera "good"."""
    rep, T = _auto_report(rgbd_edges=False)
    for name in ("colmap", "precomputed", "vggt"):
        rep.backbone, rep.backbone_info, rep.placed_by = name, {}, dict.fromkeys(T, name)
        v = camera_verdicts(rep, T, list(T))
        for c, e in v.items():
            assert e["verdict"] == "check it" and e["placed_alone"] == name, (name, c, e)
            assert f"placed by {name} alone" in e["reason"] and e["cycles"] == 1, e


def test_the_depth_agreement_threshold_is_an_argument_not_read_from_the_report():
    """The verdicts apply the threshold they are given; the report's copy of the config (calib.json
    data) is never read back for it."""
    rep, T = _auto_report(rgbd_edges=True)
    rep.config = {"min_depth_agreement": 0.99}  # would flag every camera (0.95) if it were read
    assert all(e["verdict"] == "good" for e in camera_verdicts(rep, T, list(T), min_agreement=0.8).values())
    v = camera_verdicts(rep, T, list(T), min_agreement=0.97)
    for e in v.values():
        assert e["verdict"] == "check it" and "confirm only 0.95 of its depth (below 0.97)" in e["reason"], e
