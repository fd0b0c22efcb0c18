"""``calib.blas.one_blas_thread``: BLAS on one thread inside the block, the previous counts
restored after it (also when it raises, and for nested blocks)."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

from fuseflow.calib import blas


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_sets_one_and_restores():
    np.ones((4, 3)) @ np.eye(3)  # numpy's BLAS is loaded
    if not _blas_threads():
        pytest.skip("no BLAS that threadpoolctl controls in this process: the block runs unchanged")
    with threadpool_limits(limits=2, user_api="blas"):  # as on a 2-core machine, whatever this one has
        with blas.one_blas_thread():
            assert set(_blas_threads()) == {1}
            with blas.one_blas_thread():  # nested: still one, and not restored by the inner block
                pass
            assert set(_blas_threads()) == {1}
            x = np.ones((20000, 3)) @ np.eye(3)  # numpy works inside
        assert set(_blas_threads()) == {2}
        with pytest.raises(RuntimeError), blas.one_blas_thread():
            raise RuntimeError("boom")
        assert set(_blas_threads()) == {2}
    assert x.shape == (20000, 3)
