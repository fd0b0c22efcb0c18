"""``one_blas_thread()``: numpy's (and scipy's, OpenCV's) OpenBLAS on one thread for a block.

GMAC's arrays are small and thin: (M, 3) points times a 3x3 rotation, (M, 6) Jacobians, M a
few thousand to a few tens of thousands. OpenBLAS splits such products over its threads, and on
a loaded machine the threads cost more than they save: on the 2-core benchmark machine, with
other (niced) jobs running, (12 000, 3) x (3, 3) took 96 us on two threads and 48 on one,
(288 000, 3) x (3, 3) 67-93 ms against 3.9 ms, and the default ``calibrate`` of a simulated
8-camera ring 12-18 s against 9-13 s (docs/gmac.md, "Where the time goes"). This is
``fuseflow.geometry.one_torch_thread`` for numpy's BLAS.

No dependency: the OpenBLAS libraries already loaded into the process are found in
``/proc/self/maps`` and their ``*_set_num_threads`` called through ctypes (what threadpoolctl
does). Where none is found (another BLAS, another OS) the block runs unchanged. OpenBLAS splits
a product's output over threads, not its sums, so the thread count changes no result beyond
the last bits of a few reductions (the metric scale check moved by 6e-16).
"""

from __future__ import annotations

import ctypes
import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["one_blas_thread"]

#: (get, set) symbol pairs of OpenBLAS builds: upstream, 64-bit-integer, scipy's wheels.
_SYMBOLS = (
    ("openblas_get_num_threads", "openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
)

_lock = threading.Lock()
_depth = 0
_saved: list[tuple[object, int]] = []


def _openblas() -> list[tuple[object, object]]:
    """(get, set) of every OpenBLAS loaded into this process (empty when none is found)."""
    try:
        with open("/proc/self/maps") as f:
            paths = sorted({line.split()[-1] for line in f if "openblas" in line.rsplit("/", 1)[-1].lower()})
    except OSError:
        return []
    out = []
    for p in paths:
        try:
            lib = ctypes.CDLL(p, mode=getattr(os, "RTLD_NOLOAD", 0) | ctypes.RTLD_LOCAL)  # already loaded
        except OSError:
            continue
        for g, s in _SYMBOLS:
            get, set_ = getattr(lib, g, None), getattr(lib, s, None)
            if get is not None and set_ is not None:
                get.restype, set_.argtypes = ctypes.c_int, [ctypes.c_int]
                out.append((get, set_))
                break
    return out


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with every loaded OpenBLAS on one thread; the previous counts are restored
    when the outermost such block ends (nested blocks and threads share one count)."""
    global _depth
    with _lock:
        if _depth == 0:
            _saved.clear()
            for get, set_ in _openblas():
                n = int(get())
                if n > 1:
                    set_(1)
                    _saved.append((set_, n))
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                for set_, n in _saved:
                    set_(n)
                _saved.clear()
