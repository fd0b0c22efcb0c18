"""The benchmarks the wheel ships, one module per ``fuseflow bench`` command: ``fuse``
(:mod:`fuseflow.eval.bench.fuse_speed`, FUSE and the baselines timed on this machine) and
``fuse-ratio`` (:mod:`fuseflow.eval.bench.fuse_ratio`, FUSE against VoxelBlockGrid on the user's
own recordings) and ``live`` (:mod:`fuseflow.eval.bench.live`, replayed recordings streamed with a
viewer; :mod:`fuseflow.eval.bench.live_nodes`, capture nodes on Ray against one host). The other
studies are programs of the source tree's ``benchmarks/``.

Nothing here prints: report lines go to a ``log`` callback the caller chooses. This ``__init__``
imports nothing heavy.
"""

from __future__ import annotations

from fuseflow.errors import FuseFlowError

__all__ = ["BenchmarkFailed"]


class BenchmarkFailed(FuseFlowError):
    """A benchmark run failed part-way (for example a timed child process exited with an error)."""
