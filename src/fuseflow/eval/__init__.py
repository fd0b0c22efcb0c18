"""Evaluation: metrics (docs/design.md section 4), baseline fusion methods, the demo, the paper's
tables and the benchmark programs.

Nothing in the product depends on this package (it sits above the pipeline, beside the CLI).
Import the submodules directly (``fuseflow.eval.metrics``, ``fuseflow.eval.baselines``,
``fuseflow.eval.demo``, ``fuseflow.eval.paper``, ``fuseflow.eval.bench``); this ``__init__``
imports nothing heavy.
"""
