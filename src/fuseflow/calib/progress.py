"""Progress of a GMAC run, reported to a callback the caller gives ``calibrate(..., progress=)``.

The library never prints: its stages call :func:`report` with (stage, done, total) and the
callback set by :func:`reporting` (a context variable, so nested stages need no extra argument)
decides what to show. ``total`` is 0 for a stage without countable steps (a start notice). With
no callback set, :func:`report` does nothing.

Stages reported: "<source>: cameras" (per camera prepared), "<source>: pairs" (per camera pair
registered), "<source>: scale" and "<source>: refinement" (starts), "joint refinement",
"depth agreement", "report". ``<source>`` is the backbone's name (``rgbd``, ``colmap``, ...).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from contextvars import ContextVar

__all__ = ["ProgressCallback", "report", "reporting"]

#: ``callback(stage, done, total)``: ``done`` of ``total`` steps of ``stage`` finished (total 0: started).
ProgressCallback = Callable[[str, int, int], None]

_callback: ContextVar[ProgressCallback | None] = ContextVar("fuseflow_calib_progress", default=None)


def report(stage: str, done: int = 0, total: int = 0) -> None:
    """Tell the caller's callback (if any) that ``done`` of ``total`` steps of ``stage`` are finished."""
    cb = _callback.get()
    if cb is not None:
        cb(stage, int(done), int(total))


@contextlib.contextmanager
def reporting(callback: ProgressCallback | None) -> Iterator[None]:
    """Within the block, :func:`report` calls ``callback`` (None: keeps the current one)."""
    if callback is None:
        yield
        return
    token = _callback.set(callback)
    try:
        yield
    finally:
        _callback.reset(token)
