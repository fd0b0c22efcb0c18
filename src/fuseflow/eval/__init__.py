"""Evaluation: metrics (DESIGN.md section 4) and baseline fusion methods.

Nothing in the product depends on this package. Import the submodules directly
(``fuseflow.eval.metrics``, ``fuseflow.eval.baselines``, or their aliases ``fuseflow.metrics``
and ``fuseflow.baselines``); this ``__init__`` imports nothing heavy.
"""
