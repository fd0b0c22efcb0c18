"""The FUSE-vs-VoxelBlockGrid quality grid (benchmarks.studies.fuse_quality and
``python -m benchmarks.fuse_quality``) on a tiny grid."""

from __future__ import annotations

import json

import pytest
from benchmarks import fuse_quality as program
from benchmarks.studies.fuse_quality import fusion_methods, run_fuse_quality, summarize_quality

from fuseflow.errors import ValidationError


def test_grid_rows_and_summary():
    rows = run_fuse_quality(
        cameras=(3,), resolutions=((80, 60),), seeds=(1,), dynamics=(False,), methods=("auto", "vbg")
    )
    assert [r["method"] for r in rows] == ["auto", "vbg"]
    for r in rows:
        assert r["cameras"] == 3 and r["resolution"] == "80x60" and r["points"] > 0
        for k in ("5mm", "1cm", "2cm"):
            assert 0 <= r[f"precision_{k}"] <= 1 and 0 <= r[f"recall_{k}"] <= 1
        assert r["recall_5mm"] <= r["recall_1cm"] <= r["recall_2cm"]
    (s,) = summarize_quality(rows)
    assert s["cells"] == 1 and s["wins"] == int(rows[0]["f_1cm"] >= rows[1]["f_1cm"])


def test_unknown_method_and_bad_options_are_clear_errors(tmp_path, capsys):
    with pytest.raises(ValidationError, match="unknown method"):
        fusion_methods(["nope"])
    with pytest.raises(SystemExit) as exc:
        program.main(["--kinds", "sideways"])
    assert exc.value.code == 2 and "--kinds" in capsys.readouterr().err
    out = tmp_path / "q.json"
    args = ["--cameras", "3", "--resolutions", "80x60", "--seeds", "1", "--kinds", "static"]
    assert program.main([*args, "--methods", "default,naive", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["schema"] == 1 and doc["benchmark"] == "fuse_quality" and doc["command"].startswith("python -m")
    assert len(doc["rows"]) == 2 and doc["meta"]["summary"][0]["cameras"] == 3


def test_a_method_can_change_settings_of_its_preset():
    from fuseflow.synth import SimConfig, Simulator

    fns = fusion_methods(["dense", "dense+mcm.max_missing=0+smoothing.radius=0"])
    sim = Simulator(SimConfig(cameras=3, resolution=(80, 60), frames=1, seed=1))
    frame = sim.render(0).frame
    a, b = (fns[m](frame, sim.rig) for m in fns)
    assert len(a) != len(b) or not (a.xyz.numpy() == b.xyz.numpy()).all()
    with pytest.raises(ValidationError, match="--set"):
        fusion_methods(["dense+mcm.nope=1"])


def test_vbg_at_its_best_threshold_is_at_least_as_good_as_at_fuseflows_and_open3ds():
    rows = run_fuse_quality(
        cameras=(3,), resolutions=((80, 60),), seeds=(1,), dynamics=(False,), methods=("vbg", "vbg_o3d", "vbg_best")
    )
    f = {r["method"]: r["f_1cm"] for r in rows}
    best = next(r for r in rows if r["method"] == "vbg_best")
    assert best["weight_threshold"] in (0.0, 1.0, 2.0, 3.0)
    assert f["vbg_best"] >= f["vbg"] and f["vbg_best"] >= f["vbg_o3d"]
    (s,) = summarize_quality([{**best, "method": "auto"}, *rows])
    assert s["cells_best"] == 1 and s["wins_best"] == 1  # the same cloud ties with itself
