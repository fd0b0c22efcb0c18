"""Alias of :mod:`fuseflow.eval.baselines` (the name issue 7 gives): baseline fusion methods."""

from fuseflow.eval.baselines import *  # noqa: F403
from fuseflow.eval.baselines import __all__  # noqa: F401
