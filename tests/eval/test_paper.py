"""`python -m benchmarks.paper --quick` end to end (the CI run), resume, helpers.

The quick run (every table, simulated + ICL data, one seed) takes about 90 s on 2 cores; it is
run once per module (fixture) and every check below reads its output.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from benchmarks import paper as program
from benchmarks.studies import paper

from fuseflow import Camera, Frame, Rig
from fuseflow.errors import ValidationError

SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"  # ../shared/data of the project


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("paper") / "quick"
    assert program.main(["--out", str(out), "--quick", "--data-dir", str(SHARED_DATA)]) == 0
    return out


def test_quick_writes_every_table_and_the_png(quick_run: Path) -> None:
    md = (quick_run / "paper_tables.md").read_text()
    for title in ("Table I / III", "Table IV / VI", "Table V", "Table VII", "Table VIII", "Fig. 5"):
        assert title in md
    assert "python -m benchmarks.paper" in md and "--quick" in md  # the exact command
    assert "torch " in md and "open3d " in md  # library versions
    assert "ICL-NUIM" in md
    import cv2

    img = cv2.imread(str(quick_run / "fig5_fps_vs_n.png"))
    assert img is not None and img.shape == (560, 900, 3)
    assert (img < 250).any(axis=2).mean() > 0.01  # something was drawn
    n_cells = len(paper.plan(paper.QUICK))
    assert len(list((quick_run / "cells").glob("*.json"))) == n_cells


def test_quick_numbers_are_sane(quick_run: Path) -> None:
    cells = {p.stem: json.loads(p.read_text()) for p in (quick_run / "cells").glob("*.json")}
    fuse = cells["static-sim-room-N4-s0-FUSE"]
    naive = cells["static-sim-room-N4-s0-naive"]
    assert len(fuse["frames"]) == paper.QUICK.frames
    for fr in fuse["frames"]:
        assert fr["points"] > 100 and fr["fps"] > 0 and fr["rss_mib"] > 50
        assert 0 <= float(fr["or_pct"]) <= 100 and 0 <= float(fr["fscore"]) <= 1
        assert np.isfinite(float(fr["cd_mm"])) and float(fr["cd_mm"]) > 0
    # FUSE keeps one representative per fine cell: far fewer points than the naive concatenation
    assert fuse["frames"][0]["points"] < naive["frames"][0]["points"]
    # GMAC on the perturbed-truth stand-in recovers the unknown scale: translation error far below
    # the 0.1x-10x scale the stand-in starts from (the rig's baselines are metres)
    g = cells["gmac-sim-room-perturbed-s0"]["rows"]["GMAC (default)"]
    assert not g["failed"] and g["trans_mm"] < 300
    md = (quick_run / "paper_tables.md").read_text()
    assert "| FUSE | 2 |" in md  # 1 seed x 2 frames pooled


def test_resume_recomputes_only_missing_cells(quick_run: Path) -> None:
    victim = quick_run / "cells" / "fps-N2-s0-naive.json"
    before = json.loads(victim.read_text())
    victim.unlink()
    calls = []
    files = paper.run(quick_run, paper.QUICK, command="test", progress=lambda i, n, k: calls.append(k))
    assert files["computed"] == 1
    after = json.loads(victim.read_text())
    assert after["meta"] == before["meta"] and len(after["frames"]) == len(before["frames"])


def test_other_configuration_in_same_folder_is_an_error(quick_run: Path) -> None:
    with pytest.raises(ValidationError, match="different configuration"):
        paper.run(quick_run, paper.FULL, tables=("fps",))


def test_bad_tables_are_clear_errors(tmp_path: Path, capsys) -> None:
    with pytest.raises(ValidationError, match="unknown tables"):
        paper.plan(paper.QUICK, ["static", "table9"])
    with pytest.raises(SystemExit) as exc:
        program.main(["--out", str(tmp_path), "--quick", "--tables", "nope"])
    assert exc.value.code == 2 and "unknown" in capsys.readouterr().err


def test_mean_std_formatting() -> None:
    assert paper.ms([1.0, 3.0]) == "2.00 ± 1.00"
    assert paper.ms([1.0, float("nan"), 3.0], 1) == "2.0 ± 1.0 (1 n/a)"
    assert paper.ms([]) == "-"


def test_subsample_scales_intrinsics_exactly() -> None:
    """Pixel (2u, 2v) of the full image is pixel (u, v) of the subsampled one: K / 2 (no half-pixel
    shift) keeps the back-projection of every kept pixel identical."""
    K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])
    cam = Camera("a", 64, 48, K)
    depth = torch.rand(1, 48, 64) + 1.0
    frame = Frame(0, ("a",), torch.zeros(1, 48, 64, 3, dtype=torch.uint8), depth, torch.ones(1, dtype=torch.bool))
    f2, rig2 = paper._subsample(frame, Rig((cam,)), 2)
    assert f2.depth.shape == (1, 24, 32) and rig2.cameras[0].width == 32 and rig2.cameras[0].height == 24
    u, v = 7, 5
    ray_full = np.linalg.inv(K) @ [2 * u, 2 * v, 1]
    ray_half = np.linalg.inv(rig2.cameras[0].K) @ [u, v, 1]
    np.testing.assert_allclose(ray_full, ray_half)
    assert float(f2.depth[0, v, u]) == float(depth[0, 2 * v, 2 * u])


def test_anchored_rig_keeps_relative_poses() -> None:
    from fuseflow.eval.metrics import pose_errors
    from fuseflow.synth.rigs import look_at

    K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])
    ref = [look_at(np.array([x, -2.0, 1.0]), np.zeros(3)) for x in (-1.0, 0.0, 1.0)]
    rig = Rig(tuple(Camera(f"c{k}", 64, 48, K, T_cam_world=T) for k, T in enumerate(ref)))
    G = np.eye(4)
    G[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    G[:3, 3] = [5.0, -2.0, 0.3]
    est = {f"c{k}": T @ G for k, T in enumerate(ref)}  # same rig in another world frame
    out = paper.anchored_rig(est, rig)
    for c, T in zip(out.cameras, ref):
        np.testing.assert_allclose(c.T_cam_world, T, atol=1e-9)
    assert paper.anchored_rig({"c0": ref[0]}, rig) is None  # not every camera placed
    e = pose_errors({k: v for k, v in est.items()}, {c.id: c.T_cam_world for c in rig.cameras})
    assert e.rotation_deg < 1e-6 and e.translation_mm < 1e-6


def test_icl_indices_stay_inside_the_sequence() -> None:
    for n in (2, 4, 8):
        for seed in range(6):
            idx = paper.icl_indices(n, seed, 211)
            assert len(set(idx)) == n and min(idx) >= 0 and max(idx) < 211
            assert all(b - a == 26 for a, b in zip(idx, idx[1:]))
    assert paper.icl_indices(8, 1, 211) != paper.icl_indices(8, 0, 211)
    with pytest.raises(ValidationError):
        paper.icl_indices(9, 0, 200)


def test_table_viii_has_the_default_calibration_row_and_it_places_every_camera() -> None:
    """FULL adds "default (auto) + GMAC" to Table VIII (the product's calibration, beyond the
    paper's colmap protocol); the cell calibrates a 4-camera room ring and fuses with it."""
    from dataclasses import replace

    assert "default:GMAC" in paper.extrinsic_sources(paper.FULL)
    assert "default:GMAC" not in paper.extrinsic_sources(paper.QUICK)
    pc = replace(paper.QUICK, resolution=(320, 240), frames=1, default_calib_row=True)
    keys = [c.key for c in paper.plan(pc, tables=["extrinsics"], icl=False)]
    assert any("default" in k for k in keys)
    cell = paper._extrinsics_cell("sim-room", "default:GMAC", 0, pc)
    assert not cell.get("failed"), cell.get("error")
    assert cell["pose"]["rot_deg"] < 0.5 and cell["pose"]["trans_mm"] < 20
    assert len(cell["frames"]) == 1 and cell["frames"][0]["points"] > 1000


def test_table_i_has_the_default_calibration_row_and_renders_it() -> None:
    """With default_calib_row, Table I/III gets one cell per data set and seed for the product's
    default calibration, and the markdown shows it under its own heading."""
    from dataclasses import replace

    pc = replace(paper.QUICK, resolution=(320, 240), frames=1, calib_seeds=1, default_calib_row=True)
    cells = paper.plan(pc, tables=["gmac"], icl=False)
    default = [c for c in cells if c.meta["backbone"] == "default"]
    assert [c.key for c in default] == ["gmac-sim-room-default-s0"]
    assert not [c for c in paper.plan(paper.QUICK, tables=["gmac"], icl=False) if c.meta["backbone"] == "default"]
    res = default[0].compute()
    row = res["rows"][paper.DEFAULT_ROW]
    assert not row["failed"], row.get("error")
    assert row["placed"] == pc.calib_cameras
    assert row["rot_deg"] < 0.5 and row["trans_mm"] < 20
    md = "\n".join(paper._md_gmac({default[0].key: (default[0], res)}, pc))
    assert "the product's default calibration" in md
    assert f"| {paper.DEFAULT_ROW} |" in md and "0/1 |" in md
