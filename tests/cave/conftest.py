"""Fixtures of the cluster tests."""

import pytest

from cave_packets import FrameMaker


@pytest.fixture
def frame_maker():
    """Valid frames of a small rippling sheet and the state a node must hold after each."""
    return FrameMaker()
