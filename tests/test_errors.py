"""fuseflow.errors.require: optional dependencies with an install hint."""

import pytest

from fuseflow.errors import FuseFlowError, require


def test_require_returns_the_module_or_names_the_extra():
    assert require("json", "none", "reading") is __import__("json")
    with pytest.raises(FuseFlowError, match=r"^the viewer needs no-such-sdk: pip install 'fuseflow\[viz\]'$"):
        require("no_such_module_fuseflow", "viz", "the viewer", "no-such-sdk")
    with pytest.raises(FuseFlowError, match=r"capture needs no_such_module_fuseflow: pip install"):
        require("no_such_module_fuseflow", "realsense", "capture")
