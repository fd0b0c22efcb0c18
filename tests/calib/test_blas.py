"""``calib.blas.one_blas_thread``: OpenBLAS on one thread inside the block, the previous counts
restored after the outermost block (also when it raises)."""

from __future__ import annotations

import numpy as np
import pytest

from fuseflow.calib import blas


def test_one_blas_thread_sets_one_and_restores():
    libs = blas._openblas()
    if not libs:
        pytest.skip("no OpenBLAS loaded into this process (another BLAS): the block runs unchanged")
    get0, set0 = libs[0]
    before = int(get0())
    set0(2)  # as on a 2-core machine, whatever this one has
    try:
        with blas.one_blas_thread():
            assert [int(g()) for g, _ in libs][0] == 1
            with blas.one_blas_thread():  # nested: still one, and not restored by the inner block
                pass
            assert int(get0()) == 1
            x = np.ones((20000, 3)) @ np.eye(3)  # numpy works inside
        assert int(get0()) == 2
        with pytest.raises(RuntimeError), blas.one_blas_thread():
            raise RuntimeError("boom")
        assert int(get0()) == 2
    finally:
        set0(before)
    assert x.shape == (20000, 3)
