"""The benchmark commands run library code (fuseflow.eval.bench), not files of the source tree;
eval stays above the product; the metrics' shared distance passes; the paper's data path."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fuseflow
from fuseflow.errors import ValidationError
from fuseflow.eval import metrics as M

PACKAGE = Path(fuseflow.__file__).resolve().parent


def test_bench_help_works_from_a_copy_of_the_package_without_the_source_tree(tmp_path):
    """An installed wheel has fuseflow/ and nothing else: copy the package alone and ask for help."""
    site = tmp_path / "site"
    shutil.copytree(PACKAGE, site / "fuseflow", ignore=shutil.ignore_patterns("__pycache__"))
    for sub in (["bench", "fuse", "--help"], ["bench", "fuse-ratio", "--help"]):
        proc = subprocess.run(
            [sys.executable, "-c", "import sys; sys.path.insert(0, sys.argv[1]); "
             "from fuseflow.cli import main; sys.argv = ['fuseflow'] + sys.argv[2:]; main()", str(site), *sub],
            cwd=tmp_path, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
        assert "--json" in proc.stdout or "--out" in proc.stdout


def test_bench_cli_imports_no_runpy_and_no_source_tree_path():
    tree = ast.parse((PACKAGE / "cli" / "bench.py").read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert "runpy" not in imported
    assert "__file__" not in {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}


def test_nothing_outside_eval_and_cli_imports_eval():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).parts
        if rel[0] in ("eval", "cli"):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            if any(n == "fuseflow.eval" or n.startswith("fuseflow.eval.") for n in names):
                offenders.append(str(path.relative_to(PACKAGE)))
    assert offenders == []
    assert not (PACKAGE / "metrics.py").exists() and not (PACKAGE / "baselines.py").exists()


def test_fuse_speed_library_times_a_tiny_rig_in_a_child_process(tmp_path):
    from fuseflow.eval.bench.fuse_speed import format_row, run_fuse_speed

    lines: list[str] = []
    res = run_fuse_speed(
        [1], frames=1, warmup=1, methods=["fuse"], resolution=(64, 48), work=tmp_path / "work",
        json_path=tmp_path / "speed.json", command="test", log=lines.append,
    )  # fmt: skip
    (row,) = res.rows
    assert row["method"] == "fuse" and row["cameras"] == 1 and row["frames"] == 1
    assert row["ms"] > 0 and row["points"] > 0 and row["peak_mb"] >= row["base_mb"] > 0
    assert format_row(row) in lines and lines[-1] == f"wrote {tmp_path / 'speed.json'}"
    assert (tmp_path / "speed.json").exists()


def test_fuse_speed_bad_options_are_validation_errors():
    from fuseflow.eval.bench.fuse_speed import parse_options, run_fuse_speed

    with pytest.raises(ValidationError, match="--resolution WxH"):
        parse_options("1,2", "640by480")
    with pytest.raises(ValidationError, match="1..16"):
        run_fuse_speed([17])
    with pytest.raises(ValidationError, match="unknown methods"):
        run_fuse_speed([1], methods=["nope"])


def test_calib_accuracy_rejects_unknown_data_and_icl_without_folder():
    from benchmarks.studies.calib_accuracy import run_calib_accuracy

    with pytest.raises(ValidationError, match="unknown data"):
        run_calib_accuracy(1, ["kitti"])
    with pytest.raises(ValidationError, match="backbone"):
        run_calib_accuracy(1, ["sim4"], backbone="sift")


def test_bench_paper_names_the_data_dir_when_icl_is_missing(tmp_path, capsys):
    from benchmarks import paper as program

    with pytest.raises(SystemExit) as exc:
        program.main(["--out", str(tmp_path / "p"), "--quick", "--data-dir", str(tmp_path / "none")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "--data-dir" in err and "--no-icl" in err


def test_paper_icl_cell_without_data_dir_is_a_validation_error():
    from benchmarks.studies import paper

    cell = next(c for c in paper.plan(paper.QUICK, ["static"]) if c.meta["dataset"] == "icl")
    with pytest.raises(ValidationError, match="data folder"):
        cell.compute()


def test_surface_distances_give_the_single_metrics():
    rng = np.random.default_rng(3)
    gt = rng.uniform(-1, 1, (2000, 3))
    pts = gt[:1500] + rng.normal(scale=0.01, size=(1500, 3))
    d = M.surface_distances(pts, gt)
    assert d.chamfer() == M.chamfer_distance(pts, gt)
    assert d.fscore(0.01) == M.f_score(pts, gt, 0.01)
    assert d.outlier_share(0.02) == M.outlier_share(pts, gt, 0.02)
    ref = M.reference_metrics(pts, gt, f_threshold=0.005)
    assert ref.fscore == d.fscore(0.005) and ref.chamfer == d.chamfer()
    empty = M.surface_distances(np.zeros((0, 3)), gt)
    assert empty.outlier_share() == 0.0 and empty.fscore().f_score == 0.0 and np.isinf(empty.chamfer().chamfer_mm)
    with pytest.raises(ValidationError):
        d.fscore(0.0)
