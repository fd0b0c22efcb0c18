"""Benchmark programs as library code: ``fuseflow bench fuse`` and ``fuseflow bench calib`` call
:mod:`fuseflow.eval.bench.fuse_speed` and :mod:`fuseflow.eval.bench.calib_accuracy`; the
programs in the source tree's ``benchmarks/`` folder are thin wrappers around the same functions.

Nothing here prints: report lines go to a ``log`` callback the caller chooses (the CLI and the
wrappers print them). This ``__init__`` imports nothing heavy.
"""

from __future__ import annotations

from fuseflow.errors import FuseFlowError

__all__ = ["BenchmarkFailed"]


class BenchmarkFailed(FuseFlowError):
    """A benchmark run failed part-way (for example a timed child process exited with an error)."""
