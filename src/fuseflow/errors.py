"""Exceptions raised at FuseFlow's public boundary.

Every error a user can trigger with bad input is one of these, with a message that names the
file, field or camera at fault and says what was expected and what came. Library code never
calls ``sys.exit``; the CLI turns these into one-line messages and a non-zero exit code.
"""

from __future__ import annotations

__all__ = ["FuseFlowError", "ValidationError", "RecordingError", "FormatError", "OutputError"]


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
