"""Benchmark programs as library code: each ``fuseflow bench ...`` command calls one module here
(``fuse`` :mod:`fuseflow.eval.bench.fuse_speed`, ``calib`` :mod:`fuseflow.eval.bench.calib_accuracy`,
``calib-wide`` :mod:`fuseflow.eval.bench.calib_wide`, ...); the programs in the source tree's
``benchmarks/`` folder are thin wrappers around the same functions.

Nothing here prints: report lines go to a ``log`` callback the caller chooses (the CLI and the
wrappers print them). This ``__init__`` imports nothing heavy.
"""

from __future__ import annotations

from fuseflow.errors import FuseFlowError

__all__ = ["BenchmarkFailed"]


class BenchmarkFailed(FuseFlowError):
    """A benchmark run failed part-way (for example a timed child process exited with an error)."""
