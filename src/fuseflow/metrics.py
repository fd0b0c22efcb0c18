"""Alias of :mod:`fuseflow.eval.metrics` (the name issue 7 gives): evaluation metrics."""

from fuseflow.eval.metrics import *  # noqa: F403
from fuseflow.eval.metrics import __all__  # noqa: F401
