"""Outputs of two source trees compared byte for byte: the proof that a change which should not
change results (a refactor, a move) does not.

Each tree (a folder holding ``src/fuseflow``, e.g. ``git worktree add /tmp/base <commit>``) runs
the same commands in a fresh process (``python -m fuseflow``, ``PYTHONPATH=<tree>/src``) on three
rigs:

* ``sim``: ``fuseflow simulate`` (4-camera static room ring, 320x240, 2 frames, seed 1);
* ``icl``: ``fuseflow convert <data>/icl-livingroom1 --cameras 8 --every 26`` (reference poses);
* ``hocap``: ``fuseflow convert <data>/hocap-8rs --with-extrinsics`` (8 RealSense cameras).

then ``fuseflow fuse REC --out OUT/fuse --frames 0:2`` (clouds/*.ply with the rig's extrinsics)
and ``fuseflow calibrate REC -o OUT/calib.json`` (GMAC's defaults on the first frame). The
compared files are every cloud (PLY bytes) and calib.json: its JSON with the wall-clock fields
(keys ending in ``_s`` or named ``seconds`` whose value is a number, or a dict of numbers,
under ``report``: times change from run to run) removed, the rest compared exactly, extrinsics included. A data set
missing under the data folder is reported as skipped, never as identical.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["CASES", "steps", "run_tree", "compare", "strip_times"]

CASES = ("sim", "icl", "hocap")


def steps(case: str, out: Path, data_dir: Path) -> list[list[str]] | None:
    """The fuseflow commands of one case (None when its data is missing)."""
    rec = str(out / "rec")
    if case == "sim":
        make = ["simulate", rec, "--cameras", "4", "--num-frames", "2", "--resolution", "320x240", "--seed", "1",
                "--scene", "room", "--rig", "ring"]  # fmt: skip
    elif case == "icl":
        if not (data_dir / "icl-livingroom1").is_dir():
            return None
        make = ["convert", str(data_dir / "icl-livingroom1"), rec, "--cameras", "8", "--every", "26"]
    elif case == "hocap":
        if not (data_dir / "hocap-8rs").is_dir():
            return None
        make = ["convert", str(data_dir / "hocap-8rs"), rec, "--with-extrinsics"]
    else:
        raise ValueError(f"unknown case {case!r}; cases are {', '.join(CASES)}")
    fuse = ["fuse", rec, "--out", str(out / "fuse"), "--frames", "0:2"]
    return [make, fuse, ["calibrate", rec, "-o", str(out / "calib.json")]]


def run_tree(tree: Path, case: str, out: Path, data_dir: Path, log: Callable[[str], None]) -> bool:
    """Run one case with ``tree``'s fuseflow into ``out``; False when its data is missing."""
    cmds = steps(case, out, data_dir)
    if cmds is None:
        return False
    env = {**os.environ, "PYTHONPATH": str(Path(tree) / "src")}
    out.mkdir(parents=True, exist_ok=True)
    for cmd in cmds:
        log(f"  [{tree}] fuseflow {' '.join(cmd)}")
        res = subprocess.run([sys.executable, "-m", "fuseflow", *cmd], env=env, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"fuseflow {' '.join(cmd)} failed ({res.returncode}):\n{res.stderr[-2000:]}")
    return True


def strip_times(doc: Any, path: str = "", dropped: list[str] | None = None) -> Any:
    """``doc`` without the wall-clock fields of calib.json's report (module docstring)."""
    if isinstance(doc, dict):
        out = {}
        for k, v in doc.items():
            p = f"{path}.{k}" if path else k
            timing = (k.endswith("_s") or k == "seconds") and (
                isinstance(v, (int, float))
                or (isinstance(v, dict) and all(isinstance(x, (int, float)) for x in v.values()))
            )
            if timing and p.startswith("report"):
                if dropped is not None:
                    dropped.append(p)
                continue
            out[k] = strip_times(v, p, dropped)
        return out
    if isinstance(doc, list):
        return [strip_times(v, path, dropped) for v in doc]
    return doc


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def compare(a: Path, b: Path) -> dict[str, Any]:
    """Clouds and calib.json of two runs of one case: per file identical or not."""
    clouds = sorted(p.relative_to(a) for p in (a / "fuse").rglob("*.ply"))
    other = sorted(p.relative_to(b) for p in (b / "fuse").rglob("*.ply"))
    row: dict[str, Any] = {"clouds": len(clouds), "same_cloud_files": clouds == other}
    row["different_clouds"] = [str(p) for p in clouds if p in other and _digest(a / p) != _digest(b / p)]
    dropped: list[str] = []
    ca = strip_times(json.loads((a / "calib.json").read_text()), dropped=dropped)
    cb = strip_times(json.loads((b / "calib.json").read_text()))
    row["calib_identical"] = json.dumps(ca, sort_keys=True) == json.dumps(cb, sort_keys=True)
    row["calib_fields_ignored"] = sorted(set(dropped))
    row["identical"] = row["same_cloud_files"] and not row["different_clouds"] and row["calib_identical"]
    return row


def run(
    base: Path, head: Path, cases: Sequence[str], work: Path, data_dir: Path, log: Callable[[str], None]
) -> list[dict]:
    """Each case with both trees, then :func:`compare`; one row per case."""
    rows = []
    for case in cases:
        ran = [
            run_tree(tree, case, work / name / case, data_dir, log) for name, tree in (("base", base), ("head", head))
        ]
        if not all(ran):
            rows.append({"case": case, "skipped": f"no data under {data_dir}"})
        else:
            rows.append({"case": case, **compare(work / "base" / case, work / "head" / case)})
        log(json.dumps(rows[-1]))
    return rows
