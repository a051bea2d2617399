"""Shared fixtures: the Warp devices every kernel test runs on."""

import pytest
import warp as wp

wp.config.quiet = True
wp.config.log_level = wp.LOG_WARNING
wp.init()

DEVICES = ["cpu"] + (["cuda:0"] if wp.is_cuda_available() else [])


@pytest.fixture(params=DEVICES)
def device(request):
    """Each kernel test runs once per available Warp device (CPU always, CUDA when present)."""
    return request.param
