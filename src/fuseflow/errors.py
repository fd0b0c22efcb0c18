"""Exceptions raised at FuseFlow's public boundary.

Every error a user can trigger with bad input is one of these, with a message that names the
file, field or camera at fault and says what was expected and what came. Library code never
calls ``sys.exit``; the CLI turns these into one-line messages and a non-zero exit code.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["FuseFlowError", "ValidationError", "RecordingError", "FormatError", "OutputError", "require"]


class FuseFlowError(Exception):
    """Base class of every error FuseFlow raises on purpose."""


class ValidationError(FuseFlowError, ValueError):
    """An argument has the wrong shape, dtype, range or structure (e.g. a non-rigid extrinsic)."""


class RecordingError(FuseFlowError, OSError):
    """A recording or dataset directory is missing, incomplete or has an unreadable file."""


class FormatError(FuseFlowError, ValueError):
    """A file exists but its content does not follow the format it claims (JSON schema, PLY)."""


class OutputError(FuseFlowError, OSError):
    """An output location cannot be used: a file where a directory is needed (or the reverse),
    no permission, a read-only filesystem, or a used output directory that does not match."""


def require(module: str, extra: str, purpose: str, package: str | None = None) -> ModuleType:
    """Import an optional dependency, or raise FuseFlowError with the install hint.

    Args:
        module: the import name (``"rerun"``).
        extra: the fuseflow extra that installs it (``"viz"`` -> ``pip install 'fuseflow[viz]'``).
        purpose: what needs it, starting the message (``"the rerun viewer"``).
        package: the name users know it by, when not ``module`` (``"rerun-sdk"``).

    Example: ``require("rerun", "viz", "the rerun viewer", "rerun-sdk")`` raises
    "the rerun viewer needs rerun-sdk: pip install 'fuseflow[viz]'" when rerun is missing.
    """
    try:
        return importlib.import_module(module)
    except ImportError:
        raise FuseFlowError(f"{purpose} needs {package or module}: pip install 'fuseflow[{extra}]'") from None
