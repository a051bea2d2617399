"""Device helpers: the OpenBLAS thread limit applies inside the block and is undone after."""

import numpy as np
import pytest

from softvr.device import _openblas_controls, single_threaded_blas


def test_single_threaded_blas_limits_and_restores_every_openblas():
    import scipy.linalg  # noqa: F401 - both wheels' OpenBLAS loaded

    controls = _openblas_controls()
    if not controls:
        pytest.skip("no OpenBLAS loaded (not Linux, or another BLAS): nothing to limit")
    before = [get() for get, _ in controls]
    with single_threaded_blas():
        assert [get() for get, _ in controls] == [1] * len(controls)
        a = np.random.default_rng(0).standard_normal((200, 200))
        np.testing.assert_allclose(a @ np.linalg.inv(a), np.eye(200), atol=1e-8)  # BLAS still works
    assert [get() for get, _ in controls] == before
