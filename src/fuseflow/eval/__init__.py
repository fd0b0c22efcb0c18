"""Evaluation a user runs: metrics (docs/metrics.md), the baseline fusion methods FUSE is
compared with, the simulator's reference surface, the demo, the benchmark results schema
(``fuseflow.eval.results``) and the benchmarks of ``fuseflow bench`` (``fuseflow.eval.bench``).

The studies behind the documented numbers are programs of the source tree's ``benchmarks/``,
outside the package. Nothing in the product depends on this package (it sits above the
pipeline, beside the CLI). Import the submodules directly (``fuseflow.eval.metrics``,
``fuseflow.eval.baselines``, ...); this ``__init__`` imports nothing heavy.
"""
