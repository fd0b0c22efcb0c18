"""``one_blas_thread()``: numpy's (and scipy's) BLAS on one thread for a block.

GMAC's arrays are small and thin: (M, 3) points times a 3x3 rotation, (M, 6) Jacobians, M a
few thousand to a few tens of thousands. OpenBLAS splits such products over its threads, and on
a loaded machine the threads cost more than they save: on the 2-core benchmark machine, with
other (niced) jobs running, (12 000, 3) x (3, 3) took 96 us on two threads and 48 on one,
(288 000, 3) x (3, 3) 67-93 ms against 3.9 ms, and the default ``calibrate`` of a simulated
8-camera ring 12-18 s against 9-13 s (the same ring timed with and without the limit). This is
``fuseflow.geometry.one_torch_thread`` for numpy's BLAS, done with threadpoolctl (the library
scikit-learn uses for the same job). A BLAS splits a product's output over threads, not its
sums, so the thread count changes no result beyond the last bits of a few reductions (the
metric scale check moved by 6e-16).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from threadpoolctl import threadpool_limits

__all__ = ["one_blas_thread"]


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the block with every BLAS loaded into the process on one thread; the previous counts
    are restored when the block ends, also when it raises (nested blocks restore in order)."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield
