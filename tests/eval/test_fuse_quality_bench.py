"""fuseflow bench fuse-quality (fuseflow.eval.bench.fuse_quality) on a tiny grid."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from fuseflow.cli import app
from fuseflow.errors import ValidationError
from fuseflow.eval.bench.fuse_quality import fusion_methods, run_fuse_quality, summarize_quality


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


def test_unknown_method_and_bad_options_are_clear_errors(tmp_path):
    with pytest.raises(ValidationError, match="unknown method"):
        fusion_methods(["nope"])
    res = CliRunner().invoke(app, ["bench", "fuse-quality", "--kinds", "sideways"])
    assert res.exit_code == 2 and "--kinds" in res.output
    out = tmp_path / "q.json"
    args = ["bench", "fuse-quality", "--cameras", "3", "--resolutions", "80x60", "--seeds", "1", "--kinds", "static"]
    res = CliRunner().invoke(app, [*args, "--methods", "default,naive", "--json", str(out)])
    assert res.exit_code == 0, res.output
    doc = json.loads(out.read_text())
    assert len(doc["rows"]) == 2 and doc["summary"][0]["cameras"] == 3


def test_a_method_can_change_settings_of_its_preset():
    from fuseflow.synth import SimConfig, Simulator

    fns = fusion_methods(["dense", "dense+mcm.max_missing=0+smoothing.radius=0"])
    sim = Simulator(SimConfig(cameras=3, resolution=(80, 60), frames=1, seed=1))
    frame = sim.render(0).frame
    a, b = (fns[m](frame, sim.rig) for m in fns)
    assert len(a) != len(b) or not (a.xyz.numpy() == b.xyz.numpy()).all()
    with pytest.raises(ValidationError, match="--set"):
        fusion_methods(["dense+mcm.nope=1"])
