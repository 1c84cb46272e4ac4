"""numpy's OpenBLAS set to one thread (cellctl.vision.runtime): found, set, and the products unchanged."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.vision.runtime import blas_threads, one_blas_thread


def test_one_blas_thread_sets_numpys_openblas_to_one_thread_with_the_same_products() -> None:
    if blas_threads() is None:
        pytest.skip("numpy here is not built on an OpenBLAS this process can find")
    rng = np.random.default_rng(0)
    points, matrix = rng.random((200_000, 4)) * 500, rng.random((4, 4))
    before = points @ matrix.T
    assert one_blas_thread()
    assert blas_threads() == 1
    assert np.array_equal(points @ matrix.T, before)
