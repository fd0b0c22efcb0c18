"""The CalibConfig is read once, in the placement engine: each stage gets its own frozen settings."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

import fuseflow.calib as calib
from fuseflow.calib.config import CalibConfig, RefineSettings, ScaleSettings, refine_settings, scale_settings
from fuseflow.calib.placement import stage_settings

#: The modules that may read a whole CalibConfig: where it is defined and exported, the entry point
#: and the placement engine that builds the stages' settings from it.
READERS = {"__init__", "api", "config", "placement"}


def _runtime_imports_of_calib_config(path: Path) -> bool:
    """Whether ``path`` imports CalibConfig outside an ``if TYPE_CHECKING:`` block."""
    tree = ast.parse(path.read_text())
    skip = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and getattr(node.test, "id", None) == "TYPE_CHECKING":
            skip.update(id(n) for n in ast.walk(node))
    return any(
        isinstance(n, ast.ImportFrom) and id(n) not in skip and any(a.name == "CalibConfig" for a in n.names)
        for n in ast.walk(tree)
    )


def test_no_stage_module_imports_the_calib_config():
    root = Path(calib.__file__).parent
    readers = {p.stem for p in root.glob("*.py") if _runtime_imports_of_calib_config(p)}
    assert readers <= READERS, sorted(readers - READERS)


def test_the_stage_settings_carry_the_config_values_and_are_frozen():
    cfg = CalibConfig(depth_tau=0.07, robust=True, refine=True, icp_voxel=0.03, min_depth_agreement=0.6)
    st = stage_settings(cfg)
    for f in dataclasses.fields(ScaleSettings):
        assert getattr(st.scale, f.name) == getattr(cfg, f.name), f.name
    assert st.refine == RefineSettings(icp_voxel=0.03, icp_max_distance=cfg.icp_max_distance, refine_neighbors=2)
    assert st.min_agreement == 0.6 and st.joint_refine and st.report == cfg.as_dict()
    assert stage_settings(CalibConfig()).refine is None  # refinement off: no settings
    assert scale_settings(st.scale) is st.scale and refine_settings(st.refine) is st.refine
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.scale.depth_tau = 0.1  # type: ignore[misc]
